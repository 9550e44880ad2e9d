"""What file headers and source options say, and how each mistake is named:
sensor sizes, Prophesee geometry (``geometry``, ``width``/``height``, a known
plugin or system id, unreadable values ignored), ``t0`` offsets, header
limits, and the options every file source checks."""

from __future__ import annotations

import io
from pathlib import Path

import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from tectum import FormatError
from tectum.sources.files._common import (
    header_dict,
    parse_size,
    read_prefixed_header,
    sensor_from_header,
    t0_from_header,
    thread_count,
)
from tectum.sources.files.prophesee import DatSource, check_raw_header


@pytest.mark.parametrize("text,size", [("640x480", (640, 480)), (" 346 X 260 ", (346, 260)), ("304,240", (304, 240)),
                                       ((128, 96), (128, 96)), (None, None), ("", None)])
def test_sizes(text, size) -> None:
    assert parse_size(text) == size


def test_a_size_that_is_no_size_is_named() -> None:
    with pytest.raises(ValueError, match="'640 by 480' is not WIDTHxHEIGHT"):
        parse_size("640 by 480")


@pytest.mark.parametrize("lines,size", [
    (["geometry 1280x720"], (1280, 720)), (["geometry wide"], None), (["Width 640", "Height 480"], (640, 480)),
    (["width 640", "height tall"], None), (["plugin_name hal_plugin_imx636_evk4"], (1280, 720)),
    (["plugin_name hal_plugin_gen31_fx3"], (640, 480)), (["system_ID 40"], (320, 320)), (["system_ID 999"], None),
])
def test_prophesee_geometry(lines: list[str], size) -> None:
    assert sensor_from_header(header_dict(lines)) == size


def test_t0_offsets() -> None:
    assert t0_from_header(header_dict(["t0 12345 us"]), "f") == 12345
    assert t0_from_header(header_dict(["time_offset 7"]), "f") == 7
    assert t0_from_header({}, "f") == 0
    with pytest.raises(FormatError, match="header 't0' is not an integer µs: 'soon'"):
        t0_from_header(header_dict(["t0 soon"]), "f")


def test_header_limits() -> None:
    with pytest.raises(FormatError, match="not terminated") as e:
        read_prefixed_header(io.BytesIO(b"% evt 3.0\n% geometry"), b"%", "f")
    assert e.value.offset == 10
    with pytest.raises(FormatError, match="longer than 64 bytes"):
        read_prefixed_header(io.BytesIO(b"% a\n" * 40), b"%", "f", limit=64)
    lines, end = read_prefixed_header(io.BytesIO(b"% evt 2.0\n% end\n% not header\n"), b"%", "f")
    assert lines == ["evt 2.0", "end"] and end == 16


def test_options_every_file_source_checks(tmp_path: Path) -> None:
    with pytest.raises(ValueError, match="chunk_bytes must be >= 64"):
        DatSource("x.dat", chunk_bytes=8)
    with pytest.raises(ValueError, match="t_end_us is before t_start_us"):
        DatSource("x.dat", t_start_us=10, t_end_us=5)
    with pytest.raises(FormatError, match="cannot open"):
        list(DatSource(str(tmp_path / "absent.dat")).packets())
    with pytest.raises(ValueError, match="threads must be >= 0"):
        thread_count(-1)
    assert thread_count(2) == 2 and 1 <= thread_count(0) <= 4


def test_raw_header_check(tmp_path: Path) -> None:
    path = tmp_path / "r.raw"
    path.write_bytes(b"% format EVT3;height=720;width=1280\n% end\n")
    assert check_raw_header(str(path)) == "evt3"
    path.write_bytes(b"% camera_integrator_name Prophesee\n% end\n")
    with pytest.raises(FormatError, match="names no event format"):
        check_raw_header(str(path))


def _header_by_lines(f, prefix: bytes, path: str, limit: int = 1 << 20):  # type: ignore[no-untyped-def]
    """read_prefixed_header as it was (buffered, a line at a time): the
    reference for the block-reading one."""
    f.seek(0)
    lines, pos = [], 0
    while True:
        if f.read(1) != prefix:
            break
        rest = f.readline(limit)
        if not rest.endswith(b"\n"):
            raise FormatError("header line is not terminated (truncated or not a text header)", path=path,
                              offset=pos)
        pos += 1 + len(rest)
        if pos > limit:
            raise FormatError(f"header longer than {limit} bytes", path=path, offset=pos)
        line = rest.rstrip(b"\r\n").decode("latin1").strip()
        lines.append(line)
        if prefix == b"%" and line.lower() == "end":
            break
    f.seek(pos)
    return lines, pos


_header_line = st.one_of(st.just(b"% end\n"), st.just(b"%\n"), st.just(b"% evt 2.0\r\n"),
                         st.binary(max_size=30).map(lambda b: b"%" + b.replace(b"\n", b" ") + b"\n"),
                         st.binary(min_size=3000, max_size=9000).map(lambda b: b"% " + b.replace(b"\n", b"x") + b"\n"))


@settings(max_examples=150, deadline=None)
@given(st.lists(_header_line, max_size=6), st.binary(max_size=40), st.sampled_from([64, 5000, 1 << 20]))
def test_header_read_in_blocks_as_line_by_line(tmp_path_factory, lines, tail, limit) -> None:  # type: ignore[no-untyped-def]
    """The block-reading header parser gives the line-by-line one's lines,
    end and errors (with offsets), and leaves the file at the end, from an
    unbuffered file (reads may come short) and from memory; lines longer
    than the first 4 KiB block and the limit, a header cut anywhere."""
    data = b"".join(lines) + tail
    path = tmp_path_factory.mktemp("h") / "f.raw"
    path.write_bytes(data)

    def outcome(fn, f):  # type: ignore[no-untyped-def]
        try:
            got = fn(f, b"%", "f", limit)
            return got, f.tell()
        except FormatError as e:
            return str(e), e.offset

    want = outcome(_header_by_lines, io.BytesIO(data))
    assert outcome(read_prefixed_header, io.BytesIO(data)) == want
    with open(path, "rb", buffering=0) as f:
        assert outcome(read_prefixed_header, f) == want
