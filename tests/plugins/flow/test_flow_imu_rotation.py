"""Flow against a gyro under pure rotation (Rueckauer & Delbruck 2016) on the
DAVIS240 'rotdisk' recording of ../shared/data (skipped when absent).

The camera rolls about its optical axis (about 0.5 rad/s): checked here
against the event images themselves, so the gyro is a valid ground truth.
Assumptions: focal length 200 px (no calibration given), principal point at
the sensor centre; the IMU z axis is opposite to our camera z (our image has
a top-left origin). The recording's IMU was set to ±1000 °/s and ±8 g while
the AEDAT2 reader scales for ±500 °/s and ±4 g: the factor 2 is found from
gravity here (reported as a reader bug).
"""

from __future__ import annotations

import numpy as np
import pytest

from tectum import concat
from tectum.evaluation.imu_truth import gyro_flow, imu_full_scale_factor, normal_flow_vs_rotation, read_events_and_imu
from tectum.plugins.flow import PlaneFit
from tectum.testing import feed

from helpers import shared_data

AXES = np.diag([1.0, 1.0, -1.0])  # camera = AXES @ imu


@pytest.fixture(scope="module")
def rotdisk():
    shared = shared_data()
    if shared is None:
        pytest.skip("real recordings not available: ../shared/data is absent (set TECTUM_SHARED_DATA)")
    path = shared / "aedat" / "davis240_imu_rotdisk.aedat"
    if not path.exists():
        pytest.skip(f"{path} is absent")
    return read_events_and_imu(str(path))


def test_gyro_rate_matches_the_rotation_of_the_event_images(rotdisk):
    ev, imu = rotdisk
    scale = imu_full_scale_factor(imu)
    assert scale in (1.0, 2.0)
    wz = float(np.median(imu.gyro[:, 2])) * scale
    assert abs(wz) > 0.3  # the camera really rotates: the gyro is a ground truth here

    def image(t0):
        w = ev.slice_time(t0, t0 + 30_000)
        img = np.zeros((180, 240))
        np.add.at(img, (w.y, w.x), 1.0)
        return img

    # rotate A by angle (nearest neighbour) about the centre; the best match with B 100 ms later
    a, b = image(1_000_000), image(1_100_000)
    yy, xx = np.mgrid[30:150, 40:200].astype(np.float64)
    best = None
    for deg in np.arange(-8.0, 8.01, 0.5):
        c, s = np.cos(np.radians(deg)), np.sin(np.radians(deg))
        # sample A at the point that B's pixel came from
        xs = np.rint(c * (xx - 119.5) + s * (yy - 89.5) + 119.5).astype(int)
        ys = np.rint(-s * (xx - 119.5) + c * (yy - 89.5) + 89.5).astype(int)
        corr = np.corrcoef(a[ys, xs].ravel(), b[30:150, 40:200].ravel())[0, 1]
        if best is None or corr > best[0]:
            best = (corr, deg)
    # B(p) = A(R(-deg) p): the scene turned by +deg (from x towards y, y down) in 0.1 s.
    # A camera roll wz_cam turns the scene by -wz_cam (rotational_flow), and wz_cam = AXES[2, 2] * wz
    predicted = np.degrees(-AXES[2, 2] * wz * 0.1)
    assert abs(best[1] - predicted) <= 1.0, (best, predicted)


def test_plane_fit_normal_flow_follows_the_gyro_field(rotdisk):
    ev, imu = rotdisk
    ev = ev.slice_time(int(ev.t[0]), int(ev.t[0]) + 1_000_000)
    tx, ty = gyro_flow(ev, imu, 200.0, 119.5, 89.5, axes=AXES, scale=imu_full_scale_factor(imu))
    out = concat(feed(PlaneFit(), [ev]))
    r = normal_flow_vs_rotation(out["vx"], out["vy"], out["valid"], tx, ty)
    assert r["n_scored"] > 300 and r["sign_agree"] > 0.9, r
    # today the local fits overestimate these slow (about 50 px/s) edges by 3-5x
    assert 1.5 < r["median_ratio"] < 8, r
