"""Bad input gives FormatError with file and byte offset, or a counted skip;
fuzzing every parser never crashes, hangs or returns invalid packets."""

from __future__ import annotations

import os
from pathlib import Path

import numpy as np
import pytest
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st

from tectum import EventPacket, FormatError, concat
from tectum.sinks.files import SINKS
from tectum.sinks.files._common import write_all
from tectum.sources.files import SOURCES, open_file

from helpers import decodes_or_names, mutate

EXT = {"text": ".txt", "aedat4": ".aedat4", "evt2": ".raw", "evt3": ".evt3.raw", "dat": ".dat", "hdf5": ".h5",
       "npy": ".npy"}
CORPUS = Path(__file__).parent / "corpus"


def sample(n: int = 300, seed: int = 0) -> EventPacket:
    rng = np.random.default_rng(seed)
    t = np.sort(rng.integers(0, 200_000, n))
    return EventPacket.from_arrays(t, rng.integers(0, 64, n), rng.integers(0, 48, n), rng.choice([-1, 1], n),
                                   sensor=(64, 48))


class _Files(dict):
    def __repr__(self) -> str:  # keep hypothesis reports short
        return "<small files>"


@pytest.fixture(scope="module")
def small_files(tmp_path_factory) -> dict[str, bytes]:
    d = tmp_path_factory.mktemp("small")
    out = _Files()
    for cls in SINKS:
        if cls.name in ("hdf5",):
            continue
        f = d / ("s" + EXT[cls.name])
        write_all(cls(str(f)), [sample()])
        out[cls.name] = f.read_bytes()
    return out


def decode(path: Path, **kw) -> list:
    return list(open_file(str(path), **kw).packets())


def test_truncated_evt2_names_offset(tmp_path: Path, small_files) -> None:
    data = small_files["evt2"]
    f = tmp_path / "t.raw"
    f.write_bytes(data[:-2])
    with pytest.raises(FormatError) as e:
        decode(f)
    assert e.value.path == str(f) and e.value.offset == len(data) - 4
    src = open_file(str(f), skip_bad=True)
    ev = concat([q for q in src.packets()])
    assert len(ev) == 299 and src.skipped_events == 1 and src.skipped_ranges


def test_garbage_word_in_evt3(tmp_path: Path, small_files) -> None:
    data = bytearray(small_files["evt3"])
    hdr = data.index(b"% end\n") + 6
    at = hdr + 40
    data[at:at + 2] = (0xC000).to_bytes(2, "little")  # reserved type 0xC
    f = tmp_path / "g.evt3.raw"
    f.write_bytes(bytes(data))
    with pytest.raises(FormatError) as e:
        decode(f)
    assert e.value.offset == at and "0xc000" in str(e.value)
    src = open_file(str(f), skip_bad=True)
    list(src.packets())
    assert src.skipped_events >= 1 and src.skipped_ranges[0][0] == at


def test_decreasing_timestamps_in_dat(tmp_path: Path, small_files) -> None:
    data = bytearray(small_files["dat"])
    start = len(data) - 300 * 8
    rec = start + 100 * 8
    data[rec:rec + 4] = (0).to_bytes(4, "little")
    f = tmp_path / "d.dat"
    f.write_bytes(bytes(data))
    with pytest.raises(FormatError, match="decreases") as e:
        decode(f)
    assert e.value.offset == rec
    src = open_file(str(f), skip_bad=True)
    ev = concat(list(src.packets()))
    assert len(ev) == 299 and src.skipped_events == 1
    ev.validate()


def test_out_of_geometry(tmp_path: Path, small_files) -> None:
    f = tmp_path / "o.txt"
    f.write_bytes(b"0.000001 1 2 1\n0.000002 500 2 0\n0.000003 3 4 1\n")
    with pytest.raises(FormatError, match="outside") as e:
        decode(f, sensor="64x48")
    assert e.value.offset == 15
    src = open_file(str(f), sensor="64x48", skip_bad=True)
    assert len(concat(list(src.packets()))) == 2 and src.skipped_events == 1


@pytest.mark.parametrize("name, magic", [("aedat4", b"#!AER-DAT4.0\r\n"), ("aedat2", b"#!AER-DAT2.0\r\n"),
                                         ("aedat31", b"#!AER-DAT3.1\r\n")])
def test_wrong_or_corrupt_header(tmp_path: Path, name: str, magic: bytes) -> None:
    f = tmp_path / "x.bin"
    f.write_bytes(magic + b"\xff\xff\xff\x7f garbage")
    cls = next(c for c in SOURCES if c.name == name)
    with pytest.raises(FormatError) as e:
        list(cls(str(f)).packets())
    assert e.value.path == str(f) and e.value.offset is not None


def test_unrecognised_file(tmp_path: Path) -> None:
    f = tmp_path / "x.unknown"
    f.write_bytes(os.urandom(100))
    with pytest.raises(FormatError, match="unrecognised"):
        open_file(str(f))


def _check_fuzz(path: Path, cls: type) -> None:
    decodes_or_names(cls(str(path), sensor="64x48") if cls.name in ("text", "npy", "aedat2") else cls(str(path)),
                     path)


@pytest.mark.parametrize("fmt", ["evt2", "evt3", "dat", "aedat4", "text", "npy"])
@settings(max_examples=25, deadline=None, suppress_health_check=[HealthCheck.function_scoped_fixture])
@given(data=st.data())
def test_fuzz_mutations(fmt: str, data, small_files, tmp_path_factory) -> None:
    f = tmp_path_factory.mktemp("fz") / ("f" + EXT[fmt])
    f.write_bytes(mutate(small_files[fmt], data))
    cls = next(c for c in SOURCES if c.name == fmt)
    _check_fuzz(f, cls)


@pytest.mark.parametrize("cls", SOURCES, ids=lambda c: c.name)
@settings(max_examples=15, deadline=None)
@given(blob=st.binary(max_size=300))
def test_fuzz_random_bytes(cls: type, blob: bytes, tmp_path_factory) -> None:
    prefix = {"aedat4": b"#!AER-DAT4.0\r\n", "aedat2": b"#!AER-DAT2.0\r\n# AEChip: DVS128\r\n",
              "aedat31": b"#!AER-DAT3.1\r\n#!END-HEADER\r\n", "evt2": b"% evt 2.0\n% geometry 64x48\n",
              "evt3": b"% evt 3.0\n% geometry 64x48\n", "dat": b"% Version 2\n% Width 64\n% Height 48\n",
              "npy": b"\x93NUMPY", "hdf5": b"\x89HDF\r\n\x1a\n", "text": b"", "rosbag": b"#ROSBAG V2.0\n"}[cls.name]
    f = tmp_path_factory.mktemp("rb") / ("f.bag" if cls.name == "rosbag" else "f.bin")
    f.write_bytes(prefix + blob)
    _check_fuzz(f, cls)


@pytest.mark.parametrize("path", sorted(CORPUS.glob("*")) if CORPUS.exists() else [], ids=lambda p: p.name)
def test_regression_corpus(path: Path) -> None:
    """Inputs that once crashed a parser (kept small, generated)."""
    fmt = path.name.split("-")[0]
    cls = next(c for c in SOURCES if c.name == fmt)
    _check_fuzz(path, cls)
