"""The simulate source says before it opens which streams it will give, so
ports are filled by kind from it (``simulate:SCENE?poses=true`` feeds an
operator's ``poses`` port)."""

import numpy as np

import tectum
from tectum import Kind
from tectum.sources.simulate import SimulateSource


def test_kinds_follow_the_parameters_and_the_scene():
    assert SimulateSource.kinds_for("simulate:rotation", {}) == (Kind.EVENTS,)
    assert SimulateSource.kinds_for("simulate:rotation", {"poses": True}) == (Kind.EVENTS, Kind.POSES)
    davis = SimulateSource.kinds_for("simulate:plane_6dof", {"davis": True})
    src = SimulateSource("simulate:plane_6dof", duration_us=1000, davis=True)
    assert set(davis) == set(src.produces)


def test_a_poses_port_is_filled_from_the_simulator(tmp_path):
    out = tmp_path / "pano.npz"
    p = tectum.Pipeline()
    cam = p.source("simulate:rotation", poses=True, duration_us=60_000, sensor="64x48")
    p.sink(str(out), p.op("map.poisson_mosaic", cam, calib="50;50;32;24", pano_width=128))
    tectum.run(p)
    with np.load(out) as z:
        assert z["maps_image"].shape[-2:] == (64, 128)
