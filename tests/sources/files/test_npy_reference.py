"""Structured .npy event files against numpy's own reader (the format's
reference implementation) and the layout the module describes.

Hypothesis draws the records' layout: field names among the aliases
(``t``/``timestamp``/``ts``, ``p``/``polarity``/``on``/``pol``), their order,
integer types and byte orders, extra fields, format version 1.0 or 2.0, and
the chunk size; tectum's events must be numpy's records value by value (p > 0
is ON), the sensor their extent. Headers that are no event layout, a file
holding fewer records than its header says, and a time window are checked
against the same reference.
"""

from __future__ import annotations

import io
from pathlib import Path

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from tectum import EventPacket, FormatError, concat
from tectum.sources.files._common import FROM_EXTENT, FROM_OPTION
from tectum.sources.files.npy import NpySource


@st.composite
def arrays(draw: st.DrawFn) -> np.ndarray:
    order = draw(st.sampled_from(["<", ">"]))
    fields = [(draw(st.sampled_from(["t", "timestamp", "ts"])), order + draw(st.sampled_from(["i8", "u4", "i4"]))),
              ("x", order + draw(st.sampled_from(["u2", "i4", "u1"]))),
              ("y", order + draw(st.sampled_from(["u2", "i2", "u8"]))),
              (draw(st.sampled_from(["p", "polarity", "on", "pol"])), draw(st.sampled_from(["i1", "u1", "?"])))]
    if draw(st.booleans()):
        fields.append(("extra", order + "f8"))
    fields = draw(st.permutations(fields))
    n = draw(st.integers(0, 60))
    a = np.zeros(n, dtype=fields)
    names = dict(zip("txyp", (fields_named(fields, k) for k in "txyp")))
    t0 = draw(st.integers(0, 1 << 30))
    a[names["t"]] = t0 + np.cumsum(draw(st.lists(st.integers(0, 1000), min_size=n, max_size=n)), dtype=np.int64)
    a[names["x"]] = draw(st.lists(st.integers(0, 250), min_size=n, max_size=n))
    a[names["y"]] = draw(st.lists(st.integers(0, 200), min_size=n, max_size=n))
    signed = a.dtype[names["p"]].kind == "i" and draw(st.booleans())
    a[names["p"]] = draw(st.lists(st.sampled_from([-1, 1] if signed else [0, 1]), min_size=n, max_size=n))
    return a


def fields_named(fields: list[tuple[str, str]], k: str) -> str:
    aliases = {"t": ("t", "timestamp", "ts"), "x": ("x",), "y": ("y",), "p": ("p", "polarity", "on", "pol")}
    return next(name for name, _ in fields if name in aliases[k])


def save(path: Path, a: np.ndarray, version: tuple[int, int]) -> Path:
    with open(path, "wb") as f:
        np.lib.format.write_array(f, a, version=version)
    return path


def events(path: Path, **kw: object) -> tuple[list[tuple[int, int, int, int]], set]:
    """The events, and the sensor sizes of their packets (checked to come
    from the ``sensor`` option if given, else from the coordinates)."""
    src = NpySource(str(path), **kw)
    pkts = [q for q in src.packets() if isinstance(q, EventPacket)]
    assert src.sensor_from == (FROM_OPTION if kw.get("sensor") else FROM_EXTENT)
    return [e for q in pkts for e in zip(q.t.tolist(), q.x.tolist(), q.y.tolist(), q.p.tolist())], {
        q.sensor for q in pkts}


def reference(path: Path, lo: int | None = None, hi: int | None = None) -> list[tuple[int, int, int, int]]:
    a = np.load(path)
    f = {k: fields_named([(n, "") for n in a.dtype.names], k) for k in "txyp"}
    out = [(int(r[f["t"]]), int(r[f["x"]]), int(r[f["y"]]), 1 if r[f["p"]] > 0 else -1) for r in a]
    return [e for e in out if (lo is None or e[0] >= lo) and (hi is None or e[0] < hi)]


@settings(max_examples=60, deadline=None)
@given(a=arrays(), version=st.sampled_from([(1, 0), (2, 0)]), chunk=st.sampled_from([64, 100, 1 << 20]))
def test_npy_equals_numpy(tmp_path_factory: pytest.TempPathFactory, a: np.ndarray, version: tuple[int, int],
                          chunk: int) -> None:
    path = save(tmp_path_factory.mktemp("npy") / "e.npy", a, version)
    got, sensors = events(path, chunk_bytes=chunk)
    want = reference(path)
    assert got == want
    if want:
        assert sensors == {(max(e[1] for e in want) + 1, max(e[2] for e in want) + 1)}


def test_time_window_and_truncation(tmp_path: Path) -> None:
    a = np.zeros(40, dtype=[("t", "<i8"), ("x", "<u2"), ("y", "<u2"), ("p", "i1")])
    a["t"], a["x"], a["y"], a["p"] = np.arange(40) * 10, np.arange(40) % 7, np.arange(40) % 5, np.arange(40) % 2
    path = save(tmp_path / "e.npy", a, (1, 0))
    got, _ = events(path, t_start_us=95, t_end_us=205, chunk_bytes=64)
    assert got == reference(path, 95, 205)
    data = path.read_bytes()
    cut = tmp_path / "cut.npy"
    cut.write_bytes(data[:-a.dtype.itemsize * 3 - 5])  # 3 records and 5 bytes of a fourth missing
    with pytest.raises(FormatError, match="holds 36 of the 40 records"):
        events(cut)
    src = NpySource(str(cut), skip_bad=True)
    got = concat([q for q in src.packets() if isinstance(q, EventPacket)])
    assert got.t.tolist() == a["t"][:36].tolist() and src.skipped_events == 1


@pytest.mark.parametrize("array, message", [
    (np.zeros(3, dtype=[("t", "O"), ("x", "u2"), ("y", "u2"), ("p", "i1")]), "Python objects"),
    (np.zeros((3, 2), dtype=[("t", "i8"), ("x", "u2"), ("y", "u2"), ("p", "i1")]), "expected a 1-D structured"),
    (np.zeros(3, dtype="i8"), "expected a 1-D structured"),
    (np.zeros(3, dtype=[("t", "i8"), ("x", "u2"), ("y", "u2")]), "no field for 'p'"),
])
def test_headers_that_are_no_event_layout(tmp_path: Path, array: np.ndarray, message: str) -> None:
    buf = io.BytesIO()
    np.lib.format.write_array(buf, array, allow_pickle=True)
    path = tmp_path / "e.npy"
    path.write_bytes(buf.getvalue())
    with pytest.raises(FormatError, match=message):
        events(path)
