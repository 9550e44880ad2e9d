"""Streaming: determinism, window invariance, the packet contract, the
source plugin, TOML scenes and the CLI."""

from __future__ import annotations

import numpy as np
import pytest

import tectum
from tectum import EventPacket
from tectum.sources.simulate import SimulateSource, make_simulator, simulate
from tectum.testing import assert_streams_equal

KW = dict(sensor="40x30", preset="realistic")


def windows(scene: str, window_us: int, seed: int = 0, duration: int = 60_000) -> list[EventPacket]:
    sim = make_simulator(scene, duration, seed=seed, **KW)
    return [ev for ev, _ in sim.windows(window_us)]


def test_same_seed_same_stream_other_seed_other_noise():
    a = windows("shapes", 10_000, seed=7)
    b = windows("shapes", 10_000, seed=7)
    assert_streams_equal(a, b, "same seed")
    c = tectum.concat(windows("shapes", 10_000, seed=8))
    assert not np.array_equal(tectum.concat(a).t, c.t) or not np.array_equal(tectum.concat(a).x, c.x)


@pytest.mark.parametrize("scene", ["shapes", "rotation"])
def test_any_window_size_gives_the_same_stream(scene):
    ref = windows(scene, 60_000)
    assert len(tectum.concat(ref)) > 100
    for w in (1_000, 7_777):
        assert_streams_equal(ref, windows(scene, w), f"window {w} µs")


def test_packets_keep_the_contract():
    pkts = windows("translation_edges", 3_000)
    assert pkts[0].t_start == 0 and pkts[-1].t_end == 60_000
    for a, b in zip(pkts, pkts[1:]):
        assert a.t_end == b.t_start
        if len(a) and len(b):
            assert a.t[-1] < b.t[0]  # equal timestamps never split
    for p in pkts:
        p.validate()
        assert set(p.columns) == {"vx", "vy", "lifetime", "noise", "object_id"}
        assert p["vx"].dtype == np.float32 and p["noise"].dtype == np.uint8 and p["object_id"].dtype == np.int16


def test_source_plugin_in_a_pipeline(tmp_path):
    assert tectum.get_registry().source_for("simulate:led_grid") is SimulateSource
    out = tmp_path / "ev.npz"
    p = tectum.Pipeline()
    s = p.source("simulate:translation_edges", duration_us="40000", sensor="32x24", seed="3")
    p.sink(str(out), s)
    tectum.run(p)
    got = np.load(out)
    ev, _ = simulate("translation_edges", 40_000, sensor="32x24", seed=3)
    assert len(ev) > 50
    for col in ("t", "x", "y", "p", "vx", "noise", "object_id"):
        np.testing.assert_array_equal(got[col], ev[col])


def test_source_side_streams():
    scene_davis = {"sensor": [16, 12], "background": {"intensity": 0.4},
                   "davis": {"imu_rate_hz": 500, "aps_rate_hz": 50, "exposure_us": 1000}}
    src = SimulateSource("simulate:", duration_us=40_000, poses=True, davis=True, scene=scene_davis)
    K = tectum.Kind
    assert set(src.produces) == {K.EVENTS, K.POSES, K.FRAMES, K.IMU}
    kinds = {}
    for pkt in src.packets():
        kinds[pkt.kind] = kinds.get(pkt.kind, 0) + len(pkt)
    assert kinds[tectum.Kind.IMU] == 20 and kinds[tectum.Kind.FRAMES] == 2 and kinds[tectum.Kind.POSES] == 40


def test_toml_scene(tmp_path):
    path = tmp_path / "disk.toml"
    path.write_text(
        'sensor = "32x24"\n[background]\nintensity = 0.2\n'
        '[[objects]]\nshape = "disk"\nposition = [8, 12]\nradius = 5\nvelocity = [200, 0]\nintensity = 0.9\nid = 7\n'
        '[sensor_model]\nc_on = 0.3\n'
    )
    ev, _ = simulate(str(path), 40_000)
    assert len(ev) > 50 and set(np.unique(ev["object_id"])) == {7}
    np.testing.assert_array_equal(ev["vx"], np.float32(200.0))
    bad = tmp_path / "bad.toml"
    bad.write_text("colour = 3\n")
    with pytest.raises(ValueError, match="unknown keys"):
        simulate(str(bad), 1000)


def test_cli_list_and_run(tmp_path, capsys):
    from tectum.cli import main

    assert main(["simulate", "--list"]) == 0
    listed = capsys.readouterr().out
    assert "rotation" in listed and "led_grid" in listed
    out = tmp_path / "run.npz"
    assert main(["simulate", "shapes", "--duration", "30ms", "--sensor", "32x24", "--out", str(out),
                 "--preset", "realistic", "--truth-fps", "100"]) == 0
    ev = np.load(out)
    assert {"vx", "vy", "lifetime", "noise", "object_id"} <= set(ev.files)
    truth = np.load(str(out) + ".truth.npz")
    assert truth["frame_intensity"].shape == (3, 24, 32) and truth["pose_t"].shape == (30,)


def test_truth_maps_stream_to_disk(tmp_path):
    import os

    sim = make_simulator("shapes", 30_000, sensor="32x24", truth_fps=200, preset="ideal")
    for _ in sim.windows(10_000):
        pass
    tr = sim.truth
    assert not tr.parts  # nothing held in memory: every series went to disk
    maps = tr["frame_intensity"]
    assert isinstance(maps, np.memmap) and maps.shape == (6, 24, 32)
    np.testing.assert_array_equal(tr["frame_t"], np.arange(6) * 5_000)
    for t, img in zip(tr["frame_t"], maps):  # the true images at their times
        np.testing.assert_array_equal(img, sim.render(float(t)).astype(np.float32))
    tr.save(str(tmp_path / "truth.npz"))
    z = np.load(tmp_path / "truth.npz")
    assert set(z.files) == set(tr.keys())
    for k in tr.keys():
        np.testing.assert_array_equal(z[k], tr[k])
    folder = tr._dir
    tr.close()
    assert folder is not None and not os.path.exists(folder)
