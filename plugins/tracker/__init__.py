"""Family ``tracker``: the camera's motion from events: angular velocity by
contrast maximisation (``tracker.angular_velocity``) and ego-motion with a
model ladder that picks the simplest adequate motion model
(``tracker.ego_motion``); moving objects as event clusters
(``tracker.clusters``) and blinking LED markers with the pose of their body
(``tracker.led_markers``); the 6-DoF pose by aligning event images to
semi-dense maps (``tracker.edge_align``, EVO's tracker; ``tracker.evo``, a
macro, runs it in a loop with ``map.emvs``) and against a known
photometric map with the generative event model (``tracker.pose_6dof``)."""

from __future__ import annotations

from tectum.hookspecs import hookimpl

from .angular_velocity import AngularVelocity
from .clusters import Clusters
from .edge_align import EdgeAlign
from .ego_motion import EgoMotion, MotionModelPacket
from .evo import Evo
from .features import FeatureTracker
from .led_markers import LedMarkers
from .pose_6dof import Pose6Dof

__all__: list[str] = ["AngularVelocity", "EgoMotion", "MotionModelPacket", "FeatureTracker", "Clusters", "LedMarkers",
                     "EdgeAlign", "Pose6Dof", "Evo"]


@hookimpl
def tectum_register_operators(registry) -> None:  # type: ignore[no-untyped-def]
    registry.add_operator(AngularVelocity)
    registry.add_operator(EgoMotion)
    registry.add_operator(FeatureTracker)
    registry.add_operator(Clusters)
    registry.add_operator(LedMarkers)
    registry.add_operator(EdgeAlign)
    registry.add_operator(Pose6Dof)


@hookimpl
def tectum_register_macros(registry) -> None:  # type: ignore[no-untyped-def]
    registry.add_macro(Evo)


@hookimpl
def tectum_register_kinds(registry) -> None:  # type: ignore[no-untyped-def]
    registry.add_kind(MotionModelPacket)
