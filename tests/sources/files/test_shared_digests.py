"""Real values of the shared recordings, pinned: a decoder change must keep them.

Per recording in ``../shared/data`` (see its MANIFEST.md), a small digest of
what tectum decodes: event count, ON and OFF counts, the first and last 3
events, the sensor size, a CRC-32 of each column (t, x, y, p), and for every
other stream (IMU, frames, poses, triggers) its count and a CRC-32 of each
column (floats rounded to 6 decimals). The digests live in
``shared_digests.json`` beside this file. Counts alone let a flipped
polarity through (the ON count of a file may change and the total not); the
checksums catch any changed value, the first/last events say where.

After a deliberate decoder change (checked against a peer reader or the
spec), regenerate the digests with

    python tests/sources/files/test_shared_digests.py --update

and review the JSON diff. Tests skip where ``../shared/data`` is absent.
"""

from __future__ import annotations

import json
import sys
import zlib
from pathlib import Path
from typing import Any

import numpy as np
import pytest

DIGESTS = Path(__file__).with_name("shared_digests.json")

#: (recording under ../shared/data, reader options)
RECORDINGS: list[tuple[str, dict[str, Any]]] = [
    ("aedat/davis240_imu_rotdisk.aedat", {}),
    ("aedat/dvs128_short.aedat", {}),
    ("aedat/davis346red_header_only.aedat", {}),
    ("aedat/davis346.aedat4", {}),
    ("aedat/dvxplorer_1.aedat4", {}),
    ("aedat/dvxplorer_2.aedat4", {}),
    ("prophesee/gen31_evt2.raw", {}),
    ("prophesee/imx636_evt3.raw", {}),
    ("prophesee/gen4.dat", {}),
    ("prophesee/ncars_event2d.dat", {}),
    ("ecd/slider_depth/events.txt", {}),
    ("ecd/shapes_rotation/events.txt", {}),
    ("ecd/boxes_rotation/events.txt", {}),
    ("ecd/shapes_translation/events.txt", {}),
    ("ecd/dynamic_translation/events.txt", {}),
    ("ecd/unnamed_excerpt/events.txt", {}),
    ("bags/evt3_eventpacket_ros1.bag", {}),
    ("bags/evt3_eventpacket_ros2_sqlite", {}),
    ("bags/libcaer_rollover_ros2_sqlite", {}),
    ("derived/slider_depth_excerpt_dvs_msgs.bag", {}),
    ("derived/slider_depth_excerpt_dsec_layout_gzip.h5", {}),
    ("derived/imx636_evk4_dsec_layout_blosc_zstd.h5", {}),
    ("derived/DVS128_eDVS_2017-03-21-short_aedat31.aedat", {}),
    ("other/dvs.csv", {"time_unit": "us"}),
]


def _crc(col: np.ndarray) -> str:
    a = np.asarray(col)
    if a.dtype == object:
        return _crc(np.concatenate([np.asarray(v).ravel() for v in a])) if len(a) else "00000000"
    if a.dtype.kind == "f":
        a = np.round(a.astype("<f8"), 6) + 0.0  # + 0.0: -0.0 counts as 0.0
    elif a.dtype.kind in "iub":
        a = a.astype("<i8")
    return f"{zlib.crc32(np.ascontiguousarray(a).tobytes()):08x}"


def digest(path: Path, **kw: Any) -> dict[str, Any]:
    """What tectum decodes from ``path``, in a few numbers (JSON-ready)."""
    from tectum import EventPacket, concat
    from tectum.sources.files import open_file

    src = open_file(str(path), **kw)
    by: dict[str, list[Any]] = {}
    for q in src.packets():
        if len(q):
            by.setdefault(str(q.kind), []).append(q)
    out: dict[str, Any] = {"format": src.format}
    evs = by.pop("events", [])
    ev = concat(evs) if evs else None
    if ev is not None:
        assert isinstance(ev, EventPacket)
        rows = np.stack([ev.t, ev.x, ev.y, ev.p], axis=1).astype(np.int64).tolist()
        out["events"] = {
            "n": len(ev), "on": int(np.count_nonzero(ev.p > 0)), "off": int(np.count_nonzero(ev.p <= 0)),
            "sensor": list(ev.sensor), "first": rows[:3], "last": rows[-3:],
            "crc": {c: _crc(getattr(ev, c)) for c in "txyp"},
        }
    else:
        out["events"] = {"n": 0}
    streams = {}
    for kind, pkts in sorted(by.items()):
        cols = {"t": np.concatenate([q.t for q in pkts])}
        for name in pkts[0].data:
            parts = [q.data[name] for q in pkts]
            if all(isinstance(v, np.ndarray) and v.dtype != object for v in parts) and \
                    len({v.shape[1:] for v in parts}) == 1:
                cols[name] = np.concatenate(parts)
            else:  # ragged (frames of several sizes): item by item
                cols[name] = np.array([np.asarray(v) for part in parts for v in part] + [None], object)[:-1]
        streams[kind] = {"n": int(len(cols["t"])), "crc": {k: _crc(v) for k, v in sorted(cols.items())}}
    out["streams"] = streams
    return out


def stored() -> dict[str, Any]:
    return json.loads(DIGESTS.read_text()) if DIGESTS.exists() else {}


@pytest.mark.parametrize("rel, kw", RECORDINGS, ids=[r for r, _ in RECORDINGS])
def test_decoded_values_match_the_stored_digest(shared: Path, rel: str, kw: dict[str, Any]) -> None:
    want = stored().get(rel)
    assert want is not None, f"no digest for {rel}: python tests/sources/files/test_shared_digests.py --update"
    got = digest(shared / rel, **kw)
    assert got["events"] == want["events"], f"{rel}: events differ from the stored digest"
    assert got == want, f"{rel}: other streams differ from the stored digest"


def test_every_digest_names_a_listed_recording() -> None:
    assert sorted(stored()) == sorted(r for r, _ in RECORDINGS)


def _update() -> None:
    sys.path.insert(0, str(Path(__file__).resolve().parents[2]))  # tests/, for helpers
    from helpers import shared_data

    root = shared_data()
    if root is None:
        raise SystemExit("../shared/data is absent (set TECTUM_SHARED_DATA)")
    out = {rel: digest(root / rel, **kw) for rel, kw in RECORDINGS}
    DIGESTS.write_text(json.dumps(out, indent=1, sort_keys=True) + "\n")
    print(f"wrote {len(out)} digests to {DIGESTS}")


if __name__ == "__main__":
    if sys.argv[1:] != ["--update"]:
        raise SystemExit("usage: python tests/sources/files/test_shared_digests.py --update")
    _update()
