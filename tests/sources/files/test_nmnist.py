"""N-MNIST / N-Caltech101 .bin against a record-at-a-time decoder written
from the dataset's documentation (tests/format_specs.py), the shared sample
and tonic.

Hypothesis draws events (times up to past the 23-bit field, with the
time-overflow records that carry them), the slow decoder must read what was
meant and tectum the same, in drawn chunk sizes, whole and from a drawn start.
"""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest
from format_specs import nmnist_decode, nmnist_encode
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st

from tectum import EventPacket, FormatError
from tectum.sources.files import open_file
from tectum.sources.files.nmnist import NmnistSource


def read(path: Path, **kw) -> list[tuple[int, int, int, int]]:
    ev = [q for q in NmnistSource(str(path), **kw).packets() if isinstance(q, EventPacket) and len(q)]
    return list(zip(*[np.concatenate([getattr(q, c) for q in ev]).tolist() if ev else [] for c in "txyp"]))


@st.composite
def files(draw: st.DrawFn) -> tuple[bytes, list[tuple[int, int, int, int]], tuple[int, int]]:
    w, h = draw(st.sampled_from([(34, 34), (240, 180), (256, 240)]))
    t, events = 0, []
    for _ in range(draw(st.integers(0, 60))):
        t += draw(st.one_of(st.integers(0, 50), st.integers(0, 1 << 22)))
        events.append((t, draw(st.integers(0, w - 1)), draw(st.integers(0, h - 1)), draw(st.sampled_from([1, -1]))))
    return nmnist_encode(events), events, (w, h)


@settings(max_examples=80, deadline=None, suppress_health_check=[HealthCheck.function_scoped_fixture])
@given(case=files(), chunk=st.one_of(st.sampled_from([64, 1 << 16]), st.integers(64, 300)), data=st.data())
def test_nmnist_equals_the_reference(tmp_path: Path, case: tuple, chunk: int, data: st.DataObject) -> None:
    raw, events, (w, h) = case
    assert nmnist_decode(raw) == events
    path = tmp_path / "r.bin"
    path.write_bytes(raw)
    sensor = f"{w}x{h}"
    assert read(path, chunk_bytes=chunk, sensor=sensor) == events
    if events:
        start = data.draw(st.integers(0, events[-1][0] + 1))
        assert read(path, chunk_bytes=chunk, sensor=sensor, t_start_us=start) == [e for e in events if e[0] >= start]
        assert read(path, chunk_bytes=chunk, sensor=sensor, t_end_us=start) == [e for e in events if e[0] < start]


def test_overflow_records_are_counted(tmp_path: Path) -> None:
    path = tmp_path / "o.bin"
    path.write_bytes(nmnist_encode([(5, 1, 2, 1), ((1 << 23) + 10, 3, 4, -1)]))
    src = NmnistSource(str(path))
    assert sum(len(q) for q in src.packets()) == 2
    assert src.counts["time_overflow_records"] == 1


def test_size_not_a_multiple_of_five(tmp_path: Path) -> None:
    """No magic number: a .bin is N-MNIST by its extension, and the error
    says so when the size cannot be; ``skip_bad`` drops the partial record."""
    path = tmp_path / "x.bin"
    path.write_bytes(nmnist_encode([(5, 1, 2, 1), (9, 3, 4, -1)]) + b"\x01\x02")
    assert type(open_file(str(path))) is NmnistSource
    with pytest.raises(FormatError, match="not a whole number of 5-byte N-MNIST events.*no magic number") as e:
        read(path)
    assert e.value.offset == 10
    src = NmnistSource(str(path), skip_bad=True)
    assert sum(len(q) for q in src.packets()) == 2 and src.skipped_events == 1


def test_sensor_default_and_option(tmp_path: Path) -> None:
    """34x34 by default; an N-Caltech101 file needs ``sensor=`` (its own
    largest x and y are not the sensor), and the error says so."""
    path = tmp_path / "c.bin"
    path.write_bytes(nmnist_encode([(5, 1, 2, 1), (9, 200, 150, -1)]))
    with pytest.raises(FormatError, match=r"\(200, 150\) lies outside N-MNIST's 34x34 sensor: give sensor=") as e:
        read(path)
    assert e.value.offset == 5
    assert [q.sensor for q in NmnistSource(str(path), sensor="240x180").packets()][0] == (240, 180)
    with pytest.raises(ValueError, match="8-bit x and y < 240"):
        NmnistSource(str(path), sensor="304x240")
    path.write_bytes(b"")
    assert read(path) == []


def test_shared_sample_equals_tonic(shared: Path) -> None:
    path = shared / "other/nmnist_sample.bin"
    got = read(path)
    assert len(got) == 4_325
    assert got == nmnist_decode(path.read_bytes())
    io = pytest.importorskip("tonic.io")
    ref = io.read_mnist_file(str(path), dtype=np.dtype([("x", int), ("y", int), ("t", int), ("p", int)]))
    assert got == list(zip(ref["t"].tolist(), ref["x"].tolist(), ref["y"].tolist(),
                           np.where(ref["p"] == 1, 1, -1).tolist()))
