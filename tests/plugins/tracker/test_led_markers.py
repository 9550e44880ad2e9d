"""tracker.led_markers: transitions and blob positions against slow
references, layout files (good and bad), LEDs and pose on a simulated
moving body with a flickering lamp beside it, parameter errors, empty
input, and the command line (tracks CSV, TUM poses, ``tectum info``)."""

from __future__ import annotations

import subprocess
import sys
from functools import lru_cache

import numpy as np
import pytest

import tectum
from tectum import EventPacket, FormatError, PosePacket, TrackPacket, concat
from tectum.camera import quat_to_rot, rot_to_quat
from tectum.evaluation.metrics.tracking import id_accuracy, pose_errors
from tectum.plugins.tracker import LedMarkers
from tectum.plugins.tracker._leds import transitions_kernel
from tectum.plugins.tracker.layout import parse_layout, read_layout
from tectum.plugins.tracker.led_markers import _blinking_events
from tectum.sources.simulate import simulate
from tectum.sources.simulate.objects import LedBody
from tectum.testing import ListSink, ListSource, feed

FREQS = (1000.0, 1400.0, 1900.0, 2600.0)

BODY = LedBody(points=((0, 0, 0), (0.24, 0, 0), (0.24, 0.18, 0), (0, 0.18, 0.06), (0.12, 0.09, 0.1)),
               freqs_hz=(800.0, 1050.0, 1400.0, 1850.0, 2450.0), position=(-0.12, -0.1, 0.8),
               velocity=(0.2, 0.1), flicker=((20.0, 100.0, 6.0, 100.0),))


@lru_cache(maxsize=1)
def _body_events() -> EventPacket:
    """200 ms of the body (realistic sensor: noise, threshold spread, jitter;
    the photoreceptor's cut-off raised from the preset's 300 Hz at full
    scale, office light, to 5 kHz: LEDs are far brighter, and bandwidth grows
    with light)."""
    ev, _ = simulate(BODY.scene(), 200_000, seed=1, preset="realistic", lowpass_hz=5000.0)
    return EventPacket.from_arrays(ev.t, ev.x, ev.y, ev.p, sensor=ev.sensor, t_start=ev.t_start, t_end=ev.t_end)


def _layout(tmp_path, text: str | None = None) -> str:
    path = tmp_path / "layout.txt"
    path.write_text(BODY.layout_text() if text is None else text)
    return str(path)


# -- kernels against slow references -------------------------------------------------------------

def test_transitions_match_a_per_pixel_reference():
    ev = _blinking_events(20_000)
    pix = np.zeros((ev.sensor[1], ev.sensor[0], 3), np.int64)
    pix[:, :, 1:] = -1
    got = np.empty(len(ev), np.int64)
    transitions_kernel(ev.t, ev.x, ev.y, ev.p, pix, got)
    last_pol: dict = {}
    last: dict = {}
    want = []
    for t, x, y, p in zip(ev.t.tolist(), ev.x.tolist(), ev.y.tolist(), ev.p.tolist()):
        dt = -1
        if last_pol.get((x, y)) != p:  # a transition: the first event of a burst
            prev = last.get((x, y, p))
            dt = t - prev if prev is not None else -1
            last[(x, y, p)] = t
        last_pol[(x, y)] = p
        want.append(dt)
    assert np.array_equal(got, want)
    # the LED pixels' intervals are their periods (jitter up to 5 µs)
    on_led = (ev.x == 5) & (ev.y == 5) & (got > 0)
    assert np.all(np.abs(got[on_led] - 1000) <= 5)


def _reference_tracks(ev: EventPacket, freqs, tol, reject, update, window, blob_px, min_hits):
    """Tracks from the module's description, in plain Python."""
    pix_pol: dict = {}
    pix_t: dict = {}
    obs: list[list[tuple[int, int, int]]] = [[] for _ in freqs]
    for t, x, y, p in zip(ev.t.tolist(), ev.x.tolist(), ev.y.tolist(), ev.p.tolist()):
        if pix_pol.get((x, y)) != p:
            prev = pix_t.get((x, y, p))
            pix_t[(x, y, p)] = t
            if prev is not None and t > prev:
                f = 1e6 / (t - prev)
                for m, fm in enumerate(freqs):
                    if 1e6 / (fm * (1 + tol)) <= t - prev <= 1e6 * (1 + tol) / fm:
                        obs[m].append((t, x, y))
                        break
                del f
        pix_pol[(x, y)] = p
    rows = []
    T = -(-int(ev.t[0]) // update) * update
    while T < ev.t_end:
        for m in range(len(freqs)):
            w = np.array([(x, y) for t, x, y in obs[m] if T - window < t <= T], float).reshape(-1, 2)
            if not len(w):
                continue
            med = np.median(w, axis=0)
            keep = w[np.all(np.abs(w - med) <= blob_px, axis=1)]
            if len(keep) >= min_hits:
                rows.append((T, m + 1, *keep.mean(axis=0), len(keep)))
        T += update
    return np.array(rows)


def test_tracks_match_the_slow_reference():
    ev = _blinking_events(30_000)
    op = LedMarkers(freqs=FREQS, update_us=500, window_us=3000)
    out = concat([q for q in feed(op, [ev]) if isinstance(q, TrackPacket)])
    got = np.stack([out.t, out["id"], out["x"], out["y"], out["quality"]], axis=1)
    want = _reference_tracks(ev, FREQS, 0.1, (50, 100), 500, 3000, 3.0, 4)
    assert len(got) > 100 and got.shape == want.shape
    np.testing.assert_allclose(got, want, rtol=0, atol=1e-9)
    # the four LEDs' 2x2 blobs: centres at +0.5 px
    for k, (cx, cy) in enumerate(((5, 5), (20, 5), (5, 16), (22, 18)), 1):
        m = out["id"] == k
        assert np.all(np.abs(out["x"][m] - cx - 0.5) < 0.3) and np.all(np.abs(out["y"][m] - cy - 0.5) < 0.3)


# -- the simulated body ------------------------------------------------------------------------------

def test_simulated_body_ids_positions_and_pose(tmp_path):
    ev = _body_events()
    op = LedMarkers(layout=_layout(tmp_path), calib=BODY.calib)
    outs = feed(op, [ev])
    tracks = concat([q for q in outs if isinstance(q, TrackPacket)])
    poses = concat([q for q in outs if isinstance(q, PosePacket)])
    acc, med = id_accuracy(tracks["id"], tracks["x"], tracks["y"], BODY.image_points(tracks.t), np.arange(1, 6), 3.0)
    assert acc > 0.99 and med < 0.35, (acc, med)
    assert len(np.unique(tracks.t)) >= 190  # every ms after the first window
    # the 100 Hz lamp's periods are counted as flicker, and no track is near it
    assert op.counts["flicker"] > 100
    assert np.all(np.hypot(tracks["x"] - 20, tracks["y"] - 100) > 10)
    # pose: the camera in the body's frame = the inverse of the body in the camera's
    pos, q = BODY.poses(poses.t)
    R_wc = np.transpose(quat_to_rot(q), (0, 2, 1))
    te, re = pose_errors(poses["position"], poses["orientation"], -np.einsum("nij,nj->ni", R_wc, pos),
                         rot_to_quat(R_wc))
    # (the LEDs span about 45 px: 0.2 px of position error is a few cm at 0.8 m)
    assert len(poses) >= 190 and np.median(te) < 0.04 and np.median(re) < 2.5, (np.median(te), np.median(re))


# -- layout files -------------------------------------------------------------------------------------

def test_layout_file_reads_ids_points_and_frequencies(tmp_path):
    lay = read_layout(_layout(tmp_path, "# a comment\n\n3, 0, 0, 0, 700  # first\n1 0.1 0 0 950\n"
                                        "2\t0.1\t0.08\t0\t1200\n7 0 0.08 0.02 1500\n"))
    assert lay.ids.tolist() == [3, 1, 2, 7] and lay.freqs.tolist() == [700, 950, 1200, 1500]
    assert np.allclose(lay.points[3], [0, 0.08, 0.02])


@pytest.mark.abuse
@pytest.mark.parametrize("text, match", [
    ("1 0 0 0 700\n2 1 0 0 950\n3 1 1 0 1200\n", "3 LEDs; the pose needs at least 4"),
    ("1 0 0 0 700\n2 1 0 0 950\n3 1 1 0 700\n4 0 1 0 1500\n", "line 3: frequency 700 Hz repeats line 1"),
    ("1 0 0 0 700\n2 1 0 0 950\n2 1 1 0 1200\n4 0 1 0 1500\n", "line 3: id 2 repeats line 2"),
    ("1 0 0 0 700\n2 1 nan 0 950\n3 1 1 0 1200\n4 0 1 0 1500\n", "line 2: non-finite"),
    ("1 0 0 0 700\n2 1 0 0\n", "line 2: expected 'id x y z frequency_hz', got 4 values"),
    ("1 0 0 0 700\nLED 1 0 0 950\n", "line 2: not numbers"),
    ("1 0 0 0 -5\n", "line 1: frequency -5 Hz must be > 0"),
    ("0 0 0 0 700\n", "line 1: id 0 must be a positive integer"),
    ("", "0 LEDs"),
])
def test_bad_layout_files_are_rejected_with_the_reason(tmp_path, text, match):
    path = _layout(tmp_path, text)
    with pytest.raises(FormatError, match=match):
        read_layout(path)
    with pytest.raises(FormatError, match=match):  # before any event: at construction
        LedMarkers(layout=path, calib="100;100;50;50")


def test_bands_that_overlap_or_hold_mains_flicker_are_refused(tmp_path):
    with pytest.raises(ValueError, match="1000 and 1150 Hz are within the tolerance"):
        LedMarkers(freqs=(1000.0, 1150.0, 2000.0, 3000.0))
    with pytest.raises(ValueError, match="105 Hz is within the tolerance .* of 100 Hz"):
        LedMarkers(freqs=(105.0, 1000.0, 2000.0, 3000.0))
    LedMarkers(freqs=(1000.0, 1250.0))  # far enough apart


def test_missing_frequencies_calib_or_both_sources_are_named(tmp_path):
    with pytest.raises(ValueError, match="layout= .* or freqs="):
        LedMarkers()
    with pytest.raises(ValueError, match="calib="):
        LedMarkers(layout=_layout(tmp_path))
    with pytest.raises(ValueError, match="not both"):
        LedMarkers(layout=_layout(tmp_path), freqs=FREQS)
    with pytest.raises(FormatError, match="no such layout file"):
        LedMarkers(layout=str(tmp_path / "absent.txt"), calib="1;1;1;1")
    assert len(parse_layout(BODY.layout_text())) == 5


def test_empty_input_and_ticks_give_nothing():
    op = LedMarkers(freqs=FREQS)
    empty = EventPacket.from_arrays([], [], [], [], sensor=(8, 8), t_start=0, t_end=50_000)
    assert op.process(empty) == [] and op.finish() == ()


def test_a_long_gap_costs_nothing_and_resumes_on_the_grid():
    ev = _blinking_events(10_000)
    later = EventPacket.from_arrays(ev.t + 10**12, ev.x, ev.y, ev.p, sensor=ev.sensor, t_start=10**12,
                                    t_end=10**12 + 10_000)
    op = LedMarkers(freqs=FREQS, update_us=500, window_us=3000)
    a = op.process(ev)
    gap = EventPacket.from_arrays([], [], [], [], sensor=ev.sensor, t_start=10_000, t_end=10**12)
    tail = op.process(gap)  # the last window's outputs, then nothing for 11 days of stream
    assert len(tail) == 1 and tail[0].t.max() <= 10_000 + 3000
    b = op.process(later)
    assert len(a) and len(b) and np.all(b[0].t % 500 == 0) and b[0].t[0] > 10**12


# -- the command line ---------------------------------------------------------------------------------

def _recording(tmp_path) -> str:
    """The simulated body's events as ``ev.npz`` with a UZH ``calib.txt`` beside it."""
    ev = _body_events()
    p = tectum.Pipeline()
    p.sink(str(tmp_path / "ev.npz"), p.source(ListSource([ev])))
    tectum.run(p)
    K = BODY.K
    (tmp_path / "calib.txt").write_text(f"{K[0, 0]} {K[1, 1]} {K[0, 2]} {K[1, 2]} 0 0 0 0 0\n")
    return str(tmp_path / "ev.npz")


def test_from_the_command_line_to_tum_and_csv(tmp_path):
    rec = _recording(tmp_path)
    tum, csv = tmp_path / "pose.tum", tmp_path / "leds.csv"
    run = subprocess.run([sys.executable, "-m", "tectum", "run", rec, "--op",
                          f"tracker.led_markers:layout={_layout(tmp_path)}", "--sink", str(tum), "--sink", str(csv)],
                         capture_output=True, text=True)
    assert run.returncode == 0, run.stderr
    rows = [r.split() for r in tum.read_text().splitlines() if r and not r.startswith("#")]
    assert len(rows) >= 190 and all(len(r) == 8 for r in rows)
    assert csv.read_text().startswith("# tectum tracks")
    for f in (tum, csv):
        info = subprocess.run([sys.executable, "-m", "tectum", "info", str(f)], capture_output=True, text=True)
        assert info.returncode == 0, info.stderr


def test_command_line_refuses_a_bad_layout_before_running(tmp_path):
    rec = _recording(tmp_path)
    bad = _layout(tmp_path, "1 0 0 0 700\n2 1 0 0 700\n3 1 1 0 900\n4 0 1 0 1500\n")
    run = subprocess.run([sys.executable, "-m", "tectum", "run", rec, "--op", f"tracker.led_markers:layout={bad}",
                          "--sink", str(tmp_path / "pose.tum")], capture_output=True, text=True)
    assert run.returncode != 0 and "frequency 700 Hz repeats line 1" in run.stderr
    assert len(run.stderr.strip().splitlines()) == 1 and not (tmp_path / "pose.tum").exists()


def test_in_a_pipeline_with_inline_calib(tmp_path):
    p = tectum.Pipeline()
    led = p.op("tracker.led_markers", p.source(ListSource([_body_events()])), layout=_layout(tmp_path),
               calib=BODY.calib)
    sink = ListSink()
    p.sink(sink, led)
    tectum.run(p)
    assert {q.kind for q in sink.packets if len(q)} == {tectum.Kind.TRACKS, tectum.Kind.POSES}


def test_poses_do_not_depend_on_how_packets_cut_the_stream(tmp_path):
    ev = _body_events().slice_time(0, 12_000)
    layout = _layout(tmp_path)
    tectum.testing.assert_batch_invariant(lambda: LedMarkers(layout=layout, calib=BODY.calib), ev, max_examples=5,
                                          event_by_event_check=False)


def test_pose_packets_are_back_to_back_when_some_updates_have_no_pose(tmp_path):
    ev = _body_events().slice_time(0, 20_000)
    op = LedMarkers(layout=_layout(tmp_path), calib=BODY.calib)
    poses = [q for q in feed(op, list(ev.batches(20))) if isinstance(q, PosePacket)]  # most packets: no output time
    assert len(poses) > 3 and poses[0].t_start == 0
    tectum.testing.assert_stream_contract(poses)
