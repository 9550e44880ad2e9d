"""Display sinks: rendering, video and PNG files, callback, live view in a
real headless Chromium."""

from __future__ import annotations

import os
import shutil
import socket
import subprocess
import time
import urllib.request

import cv2
import numpy as np
import pytest

import tectum
from tectum.sinks.display.files import FrameCallbackSink, PngSink, VideoSink
from tectum.sinks.display.live import LiveViewSink
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


def free_port() -> int:
    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        return s.getsockname()[1]


@pytest.fixture
def live_view():
    port = free_port()
    p = tectum.Pipeline(pace=1.0)
    p.sink(LiveViewSink(f"http://127.0.0.1:{port}", fps=20, scale=2),
           p.source("pattern:", sensor="96x64", duration_us=60_000_000, speed=40.0, period_px=32, bar_px=12,
                    noise_hz=0.0))
    th = tectum.ThreadedPipeline(p, watch=[]).start()
    base = f"http://127.0.0.1:{port}"
    deadline = time.monotonic() + 60
    while time.monotonic() < deadline:
        try:
            if '"frames": 0' not in urllib.request.urlopen(base + "/stats.json", timeout=2).read().decode():
                break
        except OSError:
            pass
        time.sleep(0.05)
    yield base
    th.stop()
    th.join(60)


def test_live_view_serves_page_frames_and_stats(live_view: str) -> None:
    page = urllib.request.urlopen(live_view + "/", timeout=5).read().decode()
    assert "/frame.png" in page and "/stats.json" in page
    png = urllib.request.urlopen(live_view + "/frame.png", timeout=5).read()
    img = cv2.imdecode(np.frombuffer(png, np.uint8), cv2.IMREAD_COLOR)
    assert img.shape == (128, 192, 3)
    import json

    st = json.loads(urllib.request.urlopen(live_view + "/stats.json", timeout=5).read())
    assert st["frames"] > 0 and st["events"] > 0


def _screenshot(url: str, path: str, profile: str) -> np.ndarray:
    exe = shutil.which("chromium") or shutil.which("chromium-browser")
    subprocess.run([exe, "--headless", "--no-sandbox", "--disable-gpu", "--disable-quic", "--no-first-run",
                    "--disable-background-networking", "--disable-component-update", "--disable-sync",
                    "--disable-dev-shm-usage", f"--user-data-dir={profile}", f"--screenshot={path}",
                    "--window-size=320,240", "--virtual-time-budget=300", url],
                   check=True, timeout=60, capture_output=True)
    img = cv2.imread(path)
    assert img is not None
    return img


@pytest.mark.skipif(not (shutil.which("chromium") or shutil.which("chromium-browser")),
                    reason="chromium is not installed (Debian package 'chromium', see .ci/apt-packages.txt)")
def test_headless_chromium_shows_the_moving_bars(live_view: str, tmp_path) -> None:
    a = _screenshot(live_view + "/", str(tmp_path / "a.png"), str(tmp_path / "prof"))
    time.sleep(0.6)
    b = _screenshot(live_view + "/", str(tmp_path / "b.png"), str(tmp_path / "prof"))
    view = (slice(0, 128), slice(0, 192))  # the image, 2x scaled, at the page's top left
    for img in (a, b):
        px = img[view].reshape(-1, 3).astype(int)
        on = (np.abs(px - ON_COLOUR).sum(axis=1) < 30).mean()
        off = (np.abs(px - OFF_COLOUR).sum(axis=1) < 30).mean()
        bg = (np.abs(px - BACKGROUND).sum(axis=1) < 30).mean()
        assert on > 0.01 and off > 0.01 and bg > 0.5, (on, off, bg)  # bar edges in both colours
    moved = np.abs(a[view].astype(int) - b[view].astype(int)).sum(axis=2) > 60
    assert moved.mean() > 0.01  # the bars moved between the two screenshots
