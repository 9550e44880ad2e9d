"""Flow kernels against slow, obvious reference implementations."""

from __future__ import annotations

import numpy as np

from tectum.evaluation.scenes import translating_edges
from tectum.plugins.flow import EdgeSpeed, PlaneFit
from tectum.plugins.flow._common import NEVER


def _scene():
    return translating_edges((24, 20), 80_000, 300.0, 120.0, angles_deg=(20.0, 100.0), spacing_px=8,
                             jitter_us=200, noise_hz=30.0, seed=3).without_columns("vx", "vy")


def _walk(pkt):
    """(t, x, y, polarity index, surface of active events) per event, the
    surface already holding the event (the references' shared first step)."""
    w, h = pkt.sensor
    sae = np.full((2, h, w), NEVER, np.int64)
    for t, x, y, p in zip(pkt.t.tolist(), pkt.x.tolist(), pkt.y.tolist(), pkt.p.tolist()):
        k = int(p > 0)
        sae[k, y, x] = t
        yield t, x, y, k, sae


def _edge_speed_reference(pkt, window_us, tol, lo, hi):
    w, h = pkt.sensor
    out = []
    for t, x, y, k, sae in _walk(pkt):
        g = []
        for dx, dy in ((1, 0), (0, 1)):
            ages = []
            for s in (-1, 1):
                xx, yy = x + s * dx, y + s * dy
                inside = 0 <= xx < w and 0 <= yy < h
                ages.append(t - sae[k, yy, xx] if inside else None)
            back, fwd = (a if a is not None and a <= window_us else None for a in ages)
            if back is not None and fwd is not None:
                g.append((back - fwd) / 2 if abs(back - fwd) <= tol else None)
            elif back is not None or fwd is not None:
                s = 1 if back is not None else -1
                tof = back if back is not None else fwd
                x2, y2 = x - 2 * s * dx, y - 2 * s * dy
                steady = not (0 <= x2 < w and 0 <= y2 < h) or abs(t - sae[k, y2, x2] - 2 * tof) <= tol + tof / 4
                g.append(s * float(tof) if steady else None)
            else:
                g.append(None)
        if None in g or g[0] ** 2 + g[1] ** 2 == 0:
            out.append(None)
            continue
        g2 = g[0] ** 2 + g[1] ** 2
        speed = 1e6 / g2 ** 0.5
        out.append((1e6 * g[0] / g2, 1e6 * g[1] / g2) if lo <= speed <= hi else None)
    return out


def test_edge_speed_matches_reference():
    pkt = _scene()
    got = EdgeSpeed(window_us=15_000).process(pkt)[0]
    ref = _edge_speed_reference(pkt, 15_000, 1000, 1.0, 20_000.0)
    assert got["valid"].tolist() == [r is not None for r in ref]
    v = got["valid"]
    assert v.sum() > 100
    exp = np.array([r for r in ref if r is not None], np.float32)
    np.testing.assert_allclose(got["vx"][v], exp[:, 0], rtol=1e-6)
    np.testing.assert_allclose(got["vy"][v], exp[:, 1], rtol=1e-6)
    assert np.isnan(got["vx"][~v]).all() and np.isnan(got["vy"][~v]).all()


def _window(sae, k, x, y, t, radius, window_us):
    """The fresh neighbours of (x, y) as points (dx, dy, T - t)."""
    _, h, w = sae.shape
    return [(dx, dy, sae[k, y + dy, x + dx] - t)
            for dy in range(-radius, radius + 1) for dx in range(-radius, radius + 1)
            if 0 <= x + dx < w and 0 <= y + dy < h and t - sae[k, y + dy, x + dx] <= window_us]


def _plane_reference(pkt, radius, window_us, min_points):
    """Plain least squares (no rejection) with numpy.linalg.lstsq."""
    out = []
    for t, x, y, k, sae in _walk(pkt):
        pts = _window(sae, k, x, y, t, radius, window_us)
        if len(pts) < min_points:
            out.append(None)
            continue
        a = np.array(pts, np.float64)
        A = np.c_[a[:, :2], np.ones(len(a))]
        if np.linalg.matrix_rank(A[:, :2] - A[:, :2].mean(0)) < 2:
            out.append(None)
            continue
        (ga, gb, _), *_ = np.linalg.lstsq(A, a[:, 2], rcond=None)
        g2 = ga * ga + gb * gb
        out.append((1e6 * ga / g2, 1e6 * gb / g2))
    return out


def test_plain_plane_fit_matches_lstsq():
    pkt = _scene()
    op = PlaneFit(radius=2, n_iter=0, reject_us=1e12, max_rms=1e12, min_speed=0.0, max_speed=1e12, window_us=20_000)
    got = op.process(pkt)[0]
    ref = _plane_reference(pkt, 2, 20_000, 6)
    has = np.array([r is not None for r in ref])
    # the kernel may refuse nearly-collinear point sets numpy still solves; never the reverse
    assert not (got["valid"] & ~has).any()
    assert (got["valid"] == has).mean() > 0.99
    both = got["valid"] & has
    exp = np.array([r for r, b in zip(ref, both) if b])
    np.testing.assert_allclose(got["vx"][both], exp[:, 0], rtol=1e-4, atol=1e-3)
    np.testing.assert_allclose(got["vy"][both], exp[:, 1], rtol=1e-4, atol=1e-3)


def test_relative_surface_rebases_without_changing_results():
    """The int32 surface keeps times relative to a base and moves the base
    when they would pass SPAN: a stream that crosses it mid-way (and one
    after a gap of several SPANs) gives exactly the outputs of the same
    events near time 0."""
    from tectum import EventPacket
    from tectum.plugins.flow._plane import EMPTY, SPAN, new_surface, rebase
    from tectum.plugins.lifetime import PlaneFitLifetime

    pkt = _scene()
    for shift in (SPAN - 30_000, 5 * SPAN + 123):
        moved = EventPacket.from_arrays(pkt.t + shift, pkt.x, pkt.y, pkt.p, sensor=pkt.sensor, t_start=0,
                                        t_end=pkt.t_end + shift)
        for make in (PlaneFit, lambda: PlaneFit(burst_us=3000), lambda: PlaneFit(radius=3, robust=True)):
            a, b = make().process(pkt)[0], make().process(moved)[0]
            assert a["valid"].sum() > 100
            np.testing.assert_array_equal(a["valid"], b["valid"])
            np.testing.assert_array_equal(a["vx"], b["vx"])
        la = PlaneFitLifetime().process(pkt)[0]["lifetime"]
        lb = PlaneFitLifetime().process(moved)[0]["lifetime"]
        np.testing.assert_array_equal(la, lb)
    # the rebase itself: same absolute times, the ones that fall off become EMPTY
    s = new_surface((4, 3), 1)
    s[1, 1, 0], s[2, 3, 1], s[3, 4, 0] = 100, SPAN - 1, 5
    base = np.array([1000], np.int64)
    rebase(s, base, 1000 + SPAN + 10)  # shift every pixel by SPAN + 10 µs
    assert base[0] == 1000 + SPAN + 10
    assert s[2, 3, 1] == -11 and s[1, 1, 0] == 90 - SPAN and s[3, 4, 0] == EMPTY and (s[0] == EMPTY).all()


def _benosman_reference(pkt, radius, window_us, n_iter, reject_us, min_points, max_rms, lo, hi):
    """Iterative outlier rejection (Benosman et al. 2014) with numpy.linalg.lstsq."""
    out = []
    for t, x, y, k, sae in _walk(pkt):
        pts = np.array(_window(sae, k, x, y, t, radius, window_us), np.float64).reshape(-1, 3)
        if len(pts) < min_points:
            out.append(None)
            continue
        A = np.c_[pts[:, :2], np.ones(len(pts))]
        use = np.ones(len(pts), bool)
        sol = None
        for it in range(n_iter + 1):
            if use.sum() < 3 or np.linalg.matrix_rank(A[use, :2] - A[use, :2].mean(0)) < 2:
                sol = None
                break
            sol = np.linalg.lstsq(A[use], pts[use, 2], rcond=None)[0]
            if it == n_iter:
                break
            keep = np.abs(pts[:, 2] - A @ sol) <= reject_us
            if (keep == use).all():
                break
            use = keep
        if sol is None or abs(sol[2]) > reject_us or use.sum() < min_points:
            out.append(None)
            continue
        rms = np.sqrt(np.mean((pts[use, 2] - A[use] @ sol) ** 2))
        g2 = sol[0] ** 2 + sol[1] ** 2
        ok = g2 > 0 and rms <= max_rms * np.sqrt(g2) and lo <= 1e6 / np.sqrt(g2) <= hi
        out.append((1e6 * sol[0] / g2, 1e6 * sol[1] / g2) if ok else None)
    return out


def test_benosman_rejection_matches_reference():
    pkt = _scene()
    got = PlaneFit().process(pkt)[0]  # defaults: 5x5, 3 rounds, 1500 µs
    ref = _benosman_reference(pkt, 2, 30_000, 3, 1500.0, 6, 1.0, 1.0, 20_000.0)
    has = np.array([r is not None for r in ref])
    assert has.sum() > 200 and (got["valid"] == has).mean() > 0.995
    both = got["valid"] & has
    exp = np.array([r for r, b in zip(ref, both) if b])
    np.testing.assert_allclose(got["vx"][both], exp[:, 0], rtol=1e-4, atol=1e-3)
    np.testing.assert_allclose(got["vy"][both], exp[:, 1], rtol=1e-4, atol=1e-3)
