"""The core plugin: the ``.npz`` file source and sink and the built-in
moving-pattern source."""

from __future__ import annotations

from tectum.hookspecs import hookimpl


@hookimpl
def tectum_register_sources(registry) -> None:  # type: ignore[no-untyped-def]
    from tectum.sources.npz import NpzSource
    from tectum.sources.pattern import PatternSource

    registry.add_source(NpzSource)
    registry.add_source(PatternSource)


@hookimpl
def tectum_register_sinks(registry) -> None:  # type: ignore[no-untyped-def]
    from tectum.sinks.npz import NpzSink
    from tectum.sinks.null import NullSink

    registry.add_sink(NpzSink)
    registry.add_sink(NullSink)
