"""Flow rendering (colour wheel, arrows) and tracks, against slow references."""

from __future__ import annotations

import colorsys
import json
import math

import numpy as np

import tectum
from tectum.sinks.display.live import LiveViewSink
from tectum.sinks.display.render import BACKGROUND, TRACK_COLOUR, Renderer, cell_flow


def flow_events(vx: np.ndarray, vy: np.ndarray, sensor=(40, 30), t: int = 1000) -> tectum.EventPacket:
    n = len(vx)
    rng = np.random.default_rng(0)
    idx = rng.permutation(sensor[0] * sensor[1])[:n]
    pkt = tectum.EventPacket(np.full(n, t, np.int64), (idx % sensor[0]).astype(np.uint16),
                             (idx // sensor[0]).astype(np.uint16), np.ones(n, np.int8), sensor=sensor,
                             t_start=0, t_end=t + 1)
    return pkt.with_columns(vx=vx.astype(np.float32), vy=vy.astype(np.float32))


def test_colour_wheel_matches_a_slow_reference() -> None:
    rng = np.random.default_rng(1)
    vx, vy = rng.normal(0, 300, 200), rng.normal(0, 300, 200)
    pkt = flow_events(vx, vy)
    r = Renderer(pkt.sensor, fps=1000, mode="flow_wheel", flow_max_px_s=500)
    r.add(pkt)
    img = r.render(1500)
    seen = set()
    for i in range(len(pkt)):
        x, y = int(pkt.x[i]), int(pkt.y[i])
        fx, fy = float(np.float32(vx[i])), float(np.float32(vy[i]))
        hue = (math.atan2(-fy, fx) / (2 * math.pi)) % 1.0
        red, green, blue = colorsys.hsv_to_rgb(hue, min(1.0, math.hypot(fx, fy) / 500), 1.0)
        expect = [round(blue * 255), round(green * 255), round(red * 255)]
        assert np.abs(img[y, x].astype(int) - expect).max() <= 1, (x, y)
        seen.add((y, x))
    quiet = [(r_, c) for r_ in range(30) for c in range(40) if (r_, c) not in seen]
    assert all(tuple(img[q]) == BACKGROUND for q in quiet)


def test_cell_means_match_numpy_and_arrows_point_along_the_flow() -> None:
    n = 600
    pkt = flow_events(np.full(n, 400.0), np.full(n, 0.0))
    r = Renderer(pkt.sensor, fps=1000, mode="flow_arrows", arrow_step=10, arrow_scale_s=0.01)
    r.add(pkt)
    mean = np.zeros((3, 4, 3))
    cell_flow(r.last_t, r.vx, r.vy, np.int64(1500), np.int64(r.period_us), 10, mean)
    for i in range(3):
        for j in range(4):
            m = (pkt.y // 10 == i) & (pkt.x // 10 == j)
            assert mean[i, j, 2] == m.sum() and np.isclose(mean[i, j, 0], 400.0)
    img = r.render(1500)
    white = np.all(img == 255, axis=2) | (img.min(axis=2) > 200)
    # each arrow runs 4 px to the right of its cell centre (5, 15, 25 ...): tips right of centres
    assert white[5, 7:9].any() and white[15, 27:29].any()


def test_tracks_are_drawn_as_polylines() -> None:
    r = Renderer((40, 30), fps=1000, mode="polarity")
    r.add_tracks(tectum.ResultPacket(np.array([10, 20, 30]), [(7, 5.0, 5.0), {"id": 7, "x": 25.0, "y": 5.0},
                                                              "not a track"]))
    r.add(tectum.EventPacket.empty((40, 30), 0, 2000))
    img = r.render(2000)
    line = np.all(img[5, 6:25] == TRACK_COLOUR, axis=1)
    assert line.mean() > 0.8 and not np.any(np.all(img[20] == TRACK_COLOUR, axis=1))


def test_live_view_stats_include_the_pipeline() -> None:
    sink = LiveViewSink("http://127.0.0.1:0")
    stats = tectum.Stats()
    stats.node("src").events_out = 12
    sink.bind_stats(stats)
    raw = sink._response("/stats.json")
    body = json.loads(raw.split(b"\r\n\r\n", 1)[1])
    assert body["pipeline"]["nodes"]["src"]["events_out"] == 12
