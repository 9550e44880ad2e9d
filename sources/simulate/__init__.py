"""An event-camera simulator with exact ground truth (``simulate:`` sources).

The DVS principle: each pixel's log intensity ``L = log(I + eps)`` is sampled
at adaptive time steps; a pixel fires when ``|L - L_ref| >= C`` (``C_on`` /
``C_off``), ``L_ref`` moves by ±C per event, several crossings in one step
give several events at linearly interpolated times (see :mod:`.dvs`,
:mod:`.sim`). Non-idealities come from a sensor model with presets
``ideal`` (none), ``realistic`` and ``noisy`` (see :mod:`.noise`); noise
events are labelled.

Python API::

    from tectum.sources.simulate import simulate
    events, truth = simulate("rotation", duration_us=200_000, seed=1, preset="realistic",
                             sensor="346x260")
    events["vx"], events["noise"], truth["pose_angular_velocity"]

Sources: ``simulate:NAME`` (a built-in scene, ``tectum simulate --list``),
``simulate:path/to/scene.toml``, or a video / image folder / ``images.txt``
(``simulate:clip.mp4?fps=30``, see :mod:`.video`), with parameters
``?duration_us=..&seed=..&preset=..&sensor=WxH&window_us=..``.

Speed: each step renders the frame once, at its end (a translating 2-D
texture with separable texel taps, a panorama with incremental ray angles);
one kernel then takes the log, refines alone the few pixels that changed
(or turned) too much on a finer grid of the step, and runs the DVS model
(see :mod:`.step`).

Event columns (besides t, x, y, p): ``vx``, ``vy`` (float32 px/s, true image
motion), ``lifetime`` (float32 µs: ``1e6 / normal speed``, the time the local
edge takes to move one pixel along the log-intensity gradient; inf when it
does not move), ``noise`` (uint8: 0 signal, 1 shot noise, 2 hot pixel,
3 leak), ``object_id`` (int16: 0 background/world, objects 1.., -1 noise).
Truth in time: see :class:`Truth` (kept on disk as it comes, memory stays
bounded) and :mod:`.features` (image positions of known points and corners).

Scene keys (a dict, or the same as TOML; lengths in pixels for image-plane
things, metres for the world; times in µs unless the name says otherwise):

``name``, ``description``; ``sensor`` [w, h] or "WxH" (default 346x260);
``fov_deg`` horizontal field of view (default 60) or ``focal_px``.

``background``: the image-plane background when there is no world:
``intensity`` (linear, 1 = full scale), ``texture`` (a texture spec, see
:mod:`.textures`), ``texel_px``, ``velocity`` [vx, vy] px/s (the texture
translates), ``log_slope`` 1/s (intensity times ``exp(slope t)``: a ramp).

``panorama``: a textured sphere at infinity: ``texture``, ``id``.
``planes``: list of textured planes: ``center`` [3] m, ``orientation`` [3]
rotation vector (the plane spans its local x, y axes; default faces the
camera), ``size`` [w, h] m (omit: unbounded), ``texture`` or ``intensity``,
``texel_m``, ``id``. ``boxes``: ``center``, ``size`` [3], ``orientation``,
``texture``/``intensity``, ``texel_m``, ``id``.

``motion``: the camera trajectory (see :mod:`.motion`): ``position``,
``velocity``, ``position_amplitude``, ``position_freq_hz``,
``position_phase``, ``orientation``, ``angular_velocity``,
``rotation_amplitude``, ``rotation_freq_hz``.

``objects``: image-plane shapes drawn over everything, in order:
``shape`` (disk, rect, bar, edge: the half-plane on the negative side of its
local x axis), ``position`` [x, y] px at t = 0, ``velocity`` [vx, vy] px/s,
``angle_deg``, ``angular_velocity`` rad/s (spin about the position),
``radius`` / ``size`` [w, h] px, ``intensity`` or ``texture`` + ``texel_px``,
``blink_hz``, ``blink_duty``, ``blink_rise_us``, ``blink_phase`` (cycles),
``intensity_off``, ``id``, ``bounce`` (true: the shape reflects off the
sensor's sides, so the scene lasts any duration; or a box [x0, y0, x1, y1]
px for its centre).

``sensor_model``: overrides of the preset's parameters (:class:`SensorModel`).
``davis``: APS frames and IMU (:mod:`.davis`). ``sim``: step limits
(``max_px_step``, ``max_dlog_frac``, ``max_bend_frac``, ``dt_max_us``,
``dt_min_us``, ``supersample``). ``duration_us``: the default duration.
``features``: world points [[x, y, z], ..] m whose image positions are
recorded (:mod:`.features`). ``video``: a video or image sequence as the
whole scene (``path``, ``fps``, ``gamma``, ``start_frame``: :mod:`.video`).
"""

from __future__ import annotations

from collections.abc import Iterator, Mapping
from typing import Any, ClassVar

from tectum import EventPacket, Kind, Packet, Source, concat
from tectum.hookspecs import hookimpl

from .davis import DavisConfig
from .noise import PRESETS, SensorModel, sensor_model
from .scenes import BUILTIN, load_scene, scene_names
from .sim import Simulator, Truth

__all__ = ["simulate", "SimulateSource", "Simulator", "Truth", "SensorModel", "PRESETS", "load_scene",
           "scene_names", "describe_scenes", "make_simulator"]


def make_simulator(scene: str | Mapping[str, Any], duration_us: int | None = None, *, seed: int = 0,
                   preset: str = "ideal", sensor: Any = None, truth_fps: float = 0.0,
                   pose_rate_hz: float = 1000.0, fps: float = 0.0, **model: Any) -> Simulator:
    """A :class:`Simulator` for a scene (name, TOML path, video / image
    folder / image list path, or dict); ``fps`` Hz overrides a video's frame
    rate; ``model`` keywords override the preset's parameters, on top of the
    scene's ``sensor_model`` section."""
    d = load_scene(scene, sensor, fps)
    m = sensor_model(preset, **{**d.get("sensor_model", {}), **model})
    dur = int(duration_us if duration_us is not None else d.get("duration_us", 1_000_000))
    return Simulator(d, m, dur, seed=seed, truth_fps=truth_fps, pose_rate_hz=pose_rate_hz)


def simulate(scene: str | Mapping[str, Any], duration_us: int | None = None, *, seed: int = 0,
             preset: str = "ideal", sensor: Any = None, window_us: int = 10_000, truth_fps: float = 0.0,
             pose_rate_hz: float = 1000.0, fps: float = 0.0, **model: Any) -> tuple[EventPacket, Truth]:
    """Simulate a whole run in memory: ``(events with truth columns, Truth)``.

    ``duration_us`` µs (default: the scene's, else 1 s); ``truth_fps`` Hz of
    dense truth maps (intensity, depth, flow, object id); other keywords as
    :func:`make_simulator`. For long runs stream with :class:`SimulateSource`.
    """
    sim = make_simulator(scene, duration_us, seed=seed, preset=preset, sensor=sensor, truth_fps=truth_fps,
                         pose_rate_hz=pose_rate_hz, fps=fps, **model)
    pkts = [ev for ev, _side in sim.windows(window_us)]
    ev = concat(pkts)
    assert isinstance(ev, EventPacket)
    return ev, sim.truth


def describe_scenes() -> dict[str, str]:
    """Built-in scene names and their one-line descriptions."""
    return {n: BUILTIN[n](346, 260).get("description", "") for n in scene_names()}


def _scene_spec(url: str) -> str:
    """The scene named by ``simulate:SCENE`` (default ``rotation``)."""
    return (url.split(":", 1)[1] if ":" in url else url).split("?", 1)[0] or "rotation"


class SimulateSource(Source):
    """Simulated events (``simulate:SCENE``) with truth columns, plus poses,
    APS frames and IMU as side streams when asked.

    Parameters (units): ``duration_us`` µs (default: the scene's, else 1 s);
    ``seed``; ``preset`` ideal | realistic | noisy; ``sensor`` "WxH" px;
    ``window_us`` µs per packet; ``poses`` emit PosePackets (with
    ``angular_velocity`` rad/s, ``velocity`` m/s) at ``pose_rate_hz``;
    ``davis`` emit the scene's APS frames and IMU; ``truth_columns`` attach
    vx, vy, lifetime, noise, object_id (else they are kept in :attr:`truth`
    as ``event_*`` arrays); ``truth_fps`` Hz of dense truth maps kept in
    :attr:`truth`; ``model`` overrides of the sensor-model parameters; ``scene`` a scene dict
    used instead of the URL's scene (Python use); ``fps`` Hz a video's frame
    rate (``simulate:clip.mp4?fps=30``; default: the container's).
    """

    name = "simulate"
    schemes = ("simulate",)
    produces: ClassVar[tuple[Kind, ...]] = (Kind.EVENTS, Kind.POSES, Kind.FRAMES, Kind.IMU)  # an instance narrows it

    @classmethod
    def kinds_for(cls, arg: str, params: Mapping[str, Any]) -> tuple[Kind, ...]:
        """Events, poses with ``poses``, and with ``davis`` the APS frames and
        IMU samples the scene's ``davis`` section asks for (ports are wired by
        these before the source opens)."""
        kinds = [Kind.EVENTS]
        if params.get("poses"):
            kinds.append(Kind.POSES)
        if params.get("davis"):
            spec: str | Mapping[str, Any] = params.get("scene") or _scene_spec(arg)
            scene = load_scene(spec, params.get("sensor"), float(params.get("fps", 0.0)))
            cfg = DavisConfig.from_spec(scene.get("davis"))
            kinds += [k for k, on in ((Kind.FRAMES, cfg.aps_rate_hz > 0), (Kind.IMU, cfg.imu_rate_hz > 0)) if on]
        return tuple(kinds)

    def __init__(self, url: str = "simulate:rotation", duration_us: int | None = None, seed: int = 0,
                 preset: str = "ideal", sensor: str | None = None, window_us: int = 10_000,
                 poses: bool = False, davis: bool = False, truth_columns: bool = True, truth_fps: float = 0.0,
                 pose_rate_hz: float = 1000.0, model: dict[str, float] | None = None,
                 scene: Mapping[str, Any] | None = None, fps: float = 0.0) -> None:
        spec: str | Mapping[str, Any] = scene if scene is not None else _scene_spec(url)
        if window_us <= 0:
            raise ValueError("window_us must be > 0")
        self.sim = make_simulator(spec, duration_us, seed=seed, preset=preset, sensor=sensor, truth_fps=truth_fps,
                                  pose_rate_hz=pose_rate_hz, fps=fps, **(model or {}))
        self.window_us = window_us
        self.truth_columns = truth_columns
        self.emit_poses, self.emit_davis = poses, davis
        kinds = [Kind.EVENTS]
        if poses:
            kinds.append(Kind.POSES)
        if davis and self.sim.davis.aps_rate_hz > 0:
            kinds.append(Kind.FRAMES)
        if davis and self.sim.davis.imu_rate_hz > 0:
            kinds.append(Kind.IMU)
        self.produces = tuple(kinds)  # type: ignore[misc]

    @property
    def truth(self) -> Truth:
        """Truth gathered so far (complete once :meth:`packets` is exhausted)."""
        return self.sim.truth

    def packets(self) -> Iterator[Packet]:
        for ev, side in self.sim.windows(self.window_us):
            if not self.truth_columns:
                self.sim.truth.add(**{f"event_{k}": v for k, v in ev.columns.items()})
                ev = ev.without_columns(*ev.columns)
            yield ev
            for pkt in side:
                if pkt.kind in self.produces:
                    yield pkt


@hookimpl
def tectum_register_sources(registry) -> None:  # type: ignore[no-untyped-def]
    registry.add_source(SimulateSource)
