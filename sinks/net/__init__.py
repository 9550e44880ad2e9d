"""Network sinks: send the event stream over TCP or UDP to a tectum
network source (``tcp://HOST:PORT``, ``udp://HOST:PORT``)."""

from __future__ import annotations

from tectum.hookspecs import hookimpl


@hookimpl
def tectum_register_sinks(registry) -> None:  # type: ignore[no-untyped-def]
    from .sink import NetSink

    registry.add_sink(NetSink)
