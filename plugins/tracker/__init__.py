"""Family ``tracker``: the camera's motion from events: angular velocity by
contrast maximisation (``tracker.angular_velocity``) and ego-motion with a
model ladder that picks the simplest adequate motion model
(``tracker.ego_motion``)."""

from __future__ import annotations

from tectum.hookspecs import hookimpl

from .angular_velocity import AngularVelocity
from .ego_motion import EgoMotion, MotionModelPacket
from .features import FeatureTracker

__all__: list[str] = ["AngularVelocity", "EgoMotion", "MotionModelPacket", "FeatureTracker"]


@hookimpl
def tectum_register_operators(registry) -> None:  # type: ignore[no-untyped-def]
    registry.add_operator(AngularVelocity)
    registry.add_operator(EgoMotion)
    registry.add_operator(FeatureTracker)


@hookimpl
def tectum_register_kinds(registry) -> None:  # type: ignore[no-untyped-def]
    registry.add_kind(MotionModelPacket)
