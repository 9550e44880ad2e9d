"""Event text files and their companion files against a slow reader written
from the layout's description (``sources/files/text.py``, ``_text_layout.py``).

Hypothesis draws events and writes them in a drawn layout: column order
(named by a header, or the default ``t x y p`` without one), separators
(spaces, tabs, commas, CRLF), polarity 0/1 or -1/+1, time unit (seconds as
decimals with sub-µs digits, ms and ns named by the header, µs integers),
comment lines; and, beside ``events.txt``, the RPG dataset's ``imu.txt``,
``groundtruth.txt`` and ``images.txt`` with PNG frames (rows of the wrong
length and comments among them, times out of order). The reference splits
each line, turns the time into µs with :class:`decimal.Decimal` (rounded
half up) and sorts the companions by time; tectum's packets must equal it
value by value: t, x, y, p, IMU, poses, frames (pixels and times).
"""

from __future__ import annotations

import re
import tempfile
from decimal import ROUND_HALF_UP, Decimal
from pathlib import Path
from typing import Any

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from tectum import EventPacket, FramePacket, ImuPacket, PosePacket, concat
from tectum.sources.files.text import TextSource

cv2 = pytest.importorskip("cv2")

DIGITS = {"s": 6, "ms": 3, "us": 0, "ns": -3}
HEADER_T = {"s": "t", "ms": "t_ms", "us": "timestamp", "ns": "timestamp[ns]"}
NAMES = {"x": "x", "y": "y", "p": "polarity"}


def to_us(text: str, unit: str) -> int:
    """A decimal time in ``unit`` as whole µs, rounded half up (away from zero)."""
    return int((Decimal(text) * Decimal(10) ** DIGITS[unit]).quantize(Decimal(1), rounding=ROUND_HALF_UP))


def ref_events(text: str, columns: str, unit: str) -> list[tuple[int, int, int, int]]:
    out = []
    for line in text.split("\n"):
        fields = [f for f in re.split(r"[ \t,\r]+", line) if f]
        if not fields or line.startswith(("#", "%")) or re.search(r"[A-Za-z]", line):
            continue
        v = dict(zip(columns, fields))
        p = int(v["p"])
        out.append((to_us(v["t"], unit), int(v["x"]), int(v["y"]), 1 if p > 0 else -1))
    return out


def ref_table(text: str, ncols: int) -> list[tuple[int, list[float]]]:
    """Rows of ``ncols`` whitespace-separated numbers (time in seconds), others
    and comments ignored, sorted by time (stable)."""
    rows = [ln.split() for ln in text.split("\n") if not ln.startswith("#")]
    rows = [(to_us(r[0], "s"), [float(v) for v in r[1:]]) for r in rows if len(r) == ncols]
    return sorted(rows, key=lambda r: r[0])


def render_time(t_us: int, sub: int, unit: str) -> str:
    """``t_us`` µs plus ``sub`` thousandths of a µs written in ``unit``."""
    ns = t_us * 1000 + sub
    if unit == "s":
        return f"{ns // 10**9}.{ns % 10**9:09d}"
    if unit == "ms":
        return f"{ns // 10**6}.{ns % 10**6:06d}"
    if unit == "us":
        return str(t_us)
    return str(ns)


@st.composite
def datasets(draw: st.DrawFn) -> dict[str, Any]:
    unit = draw(st.sampled_from(["s", "ms", "us", "ns"]))
    named = unit in ("ms", "ns") or draw(st.booleans())  # ms and ns need a header naming them
    columns = "".join(draw(st.permutations("txyp"))) if named else "txyp"
    sep = draw(st.sampled_from([" ", "\t", ",", ", "]))
    end = draw(st.sampled_from(["\n", "\r\n"]))
    signed = draw(st.booleans())
    n = draw(st.integers(1, 30))
    ns = 1000 * (draw(st.integers(0, 10**7)) if unit != "ns" else draw(st.integers(10**15, 2 * 10**15)))  # 18+ digits
    lines = [] if not named else [sep.join(HEADER_T[unit] if c == "t" else NAMES[c] for c in columns)]
    if draw(st.booleans()):
        lines.insert(0, "# written by a test")
    for _ in range(n):
        ns += draw(st.integers(0, 5_000_000)) if unit != "us" else 1000 * draw(st.integers(0, 5000))
        v = {"t": render_time(ns // 1000, ns % 1000, unit), "x": str(draw(st.integers(0, 345))), "y": str(draw(st.integers(0, 259))),
             "p": draw(st.sampled_from(["-1", "1"] if signed else ["0", "1"]))}
        lines.append(sep.join(v[c] for c in columns))
        if draw(st.integers(0, 9)) == 0:
            lines.append("% a comment among the events")
    finite = st.floats(-1e6, 1e6, allow_nan=False).map(lambda v: f"{v:.9g}")
    seconds = st.integers(0, 10**7).map(lambda us: f"{us // 10**6}.{us % 10**6:06d}")
    imu = [" ".join([draw(seconds)] + draw(st.lists(finite, min_size=6, max_size=6)))
           for _ in range(draw(st.integers(0, 4)))]
    poses = [" ".join([draw(seconds)] + draw(st.lists(finite, min_size=7, max_size=7)))
             for _ in range(draw(st.integers(0, 4)))]
    for rows, bad in ((imu, "0.5 1 2"), (poses, "# t px py pz qx qy qz qw")):
        if rows and draw(st.booleans()):
            rows.insert(draw(st.integers(0, len(rows))), bad)
    image_times = sorted(draw(st.lists(st.integers(0, 10**7), max_size=3, unique=True)))
    size = draw(st.sampled_from([(346, 260), (350, 261)]))  # w, h: the events' pixels lie on the frames
    images = [np.full(size[::-1], k * 40 + 7, np.uint8) for k in range(len(image_times))]
    return dict(text=end.join(lines) + end, columns=columns, unit=unit, imu="\n".join(imu) + "\n",
                poses="\n".join(poses) + "\n", image_times=image_times, images=images, size=size)


def write(folder: Path, d: dict[str, Any]) -> Path:
    (folder / "events.txt").write_bytes(d["text"].encode())
    (folder / "imu.txt").write_text(d["imu"])
    (folder / "groundtruth.txt").write_text(d["poses"])
    if d["images"]:
        (folder / "images").mkdir()
        lines = []
        for k, (t, img) in enumerate(zip(d["image_times"], d["images"])):
            cv2.imwrite(str(folder / "images" / f"{k:04d}.png"), img)
            lines.append(f"{t // 10**6}.{t % 10**6:06d} images/{k:04d}.png")
        (folder / "images.txt").write_text("# timestamp filename\n" + "\n".join(lines) + "\n")
    return folder / "events.txt"


@settings(max_examples=60, deadline=None)
@given(d=datasets(), chunk=st.sampled_from([64, 1 << 20]))
def test_dataset_equals_the_reference(d: dict[str, Any], chunk: int) -> None:
    with tempfile.TemporaryDirectory() as tmp:
        src = TextSource(str(write(Path(tmp), d)), chunk_bytes=chunk)
        got: dict[str, list[Any]] = {"events": [], "imu": [], "poses": [], "frames": []}
        sensors = set()
        for q in src.packets():
            if isinstance(q, EventPacket):
                got["events"] += zip(q.t.tolist(), q.x.tolist(), q.y.tolist(), q.p.tolist())
                sensors.add(q.sensor)
            elif isinstance(q, ImuPacket):
                got["imu"] += [(t, a + g) for t, a, g in zip(q.t.tolist(), q.accel.tolist(), q.gyro.tolist())]
            elif isinstance(q, PosePacket):
                got["poses"] += [(t, p + o) for t, p, o in zip(q.t.tolist(), q.position.tolist(),
                                                                  q.orientation.tolist())]
            elif isinstance(q, FramePacket):
                got["frames"] += [(t, q.t_end, img) for t, img in zip(q.t.tolist(), q.images)]  # t_end: unchecked
        assert src.layout is not None and (src.layout.columns, src.layout.time_unit) == (d["columns"], d["unit"])
    events = ref_events(d["text"], d["columns"], d["unit"])
    assert got["events"] == events
    if d["images"]:  # the sensor is the first image's size, else the extent of the coordinates
        assert sensors == {d["size"]}
    else:
        assert sensors == {(max(e[1] for e in events) + 1, max(e[2] for e in events) + 1)}
    assert got["imu"] == ref_table(d["imu"], 7)
    assert got["poses"] == ref_table(d["poses"], 8)
    assert [t for t, _, _ in got["frames"]] == d["image_times"]
    for (_, _, a), b in zip(got["frames"], d["images"]):
        assert np.array_equal(a, b)


def test_companions_off_and_an_unreadable_image(tmp_path: Path) -> None:
    """``companions=False`` reads the events alone; an image that does not
    read is left out (and gives no sensor size)."""
    (tmp_path / "events.txt").write_text("0.000001 1 2 1\n0.000002 3 4 0\n")
    (tmp_path / "imu.txt").write_text("0.0000015 0 0 9.8 0 0 0\n")
    (tmp_path / "images.txt").write_text("0.000001 missing.png\n")
    kinds = [type(q).__name__ for q in TextSource(str(tmp_path / "events.txt"), companions=False).packets()]
    assert set(kinds) == {"EventPacket"}
    pkts = list(TextSource(str(tmp_path / "events.txt")).packets())
    assert {type(q).__name__ for q in pkts} == {"EventPacket", "ImuPacket"}
    assert next(q for q in pkts if isinstance(q, EventPacket)).sensor == (4, 5)
    assert TextSource.kinds_for(str(tmp_path / "events.txt"), {"companions": False}) == (TextSource.produces[0],)


def test_ns_since_the_epoch_of_today(tmp_path: Path) -> None:
    """Times in ns since the epoch have 19 digits since 2001 and fit int64:
    they read, rounded half up to µs like every unit; 20 digits do not fit
    and are named. A header after comment lines is a header."""
    f = tmp_path / "e.csv"
    f.write_text("t_ns,x,y,p\n1700000000000001499,1,2,1\n1700000000000002500,3,4,0\n9223372036854775000,0,0,1\n")
    ev = concat([q for q in TextSource(str(f)).packets() if isinstance(q, EventPacket)])
    assert ev.t.tolist() == [1700000000000001, 1700000000000003, 9223372036854775]
    f.write_text("t_ns,x,y,p\n1700000000000001499,1,2,1\n10000000000000000000,3,4,0\n")
    with pytest.raises(Exception, match="time out of the int64 µs range"):
        list(TextSource(str(f)).packets())
    f.write_text("# comment\n\nt,x,y,p\n5,1,2,1\n")
    assert next(iter(TextSource(str(f)).packets())).t.tolist() == [5]
    f.write_text("t,x,y,p\n5,1,99999999999999999999,1\n")
    with pytest.raises(Exception, match="coordinate above 65535"):
        list(TextSource(str(f)).packets())
