"""Tracker accuracy against ground-truth positions of moving objects and
markers (the multi-object tracking protocol, simplified to point targets).

* :func:`track_scores`: estimated rows ``(t, id, x, y)`` against truth
  positions of every target at the same times. At each output time each
  target is matched to the nearest estimate within ``gate_px`` (greedy,
  nearest pairs first, one estimate per target); the scores are the
  position error of the matches (median and 90th percentile, px), the
  coverage (matched target-times over all target-times where the target
  is inside the image), false rows (estimates matched to nothing), and
  the id switches: a target's matched id changing from one matched time to
  the next (the MOT count, each change once).
* :func:`id_accuracy`: rows whose id is the target's own (markers with
  known ids: an LED's frequency names it).
* :func:`pose_errors`: translation (m) and rotation (deg) errors of poses.
* :func:`output_latencies`: event-to-output latency of a tracker fed in
  live-sized packets (stream-time wait plus processing time).
"""

from __future__ import annotations

from typing import Any

import numpy as np

__all__ = ["track_scores", "id_accuracy", "pose_errors", "output_latencies"]


def track_scores(t: np.ndarray, ids: np.ndarray, x: np.ndarray, y: np.ndarray, truth_xy: np.ndarray,
                 gate_px: float, inside: np.ndarray | None = None) -> dict[str, float]:
    """Scores of estimates against truth (see the module). ``truth_xy`` is
    (rows, targets, 2): the truth at each row's time (rows sharing a ``t``
    share it); ``inside`` (rows, targets) bool marks the targets that count
    (default all)."""
    t = np.asarray(t)
    n_targets = truth_xy.shape[1]
    inside = np.ones(truth_xy.shape[:2], bool) if inside is None else inside
    errs: list[float] = []
    last = np.full(n_targets, -1, np.int64)
    switches = matched = false_rows = 0
    counted = 0
    times, starts = np.unique(t, return_index=True)
    bounds = list(starts) + [len(t)]
    for a, b in zip(bounds[:-1], bounds[1:]):
        est = np.stack([x[a:b], y[a:b]], axis=1)
        tr = truth_xy[a]
        ok = inside[a]
        counted += int(ok.sum())
        d = np.linalg.norm(est[:, None, :] - tr[None, :, :], axis=2)
        d[:, ~ok] = np.inf
        used_e, used_t = set(), set()
        for flat in np.argsort(d, axis=None):
            e, k = divmod(int(flat), n_targets)
            if d[e, k] > gate_px:
                break
            if e in used_e or k in used_t:
                continue
            used_e.add(e)
            used_t.add(k)
            errs.append(float(d[e, k]))
            matched += 1
            if last[k] >= 0 and last[k] != ids[a + e]:
                switches += 1
            last[k] = ids[a + e]
        false_rows += (b - a) - len(used_e)
    e = np.array(errs) if errs else np.array([np.nan])
    return {"times": float(len(times)), "median_px": float(np.median(e)), "p90_px": float(np.percentile(e, 90)),
            "coverage": matched / counted if counted else float("nan"), "id_switches": float(switches),
            "false_rows": float(false_rows), "rows": float(len(t))}


def id_accuracy(ids: np.ndarray, x: np.ndarray, y: np.ndarray, truth_xy: np.ndarray, truth_ids: np.ndarray,
                gate_px: float) -> tuple[float, float]:
    """(fraction of rows whose id names the truth target nearest to them
    within ``gate_px``, median distance px to their own target's truth);
    ``truth_xy`` (rows, targets, 2) at each row's time."""
    if len(ids) == 0:
        return float("nan"), float("nan")
    est = np.stack([x, y], axis=1)
    d = np.linalg.norm(truth_xy - est[:, None, :], axis=2)
    near = np.argmin(d, axis=1)
    ok = (truth_ids[near] == ids) & (d[np.arange(len(ids)), near] <= gate_px)
    own = np.searchsorted(truth_ids, ids)
    known = (own < len(truth_ids)) & (truth_ids[np.minimum(own, len(truth_ids) - 1)] == ids)
    dist = d[np.arange(len(ids))[known], own[known]]
    return float(ok.mean()), float(np.median(dist)) if len(dist) else float("nan")


def pose_errors(p_est: np.ndarray, q_est: np.ndarray, p_true: np.ndarray,
                q_true: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Per pose, the translation error (m) and the rotation error (deg, the
    angle of ``q_true^-1 q_est``); quaternions x, y, z, w."""
    te = np.linalg.norm(np.asarray(p_est) - np.asarray(p_true), axis=1)
    a = np.asarray(q_est, np.float64)
    b = np.asarray(q_true, np.float64)
    dot = np.abs(np.sum(a * b, axis=1)) / (np.linalg.norm(a, axis=1) * np.linalg.norm(b, axis=1))
    return te, np.degrees(2 * np.arccos(np.clip(dot, -1.0, 1.0)))


def output_latencies(op: Any, events: Any, packet_us: int) -> dict[str, np.ndarray]:
    """Event-to-output latency of a tracker fed as a live source would feed
    it: ``events`` cut into packets of ``packet_us`` µs of stream time, each
    processed when it closes. Per output row: its wait in stream time (µs
    from the row's time to the close of the packet that gave it) plus the
    processing time of that packet, by the wall clock (``"wall"``) and by
    the thread's CPU time (``"cpu"``: what a core of its own would take;
    on a loaded machine the wall clock adds the time the thread waited for
    one). Also ``"cost_wall"``, ``"cost_cpu"``: µs per packet."""
    import time

    wait: list[np.ndarray] = []
    rows_wall: list[float] = []
    rows_cpu: list[float] = []
    cost_wall: list[float] = []
    cost_cpu: list[float] = []
    t0 = events.t_start
    while t0 < events.t_end:
        pkt = events.slice_time(t0, min(t0 + packet_us, events.t_end))
        c0, w0 = time.thread_time(), time.perf_counter()
        outs = [q for q in op.process(pkt) if len(q)]
        cw, cc = (time.perf_counter() - w0) * 1e6, (time.thread_time() - c0) * 1e6
        cost_wall.append(cw)
        cost_cpu.append(cc)
        for q in outs:
            wait.append(pkt.t_end - q.t)
            rows_wall += [cw] * len(q)
            rows_cpu += [cc] * len(q)
        t0 = pkt.t_end
    w = np.concatenate(wait).astype(np.float64) if wait else np.empty(0)
    return {"wall": w + np.array(rows_wall), "cpu": w + np.array(rows_cpu), "cost_wall": np.array(cost_wall),
            "cost_cpu": np.array(cost_cpu)}
