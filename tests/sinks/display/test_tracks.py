"""Feature tracks in the display sinks: trails in each track's colour over
the event frames, tracks alone on their own canvas, old trails dropped."""

from __future__ import annotations

import numpy as np

from tectum import EventPacket, TrackPacket
from tectum.sinks.display.files import PngSink
from tectum.sinks.display.tracks import CANVAS, TrackFrames, TrackOverlay, track_colour


def _tracks(t0: int, t1: int, ids: list[int], x: list[float], y: list[float], t: list[int]) -> TrackPacket:
    return TrackPacket(np.array(t, np.int64), id=np.array(ids), x=np.array(x), y=np.array(y),
                       quality=np.ones(len(t)), t_start=t0, t_end=t1)


def test_overlay_draws_each_trail_in_its_colour_and_forgets_old_ones():
    ov = TrackOverlay(trail_us=10_000)
    ov.add(_tracks(0, 20_000, [1, 1, 2], [10.0, 30.0, 50.0], [20.0, 20.0, 40.0], [1000, 2000, 3000]))
    img = np.zeros((60, 80, 3), np.uint8)
    ov.draw(img, 5000)
    assert tuple(img[20, 20]) == track_colour(1)  # on the trail from (10, 20) to (30, 20)
    assert any(tuple(img[40 + dy, 53]) == track_colour(2) for dy in (-1, 0, 1))  # the circle around (50, 40)
    assert track_colour(1) != track_colour(2)
    late = np.zeros_like(img)
    ov.draw(late, 20_000)  # 10 ms after the last row: nothing left
    assert not late.any() and not ov.trails


def test_tracks_alone_are_drawn_on_a_canvas_at_the_frame_rate():
    tf = TrackFrames(fps=100.0)
    frames = tf.add(_tracks(0, 30_000, [0, 0], [20.0, 24.0], [10.0, 10.0], [500, 15_000]))
    assert [t for t, _ in frames] == [10_000, 20_000, 30_000]
    img = frames[-1][1]
    assert tuple(img[0, 0]) == CANVAS and img.shape[1] > 24 and img.shape[0] > 10
    assert tuple(img[10, 22]) == track_colour(0)


def test_png_sink_draws_tracks_over_the_events(tmp_path):
    sink = PngSink(str(tmp_path / "f%d.png"), fps=100.0)
    n = 50
    ev = EventPacket(np.arange(n, dtype=np.int64) * 100, np.full(n, 5, np.uint16), np.full(n, 5, np.uint16),
                     np.ones(n, np.int8), sensor=(64, 48), t_start=0, t_end=10_000)
    sink.write(ev)
    sink.write(_tracks(10_000, 20_000, [3, 3], [30.0, 40.0], [30.0, 30.0], [11_000, 12_000]))
    sink.write(EventPacket(np.array([15_000], np.int64), np.array([5], np.uint16), np.array([5], np.uint16),
                           np.ones(1, np.int8), sensor=(64, 48), t_start=10_000, t_end=20_000))
    sink.close()
    import cv2

    img = cv2.imread(str(tmp_path / "f1.png"))
    assert img.shape == (48, 64, 3)
    assert tuple(img[30, 35]) == track_colour(3)
