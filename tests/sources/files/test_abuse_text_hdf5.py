"""Hostile input for the text, CSV, TUM, PLY and HDF5 readers (issue 20,
items 14 and 15): an empty file is an error, not a stream of nothing; a
damaged or truncated HDF5 file is a FormatError naming the dataset and the
events it cannot read, and with ``skip_bad`` the readable chunks come back
with the dropped events counted; mutated files of every one of these
formats give a FormatError or valid packets, never another exception."""

from __future__ import annotations

from pathlib import Path
from typing import Any

import numpy as np
import pytest
from damaged_files import check_packets, event_text_rows, mutate, sample_text_rows

from tectum import EventPacket, FormatError, concat
from tectum.sources.files import open_file
from tectum.sources.files.hdf5 import Hdf5Source

pytestmark = pytest.mark.abuse


def same_events(a: EventPacket, b: EventPacket) -> bool:
    return all(np.array_equal(getattr(a, c), getattr(b, c)) for c in "txyp")


def _cli(argv: list[str], capsys: pytest.CaptureFixture[str]) -> tuple[int, list[str]]:
    from tectum.cli import main

    code = main(argv)
    return code, capsys.readouterr().err.splitlines()


# -- empty files (item 14) ---------------------------------------------------------------------------------------
@pytest.mark.parametrize("name, content", [("empty.txt", b""), ("blank.txt", b"\n  \n\t\n"), ("empty.csv", b""),
                                           ("empty.tum", b""), ("empty.ply", b""), ("empty.h5", b""),
                                           ("empty.hdf5", b"")])
def test_empty_file_is_a_format_error(tmp_path: Path, name: str, content: bytes) -> None:
    """Once "0 events, sensor unknown" (text, CSV, TUM): an empty file says so."""
    f = tmp_path / name
    f.write_bytes(content)
    for skip_bad in (False, True):
        with pytest.raises(FormatError, match="empty file") as e:
            list(open_file(str(f), skip_bad=skip_bad).packets())
        assert e.value.path == str(f) and e.value.offset == 0
    with pytest.raises(FormatError, match="empty file"):
        open_file(str(f)).info()


@pytest.mark.parametrize("name", ["empty.txt", "empty.tum", "empty.h5"])
@pytest.mark.parametrize("verb", ["info", "convert"])
def test_empty_file_on_the_command_line(tmp_path: Path, capsys: pytest.CaptureFixture[str], name: str,
                                        verb: str) -> None:
    """``tectum convert empty.txt out.npz`` once wrote an output of no
    events and exited 0: one line on stderr, a non-zero exit, no output."""
    f = tmp_path / name
    f.write_bytes(b"")
    out = tmp_path / "out.npz"
    code, err = _cli(["info", str(f)] if verb == "info" else ["convert", "--skip-bad", str(f), str(out)], capsys)
    assert code != 0 and len(err) == 1 and "empty file" in err[0], err
    assert [p.name for p in tmp_path.iterdir()] == [name]


# -- damaged and truncated HDF5 (item 15) ------------------------------------------------------------------------
N, CHUNK = 20_000, 2_000


def dsec_file(path: Path, compression: str | None = "gzip") -> dict[str, np.ndarray]:
    """A DSEC-layout file of N events in chunks of CHUNK rows, written as a
    recorder writes it (datasets first, then the rows a chunk at a time, no
    chunk cache: the chunks of t, x, y, p interleave in the file)."""
    h5py = pytest.importorskip("h5py")
    rng = np.random.default_rng(0)
    cols = {"t": np.sort(rng.integers(0, 10**6, N)).astype(np.uint32), "x": rng.integers(0, 64, N).astype(np.uint16),
            "y": rng.integers(0, 48, N).astype(np.uint16), "p": rng.integers(0, 2, N).astype(np.uint8)}
    with h5py.File(path, "w", rdcc_nbytes=0) as h:
        g = h.create_group("events")
        ds = {k: g.create_dataset(k, shape=(0,), maxshape=(None,), dtype=a.dtype, chunks=(CHUNK,),
                                  compression=compression) for k, a in cols.items()}
        h.attrs["sensor"] = [64, 48]
        for a in range(0, N, CHUNK):
            for k, v in cols.items():
                ds[k].resize((a + CHUNK,))
                ds[k][a:a + CHUNK] = v[a:a + CHUNK]
    return cols


def chunks_of(path: Path) -> dict[str, list[tuple[int, int]]]:
    """(byte offset, size) of each chunk of events/t, x, y, p."""
    import h5py

    with h5py.File(path, "r") as h:
        out = {}
        for k in "txyp":
            d = h["events"][k]
            out[k] = [(int(c.byte_offset), int(c.size)) for c in map(d.id.get_chunk_info, range(d.id.get_num_chunks()))]
    return out


def events(path: Path, **kw) -> tuple[EventPacket, Hdf5Source]:
    src = Hdf5Source(str(path), **kw)
    return concat([q for q in src.packets() if isinstance(q, EventPacket)]), src


def expect(cols: dict[str, np.ndarray], keep: np.ndarray) -> EventPacket:
    return EventPacket.from_arrays(cols["t"][keep].astype(np.int64), cols["x"][keep], cols["y"][keep],
                                   np.where(cols["p"][keep] > 0, 1, -1), sensor=(64, 48))


@pytest.mark.parametrize("name", list("txyp"))
def test_damaged_chunk_is_named_or_skipped(tmp_path: Path, name: str) -> None:
    """Bytes overwritten inside one compressed chunk: once an OSError
    traceback from h5py; now a FormatError naming the dataset, the chunk's
    rows and its byte offset, and with skip_bad every other event."""
    f = tmp_path / "damaged.h5"
    cols = dsec_file(f)
    at, size = chunks_of(f)[name][3]  # rows 6000-7999
    raw = bytearray(f.read_bytes())
    raw[at + size // 3:at + size // 3 + 16] = b"\xa5" * 16
    f.write_bytes(bytes(raw))
    with pytest.raises(FormatError, match=f"/events/{name}: the chunk of rows 6000-7999 cannot be read") as e:
        events(f)
    assert e.value.offset == at and e.value.path == str(f)
    ev, src = events(f, skip_bad=True)
    keep = np.ones(N, bool)
    keep[6000:8000] = False
    assert same_events(ev, expect(cols, keep))
    assert src.skipped_events == 2000 and src.skipped_ranges == [(at, at + size)]


@pytest.mark.parametrize("compression", ["gzip", None])
@pytest.mark.parametrize("cut", [0.35, 0.8])
@pytest.mark.parametrize("step", [None, 3000])  # events read at a time: 3000 reads chunks in parts (cached)
def test_truncated_file_gives_the_chunks_before_the_cut(tmp_path: Path, compression: str | None, cut: float,
                                                        step: int | None) -> None:
    """A file cut short (a copy or a recording interrupted): once "not a
    readable HDF5 file" at byte 0 even with skip_bad. Now the chunks before
    the cut are read (never the zeros past it, uncompressed chunks too), and
    the error names the first chunk past the end and where the file ends."""
    kw = {} if step is None else {"chunk_bytes": 8 * step}
    f = tmp_path / "cut.h5"
    cols = dsec_file(f, compression)
    chunks = chunks_of(f)
    end = int(f.stat().st_size * cut)
    f.write_bytes(f.read_bytes()[:end])
    whole = np.array([all(a + s <= end for a, s in (chunks[k][c] for k in "txyp")) for c in range(N // CHUNK)])
    first = int(np.flatnonzero(~whole)[0])
    with pytest.raises(FormatError, match=f"rows {first * CHUNK}-{first * CHUNK + CHUNK - 1} cannot be read") as e:
        events(f, **kw)
    assert f"truncated (it ends at byte {end} of" in str(e.value)
    assert e.value.offset in [chunks[k][first][0] for k in "txyp"]
    ev, src = events(f, skip_bad=True, **kw)
    keep = np.repeat(whole, CHUNK)
    assert same_events(ev, expect(cols, keep)) and 0 < len(ev) < N
    assert len(ev) + src.skipped_events == N


def test_values_out_of_range_are_named_not_wrapped(tmp_path: Path) -> None:
    """x stored as int32 with 70000 in it: once cast to uint16 (4464), an
    invented event; now a bad row (dropped and counted with skip_bad)."""
    h5py = pytest.importorskip("h5py")
    f = tmp_path / "wide.h5"
    x = np.arange(100, dtype=np.int32) % 60
    x[40] = 70_000
    with h5py.File(f, "w") as h:
        g = h.create_group("events")
        g["t"], g["x"], g["y"], g["p"] = np.arange(100, dtype=np.int64), x, np.zeros(100, np.uint16), np.ones(100, np.uint8)
        h.attrs["sensor"] = [64, 48]
    with pytest.raises(FormatError, match="/events/x: row 40 holds 70000, out of range"):
        events(f)
    ev, src = events(f, skip_bad=True)
    assert len(ev) == 99 and src.skipped_events == 1 and 40 not in ev.t


def test_damaged_mvsec_chunk(tmp_path: Path) -> None:
    """The MVSEC (N, 4) layout: a damaged chunk of rows, named or skipped."""
    h5py = pytest.importorskip("h5py")
    f = tmp_path / "mvsec.h5"
    n = 4000
    a = np.stack([np.arange(n) % 30, np.arange(n) % 20, np.arange(n) * 1e-6, np.where(np.arange(n) % 2, 1, -1)], 1)
    with h5py.File(f, "w") as h:
        h.create_dataset("davis/left/events", data=a, chunks=(500, 4), compression="gzip")
    with h5py.File(f, "r") as h:
        info = h["davis/left/events"].id.get_chunk_info(2)
    raw = bytearray(f.read_bytes())
    raw[info.byte_offset + 50:info.byte_offset + 60] = b"\x00" * 10
    f.write_bytes(bytes(raw))
    with pytest.raises(FormatError, match="/davis/left/events: the chunk of rows 1000-1499"):
        events(f)
    ev, src = events(f, skip_bad=True)
    assert len(ev) == n - 500 and src.skipped_events == 500 and not ((ev.t >= 1000) & (ev.t < 1500)).any()


# -- fuzz: mutated small files of every format here ---------------------------------------------------------------
def _small_files(d: Path) -> dict[str, tuple[Path, bytes]]:
    """A small valid file per format (written by tectum's sinks where it has one)."""
    from tectum import ImuPacket, PointPacket, PosePacket
    from tectum.sinks.files._common import write_all
    from tectum.sinks.files.ply import PlySink
    from tectum.sinks.files.samples_csv import CsvSink
    from tectum.sinks.files.tum import TumSink

    rng = np.random.default_rng(0)
    n = 60
    t = np.sort(rng.integers(0, 100_000, n))
    x, y, p = rng.integers(0, 64, n), rng.integers(0, 48, n), rng.integers(0, 2, n)
    (d / "events.txt").write_bytes(b"".join(b"0.%06d %d %d %d\n" % r for r in zip(t, x, y, p)))
    (d / "events.csv").write_bytes(b"t,x,y,p\n" + b"".join(b"%d,%d,%d,%d\n" % r for r in zip(t, x, y, p)))
    q = rng.normal(size=(n, 4))
    q /= np.linalg.norm(q, axis=1, keepdims=True)
    write_all(CsvSink(str(d / "imu.csv"), kind="imu"), [ImuPacket(t, accel=rng.normal(size=(n, 3)),
                                                                  gyro=rng.normal(size=(n, 3)))])
    write_all(TumSink(str(d / "poses.tum")), [PosePacket(t, position=rng.normal(size=(n, 3)), orientation=q)])
    pts = PointPacket(t, position=rng.normal(size=(n, 3)), intensity=rng.random(n).astype(np.float32))
    write_all(PlySink(str(d / "ascii.ply")), [pts])
    write_all(PlySink(str(d / "binary.ply"), binary=True), [pts])
    return {f.name: (f, f.read_bytes()) for f in sorted(d.iterdir())}


def _rows(name: str, raw: bytes) -> int | None:
    """The rows a reader of ``raw`` keeps or counts as skipped (None: the
    mutation may have changed what the file says it holds)."""
    import io

    from tectum.tables import parse_ply_header

    if name.startswith("events"):
        return event_text_rows(raw)
    if name.endswith(".tum"):
        return sample_text_rows(raw)
    if name.endswith(".csv"):
        return sample_text_rows(raw) - 1  # the header row
    try:
        h = parse_ply_header(io.BytesIO(raw))
    except ValueError:
        return None
    return next(e.count for e in h.elements if e.name == "vertex")


def _source(name: str, path: Path, skip_bad: bool) -> Any:
    from tectum.sources.files.ply import PlySource
    from tectum.sources.files.samples_csv import CsvSource
    from tectum.sources.files.text import TextSource
    from tectum.sources.files.tum import TumSource

    if name.startswith("events"):
        return TextSource(str(path), companions=False, sensor="64x48", skip_bad=skip_bad)
    cls = {".csv": CsvSource, ".tum": TumSource, ".ply": PlySource}[path.suffix]
    return cls(str(path), skip_bad=skip_bad)


def _read(src: Any, path: Path) -> int | None:
    """The samples ``src`` gives (the packet contract checked), or None
    after a FormatError naming ``path``; any other exception fails."""
    try:
        pkts = list(src.packets())
    except FormatError as e:
        assert e.path == str(path), e
        return None
    check_packets(pkts)
    return sum(len(q) for q in pkts)


def test_fuzz_text_csv_tum_ply(tmp_path: Path) -> None:
    """80 mutations of each small file (truncated, bytes overwritten or
    spliced in, a line repeated elsewhere): a FormatError or valid packets;
    with skip_bad, the rows kept and skipped add up to the rows there are."""
    (tmp_path / "small").mkdir()
    files = _small_files(tmp_path / "small")
    rng = np.random.default_rng(20)
    for name, (_, raw) in files.items():
        for k in range(80):
            what, bad = mutate(raw, rng, lines=not name.endswith("binary.ply"))
            f = tmp_path / f"m{k}-{name}"
            f.write_bytes(bad)
            strict = _source(name, f, False)
            got = _read(strict, f)
            assert got is None or strict.skipped_events == 0
            lenient = _source(name, f, True)
            kept = _read(lenient, f)
            rows = _rows(name, bad)
            if kept is not None and rows is not None:
                assert kept + lenient.skipped_events == rows, (name, what, kept, lenient.skipped_events, rows)
            f.unlink()


def test_fuzz_hdf5(tmp_path: Path) -> None:
    """Mutations of a small DSEC file (chunked, compressed): bytes overwritten
    inside the chunks or anywhere, spliced in, the file cut short. A
    FormatError or valid packets, never an exception from h5py; with
    skip_bad, damage to chunks or a cut leaves kept + skipped = the events."""
    h5py = pytest.importorskip("h5py")
    f0 = tmp_path / "small.h5"
    n = 2000
    rng = np.random.default_rng(15)
    with h5py.File(f0, "w", rdcc_nbytes=0) as h:
        g = h.create_group("events")
        g.create_dataset("t", data=np.sort(rng.integers(0, 10**5, n)).astype(np.uint32), chunks=(200,),
                         compression="gzip")
        for k, hi, dt in (("x", 64, np.uint16), ("y", 48, np.uint16), ("p", 2, np.uint8)):
            g.create_dataset(k, data=rng.integers(0, hi, n).astype(dt), chunks=(200,), compression="gzip")
    raw = f0.read_bytes()
    spans = [(a, a + s) for c in chunks_of(f0).values() for a, s in c]
    for k in range(100):
        kind = ("chunk", "cut", "any")[k % 3]
        bad = bytearray(raw)
        if kind == "chunk":
            a, b = spans[int(rng.integers(len(spans)))]
            for _ in range(int(rng.integers(1, 9))):
                bad[int(rng.integers(a, b))] = int(rng.integers(256))
        elif kind == "cut":
            bad = bad[:int(rng.integers(len(bad)))]
        else:
            bad = bytearray(mutate(raw, rng)[1])
        f = tmp_path / f"m{k}.h5"
        f.write_bytes(bytes(bad))
        _read(Hdf5Source(str(f)), f)
        src = Hdf5Source(str(f), skip_bad=True)
        kept = _read(src, f)
        if kept is not None and kind != "any":
            assert kept + src.skipped_events == n, (kind, kept, src.skipped_events)
        f.unlink()
