"""Live iniVation cameras over USB (pyusb): DVS128, DAVIS240 and DAVIS346
on FX2/FX3 boards, and an emulated camera backend for tests and demos."""

from __future__ import annotations

from tectum.hookspecs import hookimpl


@hookimpl
def tectum_register_sources(registry) -> None:  # type: ignore[no-untyped-def]
    from .source import UsbSource

    registry.add_source(UsbSource)
