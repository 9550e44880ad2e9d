"""map.high_pass: the kernel against a slow reference, the leak's closed
form, the window rules, batch invariance in every mode, and the user's path
(a simulated scene written as an ECD folder, run from the command line)."""

from __future__ import annotations

import math

import numpy as np
import pytest

from tectum import EventPacket, concat
from tectum.cli import main
from tectum.evaluation.metrics.maps import pearson
from tectum.plugins.map import HighPass
from tectum.plugins.map._integrate import NEVER, integrate_events, new_state, read_map
from tectum.testing import assert_batch_invariant, feed_ports


def _reference(t, x, y, p, sensor, alpha, c_on, c_off, at):
    """Slow and obvious: per pixel, the list of its events; the map at T is
    the sum of each event's contrast times exp(-alpha (T - t_i))."""
    w, h = sensor
    out = np.zeros((h, w))
    for ti, xi, yi, pi in zip(t.tolist(), x.tolist(), y.tolist(), p.tolist()):
        if ti <= at:
            out[yi, xi] += (c_on if pi > 0 else -c_off) * math.exp(-alpha * 1e-6 * (at - ti))
    return out


def _random_events(n=3000, sensor=(9, 7), span=200_000, seed=0):
    rng = np.random.default_rng(seed)
    t = np.sort(rng.integers(0, span, n)).astype(np.int64)
    x = rng.integers(0, sensor[0], n).astype(np.uint16)
    y = rng.integers(0, sensor[1], n).astype(np.uint16)
    p = np.where(rng.random(n) < 0.6, 1, -1).astype(np.int8)
    return EventPacket(t, x, y, p, sensor=sensor, t_start=0, t_end=span)


def test_kernel_matches_a_slow_reference():
    ev = _random_events()
    D, tl = new_state(ev.sensor)
    alpha = 12.0
    integrate_events(ev.t, ev.x, ev.y, ev.p, D, tl, alpha * 1e-6, 0.25, 0.15)
    T = 210_000
    image, conf = np.empty_like(D), np.empty_like(D)
    read_map(D, tl, np.empty((0, 0), np.float32), T, alpha * 1e-6, image, conf)
    ref = _reference(ev.t, ev.x, ev.y, ev.p, ev.sensor, alpha, 0.25, 0.15, T)
    np.testing.assert_allclose(image, ref, rtol=1e-4, atol=1e-5)
    # the last update time and the confidence of the latest event
    last = np.full(D.shape, NEVER)
    last[ev.y, ev.x] = ev.t  # times increase: the last write wins
    np.testing.assert_array_equal(tl, last)
    np.testing.assert_allclose(conf, np.exp(-alpha * 1e-6 * (T - last)), rtol=1e-5)


def test_the_leak_on_one_pixel_is_the_closed_form_and_maps_leave_the_state_alone():
    # ON, ON, OFF at one pixel; maps every 10 ms: L(T) = sum c_i exp(-a (T - t_i))
    t = np.array([1_000, 4_000, 23_000], np.int64)
    ev = EventPacket.from_arrays(t, [2, 2, 2], [1, 1, 1], [1, 1, -1], sensor=(4, 3), t_start=0, t_end=50_000)
    a, con, coff = 40.0, 0.3, 0.2
    out = concat(feed_ports(HighPass(alpha=a, c_on=con, c_off=coff, window_us=10_000), {"events": [ev]}))
    assert out.t.tolist() == [9_999, 19_999, 29_999, 39_999, 49_999]
    c = np.array([con, con, -coff])
    for T, img, conf in zip(out.t, out.image, out.confidence):
        seen = t <= T
        want = float(np.sum(c[seen] * np.exp(-a * 1e-6 * (T - t[seen]))))
        assert img[1, 2] == pytest.approx(want, rel=1e-5)
        assert conf[1, 2] == pytest.approx(math.exp(-a * 1e-6 * (T - t[seen][-1])), rel=1e-5)
        assert np.count_nonzero(img) == 1 and np.count_nonzero(conf) == 1  # never-seen pixels: 0, no confidence


def test_alpha_zero_is_plain_integration():
    ev = _random_events(n=500, seed=3)
    out = concat(feed_ports(HighPass(alpha=0.0, c_on=0.2, c_off=0.2, at_us=(ev.t_end,)), {"events": [ev]}))
    want = np.zeros((7, 9))
    np.add.at(want, (ev.y, ev.x), 0.2 * ev.p)
    np.testing.assert_allclose(out.image[0], want, atol=1e-5)


def test_count_windows_and_instants():
    ev = _random_events(n=1000, seed=1)
    out = concat(feed_ports(HighPass(count=300), {"events": [ev]}))
    # every 300 events, stamped at the 300th; the last 100 at the stream's end
    assert out.t.tolist() == [int(ev.t[299]), int(ev.t[599]), int(ev.t[899]), ev.t_end]
    at = (0, 50_000, 50_001, 300_000)  # the last is past the stream's end
    got = concat(feed_ports(HighPass(at_us=at), {"events": [ev]}))
    assert got.t.tolist() == list(at)
    ref = _reference(ev.t, ev.x, ev.y, ev.p, ev.sensor, 15.0, 0.2, 0.2, 50_000)
    np.testing.assert_allclose(got.image[1], ref, rtol=1e-4, atol=1e-5)


@pytest.mark.parametrize("params", [{"count": 700, "alpha": 30.0}, {"at_us": (5_000, 12_345, 39_999, 41_000)},
                                    {"window_us": 7_000, "partial": False}])
def test_batch_invariance_in_every_mode(params):
    stream = HighPass.conformance_stream()
    assert_batch_invariant(lambda: HighPass(**params), stream, max_examples=6)


def test_bad_parameters_are_named():
    with pytest.raises(ValueError, match="alpha"):
        HighPass(alpha=-1.0)
    with pytest.raises(ValueError, match="c_on"):
        HighPass(c_on=0.0)
    with pytest.raises(ValueError, match="one of window_us, count and at_us"):
        HighPass(window_us=1000, count=10)
    with pytest.raises(ValueError, match="increasing"):
        HighPass(at_us=(5, 5))


def _write_ecd(folder, ev: EventPacket) -> None:
    lines = [f"{t / 1e6:.9f} {x} {y} {int(p > 0)}" for t, x, y, p in zip(ev.t, ev.x, ev.y, ev.p)]
    (folder / "events.txt").write_text("\n".join(lines) + "\n")


def test_from_the_command_line_on_a_simulated_scene_written_as_an_ecd_folder(tmp_path, capsys):
    from tectum.sources.simulate import simulate

    ev, truth = simulate("rotation", duration_us=200_000, sensor="48x36", truth_fps=100, seed=1)
    _write_ecd(tmp_path, ev)
    ft = np.asarray(truth["frame_t"])
    at = ft[ft >= 100_000]  # maps at the truth's instants, after 100 ms of motion (the filter's memory is 67 ms)
    op = "map.high_pass:at_us=" + ";".join(map(str, at))
    assert main(["run", "-q", str(tmp_path / "events.txt") + "?sensor=48x36", "--op", op,
                 "--sink", str(tmp_path / "maps.npz")]) == 0
    z = np.load(tmp_path / "maps.npz")
    assert z["maps_image"].shape == (len(at), 36, 48) and z["maps_confidence"].shape == (len(at), 36, 48)
    assert z["maps_image"].dtype == np.float32
    np.testing.assert_array_equal(z["maps_t"], at)
    truth_log = np.log(np.asarray(truth["frame_intensity"])[ft >= 100_000] + 1e-3)
    scores = [pearson(img, L) for img, L in zip(z["maps_image"], truth_log)]
    assert np.median(scores) > 0.8
    capsys.readouterr()
    assert main(["info", str(tmp_path / "maps.npz")]) == 0
    assert "maps" in capsys.readouterr().out
