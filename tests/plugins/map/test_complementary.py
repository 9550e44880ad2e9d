"""map.complementary: the estimate converges to the frame between events,
events ride on the frame with the closed form, frames and events in time
order, batch invariance with frames, bad frames named, and the user's path
(an ECD folder with images.txt: the frames port is filled by kind)."""

from __future__ import annotations

import math

import numpy as np
import pytest

from tectum import EventPacket, FramePacket, concat
from tectum.cli import main
from tectum.plugins.map import Complementary, HighPass
from tectum.plugins.map._integrate import log_frame
from tectum.testing import assert_batch_invariant, feed_ports

OFF = 1.0 / 255


def _frames(t, images, t_end):
    return FramePacket(np.asarray(t, np.int64), images=np.asarray(images, np.uint8), t_start=0, t_end=t_end)


def test_converges_to_the_frame_between_events():
    # frame A at 0, events at (1, 1) until 5 ms, frame B at 10 ms: afterwards L -> log B at rate alpha
    a, b = np.full((3, 4), 60), np.full((3, 4), 200)
    t = np.arange(1_000, 5_000, 500, dtype=np.int64)
    ev = EventPacket.from_arrays(t, np.ones(len(t)), np.ones(len(t)), np.ones(len(t)), sensor=(4, 3),
                                 t_start=0, t_end=200_000)
    alpha = 50.0
    at = (9_999, 10_000, 30_000, 100_000, 199_999)
    out = concat(feed_ports(Complementary(alpha=alpha, at_us=at),
                            {"events": [ev], "frames": [_frames([0, 10_000], [a, b], 200_000)]}))
    La, Lb = math.log(60 / 255 + OFF), math.log(200 / 255 + OFF)
    # at (0, 0) no event: from La towards Lb after the second frame
    assert out.image[0][0, 0] == pytest.approx(La + (La - La) * math.exp(-alpha * 9_999e-6), abs=1e-5)
    for T, img in zip(at[1:], out.image[1:]):
        want = Lb + (La - Lb) * math.exp(-alpha * 1e-6 * (T - 10_000))
        assert img[0, 0] == pytest.approx(want, abs=1e-5)
    # at (1, 1): the 8 events' 0.2 each decayed, on top of the same relaxation
    bump = sum(0.2 * math.exp(-alpha * 1e-6 * (10_000 - ti)) for ti in t)
    for T, img in zip(at[1:], out.image[1:]):
        want = Lb + (La + bump - Lb) * math.exp(-alpha * 1e-6 * (T - 10_000))
        assert img[1, 1] == pytest.approx(want, abs=1e-5)
    assert abs(out.image[-1] - Lb).max() < 1e-3  # converged: 190 ms at 50 rad/s
    assert "confidence" not in out.data


def test_the_first_frame_is_the_base_outright_and_without_frames_it_is_the_high_pass_filter():
    ev = HighPass.conformance_stream()["events"]
    hp = concat(feed_ports(HighPass(alpha=20.0), {"events": [ev]}))
    co = concat(feed_ports(Complementary(alpha=20.0), {"events": [ev]}))
    np.testing.assert_array_equal(hp.image, co.image)
    # a first frame at 25 ms: the map at 25 ms is the log frame plus what the events built up to then
    img = np.random.default_rng(1).integers(0, 256, (36, 48))
    at = (25_000,)
    got = concat(feed_ports(Complementary(alpha=20.0, at_us=at),
                            {"events": [ev], "frames": [_frames([25_000], [img], ev.t_end)]}))
    ref = concat(feed_ports(HighPass(alpha=20.0, at_us=at), {"events": [ev]}))
    np.testing.assert_allclose(got.image[0], ref.image[0] + log_frame(img.astype(np.uint8), OFF), atol=1e-5)


def test_a_map_holds_the_frames_before_its_window_end_not_one_at_the_end():
    # (an event and a frame at one instant commute: L stays continuous through a frame)
    ev = EventPacket.from_arrays(np.array([4_999, 5_000], np.int64), [0, 0], [0, 0], [1, 1], sensor=(2, 1),
                                 t_start=0, t_end=10_000)
    fr = _frames([5_000, 10_000], [np.full((1, 2), 100), np.full((1, 2), 250)], 10_001)
    out = concat(feed_ports(Complementary(alpha=0.0, window_us=5_000), {"events": [ev], "frames": [fr]}))
    L1 = math.log(100 / 255 + OFF)
    assert out.t.tolist()[:2] == [4_999, 9_999]
    assert out.image[0][0, 0] == pytest.approx(0.2, abs=1e-6)  # before any frame: the high-pass filter
    assert out.image[1][0, 0] == pytest.approx(L1 + 0.4, abs=1e-5)  # first frame: base outright under both events
    assert out.image[1][0, 1] == pytest.approx(L1, abs=1e-6)


@pytest.mark.parametrize("params", [{"window_us": 4_000}, {"count": 600}, {"at_us": (3_000, 6_000, 6_001, 31_000)}])
def test_batch_invariance_with_frames(params):
    assert_batch_invariant(lambda: Complementary(alpha=20.0, **params), Complementary.conformance_stream(),
                           max_examples=6)


def test_bad_frames_are_named():
    ev = HighPass.conformance_stream()["events"]
    small = _frames([1_000], [np.zeros((10, 10))], ev.t_end)
    with pytest.raises(ValueError, match="10x10 px at t = 1000"):
        feed_ports(Complementary(), {"events": [ev], "frames": [small]})
    with pytest.raises(ValueError, match="frame_offset"):
        Complementary(frame_offset=0.0)


def test_from_the_command_line_on_an_ecd_folder_with_frames(tmp_path):
    import cv2

    from tectum.sources.simulate import load_scene, simulate

    scene = load_scene("translation_edges", "48x36")
    scene["davis"] = {"aps_rate_hz": 50.0, "exposure_us": 2000.0}
    ev, truth = simulate(scene, duration_us=120_000, truth_fps=100, seed=2)
    (tmp_path / "events.txt").write_text(
        "".join(f"{t / 1e6:.9f} {x} {y} {int(p > 0)}\n" for t, x, y, p in zip(ev.t, ev.x, ev.y, ev.p)))
    (tmp_path / "images").mkdir()
    lines = []
    for k, (t, img) in enumerate(zip(np.asarray(truth["aps_t"]), np.asarray(truth["aps_images"]))):
        cv2.imwrite(str(tmp_path / "images" / f"frame_{k:08d}.png"), img)
        lines.append(f"{t / 1e6:.9f} images/frame_{k:08d}.png\n")
    (tmp_path / "images.txt").write_text("".join(lines))
    ft = np.asarray(truth["frame_t"])
    at = ft[ft >= 20_000]
    op = "map.complementary:at_us=" + ";".join(map(str, at))
    assert main(["run", "-q", str(tmp_path / "events.txt"), "--op", op, "--sink", str(tmp_path / "maps.npz")]) == 0
    z = np.load(tmp_path / "maps.npz")
    assert "frames_images" not in z  # the frames went into the filter, not past it
    np.testing.assert_array_equal(z["maps_t"], at)
    truth_log = np.log(np.asarray(truth["frame_intensity"])[ft >= 20_000] + 1e-3)
    err = [np.median(np.abs(m - L)) for m, L in zip(z["maps_image"], truth_log)]
    assert max(err) < 0.1  # absolute log intensity: the frames give the level the events cannot
