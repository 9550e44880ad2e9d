"""Display sinks: rendering, video and PNG files, callback, the live view's
server (its page in a real browser: test_live_browser.py)."""

from __future__ import annotations

import os
import urllib.request

import cv2
import numpy as np
import pytest

import tectum
from tectum.sinks.display.files import FrameCallbackSink, PngSink
from tectum.sinks.display.render import BACKGROUND, OFF_COLOUR, ON_COLOUR, Renderer
from tectum.sources.pattern import moving_bars


def bars(t0: int = 0, t1: int = 100_000) -> tectum.EventPacket:
    return moving_bars(t0, t1, sensor=(48, 32), speed=300.0, period_px=16, bar_px=6, noise_hz=0.0,
                       jitter_us=0.0, rng=np.random.default_rng(0))


def reference_frame(pkt: tectum.EventPacket, now: int, period: int) -> np.ndarray:
    w, h = pkt.sensor
    img = np.zeros((h, w, 3), np.uint8)
    img[:] = BACKGROUND
    last: dict[tuple[int, int], tuple[int, int]] = {}
    for t, x, y, p in zip(pkt.t.tolist(), pkt.x.tolist(), pkt.y.tolist(), pkt.p.tolist()):
        if t < now:
            last[(y, x)] = (t, p)
    for (y, x), (t, p) in last.items():
        if t >= now - period:
            img[y, x] = ON_COLOUR if p > 0 else OFF_COLOUR
    return img


def test_polarity_frames_match_a_reference_and_do_not_depend_on_batching() -> None:
    pkt = bars()
    whole = Renderer(pkt.sensor, fps=100).add(pkt)
    r = Renderer(pkt.sensor, fps=100)
    pieces = [f for q in pkt.batches(777) for f in r.add(q)]
    assert [t for t, _ in whole] == [t for t, _ in pieces] == list(range(10_000, 100_001, 10_000))
    for (t, a), (_, b) in zip(whole, pieces):
        assert np.array_equal(a, b)
        assert np.array_equal(a, reference_frame(pkt, t, 10_000))


def test_time_surface_decays() -> None:
    pkt = bars(0, 20_000)
    r = Renderer(pkt.sensor, fps=50, mode="time_surface", tau_us=5_000)
    (_, img), = r.add(pkt)
    assert img.std() > 0
    later = r.render(200_000)
    assert np.all(later == np.array(BACKGROUND, np.uint8))


@pytest.mark.parametrize("ext", [".mp4", ".avi"])
def test_video_file_has_the_frames(tmp_path, ext: str) -> None:
    out = tmp_path / f"v{ext}"
    p = tectum.Pipeline()
    p.sink(str(out), p.source("pattern:", sensor="64x48", duration_us=500_000), fps=20)
    tectum.run(p)
    cap = cv2.VideoCapture(str(out))
    n = 0
    while cap.read()[0]:
        n += 1
    cap.release()
    assert n == 10 and not [f for f in os.listdir(tmp_path) if f.startswith(".tectum")]


def test_png_snapshot_and_every_frame(tmp_path) -> None:
    p = tectum.Pipeline()
    s = p.source("pattern:", sensor="64x48", duration_us=200_000)
    p.sink(str(tmp_path / "last.png"), s, fps=10)
    p.sink(PngSink(str(tmp_path / "f%03d.png"), fps=10), s)
    tectum.run(p)
    img = cv2.imread(str(tmp_path / "last.png"))
    assert img.shape == (48, 64, 3) and (img == np.array(ON_COLOUR, np.uint8)).all(axis=2).any()
    assert sorted(os.listdir(tmp_path)) == ["f000.png", "f001.png", "last.png"]


def test_frame_callback() -> None:
    got: list[tuple[int, tuple[int, ...]]] = []
    p = tectum.Pipeline()
    p.sink(FrameCallbackSink(lambda t, img: got.append((t, img.shape)), fps=25),
           p.source("pattern:", sensor="32x16", duration_us=200_000))
    tectum.run(p)
    assert got == [(t, (16, 32, 3)) for t in range(40_000, 200_001, 40_000)]


def test_live_view_serves_page_frames_and_stats(live_view: str) -> None:
    page = urllib.request.urlopen(live_view + "/", timeout=5).read().decode()
    assert "/frame.png" in page and "/stats.json" in page
    png = urllib.request.urlopen(live_view + "/frame.png", timeout=5).read()
    img = cv2.imdecode(np.frombuffer(png, np.uint8), cv2.IMREAD_COLOR)
    assert img.shape == (128, 192, 3)
    import json

    st = json.loads(urllib.request.urlopen(live_view + "/stats.json", timeout=5).read())
    assert st["frames"] > 0 and st["events"] > 0
