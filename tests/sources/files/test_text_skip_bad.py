"""``skip_bad`` on damaged event text: one pass over the bytes whatever the
input, so random text costs time linear in its size and memory bounded by
the chunk size (it once re-copied the rest of the buffer and allocated new
columns for every bad line: 1 MB of random text took 4.4 GB), and the
count of skipped lines adds up with the events kept."""

from __future__ import annotations

import json
import subprocess
import sys
import textwrap
from pathlib import Path

import numpy as np
import pytest
from damaged_files import event_text_rows as data_lines
from damaged_files import random_text

from tectum import EventPacket, FormatError, concat
from tectum.sources.files import text
from tectum.sources.files.text import TextSource

pytestmark = pytest.mark.abuse

# Reads a file in a fresh interpreter (after a warm-up read, so the compiled
# kernels are loaded) and prints what tracemalloc saw at the peak. The address
# space is capped so that a reader gone quadratic fails fast instead of taking
# the machine's memory.
_MEASURE = textwrap.dedent("""
    import json, resource, sys, time, tracemalloc
    from tectum.sources.files.text import TextSource
    path, warm = sys.argv[1], sys.argv[2]
    list(TextSource(warm, companions=False, skip_bad=True).packets())
    with open("/proc/self/statm") as f:
        vm = int(f.read().split()[0]) * resource.getpagesize()
    resource.setrlimit(resource.RLIMIT_AS, (vm + (400 << 20), resource.RLIM_INFINITY))
    tracemalloc.start()
    t0 = time.perf_counter()
    src = TextSource(path, companions=False, skip_bad=True)
    try:
        kept = sum(len(p) for p in src.packets() if p.kind == "events")
        error = None
    except MemoryError:
        kept, error = 0, "MemoryError"
    seconds = time.perf_counter() - t0
    peak = tracemalloc.get_traced_memory()[1]
    print(json.dumps({"kept": kept, "skipped": src.skipped_events, "peak": peak, "seconds": seconds,
                      "error": error}))
""")


def test_random_text_is_one_linear_pass_in_bounded_memory(tmp_path: Path) -> None:
    raw = random_text(500_000)
    f = tmp_path / "random.txt"
    f.write_bytes(raw)
    warm = tmp_path / "warm.txt"
    warm.write_bytes(b"0.1 1 2 1\njunk\n0.2 1 1 0\n")
    out = subprocess.run([sys.executable, "-c", _MEASURE, str(f), str(warm)], capture_output=True, text=True,
                         timeout=120)
    assert out.returncode == 0, out.stderr[-2000:]
    got = json.loads(out.stdout.strip().splitlines()[-1])
    assert got["error"] is None, f"ran out of memory reading {len(raw)} bytes of text"
    assert got["kept"] + got["skipped"] == data_lines(raw) and got["skipped"] > 4000
    assert got["peak"] < 20 * len(raw), f"peak {got['peak'] / 2**20:.1f} MiB for a {len(raw) >> 10} KiB file"
    assert got["seconds"] < 2.0


def test_random_text_without_skip_bad_names_the_first_bad_line(tmp_path: Path) -> None:
    f = tmp_path / "random.txt"
    f.write_bytes(b"0.000001 1 2 1\n" + random_text(20_000))
    with pytest.raises(FormatError, match="not 4 numbers") as e:
        list(TextSource(str(f), companions=False).packets())
    assert e.value.offset == 15


@pytest.mark.parametrize("runs", [2, 4096])  # runs of bad lines a kernel call holds: 2 makes it stop and resume
@pytest.mark.parametrize("chunk", [256, 1 << 22])
def test_mixed_good_and_bad_lines_add_up(tmp_path: Path, monkeypatch, runs: int, chunk: int) -> None:
    """Junk lines among events: the events are exactly the good lines, each
    junk line is counted once and its bytes lie in a skipped range (the
    extent pass for the sensor size counts nothing)."""
    monkeypatch.setattr(text, "_RUNS", runs, raising=False)
    rng = np.random.default_rng(1)
    lines: list[bytes] = []
    good: list[tuple[int, int, int, int]] = []
    junk: list[int] = []  # byte offsets of junk lines
    offset = 0
    for k in range(3000):
        if k and rng.random() < 0.4:
            ln = b"z" + random_text(int(rng.integers(0, 40)), seed=k).replace(b"\n", b" ")
            junk.append(offset)
        elif k and rng.random() < 0.05:
            ln = b"# a comment" if rng.random() < 0.5 else b" \t"
        else:
            ev = (k, int(rng.integers(0, 50)), int(rng.integers(0, 40)), int(rng.integers(0, 2)))
            good.append(ev)
            ln = b"0.%06d %d %d %d" % ev  # seconds, as the junk's dots make the layout guess
        lines.append(ln)
        offset += len(ln) + 1
    f = tmp_path / "mixed.txt"
    f.write_bytes(b"\n".join(lines) + b"\n")
    for kw in ({}, {"sensor": "64x48"}):
        src = TextSource(str(f), companions=False, skip_bad=True, chunk_bytes=chunk, **kw)
        ev = concat([q for q in src.packets() if isinstance(q, EventPacket)])
        ref = np.array(good, np.int64)
        assert np.array_equal(ev.t, ref[:, 0]) and np.array_equal(ev.x, ref[:, 1])
        assert np.array_equal(ev.y, ref[:, 2]) and np.array_equal(ev.p, np.where(ref[:, 3] > 0, 1, -1))
        assert src.skipped_events == len(junk)
        assert len(ev) + src.skipped_events == data_lines(f.read_bytes())
        starts = np.array([a for a, _ in src.skipped_ranges])
        ends = np.array([b for _, b in src.skipped_ranges])
        k = np.searchsorted(starts, junk, side="right") - 1
        assert (k >= 0).all() and (np.array(junk) <= ends[k]).all()


def test_sensor_pass_counts_skips_once(tmp_path: Path, monkeypatch) -> None:
    """A file too large to hold is read twice (extent, then events): each
    bad line is still counted once."""
    monkeypatch.setattr(text, "_HOLD", 50)
    lines = [b"%d %d %d 1" % (k, k % 30, k % 20) if k % 10 else b"bad line" for k in range(1, 1001)]
    f = tmp_path / "big.txt"
    f.write_bytes(b"\n".join(lines) + b"\n")
    src = TextSource(str(f), companions=False, skip_bad=True, chunk_bytes=512)
    ev = concat([q for q in src.packets() if isinstance(q, EventPacket)])
    assert len(ev) == 900 and src.skipped_events == 100 and ev.sensor == (30, 20)


def test_a_long_line_in_small_chunks_is_linear(tmp_path: Path) -> None:
    """A line longer than the chunk is read in doubling pieces, not copied
    again for every chunk."""
    import time

    f = tmp_path / "long.txt"
    f.write_bytes(b"0.000001 1 2 1\n" + b"7" * 900_000 + b"\n0.000002 3 4 0\n")
    t0 = time.perf_counter()
    src = TextSource(str(f), companions=False, skip_bad=True, chunk_bytes=64)
    ev = concat([q for q in src.packets() if isinstance(q, EventPacket)])
    assert time.perf_counter() - t0 < 1.0
    assert len(ev) == 2 and src.skipped_events == 1


@pytest.mark.parametrize("line, why", [(b"99999999999999.5 1 2 1", "int64"),
                                       (b"0.5 99999999999999999999999 2 1", "above 65535"),
                                       (b"0.5 1 2 18446744073709551617", "polarity")])
def test_numbers_too_large_are_bad_not_wrapped(tmp_path: Path, line: bytes, why: str) -> None:
    """A number beyond int64 is a bad line, never a wrapped-around value
    (2**64 + 1 as a polarity once read as 1)."""
    f = tmp_path / "big.txt"
    f.write_bytes(b"0.1 1 2 1\n" + line + b"\n0.9 1 2 0\n")
    with pytest.raises(FormatError, match=why):
        list(TextSource(str(f), companions=False).packets())
    src = TextSource(str(f), companions=False, skip_bad=True)
    assert len(concat([q for q in src.packets() if isinstance(q, EventPacket)])) == 2 and src.skipped_events == 1
