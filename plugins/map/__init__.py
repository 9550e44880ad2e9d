"""Family ``map``: events (and the camera's motion) become maps: log-intensity
images (``map.high_pass``, ``map.complementary``), a panoramic mosaic under
pure rotation (``map.poisson_mosaic``) and semi-dense depth by event-based
multi-view stereo (``map.emvs``), and photometric maps (an intensity frame
with a depth map's depth, ``map.photometric``). Each emits :class:`tectum.MapPacket`s."""

from __future__ import annotations

from tectum.hookspecs import hookimpl

from .complementary import Complementary
from .emvs import Emvs
from .high_pass import HighPass
from .photometric import Photometric
from .poisson_mosaic import PoissonMosaic

__all__: list[str] = ["Complementary", "Emvs", "HighPass", "Photometric", "PoissonMosaic"]


@hookimpl
def tectum_register_operators(registry) -> None:  # type: ignore[no-untyped-def]
    registry.add_operator(HighPass)
    registry.add_operator(Complementary)
    registry.add_operator(PoissonMosaic)
    registry.add_operator(Emvs)
    registry.add_operator(Photometric)
