"""The real recordings decode with the MANIFEST's counts, and agree with
independent readers where those install."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest

from tectum import concat, get_registry
from tectum.sources.files import open_file


def read(path: Path, **kw):  # -> (events, {kind: n}, source)
    src = open_file(str(path), **kw)
    by: dict[str, list] = {}
    for q in src.packets():
        by.setdefault(str(q.kind), []).append(q)
    ev = concat(by["events"]) if by.get("events") else None
    return ev, {k: sum(len(q) for q in v) for k, v in by.items()}, src


@pytest.mark.parametrize("rel, fmt, n, sensor, extra", [
    ("prophesee/gen31_evt2.raw", "evt2", 521_252, (640, 480), {}),
    ("prophesee/imx636_evt3.raw", "evt3", 1_218_618, (1280, 720), {}),
    ("prophesee/gen4.dat", "dat", 1_218_618, (1280, 720), {}),
    ("prophesee/ncars_event2d.dat", "dat", 2_009, None, {}),
    ("aedat/davis240_imu_rotdisk.aedat", "aedat2", 374_296, (240, 180), {"imu": 7_384}),
    ("aedat/dvs128_short.aedat", "aedat2", 130_114, (128, 128), {}),
    ("aedat/davis346.aedat4", "aedat4", 78_830, (346, 260), {"frames": 59, "imu": 2_363}),
    ("aedat/dvxplorer_1.aedat4", "aedat4", 111_954, (320, 240), {"imu": 475}),
    ("aedat/dvxplorer_2.aedat4", "aedat4", 323_963, (320, 240), {"imu": 1_176}),
    ("derived/DVS128_eDVS_2017-03-21-short_aedat31.aedat", "aedat31", 130_114, (128, 128), {}),
    ("derived/slider_depth_excerpt_dsec_layout_gzip.h5", "hdf5", 50_000, None, {}),
    ("derived/imx636_evk4_dsec_layout_blosc_zstd.h5", "hdf5", 1_218_618, None, {}),
    ("ecd/slider_depth/events.txt", "text", 50_000, (240, 180), {"poses": 339, "frames": 87}),
    ("ecd/unnamed_excerpt/events.txt", "text", 34_634, None, {}),
    ("other/dvs.csv", "text", 473_225, None, {}),
])
def test_counts(shared: Path, rel: str, fmt: str, n: int, sensor, extra) -> None:
    kw = {"time_unit": "us"} if rel.endswith(".csv") else {}
    ev, counts, src = read(shared / rel, **kw)
    assert src.format == fmt
    assert len(ev) == n
    if sensor:
        assert ev.sensor == sensor
    for k, v in extra.items():
        assert counts[k] == v
    ev.validate()


def test_header_only_aedat2(shared: Path) -> None:
    ev, counts, _ = read(shared / "aedat/davis346red_header_only.aedat")
    assert ev is None or len(ev) == 0


def test_evt3_and_dat_are_the_same_events_time_shifted(shared: Path) -> None:
    a, _, _ = read(shared / "prophesee/imx636_evt3.raw")
    b, _, _ = read(shared / "prophesee/gen4.dat")
    assert np.array_equal(a.x, b.x) and np.array_equal(a.y, b.y) and np.array_equal(a.p, b.p)
    shift = a.t - b.t
    assert np.all(shift == shift[0])


def test_dsec_offset_applied_and_matches_text(shared: Path) -> None:
    h, _, src = read(shared / "derived/slider_depth_excerpt_dsec_layout_gzip.h5", sensor="240x180")
    assert src.t0_offset == 3811
    txt, _, _ = read(shared / "ecd/slider_depth/events.txt", companions=False)
    for c in "txyp":
        assert np.array_equal(getattr(h, c), getattr(txt, c))


def test_dsec_time_range_seeks(shared: Path) -> None:
    whole, _, _ = read(shared / "derived/slider_depth_excerpt_dsec_layout_gzip.h5")
    part, _, _ = read(shared / "derived/slider_depth_excerpt_dsec_layout_gzip.h5", t_start_us=50_000, t_end_us=90_000)
    ref = whole.slice_time(50_000, 90_000)
    assert np.array_equal(part.t, ref.t) and np.array_equal(part.x, ref.x)


def test_aedat2_dvs128_matches_aedat31_conversion(shared: Path) -> None:
    a, _, _ = read(shared / "aedat/dvs128_short.aedat")
    b, _, _ = read(shared / "derived/DVS128_eDVS_2017-03-21-short_aedat31.aedat")
    for c in "txyp":
        assert np.array_equal(getattr(a, c), getattr(b, c))


def test_aedat4_time_range_uses_packet_table(shared: Path) -> None:
    f = shared / "aedat/davis346.aedat4"
    whole, _, _ = read(f)
    t0, t1 = int(whole.t[10_000]), int(whole.t[20_000])
    part, _, _ = read(f, t_start_us=t0, t_end_us=t1)
    ref = whole.slice_time(t0, t1)
    assert np.array_equal(part.t, ref.t) and np.array_equal(part.y, ref.y)
    info = open_file(str(f)).info()
    assert info["indexed"] and info["events"] == 78_830 and info["streams"]["triggers"] == 236


def test_dat_time_range_bisects(shared: Path) -> None:
    f = shared / "prophesee/ncars_event2d.dat"
    whole, _, _ = read(f)
    part, _, _ = read(f, t_start_us=30_000, t_end_us=60_000)
    ref = whole.slice_time(30_000, 60_000)
    assert np.array_equal(part.t, ref.t) and np.array_equal(part.x, ref.x)


def test_detection_by_content_not_name(shared: Path, tmp_path: Path) -> None:
    src = shared / "ecd/unnamed_excerpt/events.txt"
    renamed = tmp_path / "mystery.bin"
    renamed.write_bytes(src.read_bytes()[:20000])
    assert get_registry().source_for(str(renamed)).name == "text"
    raw = tmp_path / "noext"
    raw.write_bytes((shared / "prophesee/imx636_evt3.raw").read_bytes()[:5000])
    assert get_registry().source_for(str(raw)).name == "evt3"


def test_aedat4_against_dv_processing(shared: Path) -> None:
    dv = pytest.importorskip("dv_processing", reason="dv-processing (peer) not installed")
    f = shared / "aedat/dvxplorer_1.aedat4"
    ours, _, _ = read(f)
    rec = dv.io.MonoCameraRecording(str(f))
    parts = []
    while (b := rec.getNextEventBatch()) is not None:
        parts.append(b.numpy())
    ref = np.concatenate(parts)
    assert np.array_equal(ours.t, ref["timestamp"]) and np.array_equal(ours.x, ref["x"])
    assert np.array_equal(ours.y, ref["y"]) and np.array_equal(ours.p > 0, ref["polarity"] > 0)


def test_aedat4_triggers_are_trigger_packets(shared: Path) -> None:
    from tectum import Kind

    trig = [q for q in open_file(str(shared / "aedat/davis346.aedat4")).packets() if q.kind == Kind.TRIGGERS]
    t = concat(trig)
    assert len(t) == 236 and set(np.unique(t.value)) <= {0, 1}
    assert np.all(np.diff(t.t) >= 0)


def test_aedat2_imu_uses_the_full_scale_in_the_header(shared):
    """The rotdisk header sets ±1000 °/s and ±8 g (not jAER's ±500/±4 defaults):
    at rest along gravity the accelerometer must read about 1 g."""
    from tectum.sources.files import open_file

    src = open_file(str(shared / "aedat" / "davis240_imu_rotdisk.aedat"))
    imu = [p for p in src.packets() if p.kind == "imu"]
    assert (src.gyro_full_scale_dps, src.accel_full_scale_g) == (1000, 8)
    accel = np.concatenate([p.accel for p in imu])
    assert abs(np.median(np.linalg.norm(accel, axis=1)) - 9.81) < 0.5
