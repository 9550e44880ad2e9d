"""Frames in the display sinks: a representation's frames (``repr.*``) or APS
frames become pictures, one a frame, when no events reach the sink (with
events the pictures are of the events, and the frames are counted as not
written), from the command line as a user runs it."""

from __future__ import annotations

import json
import subprocess
import sys
import time
import urllib.request
from pathlib import Path

import cv2
import numpy as np
import pytest
from davis_recording import davis_packets, write_davis

import tectum
from tectum import FramePacket, Kind
from tectum.sinks.display.files import FrameCallbackSink
from tectum.sinks.display.frames import frame_picture
from tectum.sinks.display.maps import UNKNOWN_COLOUR
from tectum.sinks.display.render import BACKGROUND, OFF_COLOUR, ON_COLOUR
from tectum.testing import ListSource

TECTUM = [sys.executable, "-m", "tectum"]


def test_an_aps_frame_is_grey_as_it_is() -> None:
    img = np.arange(12, dtype=np.uint8).reshape(3, 4) * 20
    pic = frame_picture(img, 0)
    assert pic.shape == (3, 4, 3) and pic.dtype == np.uint8
    assert (pic == img[:, :, None]).all()


def test_counts_are_stretched_to_their_99th_percentile_and_nan_is_unknown() -> None:
    img = np.zeros((10, 10), np.float32)
    img[0, :] = np.arange(1, 11)
    img[1, 0] = np.nan
    pic = frame_picture(img, 0)
    assert (pic[2:] == 0).all()  # no count: black
    assert pic[0, 9, 0] == 255 and 0 < pic[0, 0, 0] < pic[0, 5, 0] < 255
    assert (pic[1, 0] == UNKNOWN_COLOUR).all()


def test_signed_and_polarity_frames_are_drawn_in_the_event_colours() -> None:
    signed = np.array([[3, 0, -3]], np.int32)
    pic = frame_picture(signed, 0)
    assert pic[0, 0].tolist() == list(ON_COLOUR) and pic[0, 1].tolist() == list(BACKGROUND)
    assert pic[0, 2].tolist() == list(OFF_COLOUR)
    ef = np.zeros((1, 3, 2), np.int32)  # channel 0 OFF, 1 ON (repr.event_frame)
    ef[0, 0, 1], ef[0, 2, 0] = 5, 5
    pic = frame_picture(ef, 0)
    assert pic[0, 0].tolist() == list(ON_COLOUR) and pic[0, 2].tolist() == list(OFF_COLOUR)
    ts = np.zeros((1, 3, 2), np.float32)  # a time surface: 0..1 as it is, not stretched
    ts[0, 0, 1] = 0.5
    half = frame_picture(ts, 0)[0, 0].astype(float)
    np.testing.assert_allclose(half, (np.array(BACKGROUND) + np.array(ON_COLOUR)) / 2, atol=1)


def test_times_are_drawn_by_recency_newest_brightest() -> None:
    never = np.iinfo(np.int64).min // 2
    sae = np.full((1, 4, 2), never, np.int64)
    sae[0, 0, 1], sae[0, 1, 1], sae[0, 2, 0] = 1000, 900, 1000
    pic = frame_picture(sae, 1000).astype(int)
    assert pic[0, 0].tolist() == list(ON_COLOUR) and pic[0, 3].tolist() == list(BACKGROUND)
    assert abs(pic[0, 1] - np.array(BACKGROUND)).sum() < abs(pic[0, 0] - np.array(BACKGROUND)).sum()
    assert pic[0, 2].tolist() == list(OFF_COLOUR)


def test_colour_frames_are_rgb_and_bins_are_summed() -> None:
    rgb = np.zeros((1, 1, 3), np.uint8)
    rgb[0, 0] = (255, 0, 0)  # red in RGB
    assert frame_picture(rgb, 0)[0, 0].tolist() == [0, 0, 255]  # red in BGR
    bins = np.zeros((1, 2, 5), np.float32)
    bins[0, 0, :] = 1.0
    bins[0, 1, :] = -1.0
    pic = frame_picture(bins, 0)
    assert pic[0, 0].tolist() == list(ON_COLOUR) and pic[0, 1].tolist() == list(OFF_COLOUR)
    with pytest.raises(ValueError, match="not a picture"):
        frame_picture(np.zeros((2, 2, 2, 2)), 0)


def _cli(*args: str) -> subprocess.CompletedProcess[str]:
    r = subprocess.run([*TECTUM, *args], capture_output=True, text=True)
    assert r.returncode == 0, r.stderr
    return r


def test_a_representation_to_a_video_and_a_png_from_the_command_line(tmp_path: Path) -> None:
    write_davis(tmp_path / "davis.npz")
    video = tmp_path / "ef.mp4"
    _cli("run", str(tmp_path / "davis.npz"), "--op", "repr.event_frame:window_us=20000", "--sink", str(video))
    cap = cv2.VideoCapture(str(video))
    n = 0
    while True:
        ok, img = cap.read()
        if not ok:
            break
        n += 1
        assert img.shape == (26, 34, 3)
    assert n == 10  # one picture per event frame (200 ms in 20 ms windows)
    png = tmp_path / "ts.png"
    _cli("run", str(tmp_path / "davis.npz"), "--op", "repr.time_surface:window_us=20000", "--sink", str(png))
    got = cv2.imread(str(png))
    assert got.shape == (26, 34, 3) and len(np.unique(got.reshape(-1, 3), axis=0)) > 10  # not a blank picture


def test_with_events_the_pictures_are_of_the_events_and_the_frames_are_counted(tmp_path: Path) -> None:
    write_davis(tmp_path / "davis.npz")
    r = _cli("run", str(tmp_path / "davis.npz"), "--sink", str(tmp_path / "ev.mp4"))
    assert "not written: 10 frames" in r.stderr


def test_a_sink_built_in_python_draws_frames_until_events_come() -> None:
    frames = [q for q in davis_packets() if q.kind == Kind.FRAMES]
    got: list[tuple[int, np.ndarray]] = []
    p = tectum.Pipeline()
    p.sink(FrameCallbackSink(lambda t, img: got.append((t, img))), p.source(ListSource(frames)))
    tectum.run(p)
    assert [t for t, _ in got] == [int(t) for q in frames for t in q.t]
    assert all(isinstance(q, FramePacket) for q in frames)
    np.testing.assert_array_equal(got[0][1], frame_picture(frames[0].data["images"][0], int(frames[0].t[0])))



@pytest.mark.parametrize("live_view", [{"op": "repr.event_frame", "op_params": {"window_us": 50_000}}], indirect=True)
def test_the_live_view_serves_a_representation_with_its_caption(live_view: str) -> None:
    stats = json.loads(urllib.request.urlopen(live_view + "/stats.json", timeout=2).read())
    assert stats["frames"] >= 1 and stats["events"] == 0, stats
    assert stats["view"]["title"] == "Frames" and "Frame (96x64 px)" in stats["view"]["caption"]
    assert "ON events light blue" in stats["view"]["caption"]
    deadline = time.monotonic() + 30
    while True:  # the frames keep coming: one shows the bars' edges over the background
        png = urllib.request.urlopen(live_view + "/frame.png", timeout=2).read()
        pic = cv2.imdecode(np.frombuffer(png, np.uint8), cv2.IMREAD_COLOR)
        assert pic.shape == (128, 192, 3)  # scale=2
        colours = {tuple(int(v) for v in c) for c in pic.reshape(-1, 3)}
        if len(colours) > 2 or time.monotonic() > deadline:
            break
        time.sleep(0.05)
    assert tuple(BACKGROUND) in colours and tuple(ON_COLOUR) in colours and tuple(OFF_COLOUR) in colours
