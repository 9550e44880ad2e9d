"""The TUM trajectory reader: exact times, every kind of bad row named by
its line (or skipped and counted), and the files it recognises."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st

from tectum import FormatError, PosePacket, concat
from tectum.cli import main
from tectum.sources.files import open_file
from tectum.sources.files.tum import TumSource

from helpers import decodes_or_names

GOOD = [b"# t[s] tx ty tz qx qy qz qw", b"1.0 0 0 0 0 0 0 1", b"1.5 1 2 3 0.5 0.5 0.5 0.5",
        b"2.25 -1 0.5 4 0 0.6 0 0.8", b"3 9 9 9 0 0 1 0"]


def _file(tmp_path: Path, lines: list[bytes], name: str = "a.tum") -> Path:
    f = tmp_path / name
    f.write_bytes(b"\n".join(lines) + b"\n")
    return f


def _poses(f: Path, **kw: object) -> tuple[PosePacket, TumSource]:
    src = TumSource(str(f), **kw)
    return concat(list(src.packets())), src  # type: ignore[return-value]


def test_reads_poses_with_exact_times(tmp_path: Path) -> None:
    lines = GOOD + [b"1403636579.763555584 0 0 0 0 0 0 1", b"1403636579.7635565 0 0 0 0 0 0 1",
                    b"1.4036365797635566e9\t0 0 0 0 0 0 1"]
    p, _ = _poses(_file(tmp_path, lines))
    # digits below 1 µs round half up, from the decimal digits (a float64 of 1403636579.7635565 s is 0.2 µs off)
    assert p.t.tolist() == [1_000_000, 1_500_000, 2_250_000, 3_000_000, 1_403_636_579_763_556,
                            1_403_636_579_763_557, 1_403_636_579_763_557]
    assert p.position[1].tolist() == [1, 2, 3] and p.orientation[2].tolist() == [0, 0.6, 0, 0.8]


@pytest.mark.parametrize("bad, why", [
    (b"2.5 0 0 zero 0 0 0 1", "column 'tz': b'zero' is not a number"),
    (b"2.5 0 0 0 0 0 1", "7 columns, expected 8"),
    (b"2.5 0 0 0 0 0 0 1 7", "9 columns, expected 8"),
    (b"2.5 nan 0 0 0 0 0 1", "NaN or infinite"),
    (b"2.5 0 0 inf 0 0 0 1", "NaN or infinite"),
    (b"2.5 0 0 0 0 0 0 1.002", "quaternion norm 1.002 is not 1"),
    (b"1.2 0 0 0 0 0 0 1", "time goes backwards: 1200000 µs after 1500000 µs"),
    (b"two 0 0 0 0 0 0 1", "time: b'two' is not a decimal number"),
    (b"nan 0 0 0 0 0 0 1", "time: b'nan' is not a decimal number"),
])
@pytest.mark.parametrize("chunk", [64, 1 << 20])
def test_a_bad_row_is_named_by_line_or_skipped(tmp_path: Path, bad: bytes, why: str, chunk: int) -> None:
    lines = GOOD[:3] + [bad] + GOOD[3:]
    f = _file(tmp_path, lines)
    with pytest.raises(FormatError, match=why) as e:
        _poses(f, chunk_bytes=chunk)
    assert "line 4:" in str(e.value) and e.value.offset == sum(len(ln) + 1 for ln in lines[:3])
    assert str(f) in str(e.value)
    p, src = _poses(f, chunk_bytes=chunk, skip_bad=True)
    assert len(p) == 4 and src.skipped_events == 1 and src.counts == {"skipped_rows": 1}


def test_a_quaternion_within_the_tolerance_is_a_pose(tmp_path: Path) -> None:
    p, _ = _poses(_file(tmp_path, [b"0 0 0 0 0 0 0 1.0009", b"1 0 0 0 0 0 0 0.9991"]))
    assert len(p) == 2


def test_skipped_rows_show_in_the_run_stats(tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    f = _file(tmp_path, GOOD[:3] + [b"x", b"0.1 0 0 0 0 0 0 1"] + GOOD[3:])
    out = tmp_path / "b.tum"
    assert main(["run", f"{f}?skip_bad=true", "--sink", str(out), "--stats"]) == 0
    assert "skipped_rows" in capsys.readouterr().out
    p, _ = _poses(out)
    assert p.t.tolist() == [1_000_000, 1_500_000, 2_250_000, 3_000_000]


def test_run_info_and_convert_keep_every_pose(tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    f = _file(tmp_path, GOOD)
    ref, _ = _poses(f)
    again, csv = tmp_path / "again.tum", tmp_path / "poses.csv"
    assert main(["run", str(f), "--sink", str(again)]) == 0
    assert main(["convert", str(again), str(csv)]) == 0
    capsys.readouterr()
    assert main(["info", str(csv)]) == 0
    table = capsys.readouterr().out
    assert "poses 4" in table and "1000000 / 3000000 µs" in table
    for path in (again, csv):
        got = concat([q for q in open_file(str(path)).packets()])
        assert np.array_equal(got.t, ref.t) and np.array_equal(got.position, ref.position)
        assert np.array_equal(got.orientation, ref.orientation)


def test_an_ecd_groundtruth_file_is_recognised(tmp_path: Path) -> None:
    f = _file(tmp_path, GOOD[1:], name="groundtruth.txt")
    assert isinstance(open_file(str(f)), TumSource)
    events = _file(tmp_path, [b"0.1 1 2 1", b"0.2 3 4 0"], name="events.txt")
    assert not isinstance(open_file(str(events)), TumSource)
    assert not TumSource.sniff(b"1 0 0 0 0 0 0 7\n")  # eight numbers but no quaternion


@settings(max_examples=40, deadline=None, suppress_health_check=[HealthCheck.function_scoped_fixture])
@given(blob=st.binary(max_size=300))
def test_fuzz_random_bytes(tmp_path_factory, blob: bytes) -> None:
    f = tmp_path_factory.mktemp("fz") / "f.tum"
    f.write_bytes(b"1.0 0 0 0 0 0 0 1\n" + blob)
    decodes_or_names(TumSource(str(f)), f)
