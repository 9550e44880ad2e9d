"""Network sources: tectum's own event stream over TCP and UDP, and the
AEDAT 4.0 network stream of iniVation's DV (``dv+tcp://``)."""

from __future__ import annotations

from tectum.hookspecs import hookimpl


@hookimpl
def tectum_register_sources(registry) -> None:  # type: ignore[no-untyped-def]
    from .dv import DvNetSource
    from .source import NetSource

    registry.add_source(NetSource)
    registry.add_source(DvNetSource)
