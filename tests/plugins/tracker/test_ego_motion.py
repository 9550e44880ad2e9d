"""tracker.ego_motion: the ladder's kernels against slow references, the
focus gradient against finite differences, the collapse guard, the choice
on generated translating / rotating / 6-DoF scenes, bad input, batch
invariance and the command line on an ECD-layout folder."""

from __future__ import annotations

import subprocess
import sys

import numpy as np
import pytest
from scipy.ndimage import correlate1d

from tectum.plugins.tracker import _ladder as L
from tectum.plugins.tracker.ego_motion import MODEL_CODES, EgoMotion, moving_points
from tectum.testing import assert_batch_invariant, feed

CALIB = "40;40;31.5;23.5"  # the 64x48 sensor of moving_points
RNG = np.random.default_rng(7)


def _frame(n=400, span_s=0.02, seed=0):
    r = np.random.default_rng(seed)
    return L.Frame(r.uniform(-0.6, 0.6, n), r.uniform(-0.45, 0.45, n), r.uniform(-span_s / 2, span_s / 2, n),
                   40.0, 41.0, 31.5, 23.5, 64, 48, 8)


def _theta(model, seed=1):
    """Parameters of about a pixel or two of displacement over the frame's span."""
    G = L.generators(model, 40.0, 41.0)
    return np.random.default_rng(seed).normal(0, 1.5, G.shape[0]) * L.param_scales(_frame(), G)


# -- kernels against slow references -------------------------------------------------------
def _warp_reference(x, y, dt, A):
    """Per event: M = I + dt A + dt^2 A^2 / 2, the projection of M (x, y, 1),
    and log |det d(x', y')/d(x, y)| by central differences."""
    def carry(a, b, t):
        M = np.eye(3) + t * A + 0.5 * t * t * A @ A
        m = M @ np.array([a, b, 1.0])
        return m[:2] / m[2]

    out, logdet = [], []
    h = 1e-6
    for a, b, t in zip(x, y, dt):
        out.append(carry(a, b, t))
        J = np.column_stack([(carry(a + h, b, t) - carry(a - h, b, t)) / (2 * h),
                             (carry(a, b + h, t) - carry(a, b - h, t)) / (2 * h)])
        logdet.append(np.log(abs(np.linalg.det(J))))
    return np.array(out), np.array(logdet)


def _run_warp(fr, model, theta, grad=True):
    G = L.generators(model, fr.fx, fr.fy)
    obj = L._Objective(fr, G, np.ones(len(theta)), 1.0, 1.0)
    obj.warp(theta, grad)
    return obj


@pytest.mark.parametrize("model", L.MODELS)
def test_warp_matches_the_matrix_written_out(model):
    fr = _frame(60)
    theta = _theta(model)
    obj = _run_warp(fr, model, theta)
    A = np.tensordot(theta, L.generators(model, fr.fx, fr.fy), axes=1)
    ref, ref_logdet = _warp_reference(fr.x, fr.y, fr.dt, A)
    np.testing.assert_allclose(np.column_stack([obj.xw, obj.yw]), ref, rtol=0, atol=1e-12)
    # log det: dt tr A - 3 log m3, exact for exp(dt A); M is exp(dt A) to second order, so the area
    # ratio of M's own warp differs by the third-order term
    m3 = 1 + fr.dt * (A[2, 0] * fr.x + A[2, 1] * fr.y + A[2, 2]) \
        + 0.5 * fr.dt ** 2 * ((A @ A)[2, 0] * fr.x + (A @ A)[2, 1] * fr.y + (A @ A)[2, 2])
    np.testing.assert_allclose(obj.ld, fr.dt * np.trace(A) - 3 * np.log(m3), rtol=0, atol=1e-12)
    third = np.abs(fr.dt) ** 3 * np.abs(np.linalg.eigvals(A)).max() ** 3
    assert (np.abs(obj.ld - ref_logdet) <= 1e-6 + third).all()
    # d(x', y')/d theta against central differences of the reference
    h = 1e-6
    for k in range(len(theta)):
        e = np.zeros(len(theta))
        e[k] = h * max(abs(theta[k]), 1.0)
        Ap = np.tensordot(theta + e, L.generators(model, fr.fx, fr.fy), axes=1)
        Am = np.tensordot(theta - e, L.generators(model, fr.fx, fr.fy), axes=1)
        fd = (_warp_reference(fr.x, fr.y, fr.dt, Ap)[0] - _warp_reference(fr.x, fr.y, fr.dt, Am)[0]) / (2 * e[k])
        np.testing.assert_allclose(obj.J[:, :, k], fd, rtol=1e-5, atol=1e-9)


def test_rotation_warp_is_the_rotation_of_the_bearing():
    """Rotation rung: x' is the projection of exp(dt [w]x) (x, y, 1), the
    rotational warp, up to the second-order truncation (below 1e-6 here)."""
    from tectum.camera import so3_exp

    fr = _frame(50, span_s=0.01)
    w = np.array([1.0, -2.0, 0.5])
    obj = _run_warp(fr, "rotation", w, grad=False)
    for i in range(len(fr.x)):
        b = np.asarray(so3_exp(w * fr.dt[i])) @ np.array([fr.x[i], fr.y[i], 1.0])
        np.testing.assert_allclose([obj.xw[i], obj.yw[i]], b[:2] / b[2], atol=2e-6)


def test_vote_and_blur_match_numpy_and_scipy():
    img = np.zeros((12, 15))
    px, py = RNG.uniform(-1, 16, 200), RNG.uniform(-1, 13, 200)
    w = RNG.uniform(0.5, 2, 200)
    landed = L.vote(px, py, w, img)
    ref = np.zeros((12, 15))
    n = 0
    for a, b, c in zip(px, py, w):
        i, j = int(np.floor(b)), int(np.floor(a))
        if 0 <= i < 11 and 0 <= j < 14:
            fy, fx = b - i, a - j
            ref[i, j] += c * (1 - fx) * (1 - fy)
            ref[i, j + 1] += c * fx * (1 - fy)
            ref[i + 1, j] += c * (1 - fx) * fy
            ref[i + 1, j + 1] += c * fx * fy
            n += 1
    np.testing.assert_allclose(img, ref, atol=1e-12)
    assert landed == n
    taps = L.gaussian_taps(1.3)
    out, tmp = np.zeros_like(img), np.zeros_like(img)
    L.blur(img, taps, tmp, out)
    want = correlate1d(correlate1d(img, taps, axis=0, mode="constant"), taps, axis=1, mode="constant")
    np.testing.assert_allclose(out, want, atol=1e-12)
    # the same computed over a box holding every non-zero pixel
    sparse = np.zeros((12, 15))
    sparse[4:7, 5:9] = RNG.uniform(size=(3, 4))
    L.blur(sparse, taps, tmp, out, 4, 6, 5, 8)
    want = correlate1d(correlate1d(sparse, taps, axis=0, mode="constant"), taps, axis=1, mode="constant")
    np.testing.assert_allclose(out, want, atol=1e-12)


@pytest.mark.parametrize("model", L.MODELS)
def test_focus_gradient_matches_finite_differences(model):
    fr = _frame(500)
    G = L.generators(model, fr.fx, fr.fy)
    obj = L._Objective(fr, G, L.param_scales(fr, G), 1.0, 1.0)
    z = np.random.default_rng(3).normal(0, 2, G.shape[0])
    _, g = obj(z)
    eps = 1e-7  # scaled units: 1e-7 px, far below the spacing of the bilinear kinks
    fd = np.array([(obj(z + eps * e)[0] - obj(z - eps * e)[0]) / (2 * eps) for e in np.eye(len(z))])
    np.testing.assert_allclose(g, fd, rtol=1e-4, atol=1e-6 * np.abs(g).max())


def test_the_weighted_focus_gains_nothing_from_collapse():
    """A strong contraction piles events up (the plain IWE's sum of squares
    soars); the Jacobian-weighted focus stays where it was."""
    fr = _frame(3000)
    fr.dt = np.abs(fr.dt) * 2  # 0..20 ms after the reference: a contraction squeezes the late events
    G = L.generators("similarity", fr.fx, fr.fy)
    obj = L._Objective(fr, G, np.ones(4), 1.0, 1.0)
    still = obj.focus(np.zeros(4))
    shrink = np.array([0.0, 0.0, 0.0, 30.0])  # scale rate 30/s undone: the last events shrink to 58 %
    weighted = obj.focus(shrink)
    plain = np.zeros(obj.shape)
    L.vote(obj.sx * obj.xw + obj.ox, obj.sy * obj.yw + obj.oy, np.ones(len(obj.xw)), plain)
    plain_still = np.zeros(obj.shape)
    obj.warp(np.zeros(4), False)
    L.vote(obj.sx * obj.xw + obj.ox, obj.sy * obj.yw + obj.oy, np.ones(len(obj.xw)), plain_still)
    assert (plain ** 2).sum() > 1.3 * (plain_still ** 2).sum()
    assert weighted < 1.05 * still


# -- the choice --------------------------------------------------------------------------------
def _ladder(ev, **kw):
    op = EgoMotion(calib=kw.pop("calib", CALIB), window_events=len(ev), **kw)
    out = feed(op, [ev])
    assert len(out) == 1 and len(out[0]) == 1, op.counts
    return out[0], op


def test_translation_picks_translation_and_homography_does_not_win():
    ev = moving_points(velocity=(3.0, -1.5, 0.0), n_points=80)  # image velocity (-120, 60) px/s
    s, _ = _ladder(ev)
    assert int(s.model[0]) == MODEL_CODES["translation"]
    np.testing.assert_allclose(s.params[0, :2], [-120.0, 60.0], atol=4.0)
    assert np.isnan(s.params[0, 2:]).all()
    sc = dict(zip(L.MODELS, s.scores[0]))
    assert sc["translation"] >= sc["homography"] - 0.002  # held out: the 8 parameters buy nothing


def test_rotation_picks_rotation():
    ev = moving_points(omega=(2.0, -4.0, 1.5), n_points=80, seed=1)
    s, _ = _ladder(ev)
    assert int(s.model[0]) == MODEL_CODES["rotation"]
    np.testing.assert_allclose(s.params[0, :3], [2.0, -4.0, 1.5], atol=0.2)


def test_rotation_and_translation_need_6dof():
    ev = moving_points(velocity=(2.0, -1.0, 2.0), omega=(2.0, 3.0, -1.5), n_points=80, seed=3)
    s, _ = _ladder(ev)
    assert int(s.model[0]) == MODEL_CODES["6dof"]
    sc = dict(zip(L.MODELS, s.scores[0]))
    assert sc["6dof"] > max(sc["translation"], sc["rotation"], sc["similarity"]) + 0.02


def test_choose_takes_the_simplest_within_the_margins():
    n = 1000
    base = np.random.default_rng(0).normal(0, 1, n)
    ll = {"translation": base, "rotation": base + 0.5, "similarity": base + 0.502, "homography": base + 0.6,
          "6dof": base + 0.599}
    # margins: 1 % of 0.6 + 0.5 over 'still' (0.011) and 10 % of 0.6 over translation (0.06)
    assert L.choose(ll, still=-0.5, blocks=10, k_se=1.0, tol=0.01, tol_rel=0.1)[0] == "6dof"  # 6 < 8 parameters
    assert L.choose({**ll, "6dof": base + 0.52}, still=-0.5, blocks=10, k_se=1.0, tol=0.01,
                    tol_rel=0.1)[0] == "homography"
    assert L.choose(ll, still=-0.5, blocks=10, k_se=1.0, tol=0.01, tol_rel=0.2)[0] == "rotation"
    assert L.choose(ll, still=-0.5, blocks=10, k_se=1.0, tol=0.6, tol_rel=0.0)[0] == "translation"


# -- bad input ---------------------------------------------------------------------------------
def test_without_calibration_the_calibrated_rungs_are_skipped_and_counted():
    ev = moving_points(velocity=(3.0, -1.5, 0.0), n_points=80)
    s, op = _ladder(ev, calib="")
    assert int(s.model[0]) == MODEL_CODES["translation"]
    sc = dict(zip(L.MODELS, s.scores[0]))
    assert np.isnan(sc["rotation"]) and np.isnan(sc["6dof"])
    assert np.isfinite([sc["translation"], sc["similarity"], sc["homography"]]).all()
    assert op.counts["rungs_skipped_no_calibration"] == 2


def test_asking_for_a_calibrated_rung_without_calibration_says_how_to_give_it():
    with pytest.raises(ValueError, match=r"models \['rotation'\] need the camera calibration: give calib="):
        EgoMotion(models="translation,rotation")
    with pytest.raises(ValueError, match="unknown"):
        EgoMotion(models="affine")


def test_too_few_events_give_no_sample_and_are_counted():
    ev = moving_points(duration_us=4000, velocity=(3.0, 0.0, 0.0), n_points=20)
    op = EgoMotion(calib=CALIB, window_events=10_000, min_events=len(ev) + 1)
    assert sum(len(q) for q in feed(op, [ev])) == 0
    assert op.counts["too_few_events"] == 1
    op = EgoMotion(calib=CALIB, window_us=1000, min_events=10_000)
    assert sum(len(q) for q in feed(op, [ev])) == 0
    assert op.counts["too_few_events"] == 4


def test_time_windows():
    ev = moving_points(duration_us=30_000, velocity=(3.0, -1.5, 0.0), n_points=60)
    out = feed(EgoMotion(calib=CALIB, window_us=10_000, min_events=500), [ev])
    t = np.concatenate([q.t for q in out])
    assert len(t) == 3 and (t < [10_000, 20_000, 30_000]).all() and (t >= [9_000, 19_000, 29_000]).all()


def test_batch_invariance():
    assert_batch_invariant(lambda: EgoMotion(**EgoMotion.conformance_params), EgoMotion.conformance_stream(),
                           max_examples=3)


# -- the command line ----------------------------------------------------------------------------
def test_from_the_command_line_on_an_ecd_folder(tmp_path):
    ev = moving_points(duration_us=40_000, omega=(2.0, -4.0, 1.5), n_points=60, seed=1)
    with open(tmp_path / "events.txt", "w") as f:
        for t, x, y, p in zip(ev.t, ev.x, ev.y, ev.p):
            f.write(f"{t / 1e6:.6f} {x} {y} {int(p > 0)}\n")
    (tmp_path / "calib.txt").write_text("40 40 31.5 23.5 0 0 0 0 0\n")
    out = subprocess.run([sys.executable, "-m", "tectum", "run", f"{tmp_path / 'events.txt'}?sensor=64x48", "--op",
                          f"tracker.ego_motion:window_events={len(ev) // 2}", "--sink", str(tmp_path / "motion.csv")],
                         capture_output=True, text=True)
    assert out.returncode == 0, out.stderr
    lines = (tmp_path / "motion.csv").read_text().splitlines()
    assert lines[0] == "# tectum motion_model"
    header = lines[1].split(",")
    assert header[:2] == ["t", "model"] and "score_6dof" in header and "p7" in header
    rows = [dict(zip(header, r.split(","))) for r in lines[2:]]
    assert len(rows) == 2 and all(r["model"] == str(MODEL_CODES["rotation"]) for r in rows)
    info = subprocess.run([sys.executable, "-m", "tectum", "info", str(tmp_path / "motion.csv")],
                          capture_output=True, text=True)
    assert info.returncode == 0, info.stderr
    assert "motion_model" in info.stdout
