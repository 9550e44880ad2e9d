"""tracker.clusters: the kernel against a slow reference written from the
module's description, accuracy against the simulator's object positions,
output cadence and its resumption, parameter checks, empty input, and the
command line (CSV out, read back by ``tectum info``)."""

from __future__ import annotations

import math
import subprocess
import sys
from functools import lru_cache

import numpy as np
import pytest

from tectum import ClusterPacket, EventPacket, concat
from tectum.evaluation.metrics.tracking import track_scores
from tectum.plugins.filter.background_activity import BackgroundActivity
from tectum.plugins.tracker import Clusters
from tectum.plugins.tracker.clusters import track_clusters
from tectum.sources.simulate import simulate
from tectum.sources.simulate.objects import moving_objects, object_truth
from tectum.testing import event_by_event, feed

GROW = 1.5


class _Ref:
    """The tracker as plain Python, one event at a time (a dict per cluster
    in a list; a removal moves the last cluster into the hole, as in the
    kernel's array, so that ties go to the same cluster)."""

    def __init__(self, radius=14.0, max_radius=20.0, K=16, mix=0.05, tau=10_000.0, min_mass=30.0, prune=0.5,
                 update=1000, vel_dt=1000.0, vel_tau=10_000.0, merge=1.0, predict=True):
        self.__dict__.update(locals())
        self.cl: list[dict] = []
        self.next_id, self.T = 1, None
        self.rows: list[tuple] = []

    def _cap(self, c):
        lo, hi = self.radius ** 2, self.max_radius ** 2
        c["rx"] = min(hi, max(lo, 3 * GROW * GROW * c["vx2"]))
        c["ry"] = min(hi, max(lo, 3 * GROW * GROW * c["vy2"]))

    def _remove(self, c):
        i = next(j for j, o in enumerate(self.cl) if o is c)
        self.cl[i] = self.cl[-1]
        self.cl.pop()

    def _mass(self, c, t):
        return c["m"] * math.exp(-(t - c["t"]) / self.tau)

    def _emit(self, T):
        seen = False
        for c in self.cl:
            if c["id"] >= 0 and self._mass(c, T) >= self.min_mass - 1e-9:
                seen = True
                self.rows.append((T, c["id"], c["x"], c["y"], c["v"][0], c["v"][1], math.sqrt(12 * c["vx2"]),
                                  math.sqrt(12 * c["vy2"]), self._mass(c, T)))
        return seen

    def event(self, t, x, y):
        if self.update:
            if self.T is None:
                self.T = math.ceil(t / self.update) * self.update
            while self.T < t:
                seen = self._emit(self.T)
                self.T = self.T + self.update if seen else max(self.T + self.update, math.ceil(t / self.update) * self.update)
        k = 0
        while k < len(self.cl):
            if self._mass(self.cl[k], t) < self.prune:
                self._remove(self.cl[k])
            else:
                k += 1
        near = [(max(abs(x - c["x"]), abs(y - c["y"])), i) for i, c in enumerate(self.cl)
                if (x - c["x"]) ** 2 <= c["rx"] and (y - c["y"]) ** 2 <= c["ry"]]
        if not near:
            if len(self.cl) == self.K:
                fresh = [c for c in self.cl if c["id"] < 0]
                if not fresh:
                    return
                self._remove(min(fresh, key=lambda c: c["t"]))
            c = {"x": x, "y": y, "v": [0.0, 0.0], "m": 1.0, "t": t, "ref": (x, y, t), "nv": 0, "id": -1,
                 "vx2": self.radius ** 2 / (3 * GROW * GROW)}
            c["vy2"] = c["vx2"]
            self.cl.append(c)
            merge_now = True
        else:
            c = self.cl[min(near)[1]]
            gap = t - c["t"]
            c["m"] = self._mass(c, t) + 1
            if self.predict:
                c["x"] += c["v"][0] * gap * 1e-6
                c["y"] += c["v"][1] * gap * 1e-6
            dx, dy = x - c["x"], y - c["y"]
            c["x"] += self.mix * dx
            c["y"] += self.mix * dy
            c["vx2"] += self.mix * (dx * dx - c["vx2"])
            c["vy2"] += self.mix * (dy * dy - c["vy2"])
            c["t"] = t
            merge_now = False
            rx, ry, rt = c["ref"]
            if t - rt >= self.vel_dt:
                inst = [(c["x"] - rx) / ((t - rt) * 1e-6), (c["y"] - ry) / ((t - rt) * 1e-6)]
                a = 1.0 if c["nv"] == 0 else (t - rt) / (t - rt + self.vel_tau)
                c["v"] = [v + a * (i - v) for v, i in zip(c["v"], inst)]
                c["nv"] += 1
                c["ref"] = (c["x"], c["y"], t)
                merge_now = True
        self._cap(c)
        while merge_now:
            merge_now = False
            for o in self.cl:
                if o is c:
                    continue
                f2 = self.merge ** 2
                if (o["x"] - c["x"]) ** 2 <= f2 * max(o["rx"], c["rx"]) and (o["y"] - c["y"]) ** 2 <= f2 * max(o["ry"], c["ry"]):
                    mc, mo = self._mass(c, t), self._mass(o, t)
                    a, b = (c, o) if mc >= mo else (o, c)
                    if a["id"] < 0 or 0 <= b["id"] < a["id"]:
                        a["id"] = b["id"]
                    w = min(mc, mo) / (mc + mo)
                    for k in ("x", "y", "vx2", "vy2"):
                        a[k] += w * (b[k] - a[k])
                    a["v"] = [va + w * (vb - va) for va, vb in zip(a["v"], b["v"])]
                    a["m"], a["t"] = mc + mo, t
                    self._cap(a)
                    self._remove(b)
                    c, merge_now = a, True
                    break
        if c["id"] < 0 and c["m"] >= self.min_mass:
            c["id"] = self.next_id
            self.next_id += 1
        if not self.update and c["id"] >= 0:
            self.rows.append((t, c["id"], c["x"], c["y"], c["v"][0], c["v"][1], math.sqrt(12 * c["vx2"]),
                              math.sqrt(12 * c["vy2"]), c["m"]))

    def finish(self, watermark):
        while self.update and self.T is not None and self.T < watermark:
            if not self._emit(self.T):
                break
            self.T += self.update


def _blobs(n_events: int = 6000, seed: int = 0) -> EventPacket:
    """Two blobs crossing each other, one resting, and uniform noise, on 64x48."""
    rng = np.random.default_rng(seed)
    t = np.sort(rng.integers(0, 60_000, n_events))
    k = rng.integers(0, 4, n_events)
    cx = np.select([k == 0, k == 1, k == 2], [8 + t * 8e-4, 56 - t * 8e-4, 32 + 0 * t], rng.uniform(0, 63, n_events))
    cy = np.select([k == 0, k == 1, k == 2], [20 + 0 * t, 26 + 0 * t, 40 + 0 * t], rng.uniform(0, 47, n_events))
    x = np.clip(np.round(cx + rng.normal(0, 2.5, n_events) * (k < 3)), 0, 63)
    y = np.clip(np.round(cy + rng.normal(0, 2.5, n_events) * (k < 3)), 0, 47)
    return EventPacket.from_arrays(t, x, y, np.ones(n_events), sensor=(64, 48), t_start=0, t_end=60_000)


def _rows(pkts) -> np.ndarray:
    out = concat([q for q in pkts if isinstance(q, ClusterPacket)])
    return np.stack([out.t, out["id"], out["x"], out["y"], out["vx"], out["vy"], out["width"], out["height"],
                     out["mass"]], axis=1)


@pytest.mark.parametrize("params", [
    {}, {"update_us": 0}, {"update_us": 250, "predict": False}, {"max_clusters": 4, "radius_px": 6.0, "max_radius_px": 9.0, "min_mass": 15.0},
    {"merge": 0.0, "mix": 0.2, "min_mass": 10.0, "tau_us": 3000},
])
def test_kernel_matches_the_slow_reference(params):
    ev = _blobs()
    op = Clusters(**params)
    got = _rows(feed(op, [ev]))
    names = {"radius_px": "radius", "max_radius_px": "max_radius", "max_clusters": "K", "tau_us": "tau",
             "update_us": "update"}
    ref = _Ref(**{names.get(k, k): v for k, v in params.items()})
    for t, x, y in zip(ev.t, ev.x, ev.y):
        ref.event(float(t), float(x), float(y))
    ref.finish(ev.t_end)
    want = np.array(ref.rows)
    want = want[np.lexsort((want[:, 1], want[:, 0]))]
    assert len(got) > 20 and got.shape == want.shape, (got.shape, want.shape)
    np.testing.assert_array_equal(got[:, :2], want[:, :2])
    np.testing.assert_allclose(got[:, 2:], want[:, 2:], rtol=1e-6, atol=1e-6)
    assert op.counts["seeded"] > 3
    if params.get("max_clusters"):
        assert op.counts["evicted"] > 0


@lru_cache(maxsize=1)
def _scene() -> tuple[dict, EventPacket]:
    """Three disks at 300 px/s for 0.4 s (realistic sensor), denoised as the
    operator's docstring advises."""
    sc = moving_objects(3, sensor=(160, 120), speed_px_s=300.0, seed=2)
    ev, _ = simulate(sc, 400_000, seed=1, preset="realistic")
    return sc, BackgroundActivity(dt_us=3000).process(ev)[0]


def test_follows_simulated_objects():
    sc, ev = _scene()
    out = track_clusters(ev)
    _, xy, v = object_truth(sc, out.t)
    s = track_scores(out.t, out["id"], out["x"], out["y"], xy, gate_px=10.0)
    assert s["median_px"] < 1.5 and s["p90_px"] < 3.5, s
    assert s["coverage"] > 0.9 and s["false_rows"] < 0.02 * s["rows"], s
    assert s["id_switches"] <= 10, s  # the disks cross each other several times
    # velocities of rows within 3 px of an object: its speed (300 px/s) within 15 % at the median,
    # the vector error (noise of 1 ms displacement samples, low-passed over 10 ms) under 35 %
    d = np.linalg.norm(xy - np.stack([out["x"], out["y"]], 1)[:, None], axis=2)
    k = np.argmin(d, axis=1)
    ok = d[np.arange(len(k)), k] < 3
    est = np.stack([out["vx"], out["vy"]], 1)[ok]
    err = np.linalg.norm(v[np.arange(len(k)), k][ok] - est, axis=1)
    assert abs(np.median(np.linalg.norm(est, axis=1)) - 300) < 45 and np.median(err) < 105, np.median(err)


def test_rows_come_every_update_us_and_per_event_with_zero():
    ev = _blobs()
    grid = track_clusters(ev, update_us=500)
    assert len(grid) and np.all(grid.t % 500 == 0)
    per_event = track_clusters(ev, update_us=0)
    assert np.isin(per_event.t, ev.t).all() and len(per_event) > 10 * len(np.unique(grid.t))
    # the first row of a cluster comes with the event that makes it visible: no delay
    first = per_event.t[0]
    assert grid.t[0] - first < 500


def test_many_output_times_in_one_packet_resume_where_they_stopped():
    """A tick far ahead and a fine grid overflow one output buffer: the rows
    are those of the stream fed event by event."""
    ev = _blobs()
    op = lambda: Clusters(update_us=5, tau_us=200_000, min_mass=5.0)  # noqa: E731
    whole = _rows(feed(op(), [ev]))
    one = _rows(feed(op(), event_by_event(ev)))
    assert len(whole) > 64 * 16 and np.array_equal(whole, one)


def test_bad_parameters_are_named():
    with pytest.raises(ValueError, match="radius_px"):
        Clusters(radius_px=0)
    with pytest.raises(ValueError, match="max_radius_px"):
        Clusters(radius_px=20, max_radius_px=10)
    with pytest.raises(ValueError, match="prune_mass < min_mass"):
        Clusters(prune_mass=40)
    with pytest.raises(ValueError, match="mix"):
        Clusters(mix=1.5)


def test_empty_packets_and_ticks_give_nothing():
    op = Clusters()
    empty = EventPacket.from_arrays([], [], [], [], sensor=(8, 8), t_start=0, t_end=10_000)
    assert op.process(empty) == [] and op.on_tick(10_000) == () and op.finish() == ()
    assert len(track_clusters(empty)) == 0


def test_from_the_command_line_to_csv_and_back(tmp_path):
    csv = tmp_path / "c.csv"
    run = subprocess.run([sys.executable, "-m", "tectum", "run",
                          "simulate:shapes?duration_us=150000&sensor=96x72", "--op", "tracker.clusters:radius_px=10",
                          "--sink", str(csv)], capture_output=True, text=True)
    assert run.returncode == 0, run.stderr
    head = csv.read_text().splitlines()[:2]
    assert head[0].startswith("# tectum clusters")
    assert head[1].split(",") == ["t", "id", "x", "y", "vx", "vy", "mass", "width", "height"]
    info = subprocess.run([sys.executable, "-m", "tectum", "info", str(csv)], capture_output=True, text=True)
    assert info.returncode == 0 and "clusters" in info.stdout, info.stdout + info.stderr
