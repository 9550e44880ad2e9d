"""Family ``map``: events (and the camera's motion) become maps: log-intensity
images (``map.high_pass``, ``map.complementary``), a panoramic mosaic under
pure rotation (``map.poisson_mosaic``) and semi-dense depth by event-based
multi-view stereo (``map.emvs``). Each emits :class:`tectum.MapPacket`s."""

from __future__ import annotations

from tectum.hookspecs import hookimpl

from .complementary import Complementary
from .emvs import Emvs
from .high_pass import HighPass
from .poisson_mosaic import PoissonMosaic

__all__: list[str] = ["Complementary", "Emvs", "HighPass", "PoissonMosaic"]


@hookimpl
def tectum_register_operators(registry) -> None:  # type: ignore[no-untyped-def]
    registry.add_operator(HighPass)
    registry.add_operator(Complementary)
    registry.add_operator(PoissonMosaic)
    registry.add_operator(Emvs)
