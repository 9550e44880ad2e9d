"""Network sources: tectum's own event stream over TCP and UDP."""

from __future__ import annotations

from tectum.hookspecs import hookimpl


@hookimpl
def tectum_register_sources(registry) -> None:  # type: ignore[no-untyped-def]
    from .source import NetSource

    registry.add_source(NetSource)
