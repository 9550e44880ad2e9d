"""Network sinks: send the event stream over TCP or UDP to a tectum
network source (``tcp://HOST:PORT``, ``udp://HOST:PORT``), or serve it as
iniVation's AEDAT 4.0 network stream (``dv+tcp://HOST:PORT``)."""

from __future__ import annotations

from tectum.hookspecs import hookimpl


@hookimpl
def tectum_register_sinks(registry) -> None:  # type: ignore[no-untyped-def]
    from .dv import DvNetSink
    from .sink import NetSink

    registry.add_sink(NetSink)
    registry.add_sink(DvNetSink)
