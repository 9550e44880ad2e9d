"""Trajectory metrics (ATE, RPE, Umeyama alignment, association by time)
against cases computed by hand, and against the ``evo`` package when it is
installed (``pip install tectum[evo]``)."""

from __future__ import annotations

import numpy as np
import pytest

from tectum.camera import quat_to_rot, rot_to_quat, so3_exp
from tectum.evaluation.metrics.trajectory import (
    Associated,
    associate,
    ate,
    path_length,
    rpe,
    trajectory_scores,
    umeyama,
)

ID = np.array([0.0, 0.0, 0.0, 1.0])


def _line(n: int = 11, dt_us: int = 100_000, speed: float = 1.0) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Truth: along +x at ``speed`` m/s, no rotation, a pose every ``dt_us``."""
    t = np.arange(n, dtype=np.int64) * dt_us
    p = np.zeros((n, 3))
    p[:, 0] = speed * t * 1e-6
    return t, p, np.tile(ID, (n, 1))


def _wiggly(n: int, seed: int) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    rng = np.random.default_rng(seed)
    t = np.arange(n, dtype=np.int64) * 50_000
    p = np.cumsum(rng.normal(0, 0.05, (n, 3)), axis=0)
    w = np.cumsum(rng.normal(0, 0.05, (n, 3)), axis=0)
    return t, p, rot_to_quat(np.stack([so3_exp(v) for v in w]))


def test_a_perfect_estimate_scores_zero() -> None:
    t, p, q = _wiggly(40, 0)
    s = trajectory_scores(t, p, q, t, p, q, mode="sim3", delta_us=100_000)
    assert s["ate_m"] == pytest.approx(0, abs=1e-9) and s["rot_median_deg"] == pytest.approx(0, abs=1e-5)
    assert s["rpe_t_m"] == pytest.approx(0, abs=1e-9) and s["scale"] == pytest.approx(1)
    assert s["poses"] == 40 and s["path_m"] == pytest.approx(path_length(p))


def test_a_constant_offset_is_the_ate_without_alignment_and_nothing_after_it() -> None:
    t, p, q = _line()
    est = p + [0.0, 0.03, 0.04]  # 5 cm off everywhere
    a = associate(t, est, q, t, p, q)
    assert ate(a, "none")["rmse"] == pytest.approx(0.05)
    assert ate(a, "se3")["rmse"] == pytest.approx(0, abs=1e-9)
    assert rpe(a, 200_000)["trans_rmse"] == pytest.approx(0, abs=1e-12)
    s = trajectory_scores(t, est, q, t, p, q, mode="none")
    assert s["path_m"] == pytest.approx(1.0) and s["pos_pct"] == pytest.approx(5.0)


def test_umeyama_recovers_a_similarity_and_sim3_removes_it() -> None:
    rng = np.random.default_rng(1)
    x = rng.normal(size=(30, 3))
    R = so3_exp(np.array([0.3, -1.2, 0.5]))
    y = 2.5 * x @ R.T + [1.0, -2.0, 0.5]
    s, R2, t2 = umeyama(x, y, with_scale=True)
    assert s == pytest.approx(2.5) and np.allclose(R2, R) and np.allclose(t2, [1.0, -2.0, 0.5])
    s, R2, _ = umeyama(x, y, with_scale=False)
    assert s == 1.0 and np.allclose(R2, R, atol=1e-9)  # the rotation does not depend on the scale
    # the estimate is the truth seen through an unknown similarity (monocular)
    t, p, q = _wiggly(30, 2)
    inv = R.T
    p_est = (p - [1.0, -2.0, 0.5]) @ inv.T / 2.5
    q_est = rot_to_quat(inv[None] @ quat_to_rot(q))
    a = associate(t, p_est, q_est, t, p, q)
    assert ate(a, "sim3")["rmse"] == pytest.approx(0, abs=1e-9) and ate(a, "sim3")["scale"] == pytest.approx(2.5)
    assert ate(a, "se3")["rmse"] > 0.01
    got = trajectory_scores(t, p_est, q_est, t, p, q, mode="sim3")
    assert got["rot_median_deg"] == pytest.approx(0, abs=1e-5)


def test_umeyama_returns_a_rotation_never_a_reflection() -> None:
    x = np.array([[0.0, 0, 0], [1, 0, 0], [0, 1, 0], [0, 0, 1]])
    y = x * [1, 1, -1]  # the mirror image: the best proper rotation is not the reflection
    _, R, _ = umeyama(x, y, with_scale=False)
    assert np.linalg.det(R) == pytest.approx(1.0)


def test_rpe_over_a_time_delta_by_hand() -> None:
    t, p, q = _line(n=11, dt_us=100_000, speed=1.0)
    _, p_fast, _ = _line(n=11, dt_us=100_000, speed=1.1)
    a = associate(t, p_fast, q, t, p, q)
    r = rpe(a, 200_000)
    assert r["pairs"] == 9 and r["trans_rmse"] == pytest.approx(0.02) and r["rot_rmse"] == pytest.approx(0)
    # an estimate turning at 10 deg/s about z while the truth does not: 2 deg per 0.2 s
    q_turn = rot_to_quat(np.stack([so3_exp(np.array([0, 0, np.radians(10) * s])) for s in t * 1e-6]))
    r = rpe(associate(t, p, q_turn, t, p, q), 200_000)
    assert r["rot_median"] == pytest.approx(2.0) and r["rot_rmse"] == pytest.approx(2.0)
    # its translation error: the truth's 0.2 m step seen in the estimate's frame at t_i, turned by
    # theta_i = 10 deg/s * t_i: |Rz(-theta_i) d - d| = 2 |d| sin(theta_i / 2), pairs i = 0..8
    theta = np.radians(10) * t[:9] * 1e-6
    assert r["trans_mean"] == pytest.approx(np.mean(0.4 * np.sin(theta / 2)), rel=1e-9)
    assert rpe(a, 5_000_000)["pairs"] == 0
    # a pose missing at 0.5 s: 0.3 s has no partner 0.2 s later (the next one, at 0.6 s, is too far)
    keep = np.delete(np.arange(11), 5)
    assert rpe(associate(t[keep], p_fast[keep], q[keep], t, p, q), 200_000)["pairs"] == 7


def test_association_interpolates_the_truth_and_drops_what_lies_outside() -> None:
    t = np.array([0, 1_000_000], np.int64)
    p = np.array([[0.0, 0, 0], [2.0, 0, 0]])
    q = np.stack([ID, rot_to_quat(so3_exp(np.array([0, 0, np.pi / 2])))])
    a = associate(np.array([-5, 500_000, 2_000_000]), np.zeros((3, 3)), np.tile(ID, (3, 1)), t, p, q)
    assert isinstance(a, Associated) and list(a.t) == [500_000]
    assert np.allclose(a.p_true, [[1.0, 0, 0]])
    assert np.allclose(a.q_true, rot_to_quat(so3_exp(np.array([0, 0, np.pi / 4]))))
    with pytest.raises(ValueError, match="time span"):
        associate(np.array([5_000_000]), np.zeros((1, 3)), ID[None], t, p, q)


def _evo_traj(t: np.ndarray, p: np.ndarray, q: np.ndarray):  # type: ignore[no-untyped-def]
    from evo.core.trajectory import PoseTrajectory3D

    return PoseTrajectory3D(positions_xyz=p, orientations_quat_wxyz=q[:, [3, 0, 1, 2]], timestamps=t * 1e-6)


def test_ate_and_rpe_equal_evo() -> None:
    pytest.importorskip("evo.core", reason="evo (the trajectory evaluation package) is not installed: "
                        "pip install tectum[evo]")
    from evo.core import metrics
    from evo.core.units import Unit

    t, p, q = _wiggly(60, 3)
    rng = np.random.default_rng(4)
    p_est = p + rng.normal(0, 0.02, p.shape)
    q_est = rot_to_quat(np.stack([quat_to_rot(qi) @ so3_exp(rng.normal(0, 0.01, 3)) for qi in q]))
    a = associate(t, p_est, q_est, t, p, q)
    for mode, scale in (("se3", False), ("sim3", True)):
        est = _evo_traj(t, p_est, q_est)
        est.align(_evo_traj(t, p, q), correct_scale=scale)
        ape = metrics.APE(metrics.PoseRelation.translation_part)
        ape.process_data((_evo_traj(t, p, q), est))
        assert ate(a, mode)["rmse"] == pytest.approx(ape.get_statistic(metrics.StatisticsType.rmse), rel=1e-9)
    for relation, key in ((metrics.PoseRelation.translation_part, "trans_rmse"),
                          (metrics.PoseRelation.rotation_angle_deg, "rot_rmse")):
        m = metrics.RPE(relation, delta=4, delta_unit=Unit.frames, all_pairs=True)
        m.process_data((_evo_traj(t, p, q), _evo_traj(t, p_est, q_est)))
        assert rpe(a, 4 * 50_000)[key] == pytest.approx(m.get_statistic(metrics.StatisticsType.rmse), rel=1e-7)
