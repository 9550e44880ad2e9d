"""Clusters in the display sinks: boxes, velocity lines and ids in each
cluster's colour over the event frames, the newest row as of the frame's
time, old clusters dropped, clusters alone as trails on a canvas."""

from __future__ import annotations

import cv2
import numpy as np

from tectum import ClusterPacket, EventPacket
from tectum.sinks.display.clusters import ClusterOverlay
from tectum.sinks.display.files import PngSink
from tectum.sinks.display.tracks import CANVAS, track_colour


def _clusters(t0: int, t1: int, t: list[int], ids: list[int], x: list[float], y: list[float]) -> ClusterPacket:
    n = len(t)
    return ClusterPacket(np.array(t, np.int64), id=np.array(ids), x=np.array(x), y=np.array(y),
                         vx=np.full(n, 200.0), vy=np.zeros(n), width=np.full(n, 10.0), height=np.full(n, 6.0),
                         mass=np.full(n, 50.0), t_start=t0, t_end=t1)


def test_overlay_draws_the_newest_box_as_of_the_frame_and_drops_old_ones():
    ov = ClusterOverlay(hold_us=5_000, lead_us=50_000)
    ov.add(_clusters(0, 10_000, [1000, 3000, 9000], [4, 4, 4], [20.0, 40.0, 60.0], [20.0, 20.0, 20.0]))
    img = np.zeros((40, 90, 3), np.uint8)
    ov.draw(img, 4000)  # the row at 3000: box 35..45 x 17..23, velocity line to x = 50
    c = track_colour(4)
    assert tuple(img[17, 40]) == c and tuple(img[23, 40]) == c and tuple(img[20, 35]) == c
    assert tuple(img[20, 48]) == c  # the velocity line, 200 px/s over 50 ms = 10 px
    assert not img[:, 55:].any()  # not the box of the row at 9000 (after the frame)
    late = np.zeros_like(img)
    ov.draw(late, 20_000)  # 11 ms after the last row: dropped
    assert not late.any() and not ov.rows


def test_png_sink_draws_clusters_over_the_events_and_alone_on_a_canvas(tmp_path):
    sink = PngSink(str(tmp_path / "f%d.png"), fps=100.0)
    ev = EventPacket(np.arange(50, dtype=np.int64) * 100, np.full(50, 5, np.uint16), np.full(50, 5, np.uint16),
                     np.ones(50, np.int8), sensor=(64, 48), t_start=0, t_end=10_000)
    sink.write(ev)
    sink.write(_clusters(10_000, 20_000, [11_000], [2], [30.0], [30.0]))
    sink.write(EventPacket(np.array([15_000], np.int64), np.array([5], np.uint16), np.array([5], np.uint16),
                           np.ones(1, np.int8), sensor=(64, 48), t_start=10_000, t_end=20_000))
    sink.close()
    img = cv2.imread(str(tmp_path / "f1.png"))
    assert tuple(img[27, 30]) == track_colour(2)  # the box's top edge
    alone = PngSink(str(tmp_path / "a%d.png"), fps=100.0)
    alone.write(_clusters(0, 30_000, [500, 15_000], [7, 7], [20.0, 24.0], [10.0, 10.0]))
    alone.close()
    img = cv2.imread(str(tmp_path / "a2.png"))
    assert tuple(img[0, 0]) == CANVAS and tuple(img[10, 22]) == track_colour(7)
