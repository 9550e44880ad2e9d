"""DVXplorer: the word decoder against a slow reference, and the emulated
camera through pyusb (events, IMU, libcaer's configuration)."""

from __future__ import annotations

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

import tectum
from tectum import Kind
from tectum.sources.usb import _protocol as P
from tectum.sources.usb._device import Camera, find_cameras, list_devices
from tectum.sources.usb._dvx import DvxDecoder
from tectum.sources.usb.emulated import EmulatedBackend, EmulatedCamera
from tectum.sources.usb.source import UsbSource
from tectum.testing import ListSink

from helpers import run_camera


def ref_dvx(words: list[int], w: int, h: int, flips: int = 0) -> tuple[list, list]:
    """libcaer's DVXplorer parse, written plainly: (events, IMU samples)."""
    ev, imu = [], []
    wrap = cur = base = 0
    last = -1
    lx = ly1 = ly2 = 0
    on = False
    cnt = typ = tmp = asc = gsc = 0
    vals: dict[str, float] = {}

    def emit() -> int:
        nonlocal last
        last = max(base + cur, last)
        return last

    for v in words:
        if v & 0x8000:
            cur = wrap + (v & 0x7FFF)
            continue
        code, data = v >> 12 & 7, v & 0xFFF
        if code == 0 and data == 1:
            wrap, cur, base = 0, 0, (last + 1 if last >= 0 else 0)
        elif code == 0 and data == 5:
            on, cnt, typ, vals = True, 0, 0, {}
        elif code == 0 and data == 7 and on:
            if cnt == 14 and gsc <= 4:
                a = 65536 / (4 * 2 ** asc)
                g = 65536 / (250 * 2 ** (4 - gsc))
                imu.append((emit(), *(vals.get(k, 0) / a * 9.80665 for k in ("ax", "ay", "az")),
                            vals.get("t", 0) / 512 + 23, *(vals.get(k, 0) / g * np.pi / 180 for k in ("gx", "gy", "gz"))))
        elif code == 1 and (data & 0x3FF) < w:
            lx = data & 0x3FF
        elif code in (2, 3):
            for b in range(8):
                if data >> b & 1 and (ly1 if code == 3 else ly2) + b < h:
                    ev.append((emit(), lx, (ly1 if code == 3 else ly2) + b, -1 if data & 0x100 else 1))
        elif code == 4:
            g1 = data & 0x3F
            g2 = g1 - (data >> 6 & 0x1F) if data & 0x800 else g1 + (data >> 6 & 0x1F)
            if g1 * 8 < h and 0 <= g2 * 8 < h:
                ly1, ly2 = g1 * 8, g2 * 8
        elif code == 5 and data >> 8 == 0 and on:
            if cnt % 2 == 0:
                tmp = data & 0xFF
            elif cnt <= 13:
                raw = tmp << 8 | data & 0xFF
                raw = raw - 65536 if raw >= 32768 else raw
                name = {1: "ay", 3: "ax", 5: "az", 7: "t", 9: "gy", 11: "gx", 13: "gz"}[cnt]
                bit = {"x": 4, "y": 2, "z": 1}.get(name[-1], 0)
                if name != "t" and flips & bit and raw != -32768:
                    raw = -raw
                vals[name] = raw
                if cnt == 5 and not typ & 1:
                    cnt += 2 if typ & 2 else 8
                elif cnt == 7 and not typ & 2:
                    cnt += 6
            cnt += 1
        elif code == 5 and data >> 8 == 3 and on:
            asc, gsc, typ = data >> 3 & 3, data & 7, data >> 5 & 7
            cnt = 0 if typ & 4 else 6 if typ & 1 else 8 if typ & 2 else 14
        elif code == 7:
            wrap += data << 15
            cur = wrap
    return ev, imu


WORDS = st.lists(st.one_of(
    st.integers(0, 0xFFFF),
    st.sampled_from([0x0001, 0x0005, 0x0007, 0x7001, 0x8000, 0x5300 | 0xE0 | 0x0A, 0x5300 | 0x80, 0x5300 | 0x47]),
    st.integers(0x1000, 0x1000 | 0x3FF), st.integers(0x2000, 0x3FFF), st.integers(0x4000, 0x4FFF),
    st.integers(0x5000, 0x50FF)), max_size=400)


@settings(max_examples=30, deadline=None)
@given(WORDS, st.integers(1, 41), st.integers(0, 7))
def test_decoder_matches_reference_in_any_chunking(words: list[int], step: int, flips: int) -> None:
    raw = np.array(words, "<u2").tobytes()
    dec = DvxDecoder((320, 240), imu_flips=flips)
    ev, imu = [], []
    for i in range(0, len(raw), step):
        d = dec.feed(raw[i:i + step])
        ev += list(zip(d.t.tolist(), d.x.tolist(), d.y.tolist(), d.p.tolist()))
        imu += [(t, *row) for t, row in zip(d.imu_t.tolist(), d.imu.tolist())]
    want_ev, want_imu = ref_dvx(words, 320, 240, flips)
    assert ev == want_ev
    assert len(imu) == len(want_imu)
    if imu:
        np.testing.assert_allclose(np.array(imu), np.array(want_imu), rtol=1e-12, atol=1e-12)


def test_group_words_by_hand() -> None:
    words = [0x8000 | 7, 0x1000 | 0x800 | 12,  # t=7, first column of a readout: x=12
             0x4000 | 2 | (3 << 6) | 0x800,        # group 1 = rows 16.., group 2 = 2-3 = rows -8: bad, kept 0/0
             0x4000 | 5 | (2 << 6),                # group 1 = rows 40.., group 2 = 7 -> rows 56..
             0x3000 | 0b1000_0001,                 # ON at y=40 and y=47
             0x2000 | 0x100 | 0b10,                # OFF at y=57
             0x7002, 0x8000 | 1, 0x1000 | 700,     # two wraps; a column past 640: bad
             0x3000 | 0b100]                       # ON at (12, 42), t = 65537
    d = DvxDecoder((640, 480)).feed(np.array(words, "<u2").tobytes())
    assert list(zip(d.t.tolist(), d.x.tolist(), d.y.tolist(), d.p.tolist())) == [
        (7, 12, 40, 1), (7, 12, 47, 1), (7, 12, 57, -1), (65537, 12, 42, 1)]
    assert d.t.dtype == np.int64 and d.x.dtype == np.uint16
    c = DvxDecoder((640, 480))
    c.feed(np.array(words, "<u2").tobytes())
    assert c.counts["bad_address"] == 2 and c.counts["readouts"] == 1 and c.counts["wraps"] == 1


def test_imu_sample_axes_swapped_scaled_and_flipped() -> None:
    # ±8 g (range 2: 4096 LSB/g), ±250 °/s (range 3: 131.072 LSB per °/s), all three sensors
    vals = [4096, -8192, 2048, 512, 1311, -1311, 0]  # sent: accel Y, X, Z, temperature, gyro Y, X, Z
    words = [0x8000 | 50, 0x0005, 0x5300 | (0b111 << 5) | (2 << 3) | 3]
    for v in vals:
        v &= 0xFFFF
        words += [0x5000 | v >> 8, 0x5000 | v & 0xFF]
    words.append(0x0007)
    d = DvxDecoder((640, 480), imu_flips=0b001).feed(np.array(words, "<u2").tobytes())
    assert d.imu_t.tolist() == [50]
    g = 9.80665
    np.testing.assert_allclose(d.imu[0, :3], [-2 * g, g, -0.5 * g], rtol=1e-12)  # z flipped
    np.testing.assert_allclose(d.imu[0, 3], 24.0)
    np.testing.assert_allclose(np.degrees(d.imu[0, 4:]), [-10.0, 10.0, 0.0], rtol=1e-3, atol=1e-9)


RESET = 35_000  # past one timestamp wrap (2^15 µs)


def run(cam: EmulatedCamera, **kw) -> tuple[UsbSource, ListSink]:
    src, (sink,) = run_camera(cam, "usb:dvxplorer", **kw)
    return src, sink


@pytest.mark.parametrize("model,duration,speed", [("dvxplorer_lite", 70_000, 60.0), ("dvxplorer", 50_000, 40.0)])
def test_stream_equals_what_the_camera_sent(model: str, duration: int, speed: float) -> None:
    cam = EmulatedCamera(model, duration_us=duration, speed=speed, noise_hz=2.0, reset_at_us=RESET,
                         overrun_reads=(2, 4), max_transfer=1001, imu_flips=0b110)
    src, sink = run(cam)
    ev = sink.events()
    tt, tx, ty, tp = cam.truth.events()
    assert len(ev) == len(tt) > 5000 and ev.sensor == cam.sensor
    assert np.array_equal(ev.x, tx) and np.array_equal(ev.y, ty) and np.array_equal(ev.p, tp)
    pre = tt < RESET
    assert np.array_equal(ev.t[pre], tt[pre])  # device time, wraps included
    after = ev.t[~pre]
    assert after[0] == ev.t[pre][-1] + 1 + (tt[~pre][0] - RESET)  # a reset goes on just past the last time
    assert np.array_equal(after - after[0], tt[~pre] - tt[~pre][0])
    imu = tectum.concat([q for q in sink.packets if q.kind == Kind.IMU])
    assert len(imu) == len(cam.truth.imu_t) > 40
    np.testing.assert_allclose(imu.accel, np.array(cam.truth.accel), rtol=1e-9, atol=1e-9)
    np.testing.assert_allclose(imu.gyro, np.array(cam.truth.gyro), rtol=1e-9, atol=1e-9)
    c = src.decoder.counts
    assert c["resets"] == 1 and c["wraps"] >= 1 and c["bad_address"] == 0 and c["imu_incomplete"] == 0
    assert src.counts["overruns"] == 2


def regs_after(cam: EmulatedCamera, start: int) -> dict[int, int]:
    return dict(cam.register_log[start:])


def test_libcaer_configuration_reaches_the_chip() -> None:
    cam = EmulatedCamera("dvxplorer_lite", duration_us=10_000, speed=40.0)
    run(cam)
    log = cam.register_log
    w, h = cam.sensor
    # at open: bias reset, bias pins, the "default" simple biases, MGROUP packets, 1 ms reference
    assert log[0] == (P.R_BIAS_OTP_TRIM, 0x24)
    assert (P.R_PACKET_FORMAT, 0x80) in log and (P.R_TS_REFUNIT, 0x03) in log and (P.R_TS_REFUNIT + 1, 0xE7) in log
    reg = {a: v for (m, a), v in cam.config.items() if m == P.DVX_DEVICE_DVS}
    assert [reg[a] for a in (P.R_BIAS_AMP, P.R_BIAS_RANGE_LOGALOGD_MONITOR, P.R_BIAS_RANGE_LOGSFONREST,
                             P.R_BIAS_LEVEL_SFOFF, P.R_BIAS_ON, P.R_BIAS_OFF)] == [4, 0x14, 6, 0x7D, 0, 8]
    # defaults: read-modify-write bits, subsampling ratio of the Lite, area blocking, timing, cropper
    assert reg[P.R_MODE_CONTROL] == 0x0D  # R/AY signals + global hold, no global reset
    assert reg[P.R_PACKET_FORMAT] == 0x80 and reg[P.R_DIGITAL_ENABLE] == 0x06
    assert reg[P.R_SUBSAMPLE_RATIO] == 0x09  # Lite: "none" is (0 << 1) | 1 in both directions
    assert all(reg[P.R_AREA_BLOCK + k] == (0x7F if k % 2 == 0 else 0xFF) for k in range(40))
    assert (reg[P.R_GH_COUNT], reg[P.R_GH_COUNT + 2], reg[P.R_GRS_END + 2]) == (0, 2, 1)
    assert (reg[P.R_READ_TIME_INTERVAL] << 8 | reg[P.R_READ_TIME_INTERVAL + 1]) == 45000
    assert (reg[P.R_NEXT_SELX_START + 1], reg[P.R_MAX_EVENT_NUM]) == (15, 10)
    assert (reg[P.R_CROPPER_X_END] << 8 | reg[P.R_CROPPER_X_END + 1]) == w - 1
    assert (reg[P.R_CROPPER_Y_END_GROUP], reg[P.R_CROPPER_Y_END_MASK]) == ((h - 1) // 8, 0xFF)
    assert (reg[P.R_ACTIVITY_POS_THRESHOLD + 1], reg[P.R_ACTIVITY_DEC_TIME], reg[P.R_DIGITAL_RESTART]) == (44, 3, 2)
    # FPGA modules: IMU (800 Hz, ±4 g, ±500 °/s), µs and 125 µs slices in clock cycles
    assert all(cam.config[(P.MOD_IMU, k)] == v for k, v in P.DVX_IMU_DEFAULTS.items())
    assert cam.config[(P.MOD_USB, P.USB_EARLY_PACKET_DELAY)] == 8 * 125 * 80
    assert cam.config[(P.MOD_EXTINPUT, P.EXTINPUT_PULSE_LENGTH)] == 10 * 104
    assert cam.config[(P.MOD_EXTINPUT, P.EXTINPUT_GEN_LENGTH)] == 5 * 104
    # start: timestamp-reset pulse, then stream mode; stop: mode off, FPGA stopped
    i = log.index((P.R_TS_RESET, 1))
    assert log[i + 1:i + 3] == [(P.R_TS_RESET, 0), (P.R_CONTROL_MODE, P.DVX_MODE_STREAM)]
    assert log[-1] == (P.R_CONTROL_MODE, P.DVX_MODE_OFF) and cam.config[(P.MOD_USB, P.USB_RUN)] == 0


def test_full_size_model_crops_and_keeps_ratio() -> None:
    cam = EmulatedCamera("dvxplorer", duration_us=5_000, speed=20.0)
    run(cam)
    reg = {a: v for (m, a), v in cam.config.items() if m == P.DVX_DEVICE_DVS}
    assert reg[P.R_SUBSAMPLE_RATIO] == 0 and reg[P.R_DUAL_BINNING] == 0
    assert (reg[P.R_CROPPER_X_END] << 8 | reg[P.R_CROPPER_X_END + 1]) == 639


def test_mini_is_refused_with_the_reason_and_listed() -> None:
    cam = EmulatedCamera("dvxplorer", mipi=True)
    with pytest.raises(tectum.NodeError, match="MIPI"):
        run(cam)
    found = list_devices(EmulatedBackend(EmulatedCamera("dvxplorer_lite", serial="L1"), cam))
    assert (found[0].model, found[0].chip, found[0].sensor, found[0].firmware) == ("DVXplorer", "DVXplorer Lite",
                                                                                   (320, 240), 8)
    assert "MIPI" in found[1].error


def test_wrong_chip_stream_mode_means_no_data() -> None:
    """The emulated chip streams only in stream mode: our start sequence set it."""
    cam = EmulatedCamera("dvxplorer_lite", duration_us=5_000, speed=20.0)
    be = EmulatedBackend(cam)
    c = Camera(find_cameras(be)[0])
    c.open()
    c.send_defaults()
    c.dvx.set(P.MOD_USB, P.USB_RUN, 1)  # FPGA running, chip still off
    c.dvx.set(P.MOD_MUX, P.MUX_RUN, 1)
    c.dvx.set(P.MOD_DVS, P.DVS_RUN, 1)
    assert c.read(4096, 5) == b"" and not cam.streaming
    c.start()
    assert len(c.read(4096, 5)) > 0
    c.close()
