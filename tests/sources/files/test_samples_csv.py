"""The sample CSV reader: which files it takes (and leaves to the event
text reader), headers, dtypes of extra fields, bad rows by line number."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st

from tectum import FormatError, Kind, concat
from tectum.sources.files import open_file
from tectum.sources.files.samples_csv import CsvSource
from tectum.sources.files.text import TextSource

from helpers import decodes_or_names

IMU = [b"# tectum imu", b"t,ax,ay,az,gx,gy,gz", b"10,0,0,9.81,0.1,0.2,0.3", b"20,0,0,9.8,0.1,0.2,0.3",
       b"30,1e-3,-0,9.8,0.1,0.2,0.3"]


def _file(tmp_path: Path, lines: list[bytes], name: str = "a.csv") -> Path:
    f = tmp_path / name
    f.write_bytes(b"\n".join(lines) + b"\n")
    return f


def _read(f: Path, **kw: object):  # type: ignore[no-untyped-def]
    src = CsvSource(str(f), **kw)
    return concat(list(src.packets())), src


@pytest.mark.parametrize("lines, source", [
    (IMU, CsvSource),
    (IMU[1:], CsvSource),  # the header alone says imu
    ([b"t,x,y,z", b"1,0.5,0.25,2.0"], CsvSource),  # points
    ([b"t,x,y,p", b"1,3,4,1", b"2,5,6,0"], TextSource),  # events stay with the text reader
    ([b"t,x@320,y@240,on", b"0,0,0,1", b"0,1,0,1"], TextSource),
    ([b"0.1 1 2 1", b"0.2 3 4 0"], TextSource),
])
def test_sample_csvs_and_event_csvs_each_find_their_reader(tmp_path: Path, lines: list[bytes], source: type) -> None:
    assert type(open_file(str(_file(tmp_path, lines)))) is source


def test_header_order_comments_and_optional_fields(tmp_path: Path) -> None:
    lines = [b"# from elsewhere: columns in another order", b"t, gz,gy,gx,az,ay,ax,temperature",
             b"5,3,2,1,6,5,4,25.5", b"# a comment between rows", b"", b"6,3,2,1,6,5,4,nan"]
    pkt, _ = _read(_file(tmp_path, lines))
    assert pkt.kind == Kind.IMU and pkt.t.tolist() == [5, 6]
    assert pkt.gyro[0].tolist() == [1, 2, 3] and pkt.accel[0].tolist() == [4, 5, 6]
    assert pkt.temperature[0] == 25.5 and np.isnan(pkt.temperature[1])


def test_extra_fields_come_back_with_the_dtype_of_the_kind_line(tmp_path: Path) -> None:
    lines = [b"# tectum tracks code=int16[2] score=float32", b"t,id,x,y,code_0,code_1,score,other",
             b"1,7,0.5,0.5,-3,4,0.1,2.5"]
    pkt, _ = _read(_file(tmp_path, lines))
    assert pkt.code.dtype == np.int16 and pkt.code.tolist() == [[-3, 4]]
    assert pkt.score.dtype == np.float32 and pkt.score[0] == np.float32(0.1)
    assert pkt.other.dtype == np.float64 and pkt.id.dtype == np.int64


def test_a_header_that_fits_two_kinds_needs_the_kind_option(tmp_path: Path) -> None:
    f = _file(tmp_path, [b"t,id,x,y", b"1,7,0.5,0.5"])
    with pytest.raises(FormatError, match="fits tracks and clusters: say which with \\?kind="):
        _read(f)
    assert _read(f, kind="clusters")[0].kind == Kind.CLUSTERS
    with pytest.raises(FormatError, match="the file holds imu, the kind option says poses"):
        _read(_file(tmp_path, IMU, "b.csv"), kind="poses")


@pytest.mark.parametrize("lines, why", [
    ([b"# tectum imu", b"t,ax,ay,az,gx,gy"], "field 'gyro' needs columns \\['gx', 'gy', 'gz'\\]"),
    ([b"# tectum imu", b"t,gx,gy,gz"], "imu needs field 'accel'"),
    ([b"# tectum imu", b"time,ax,ay,az,gx,gy,gz"], "first column must be 't'"),
    ([b"# tectum imu", b"t,ax,ax,az,gx,gy,gz"], "column names repeat"),
    ([b"# tectum frames", b"t,images"], "'frames' is no stream kind a CSV holds"),
    ([b"# tectum tracks code=int16[2]", b"t,id,x,y,code"], "declares field 'code' but the header lacks"),
    ([b"# tectum tracks code:int16", b"t,id,x,y,code"], "is not NAME=DTYPE"),
    ([b"# tectum imu"], "no header row"),
])
def test_header_errors(tmp_path: Path, lines: list[bytes], why: str) -> None:
    with pytest.raises(FormatError, match=why):
        _read(_file(tmp_path, lines))


@pytest.mark.parametrize("bad, why", [
    (b"25,0,0,9.8,0.1,0.2", "6 columns, expected 7"),
    (b"25,0,0,9.8,0.1,0.2,x", "column 'gz': b'x' is not a number"),
    (b"25.5,0,0,9.8,0.1,0.2,0.3", "time: b'25.5' is not an integer µs"),
    (b"15,0,0,9.8,0.1,0.2,0.3", "time goes backwards: 15 µs after 20 µs"),
    (b"25,0,0,9.8,0.1,0.2,1_0", "'_' inside a number"),
])
@pytest.mark.parametrize("chunk", [64, 1 << 20])
def test_a_bad_row_is_named_by_line_or_skipped(tmp_path: Path, bad: bytes, why: str, chunk: int) -> None:
    lines = IMU[:4] + [bad] + IMU[4:]
    f = _file(tmp_path, lines)
    with pytest.raises(FormatError, match=why) as e:
        _read(f, chunk_bytes=chunk)
    assert "line 5:" in str(e.value) and e.value.offset == sum(len(ln) + 1 for ln in lines[:4])
    pkt, src = _read(f, chunk_bytes=chunk, skip_bad=True)
    assert pkt.t.tolist() == [10, 20, 30] and src.counts == {"skipped_rows": 1}


@pytest.mark.parametrize("bad, why", [(b"3,7,x,0.5", "column 'x'"), (b"3,7.5,1,0.5", "'7.5' is not an integer"),
                                      (b"3,9223372036854775808,1,0.5", "out of the int64 range")])
def test_integer_fields_take_integers_only(tmp_path: Path, bad: bytes, why: str) -> None:
    with pytest.raises(FormatError, match=why):
        _read(_file(tmp_path, [b"# tectum tracks", b"t,id,x,y", b"1,7,0.5,0.5", bad]))


def test_poses_must_be_poses(tmp_path: Path) -> None:
    lines = [b"# tectum poses", b"t,tx,ty,tz,qx,qy,qz,qw", b"1,0,0,0,0,0,0,1", b"2,0,0,0,0,0,0,2"]
    with pytest.raises(FormatError, match="line 4: quaternion norm 2 is not 1"):
        _read(_file(tmp_path, lines))


@settings(max_examples=40, deadline=None, suppress_health_check=[HealthCheck.function_scoped_fixture])
@given(blob=st.binary(max_size=300), prefix=st.sampled_from([b"# tectum imu\n", b"t,wx,wy,wz\n", b"# tectum tracks\n"]))
def test_fuzz_random_bytes(tmp_path_factory, blob: bytes, prefix: bytes) -> None:
    f = tmp_path_factory.mktemp("fz") / "f.csv"
    f.write_bytes(prefix + blob)
    decodes_or_names(CsvSource(str(f)), f)


def test_the_event_text_sniffer_leaves_tectum_sample_files_alone() -> None:
    tracks = b"# tectum tracks\nt,id,x,y\n1,2,3,1\n2,3,4,0\n"  # four numbers a row, the last 0/1: like events
    assert not TextSource.sniff(tracks) and CsvSource.sniff(tracks)
    assert TextSource.sniff(tracks.split(b"\n", 2)[2])  # without the header lines, it would be taken for events


def test_the_kind_is_known_before_opening(tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    from tectum.cli import main

    f = _file(tmp_path, IMU)
    assert CsvSource.kinds_for(str(f), {}) == (Kind.IMU,)
    assert CsvSource.kinds_for(str(_file(tmp_path, [b"t,id,x,y"], "b.csv")), {"kind": "tracks"}) == (Kind.TRACKS,)
    assert main(["run", str(f), "--sink", str(tmp_path / "out.tum")]) != 0
    err = capsys.readouterr().err
    assert "consumes {poses} but its input(s) 'source' provide only {imu}" in err
