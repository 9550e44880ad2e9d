"""Bad input gives FormatError with file and byte offset, or a counted skip;
fuzzing every parser never crashes, hangs or returns invalid packets."""

from __future__ import annotations

import gc
import importlib.util
import os
import struct
import warnings
from pathlib import Path

import numpy as np
import pytest
from event_files import AEDAT2_DVS128_HEADER, aedat2_dvs128, dvs_bag
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st

from tectum import EventPacket, FormatError, concat
from tectum.sinks.files import SINKS
from tectum.sinks.files._common import write_all
from tectum.sources.files import SOURCES, open_file

from helpers import decodes_or_names, mutate

EXT = {"text": ".txt", "aedat4": ".aedat4", "evt2": ".raw", "evt3": ".evt3.raw", "dat": ".dat", "hdf5": ".h5",
       "npy": ".npy", "es": ".es", "nmnist": ".bin"}
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


def same_events(a: EventPacket, b: EventPacket) -> bool:
    return all(np.array_equal(getattr(a, c), getattr(b, c)) for c in "txyp")


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
    decodes_or_names(cls(str(path), sensor="64x48") if cls.name in ("text", "npy", "aedat2", "nmnist") else cls(str(path)),
                     path)


@pytest.mark.parametrize("fmt", ["evt2", "evt3", "dat", "aedat4", "text", "npy", "es", "nmnist"])
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
              "npy": b"\x93NUMPY", "hdf5": b"\x89HDF\r\n\x1a\n", "text": b"", "rosbag": b"#ROSBAG V2.0\n",
              "es": b"Event Stream\x02\x00\x00\x02\x40\x00\x30\x00", "nmnist": b""}[cls.name]
    f = tmp_path_factory.mktemp("rb") / ("f.bag" if cls.name == "rosbag" else "f.bin")
    f.write_bytes(prefix + blob)
    _check_fuzz(f, cls)


@pytest.mark.parametrize("path", sorted(CORPUS.glob("*")) if CORPUS.exists() else [], ids=lambda p: p.name)
def test_regression_corpus(path: Path) -> None:
    """Inputs that once crashed a parser (kept small, generated)."""
    fmt = path.name.split("-")[0]
    cls = next(c for c in SOURCES if c.name == fmt)
    _check_fuzz(path, cls)


# -- no header, no guess (issue 20, item 14) ---------------------------------------------
def _cli(argv: list[str], capsys) -> tuple[int, list[str]]:
    from tectum.cli import main

    code = main(argv)
    return code, capsys.readouterr().err.splitlines()


@pytest.mark.abuse
@pytest.mark.parametrize("verb", ["info", "convert"])
def test_random_bytes_named_raw_are_refused(verb: str, tmp_path: Path, capsys) -> None:
    """Random bytes named .raw used to decode as EVT 2.0 (tens of thousands
    of invented events with --skip-bad, exit 0): no header, no guess."""
    f = tmp_path / "noise.raw"
    f.write_bytes(np.random.default_rng(1).integers(0, 256, 400_000, dtype=np.uint8).tobytes())
    out = tmp_path / "o.npz"
    argv = ["info", str(f)] if verb == "info" else ["convert", "--skip-bad", str(f), str(out)]
    code, err = _cli(argv, capsys)
    assert code != 0 and len(err) == 1 and "format=evt2" in err[0], err
    assert not out.exists() and sorted(p.name for p in tmp_path.iterdir()) == ["noise.raw"]
    with pytest.raises(FormatError, match="no header") as e:
        decode(f, skip_bad=True)
    assert e.value.offset == 0


@pytest.mark.abuse
def test_damaged_evt3_header_is_not_read_as_evt2(tmp_path: Path, small_files) -> None:
    data = small_files["evt3"]
    assert b"% evt 3.0\n" in data and b"% format EVT3\n" in data
    f = tmp_path / "d.raw"
    f.write_bytes(data.replace(b"evt 3.0", b"e\x00t 3.0").replace(b"EVT3", b"E\x00T3"))  # two damaged bytes
    with pytest.raises(FormatError, match="naming no event format"):
        decode(f, skip_bad=True)
    named = open_file(str(f), format="evt3")
    assert same_events(concat([q for q in named.packets() if isinstance(q, EventPacket)]), sample())
    assert open_file(str(f), format="evt3").info()["format"] == "evt3"
    ok = tmp_path / "ok.raw"
    ok.write_bytes(data)
    with pytest.raises(FormatError, match="the format option says evt2"):
        decode(ok, format="evt2")


@pytest.mark.abuse
def test_named_format_reads_words_without_header(tmp_path: Path, small_files, capsys) -> None:
    """``FILE?format=evt2``: the words of a headerless file, read as named."""
    data = small_files["evt2"]
    f = tmp_path / "bare.raw"
    f.write_bytes(data[data.index(b"% end\n") + 6:])
    ev = concat([q for q in open_file(str(f), format="evt2", sensor="64x48").packets()])
    assert same_events(ev, sample())
    code, err = _cli(["info", f"{f}?format=evt2", "--json"], capsys)
    assert code == 0, err
    with pytest.raises(ValueError, match="not a RAW event format"):
        open_file(str(f), format="evt9")


@pytest.mark.abuse
@pytest.mark.parametrize("ext", [".raw", ".evt3.raw", ".dat", ".aedat", ".aedat4", ".npy", ".bag"])
@pytest.mark.parametrize("verb", ["info", "convert"])
def test_empty_file_is_an_error(ext: str, verb: str, tmp_path: Path, capsys) -> None:
    f = tmp_path / ("empty" + ext)
    f.write_bytes(b"")
    out = tmp_path / "o.npz"
    with warnings.catch_warnings(record=True) as caught:  # a file the error left open warns when it is freed
        warnings.simplefilter("always", ResourceWarning)
        code, err = _cli(["info", str(f)] if verb == "info" else ["convert", "--skip-bad", str(f), str(out)], capsys)
        gc.collect()
    assert code != 0 and len(err) == 1 and "error:" in err[0], err
    assert not out.exists() and [p.name for p in tmp_path.iterdir()] == [f.name]
    assert not [str(w.message) for w in caught if issubclass(w.category, ResourceWarning)]


# -- damage with skip_bad, over every binary format (issue 20, items 14-15) -----------------
def _aedat31_bytes(ev: EventPacket, per: int = 100) -> tuple[bytes, int]:
    """libcaer polarity packets (28-byte header, 8-byte events: valid bit,
    polarity bit 1, y bits 2-16, x bits 17-31; int32 µs)."""
    head = b"#!AER-DAT3.1\r\n#Source 1: DAVIS346\r\n#!END-HEADER\r\n"
    out = [head]
    for k in range(0, len(ev), per):
        n = min(per, len(ev) - k)
        out.append(struct.pack("<hhiiiiii", 1, 1, 8, 4, 0, n, n, n))  # polarity, source 1, 8-byte events
        rec = np.empty((n, 2), "<u4")
        rec[:, 0] = 1 | ((ev.p[k:k + n] > 0).astype(np.uint32) << 1) | (ev.y[k:k + n].astype(np.uint32) << 2) | (
            ev.x[k:k + n].astype(np.uint32) << 17)
        rec[:, 1] = ev.t[k:k + n]
        out.append(rec.tobytes())
    return b"".join(out), len(head)


#: format -> (source name, file extension, record size in bytes (0: no fixed records), events a byte can yield)
DAMAGED = {"evt2": ("evt2", ".raw", 0, 1 / 4), "evt3": ("evt3", ".raw", 0, 12 / 2), "dat": ("dat", ".dat", 8, 1 / 8),
           "npy": ("npy", ".npy", 0, 1), "aedat2": ("aedat2", ".aedat", 8, 1 / 8),
           "aedat31": ("aedat31", ".aedat", 8, 1 / 8), "aedat4": ("aedat4", ".aedat4", 0, 1),
           "rosbag": ("rosbag", ".bag", 0, 1 / 13), "es": ("es", ".es", 0, 1 / 5), "nmnist": ("nmnist", ".bin", 0, 1 / 5)}


@pytest.fixture(scope="module")
def damage_files(small_files, tmp_path_factory) -> dict[str, tuple[bytes, int]]:
    """Each format's small file of :func:`sample` and where its records start."""
    ev = sample()
    out = _Files()
    for name in ("evt2", "evt3"):
        out[name] = (small_files[name], small_files[name].index(b"% end\n") + 6)
    out["dat"] = (small_files["dat"], len(small_files["dat"]) - 8 * len(ev))
    itemsize = (len(small_files["npy"]) - 128) // len(ev)
    out["npy"] = (small_files["npy"], len(small_files["npy"]) - itemsize * len(ev))
    out["aedat2"] = (aedat2_dvs128(ev), len(AEDAT2_DVS128_HEADER))
    out["aedat31"] = _aedat31_bytes(ev)
    out["aedat4"] = (small_files["aedat4"], 0)
    out["es"] = (small_files["es"], 20)
    out["nmnist"] = (small_files["nmnist"], 0)
    for name, cls_name, kw in (("aedat2", "aedat2", {"sensor": "128x128"}), ("aedat31", "aedat31", {})):
        f = tmp_path_factory.mktemp("ok") / "ok.aedat"
        f.write_bytes(out[name][0])
        got = concat([q for q in next(c for c in SOURCES if c.name == cls_name)(str(f), **kw).packets()])
        assert same_events(got, ev), name  # the builders write what the readers read
    if importlib.util.find_spec("rosbags") is not None:
        t = ev.t + 1_000_000  # µs since the epoch: 1 s on
        bag_ev = EventPacket(t, ev.x, ev.y, ev.p, sensor=ev.sensor)
        out["rosbag"] = (dvs_bag(tmp_path_factory.mktemp("bag") / "s.bag", bag_ev), 0)
    return out


@pytest.mark.abuse
@pytest.mark.parametrize("fmt", list(DAMAGED))
@settings(max_examples=30, deadline=None, suppress_health_check=[HealthCheck.function_scoped_fixture])
@given(data=st.data())
def test_fuzz_damage_with_skip_bad(fmt: str, data, damage_files, tmp_path_factory) -> None:
    """Cut, overwritten or spliced files read with skip_bad: a FormatError
    naming the file (damage the reader cannot pass) or packets obeying the
    contract (pixels on the sensor, time never decreasing, across packets
    too); never more events than the bytes can hold; and where single
    bytes of fixed-size records were overwritten, every record is either
    kept or counted as skipped."""
    if fmt not in damage_files:
        pytest.skip("rosbags not installed")
    name, ext, size, per_byte = DAMAGED[fmt]
    raw, head = damage_files[fmt]
    out = bytearray(raw)
    op = data.draw(st.sampled_from(["truncate", "flip", "flip-body", "splice"]))
    if op == "truncate":
        out = out[:data.draw(st.integers(0, len(out)))]
    elif op.startswith("flip"):
        lo = head if op == "flip-body" else 0
        for _ in range(data.draw(st.integers(1, 8))):
            out[data.draw(st.integers(lo, len(out) - 1))] = data.draw(st.integers(0, 255))
    else:
        i = data.draw(st.integers(0, len(out)))
        out[i:i] = data.draw(st.binary(max_size=64))
    f = tmp_path_factory.mktemp("dmg") / ("f" + ext)
    f.write_bytes(bytes(out))
    cls = next(c for c in SOURCES if c.name == name)
    kw = {"npy": {"sensor": "64x48"}, "aedat2": {"sensor": "128x128"}, "nmnist": {"sensor": "64x48"}}.get(fmt, {})
    src = cls(str(f), skip_bad=True, chunk_bytes=data.draw(st.sampled_from([64, 1000, 1 << 22])), **kw)
    try:
        pkts = [q for q in src.packets() if isinstance(q, EventPacket)]
    except FormatError as e:
        assert e.path == str(f)
        return
    for q in pkts:
        q.validate()
    t = np.concatenate([q.t for q in pkts]) if pkts else np.empty(0, np.int64)
    assert np.all(np.diff(t) >= 0)
    for a, b in zip(pkts, pkts[1:]):
        assert a.t_end <= b.t_start
    kept = int(t.shape[0])
    assert kept <= len(out) * per_byte + 1
    if op == "flip-body" and fmt in ("dat", "npy"):
        assert kept + src.skipped_events == len(sample()), (kept, src.skipped_events)
