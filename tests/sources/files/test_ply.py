"""The PLY point-cloud reader: files as other tools write them (float or
double coordinates, colours, faces, other elements, either byte order),
tectum's own files read with plain numpy, header errors, bad rows."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st

from tectum import FormatError, PointPacket, concat
from tectum.cli import main
from tectum.sinks.files._common import write_all
from tectum.sinks.files.ply import PlySink
from tectum.sources.files import open_file
from tectum.sources.files.ply import PlySource
from tectum.testing import assert_streams_equal

from helpers import decodes_or_names

CUBE = b"""ply
format ascii 1.0
comment made by hand, as the PLY specification's example
element vertex 8
property float x
property float y
property float z
property uchar red
property uchar green
property uchar blue
element face 6
property list uchar int vertex_index
end_header
0 0 0 255 0 0
0 0 1 255 0 0
0 1 1 255 0 0
0 1 0 255 0 0
1 0 0 0 0 255
1 0 1 0 0 255
1 1 1 0 0 255
1 1 0 0 0 255
4 0 1 2 3
4 7 6 5 4
4 0 4 5 1
4 1 5 6 2
4 2 6 7 3
4 3 7 4 0
"""
CUBE_XYZ = [[0, 0, 0], [0, 0, 1], [0, 1, 1], [0, 1, 0], [1, 0, 0], [1, 0, 1], [1, 1, 1], [1, 1, 0]]


def _read(f: Path, **kw: object) -> PointPacket:
    return concat(list(PlySource(str(f), **kw).packets()))  # type: ignore[return-value]


def test_an_ascii_mesh_from_elsewhere_is_one_cloud(tmp_path: Path) -> None:
    f = tmp_path / "cube.ply"
    f.write_bytes(CUBE)
    p = _read(f, t_us=1_000_000)
    assert p.position.tolist() == CUBE_XYZ and p.t.tolist() == [1_000_000] * 8 and "intensity" not in p.data
    assert isinstance(open_file(str(f)), PlySource)
    first = CUBE.replace(b"element vertex 8", b"element camera 2\nproperty float f\nelement vertex 8")
    first = first.replace(b"end_header\n", b"end_header\n500.5\n499.5\n")  # its rows come first
    f.write_bytes(first)
    assert _read(f).position.tolist() == CUBE_XYZ


@pytest.mark.parametrize("order", ["<", ">"])
def test_a_binary_file_from_elsewhere_with_an_element_before_the_vertices(tmp_path: Path, order: str) -> None:
    rng = np.random.default_rng(0)
    xyz = rng.normal(size=(50, 3)).astype(np.float32)
    cams = [np.array([2], order + "u1").tobytes() + np.array([7, 8], order + "i4").tobytes(),
            np.array([1], order + "u1").tobytes() + np.array([9], order + "i4").tobytes()]
    vert = np.empty(50, [("nx", order + "f4"), ("x", order + "f4"), ("y", order + "f4"), ("z", order + "f4"),
                         ("intensity", order + "u2")])
    vert["nx"], vert["x"], vert["y"], vert["z"] = 0, xyz[:, 0], xyz[:, 1], xyz[:, 2]
    vert["intensity"] = np.arange(50)
    fmt = "binary_little_endian" if order == "<" else "binary_big_endian"
    head = (f"ply\r\nformat {fmt} 1.0\r\nobj_info from elsewhere\r\nelement camera 2\r\n"
            "property list uchar int ids\r\nelement vertex 50\r\nproperty float nx\r\nproperty float32 x\r\n"
            "property float y\r\nproperty float z\r\nproperty ushort intensity\r\nend_header\r\n").encode()
    f = tmp_path / "scan.ply"
    f.write_bytes(head + b"".join(cams) + vert.tobytes() + b"trailing elements are ignored")
    p = _read(f)
    assert np.array_equal(p.position, xyz.astype(np.float64)) and p.intensity.tolist() == list(range(50))
    assert p.position.dtype == np.float64 and p.intensity.dtype == np.float32 and p.t.tolist() == [0] * 50


def test_tectum_files_are_plain_ply(tmp_path: Path) -> None:
    """What the sink writes, read with nothing but numpy and the header's words."""
    rng = np.random.default_rng(1)
    t = np.repeat([5, (1 << 53) - 1], 10)
    pts = PointPacket(t, position=rng.normal(size=(20, 3)), intensity=rng.random(20).astype(np.float32))
    f = tmp_path / "b.ply"
    write_all(PlySink(str(f), binary=True), [pts])
    raw = f.read_bytes()
    end = raw.index(b"end_header\n") + len(b"end_header\n")
    words = [ln.split() for ln in raw[:end].decode().splitlines()]
    assert ["element", "vertex", "20"] in words and ["format", "binary_little_endian", "1.0"] in words
    props = [(w[1], w[2]) for w in words if w[0] == "property"]
    assert props == [("double", "x"), ("double", "y"), ("double", "z"), ("float", "intensity"), ("double", "t_us")]
    rec = np.frombuffer(raw[end:], [("x", "<f8"), ("y", "<f8"), ("z", "<f8"), ("i", "<f4"), ("t", "<f8")])
    assert np.array_equal(rec["t"].astype(np.int64), t) and np.array_equal(rec["x"], pts.position[:, 0])
    assert np.array_equal(rec["i"], pts.intensity)


@pytest.mark.parametrize("head, why", [
    (b"plyx\n", "not a PLY file"),
    (b"ply\nformat ascii 2.0\nend_header\n", "header line 2 .*unknown format"),
    (b"ply\nformat ascii 1.0\nproperty float x\nend_header\n", "header line 3 .*before any element"),
    (b"ply\nformat ascii 1.0\nelement vertex many\nend_header\n", "header line 3 .*element NAME COUNT"),
    (b"ply\nformat ascii 1.0\nelement vertex 1\nproperty float\nend_header\n", "header line 4 .*property TYPE NAME"),
    (b"ply\nformat ascii 1.0\nelement vertex 1\nproperty float128 x\nend_header\n", "header line 4"),
    (b"ply\nformat ascii 1.0\nbanana\nend_header\n", "unknown keyword 'banana'"),
    (b"ply\nformat ascii 1.0\nelement vertex 1\nproperty float x\n", "does not end"),
    (b"ply\nelement vertex 0\nend_header\n", "no 'format' line"),
    (b"ply\nformat ascii 1.0\nelement face 0\nend_header\n", "no 'vertex' element"),
    (b"ply\nformat ascii 1.0\nelement vertex 1\nproperty float x\nproperty float y\nend_header\n", "has no z"),
    (b"ply\nformat ascii 1.0\nelement vertex 1\nproperty float x\nproperty float y\nproperty float z\n"
     b"property list uchar int n\nend_header\n", "list properties \\['n'\\]"),
])
def test_header_errors_say_what_is_wrong(tmp_path: Path, head: bytes, why: str) -> None:
    f = tmp_path / "bad.ply"
    f.write_bytes(head + (b"0 0 0\n" if b"end_header" in head else b"0 0 0"))
    with pytest.raises(FormatError, match=why) as e:
        _read(f)
    assert e.value.path == str(f)


ASCII_T = b"ply\nformat ascii 1.0\nelement vertex 4\nproperty double x\nproperty double y\nproperty double z\n" \
          b"property double t_us\nend_header\n"


@pytest.mark.parametrize("bad, why", [(b"0 0 0 2.5", "time: t_us=2.5 is not a whole number"),
                                      (b"0 0 0 1", "time goes backwards: 1 µs after 3 µs"),
                                      (b"0 0 0", "3 columns, expected 4"), (b"0 x 0 4", "column 'y'")])
def test_a_bad_ascii_row_is_named_by_line_or_skipped(tmp_path: Path, bad: bytes, why: str) -> None:
    f = tmp_path / "a.ply"
    f.write_bytes(ASCII_T + b"0 0 0 2\n0 0 0 3\n" + bad + b"\n0 0 0 9\n")
    with pytest.raises(FormatError, match=f"line 11: {why}") as e:
        _read(f)
    assert e.value.offset == len(ASCII_T) + 16
    src = PlySource(str(f), skip_bad=True)
    assert concat(list(src.packets())).t.tolist() == [2, 3, 9] and src.counts == {"skipped_rows": 1}


def test_bad_binary_rows_and_a_short_file(tmp_path: Path) -> None:
    pts = PointPacket([1, 2, 3, 4], position=np.zeros((4, 3)))
    f = tmp_path / "b.ply"
    write_all(PlySink(str(f), binary=True), [pts])
    raw = bytearray(f.read_bytes())
    start = len(raw) - 4 * 32
    raw[start + 2 * 32 + 24:start + 2 * 32 + 32] = np.array([0.5], "<f8").tobytes()  # vertex 2: t = 0.5 µs
    f.write_bytes(bytes(raw))
    with pytest.raises(FormatError, match="vertex 2: t_us=.*0.5.* is not a whole number") as e:
        _read(f, chunk_bytes=64)
    assert e.value.offset == start + 2 * 32
    src = PlySource(str(f), skip_bad=True, chunk_bytes=64)
    assert concat(list(src.packets())).t.tolist() == [1, 2, 4] and src.skipped_events == 1
    f.write_bytes(bytes(raw[:-40]))  # the last vertex and a bit cut off
    with pytest.raises(FormatError, match="the header says 4 vertices, the file holds 2"):
        _read(f)
    src = PlySource(str(f), skip_bad=True)
    assert concat(list(src.packets())).t.tolist() == [1, 2] and src.skipped_events == 2


def test_run_info_and_convert_keep_every_point(tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    rng = np.random.default_rng(2)
    pts = PointPacket(np.repeat([0, 40_000, 80_000], 100), position=rng.normal(size=(300, 3)),
                      intensity=rng.random(300).astype(np.float32))
    f = tmp_path / "a.ply"
    write_all(PlySink(str(f)), [pts])
    again, csv, npz = tmp_path / "again.ply", tmp_path / "pts.csv", tmp_path / "pts.npz"
    assert main(["run", str(f), "--sink", f"{again}?binary=true"]) == 0
    assert main(["convert", str(again), str(csv)]) == 0
    assert main(["convert", str(csv), str(npz)]) == 0
    capsys.readouterr()
    assert main(["info", str(again)]) == 0
    assert "points 300" in capsys.readouterr().out
    for path in (again, csv, npz):
        assert_streams_equal([pts], list(open_file(str(path)).packets()), str(path))


@pytest.mark.abuse
@settings(max_examples=40, deadline=None, suppress_health_check=[HealthCheck.function_scoped_fixture])
@given(blob=st.binary(max_size=300), binary=st.booleans())
def test_fuzz_random_bytes(tmp_path_factory, blob: bytes, binary: bool) -> None:
    head = ASCII_T.replace(b"ascii", b"binary_little_endian") if binary else ASCII_T
    f = tmp_path_factory.mktemp("fz") / "f.ply"
    f.write_bytes(head + blob)
    decodes_or_names(PlySource(str(f)), f)
