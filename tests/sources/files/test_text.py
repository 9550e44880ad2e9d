"""The text reader's checks, made while parsing: each bad line is named by
its byte offset (or skipped and counted), whichever chunk it falls in, and
the sensor size inferred from one pass or two gives the same events."""

from __future__ import annotations

import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest

from tectum import EventPacket, FormatError, concat
from tectum.sources.files import text
from tectum.sources.files.text import TextSource

LINES = [b"0.000001 1 2 1", b"0.000002 3 4 0", b"0.000003 5 6 1", b"0.000004 7 8 0"]


def _file(tmp_path: Path, lines: list[bytes]) -> Path:
    f = tmp_path / "events.txt"
    f.write_bytes(b"\n".join(lines) + b"\n")
    return f


def _read(f: Path, **kw) -> tuple[EventPacket, TextSource]:
    src = TextSource(str(f), companions=False, **kw)
    return concat([q for q in src.packets() if isinstance(q, EventPacket)]), src


def _offset(lines: list[bytes], k: int) -> int:
    return sum(len(ln) + 1 for ln in lines[:k])


@pytest.mark.parametrize("bad, why", [(b"0.0000035 -1 2 1", "negative coordinate"),
                                      (b"0.0000035 70000 2 1", "above 65535"),
                                      (b"0.0000035 65536 2 1", "above 65535"),
                                      (b"0.0000035 3 65536 1", "above 65535"),
                                      (b"0.0000035 1 2 2", "polarity"),
                                      (b"0.0000035 1 2 -1", "polarity"),  # -1 after 0/1 polarities
                                      (b"0.0000035 1.5 2 1", "not 4 numbers"),
                                      (b"0.0000035 1 2", "not 4 numbers")])
@pytest.mark.parametrize("chunk", [64, 1 << 20])
def test_bad_line_is_named_or_skipped(tmp_path: Path, bad: bytes, why: str, chunk: int) -> None:
    lines = [b"%.6f %d %d %d" % (k * 1e-6, k % 7, k % 5, k % 2) for k in range(1, 81)]
    lines = lines[:50] + [bad.replace(b"0.0000035", b"0.0000505")] + lines[50:]
    f = _file(tmp_path, lines)
    with pytest.raises(FormatError, match=why) as e:
        _read(f, sensor="16x16", chunk_bytes=chunk)
    assert e.value.offset == _offset(lines, 50)
    ev, src = _read(f, sensor="16x16", chunk_bytes=chunk, skip_bad=True)
    assert len(ev) == 80 and src.skipped_events == 1 and src.skipped_ranges[0][0] == _offset(lines, 50)


def test_polarity_conventions(tmp_path: Path) -> None:
    zero_one, _ = _read(_file(tmp_path, LINES))
    signed, _ = _read(_file(tmp_path, [ln.replace(b" 0", b" -1") for ln in LINES]))
    assert zero_one.p.tolist() == signed.p.tolist() == [1, -1, 1, -1]


def test_time_going_back_is_named_in_a_later_chunk(tmp_path: Path) -> None:
    lines = [b"%.6f %d %d 1" % (k * 1e-6, k % 16, k % 16) for k in range(1, 400)]
    lines[300] = b"0.000010 1 1 1"
    f = _file(tmp_path, lines)
    with pytest.raises(FormatError, match="timestamp decreases") as e:
        _read(f, sensor="16x16", chunk_bytes=256)
    assert e.value.offset == _offset(lines, 300)


def test_sensor_from_one_pass_or_two(tmp_path: Path, monkeypatch) -> None:
    rng = np.random.default_rng(0)
    lines = [b"%.6f %d %d %d" % (k * 1e-6, rng.integers(0, 40), rng.integers(0, 30), rng.integers(0, 2))
             for k in range(1, 3000)]
    f = _file(tmp_path, lines)
    held, _ = _read(f, chunk_bytes=4096)
    monkeypatch.setattr(text, "_HOLD", 500)  # too many to hold: a first pass for the extent
    twice, _ = _read(f, chunk_bytes=4096)
    assert held.sensor == twice.sensor == (40, 30)
    assert all(np.array_equal(getattr(held, c), getattr(twice, c)) for c in "txyp") and len(held) == 2999


def _tectum(*args: str) -> subprocess.CompletedProcess[str]:
    return subprocess.run([sys.executable, "-m", "tectum", *args], capture_output=True, text=True)


def test_a_sequence_folder_opens_as_its_events_txt(tmp_path: Path) -> None:
    """A folder of the RPG event-camera dataset layout (``events.txt`` with
    ``groundtruth.txt`` beside it) is a recording: ``info``, ``convert`` and
    ``run`` take the folder as they take its ``events.txt``, companions
    included; a folder without an events file stays a one-line error."""
    seq = tmp_path / "slider"
    seq.mkdir()
    _file(seq, LINES)
    (seq / "groundtruth.txt").write_text("0.000001 1 2 3 0 0 0 1\n0.000003 2 2 3 0 0 0 1\n")
    info = _tectum("info", str(seq))
    assert info.returncode == 0, info.stderr
    assert "events: 4" in info.stdout and "poses 2" in info.stdout and str(seq / "events.txt") in info.stdout
    for arg, out in ((seq, tmp_path / "a.h5"), (seq / "events.txt", tmp_path / "b.h5")):
        r = _tectum("convert", str(arg), str(out))
        assert r.returncode == 0, r.stderr
    r = _tectum("run", str(tmp_path / "a.h5"), "--sink", str(tmp_path / "a.npz"))
    assert r.returncode == 0, r.stderr
    h5 = [_tectum("info", str(tmp_path / n)).stdout.split("file:")[1].split("\n", 1)[1] for n in ("a.h5", "b.h5")]
    assert h5[0] == h5[1] and "poses 2" in h5[0]
    assert np.load(tmp_path / "a.npz")["t"].tolist() == [1, 2, 3, 4]
    r = _tectum("run", str(seq), "--op", "filter.refractory:period_us=1", "--sink", str(tmp_path / "c.npz"))
    assert r.returncode == 0, r.stderr
    assert np.load(tmp_path / "c.npz")["t"].tolist() == [1, 2, 3, 4]
    r = _tectum("run", str(seq), "--sink", str(tmp_path / "p.tum"))  # wired by the folder's kinds: poses
    assert r.returncode == 0, r.stderr
    assert (tmp_path / "p.tum").read_text().splitlines()[1:] == ["0.000001 1.0 2.0 3.0 0.0 0.0 0.0 1.0",
                                                                 "0.000003 2.0 2.0 3.0 0.0 0.0 0.0 1.0"]
    (seq / "events.txt").rename(seq / "other.txt")
    r = _tectum("info", str(seq))
    assert r.returncode != 0 and r.stderr.count("\n") == 1 and "a folder that no source recognises" in r.stderr
