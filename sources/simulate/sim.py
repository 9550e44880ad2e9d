"""The simulation loop: adaptive steps, events with truth, windows out.

Time steps are chosen from the scene alone (never from the output windows),
so the stream is the same however it is cut: a step ``(t0, t1]`` is at most
``max_px_step`` pixels of image motion (a bound from the scene's true flow)
and at most ``dt_max_us``; every pixel is sampled so that its log intensity
changes by at most ``max_dlog_frac * min(c_on, c_off)`` (nominal) between
two samples: the frame is rendered at the step's end and the pixels that
changed more, or bent away from their previous slope by more than
``max_bend_frac`` of that, are refined alone on a finer grid of the step
(down to ``dt_min_us``), see :mod:`.step`.
A window ``[w0, w1)`` is released once the simulation has passed ``w1`` plus
the jitter margin; its events are sorted by timestamp, ties in generation
order.

Per-event truth is evaluated at the pixel centre at the end of the step that
made the event: ``vx``/``vy`` the true image motion (px/s), ``object_id``,
and ``lifetime`` in µs: the time the local edge takes to move one pixel,
``1e6 / |v . g/|g||`` with ``g`` the log-intensity gradient there (inf when the
normal speed is 0). Noise events have NaN truth and ``object_id = -1``.
"""

from __future__ import annotations

import math
from collections.abc import Iterator, Mapping
from dataclasses import dataclass
from typing import Any

import numpy as np

from tectum import EventPacket, FramePacket, ImuPacket, Packet, PosePacket

from .davis import DavisConfig, aps_frame, imu_samples
from .dvs import log_intensity
from .features import Features
from .noise import SHOT, NoiseSource, SensorModel, start_references, thresholds
from .order import time_order
from .render import lifetimes, probe, render
from .scenes import CompiledScene, compile_scene
from .step import NodeCache, advance
from .truth import Truth
from .video import FrameReader, VideoLayer

__all__ = ["Simulator", "Truth", "StepConfig"]

_DELTA_S = 1e-5
_MAX_LEV = 10  # at most 1024 sub-steps of a step for a pixel
_COLS = ("t", "i", "p", "vx", "vy", "lifetime", "noise", "object_id")


@dataclass(frozen=True)
class StepConfig:
    """Adaptive time-step limits (scene key ``sim``)."""

    max_px_step: float = 0.25    #: image motion per step, pixels
    max_dlog_frac: float = 0.5   #: log-intensity change per sample, fraction of min threshold
    max_bend_frac: float = 0.1   #: departure from the previous piece's line that refines a pixel, fraction of the above
    dt_max_us: float = 1000.0
    dt_min_us: float = 0.5

    @classmethod
    def from_spec(cls, spec: Mapping[str, Any] | None) -> StepConfig:
        spec = {k: float(v) for k, v in (spec or {}).items() if k != "supersample"}
        bad = set(spec) - set(cls.__dataclass_fields__)
        if bad:
            raise ValueError(f"unknown sim keys {sorted(bad)}; known: supersample, {sorted(cls.__dataclass_fields__)}")
        return cls(**spec)


class Simulator:
    """One simulation run (see the module docstring).

    Parameters: ``scene`` a scene dict (from :func:`load_scene`); ``model``
    the sensor model; ``duration_us`` µs; ``seed``; ``truth_fps`` Hz of
    truth maps (0: none); ``pose_rate_hz`` Hz of pose samples (0: none).
    """

    def __init__(self, scene: Mapping[str, Any], model: SensorModel, duration_us: int, seed: int = 0,
                 truth_fps: float = 0.0, pose_rate_hz: float = 1000.0) -> None:
        if duration_us <= 0:
            raise ValueError("duration_us must be > 0")
        self.cs: CompiledScene = compile_scene(scene)
        self.model = model
        self.cfg = StepConfig.from_spec(scene.get("sim"))
        self.davis = DavisConfig.from_spec(scene.get("davis"))
        self.T = float(duration_us)
        self.seed = int(seed) & 0x7FFFFFFF
        w, h = self.cs.sensor
        self.W, self.H, self.npix = w, h, w * h
        self.truth_fps, self.pose_rate_hz = float(truth_fps), float(pose_rate_hz)
        dt_max = self.cfg.dt_max_us
        if self.cs.max_blink_hz > 0:  # never step over a whole blink phase
            dt_max = min(dt_max, 0.25 * self.cs.min_blink_duty / self.cs.max_blink_hz * 1e6)
        self.dt_max = dt_max
        self.c_on, self.c_off = thresholds(model, self.npix, self.seed)
        self.max_dlog = self.cfg.max_dlog_frac * min(model.c_on, model.c_off)
        self.max_bend = self.cfg.max_bend_frac * self.max_dlog
        self.noise = NoiseSource(model, (w, h), self.seed)
        self.rng_jitter = np.random.default_rng([self.seed, 104])
        self.rng_aps = np.random.default_rng([self.seed, 105])
        self.rng_imu = np.random.default_rng([self.seed, 106])
        self._img = np.empty((h, w))
        self.video: VideoLayer | None = None
        if self.cs.video is not None:
            v = self.cs.video
            self.video = VideoLayer(FrameReader(v["path"], float(v.get("fps", 0.0)), float(v.get("gamma", 1.0)),
                                                int(v.get("start_frame", 0)), (w, h)), model.eps)
        self.lp = self.render(0.0).ravel().copy()
        self.L = np.empty(self.npix)
        log_intensity(self.lp, model.eps, self.L, self.lp)
        self.l_ref = start_references(self.L, self.c_on, self.c_off, model.ref_spread, self.seed)
        self.slope = np.zeros(self.npix)  # log intensity per µs over each pixel's last sampled piece
        self.t_release = np.full(self.npix, -np.inf)
        self.t = 0.0
        self.steps = 0
        self.refined = 0  #: pixel-steps refined alone (see :mod:`.step`)
        self._nodes = NodeCache(_MAX_LEV, self.cs.patches.shape[0], self.cs.sprites.shape[0])
        cap = 1 << 16
        self._ot, self._oi, self._op = np.empty(cap), np.empty(cap, np.int64), np.empty(cap, np.int8)
        self._pending: list[dict[str, np.ndarray]] = []
        gy, gx = np.mgrid[0:h, 0:w]
        self._gx = gx.ravel().astype(np.int64)
        self._gy = gy.ravel().astype(np.int64)
        cgx = np.unique(np.linspace(0, w - 1, 9).round().astype(np.int64))
        cgy = np.unique(np.linspace(0, h - 1, 7).round().astype(np.int64))
        self._cx, self._cy = (a.ravel() for a in np.meshgrid(cgx, cgy))
        self.truth = Truth(meta={"camera": np.array([self.cs.f, self.cs.cx, self.cs.cy]),
                                 "sensor": np.array([w, h]), "duration_us": np.array(int(self.T)),
                                 "seed": np.array(self.seed)})
        self.features = Features(self.cs, scene)
        if self.features.count:
            self.truth.meta.update(feature_object_id=self.features.object_id,
                                   feature_world=self.features.world_points)

    # -- the scene ----------------------------------------------------------------
    def pose(self, t_s: float) -> tuple[np.ndarray, np.ndarray]:
        return self.cs.trajectory.pose(t_s)

    def render(self, t_us: float) -> np.ndarray:
        """The true linear intensity image (H, W) at ``t_us`` (a view of a
        reused buffer: copy to keep)."""
        cs = self.cs
        if self.video is not None:
            self.video.render(t_us, self._img)
            return self._img
        R, p = self.pose(t_us * 1e-6)
        render(self._img, t_us * 1e-6, R, p, cs.f, cs.cx, cs.cy, cs.patches, cs.pano, cs.bg, cs.sprites,
               cs.tex_data, cs.tex_table, cs.supersample)
        return self._img

    def probe(self, xs: np.ndarray, ys: np.ndarray, t_us: float) -> tuple[np.ndarray, ...]:
        """True ``(vx, vy, object_id, depth)`` at pixels at ``t_us``."""
        cs, t = self.cs, t_us * 1e-6
        n = xs.shape[0]
        if self.video is not None:  # the motion in a video is not known
            return np.full(n, np.nan), np.full(n, np.nan), np.zeros(n, np.int64), np.full(n, np.nan)
        vx, vy, depth = np.empty(n), np.empty(n), np.empty(n)
        oid = np.empty(n, np.int64)
        traj = cs.trajectory
        R, p = self.pose(t)
        if traj.static or not cs.has_world:
            Ra, pa, Rb, pb = R, p, R, p
        else:
            Ra, pa = self.pose(t - _DELTA_S)
            Rb, pb = self.pose(t + _DELTA_S)
        probe(xs, ys, t, R, p, Ra, pa, Rb, pb, _DELTA_S, cs.f, cs.cx, cs.cy, cs.patches, cs.pano, cs.bg,
              cs.sprites, vx, vy, oid, depth)
        return vx, vy, oid, depth

    def max_flow(self, t_us: float) -> float:
        """A bound on the image speed (px/s) at ``t_us``."""
        cs = self.cs
        best = 0.0
        if self.video is not None:
            return 0.0
        if cs.has_world or cs.bg[3] or cs.bg[4]:
            vx, vy, _, _ = self.probe(self._cx, self._cy, t_us)
            best = 1.5 * float(np.sqrt(vx * vx + vy * vy).max())
        if cs.sprites.shape[0]:
            s = cs.sprites
            diag = math.hypot(self.W, self.H)
            reach = np.where(s[:, 0] == 2, diag, np.hypot(s[:, 7], s[:, 8]) + 2)
            best = max(best, float((np.hypot(s[:, 3], s[:, 4]) + np.abs(s[:, 6]) * reach).max()))
        return best

    # -- stepping -----------------------------------------------------------------
    def step(self) -> None:
        """Advance one step and queue its events: the frame is rendered once
        at the step's end, pixels that change too fast are refined alone
        (see :mod:`.step`)."""
        t0, cfg, cs, m = self.t, self.cfg, self.cs, self.model
        dt = min(self.dt_max, self.T - t0)
        mf = self.max_flow(t0)
        if mf > 0:
            dt = min(dt, cfg.max_px_step / mf * 1e6)
        dt = max(dt, min(cfg.dt_min_us, self.T - t0))
        t1 = t0 + dt if self.T - (t0 + dt) > 1e-6 else self.T
        nlev = int(min(_MAX_LEV, max(0, math.floor(math.log2(max((t1 - t0) / cfg.dt_min_us, 1.0))))))
        if self.video is not None:  # never across a frame time: L is linear in t between frames
            t1 = min(t1, self.video.next_frame_after(t0))
            nlev = 0
        img = self.render(t1).ravel()
        nc = self._nodes
        nc.reset()
        start, parts = 0, []
        while True:
            n, start, refined = advance(
                img, self.W, self.L, self.lp, self.slope, t0, t1, m.eps, m.lowpass_hz, m.lowpass_min_hz, self.max_dlog,
                self.max_bend, nlev,
                self.l_ref, self.t_release, self.c_on, self.c_off, m.refractory_us,
                cs.trajectory.params, cs.f, cs.cx, cs.cy, cs.patches, cs.pano, cs.bg, cs.sprites, cs.tex_data,
                cs.tex_table, cs.supersample, nc.t, nc.R, nc.p, nc.pc, nc.st, nc.g, nc.done, nc.seg_t, nc.seg_L,
                start, self._ot, self._oi, self._op)
            self.refined += refined
            parts.append((self._ot[:n].copy(), self._oi[:n].copy(), self._op[:n].copy()))
            if start >= self.npix:
                break
            cap = 2 * self._ot.shape[0]
            self._ot, self._oi, self._op = np.empty(cap), np.empty(cap, np.int64), np.empty(cap, np.int8)
        chunk = self._events(t0, t1, parts)
        self.t = t1
        self.steps += 1
        if chunk is not None:
            self._pending.append(chunk)

    def _events(self, t0: float, t1: float,
                parts: list[tuple[np.ndarray, np.ndarray, np.ndarray]]) -> dict[str, np.ndarray] | None:
        m = self.model
        ts, idx, pol = ((np.concatenate([p[k] for p in parts]) if len(parts) > 1 else parts[0][k]) for k in range(3))
        nt, ni, npol, u, lab = self.noise.take(t0, t1)
        if lab.size:
            img = self._img.ravel()
            keep = (lab != SHOT) | (u * self.noise.rate_max < self.noise.shot_rate(img[ni]))
            nt, ni, npol, lab = nt[keep], ni[keep], npol[keep], lab[keep]
        if ts.size == 0 and nt.size == 0:
            return None
        xs, ys = idx % self.W, idx // self.W
        vx, vy, oid, _ = self.probe(xs, ys, t1)
        life = np.empty(idx.size)
        lifetimes(self.L.reshape(self.H, self.W), xs, ys, vx, vy, life)
        k = nt.size
        t = np.concatenate([ts, nt])
        if m.jitter_us > 0:
            t = t + np.minimum(np.abs(self.rng_jitter.standard_normal(t.size)) * m.jitter_us, 4 * m.jitter_us)
        nan = np.full(k, np.nan, np.float32)
        return {"t": np.floor(t).astype(np.int64), "i": np.concatenate([idx, ni]),
                "p": np.concatenate([pol, npol]),
                "vx": np.concatenate([vx.astype(np.float32), nan]),
                "vy": np.concatenate([vy.astype(np.float32), nan]),
                "lifetime": np.concatenate([life.astype(np.float32), nan]),
                "noise": np.concatenate([np.zeros(idx.size, np.uint8), lab]),
                "object_id": np.concatenate([oid.astype(np.int16), np.full(k, -1, np.int16)])}

    # -- windows ------------------------------------------------------------------
    def _release(self, w0: int, w1: int) -> EventPacket:
        if self._pending:
            cat = {c: np.concatenate([ch[c] for ch in self._pending]) for c in _COLS}
            order = time_order(cat["t"])
            cat = {c: a[order] for c, a in cat.items()}
            j = int(np.searchsorted(cat["t"], w1, side="left"))
            rest = {c: a[j:] for c, a in cat.items()}
            self._pending = [rest] if j < cat["t"].size and w1 < self.T else []
            out = {c: a[:j] for c, a in cat.items()}
        else:
            out = {c: np.empty(0, np.int64) for c in _COLS}
        i = out["i"]
        return EventPacket(
            np.ascontiguousarray(out["t"], np.int64), (i % self.W).astype(np.uint16), (i // self.W).astype(np.uint16),
            out["p"].astype(np.int8), sensor=(self.W, self.H), t_start=w0, t_end=w1,
            columns={"vx": out["vx"].astype(np.float32), "vy": out["vy"].astype(np.float32),
                     "lifetime": out["lifetime"].astype(np.float32), "noise": out["noise"].astype(np.uint8),
                     "object_id": out["object_id"].astype(np.int16)})

    @staticmethod
    def _ticks(rate_hz: float, w0: int, w1: int, offset_us: float = 0.0) -> np.ndarray:
        """Sample times k / rate (+ offset) in [w0, w1), integer µs."""
        if rate_hz <= 0:
            return np.empty(0, np.int64)
        period = 1e6 / rate_hz
        k0 = math.ceil((w0 - offset_us) / period - 1e-9)
        k1 = math.ceil((w1 - offset_us) / period - 1e-9)
        t = np.floor(np.arange(max(k0, 0), max(k1, 0)) * period + offset_us).astype(np.int64)
        return t[(t >= w0) & (t < w1)]

    def _side(self, w0: int, w1: int) -> list[Packet]:
        out: list[Packet] = []
        traj = self.cs.trajectory
        tp = self._ticks(self.pose_rate_hz, w0, w1)
        if self.pose_rate_hz > 0:
            ts = tp * 1e-6
            pos = traj.position(ts).reshape(-1, 3)
            quat = traj.rotation(ts).as_quat().reshape(-1, 4) if ts.size else np.empty((0, 4))
            om = traj.angular_velocity(ts).reshape(-1, 3) if ts.size else np.empty((0, 3))
            vel = traj.velocity(ts).reshape(-1, 3)
            out.append(PosePacket(tp, position=pos, orientation=quat, angular_velocity=om, velocity=vel,
                                  t_start=w0, t_end=w1))
            self.truth.add(pose_t=tp, pose_position=pos, pose_orientation=quat, pose_angular_velocity=om,
                           pose_velocity=vel)
            if self.features.count:
                self.truth.add(feature_t=tp, feature_xy=self.features.positions(traj, tp))
        for tf in self._ticks(self.truth_fps, w0, w1):
            img = self.render(float(tf)).copy()
            vx, vy, oid, depth = self.probe(self._gx, self._gy, float(tf))
            hw = (1, self.H, self.W)
            self.truth.add(frame_t=[tf], frame_intensity=img.astype(np.float32)[None],
                           frame_depth=depth.reshape(hw).astype(np.float32),
                           frame_vx=vx.reshape(hw).astype(np.float32), frame_vy=vy.reshape(hw).astype(np.float32),
                           frame_object_id=oid.reshape(hw).astype(np.int16))
        d = self.davis
        if d.aps_rate_hz > 0:
            tm = self._ticks(d.aps_rate_hz, w0, w1, offset_us=0.5 * d.exposure_us)
            frames, starts = [], []
            for t_mid in tm:
                ts0 = float(t_mid) - 0.5 * d.exposure_us
                frames.append(aps_frame(lambda tu: self.render(tu), self.max_flow, ts0, d, self.rng_aps))
                starts.append(int(round(ts0)))
            imgs = np.stack(frames) if frames else np.empty((0, self.H, self.W), np.uint8)
            es = np.array(starts, np.int64)
            ee = es + int(round(d.exposure_us))
            out.append(FramePacket(tm, images=imgs, exposure_start=es, exposure_end=ee, t_start=w0, t_end=w1))
            self.truth.add(aps_t=tm, aps_images=imgs, aps_exposure_start=es, aps_exposure_end=ee)
        if d.imu_rate_hz > 0:
            ti = self._ticks(d.imu_rate_hz, w0, w1)
            acc, gyr = imu_samples(traj, ti, d, self.rng_imu)
            out.append(ImuPacket(ti, accel=acc, gyro=gyr, t_start=w0, t_end=w1))
            self.truth.add(imu_t=ti, imu_accel=acc, imu_gyro=gyr)
        return out

    def windows(self, window_us: int) -> Iterator[tuple[EventPacket, list[Packet]]]:
        """Run to the end; yield each window's events and side packets
        (poses, APS frames, IMU) covering ``[w0, w1)`` µs."""
        if window_us <= 0:
            raise ValueError("window_us must be > 0")
        margin = self.model.jitter_margin_us() + 1
        T = int(self.T)
        for w0 in range(0, T, window_us):
            w1 = min(w0 + window_us, T)
            goal = min(float(w1 + margin), self.T)
            while self.t < goal:
                self.step()
            yield self._release(w0, w1), self._side(w0, w1)
            if self.video is not None:
                self.video.forget_before(w1 - self.davis.exposure_us)
