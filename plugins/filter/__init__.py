"""Family ``filter``: event filters (denoising, refractory, masks, geometry)."""

from __future__ import annotations

from tectum.hookspecs import hookimpl

from .refractory import Refractory

__all__ = ["Refractory"]


@hookimpl
def tectum_register_operators(registry) -> None:  # type: ignore[no-untyped-def]
    registry.add_operator(Refractory)
