"""Video and image-sequence scenes: log-space interpolation between frames,
frame timestamps as the time axis."""

from __future__ import annotations

import math

import cv2
import numpy as np
import pytest

import tectum
from tectum.sources.simulate import make_simulator, simulate
from tectum.testing import ListSink

W, H, DARK, BRIGHT, EPS = 64, 48, 50, 200, 1e-3
C_ON, C_OFF = 0.2, 0.25  # unequal: an ON run then an OFF run never ends exactly on a threshold


def bar_frame(k: int, step: int = 3) -> np.ndarray:
    img = np.full((H, W), DARK, np.uint8)
    img[:, 10 + step * k: 20 + step * k] = BRIGHT
    return img


def expected_times(ta_us: float, tb_us: float, up: bool) -> list[float]:
    """Crossing times of a pixel whose log intensity goes linearly from one
    level to the other over [ta, tb] (log-space interpolation), its
    reference at the starting level."""
    lo, hi = math.log(DARK / 255 + EPS), math.log(BRIGHT / 255 + EPS)
    dl, c = hi - lo, (C_ON if up else C_OFF)
    n = math.floor(dl / c)
    return [ta_us + k * c / dl * (tb_us - ta_us) for k in range(1, n + 1)]


def check_bar_events(ev, times: list[float], step: int = 3) -> None:
    """ON events exactly where the leading edge moved, OFF where the trailing
    edge left, each at the analytic times of its frame interval."""
    assert np.all(ev["noise"] == 0) and np.all(np.isnan(ev["vx"]))
    x, y, t, p = ev.x.astype(int), ev.y.astype(int), ev.t, ev.p
    for k in range(len(times) - 1):
        ta, tb = times[k], times[k + 1]
        inside = (t > ta) & (t <= tb)
        on_cols = set(range(20 + step * k, 20 + step * (k + 1)))
        off_cols = set(range(10 + step * k, 10 + step * (k + 1)))
        assert set(np.unique(x[inside & (p == 1)])) == on_cols
        assert set(np.unique(x[inside & (p == -1)])) == off_cols
        for col, up in ((min(on_cols), True), (min(off_cols), False)):
            if not up and col >= 20:
                continue  # not bright from the start: its reference is not the bright level
            mine = np.sort(t[inside & (x == col) & (y == H // 2)])
            want = np.floor(expected_times(ta, tb, up))
            np.testing.assert_allclose(mine, want, atol=1)
    assert set(np.unique(x)) == set(range(10, 10 + step * (len(times) - 1))) | set(
        range(20, 20 + step * (len(times) - 1)))


def test_video_file_moving_bar(tmp_path):
    path = str(tmp_path / "bar.avi")
    wr = cv2.VideoWriter(path, cv2.VideoWriter_fourcc(*"FFV1"), 10, (W, H), False)
    if not wr.isOpened():
        pytest.skip("OpenCV has no FFV1 writer here")
    for k in range(6):
        wr.write(bar_frame(k))
    wr.release()
    sim = make_simulator(path, c_on=C_ON, c_off=C_OFF)
    assert sim.T == 500_000 and (sim.W, sim.H) == (W, H)  # five intervals of 100 ms at 10 fps
    ev = tectum.concat([e for e, _ in sim.windows(30_000)])
    assert len(sim.video._t) <= 3  # frames behind the released windows are forgotten
    check_bar_events(ev, [k * 100_000 for k in range(6)])
    # the source plugin takes the path as the scene; fps overrides the container's rate
    p = tectum.Pipeline()
    s = p.source(f"simulate:{path}", fps="20", model={"c_on": C_ON, "c_off": C_OFF})
    sink = ListSink()
    p.sink(sink, s)
    tectum.run(p)
    got = sink.events()
    assert got.t_end == 250_000 and len(got) > 0 and got.t.max() < 250_000


def test_image_list_with_timestamps(tmp_path):
    stamps = [1468939993.0, 1468939993.05, 1468939993.2, 1468939993.23]  # uneven, UZH-style absolute seconds
    lines = []
    (tmp_path / "images").mkdir()
    for k, ts in enumerate(stamps):
        name = f"images/frame_{k:08d}.png"
        cv2.imwrite(str(tmp_path / name), bar_frame(k, step=2))
        lines.append(f"{ts:.6f} {name}")
    (tmp_path / "images.txt").write_text("# timestamp filename\n" + "\n".join(lines) + "\n")
    times = [round((s - stamps[0]) * 1e6) for s in stamps]
    ev, _ = simulate(str(tmp_path), c_on=C_ON, c_off=C_OFF)  # a folder with an images.txt
    assert ev.t_end == times[-1]
    check_bar_events(ev, times, step=2)


def test_image_folder_needs_a_frame_rate(tmp_path):
    for k in range(3):
        cv2.imwrite(str(tmp_path / f"{k:03d}.png"), bar_frame(k))
    with pytest.raises(ValueError, match="fps"):
        simulate(str(tmp_path))
    ev, _ = simulate(str(tmp_path), fps=50, sensor="32x24")  # resized to the asked sensor
    assert ev.sensor == (32, 24) and ev.t_end == 40_000 and len(ev) > 0
