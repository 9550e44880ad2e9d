"""DAVIS: libcaer's full default configuration, read back from the emulated
camera's control-transfer log (values encoded by hand here)."""

from __future__ import annotations

import struct

import pytest

from tectum.sources.usb import _protocol as P
from tectum.sources.usb.emulated import EmulatedCamera

from helpers import run_camera


def written(cam: EmulatedCamera) -> list[tuple[int, int, int]]:
    """(module, parameter, value) of every configuration write, in order."""
    return [(v, i, struct.unpack(">I", d)[0]) for rt, req, v, i, d in cam.control_log
            if rt == 0x40 and req == P.REQ_CONFIG]


def run(cam: EmulatedCamera) -> list[tuple[int, int, int]]:
    run_camera(cam)
    return written(cam)


# coarse/fine: bit 0 enabled, 1 N-type, 2 normal type, 3 normal current, fine << 4, coarse << 12
DAVIS346 = {10: 0x4000 | 39 << 4 | 0xF, 12: 0x4000 | 1 << 4 | 0xF,  # DiffBn 4/39, OffBn 4/1
            14: 0x2000 | 58 << 4 | 0xD,  # PrBp 2/58 (P-type)
            9: 0x7000 | 215 << 4 | 0xE,  # PadFollBn 7/215, disabled
            0: 27 | 6 << 6, 4: 21 | 7 << 6,  # VDACs ApsOverflowLevel 27/6, AdcTestVoltage 21/7
            35: 1 << 4 | 33 << 10, 36: 1 << 4 | 33 << 10,  # shifted sources 1/33
            34: 0x5000 | 254 << 4 | 0xF}  # BiasBuffer 5/254
DAVIS240 = {0: 0x4000 | 39 << 4 | 0xF, 3: 0x5000 | 185 << 4 | 0xB,  # ApsCasEpc: cascode 5/185
            4: 0x5000 | 115 << 4 | 0xB, 14: 0x7000 | 152 << 4 | 0xD, 19: 0x5000 | 254 << 4 | 0xF,
            20: 1 << 4 | 33 << 10}


@pytest.mark.parametrize("model,filters,expect", [("davis346", True, DAVIS346), ("davis240", False, DAVIS240)])
def test_every_bias_and_the_fpga_defaults_are_sent(model: str, filters: bool, expect: dict[int, int]) -> None:
    cam = EmulatedCamera(model, duration_us=5_000, speed=100.0, filters=filters, fx2=not filters)
    log = run(cam)
    biases = {i: v for m, i, v in log if m == P.MOD_BIAS and i < 128}
    family = "DAVIS346" if model == "davis346" else "DAVIS240"
    assert set(biases) == set(P.DAVIS_FULL_BIASES[family])  # all of the family's biases, nothing else
    assert all(biases[k] == v for k, v in expect.items())
    chip = {i: v for m, i, v in log if m == P.MOD_BIAS and i >= 128}
    assert chip[136] == 1 and chip[138] == 1 and chip[143] == 1 and chip[128] == 0
    assert (144 in chip) == (model == "davis346")  # the ADC test flag exists on DAVIS346 only
    # biases before the chip runs
    order = [(m, i) for m, i, _ in log]
    assert max(order.index((P.MOD_BIAS, k)) for k in biases) < order.index((P.MOD_MUX, P.MUX_RUN_CHIP))
    cfg = cam.config
    w, h = cam.sensor
    dvs = {i: v for m, i, v in log if m == P.MOD_DVS}
    if filters:  # the FX3 logic has the filters: libcaer's filter defaults
        assert all(dvs[P.DVS_FILTER_PIXEL_0_ROW + 2 * k] == h and dvs[P.DVS_FILTER_PIXEL_0_ROW + 2 * k + 1] == w
                   for k in range(8))
        assert (dvs[P.DVS_FILTER_BA], dvs[P.DVS_FILTER_BA_TIME]) == (1, 8)
        assert (dvs[P.DVS_FILTER_REFRACTORY], dvs[P.DVS_FILTER_REFRACTORY_TIME]) == (0, 1)
        assert (dvs[P.DVS_ROI_END_COLUMN], dvs[P.DVS_ROI_END_ROW]) == (w - 1, h - 1)
        assert (dvs[P.DVS_SKIP_EVENTS], dvs[P.DVS_SKIP_EVENTS_EVERY], dvs[P.DVS_POLARITY_SUPPRESS]) == (0, 5, 0)
        assert cfg[(P.MOD_EXTINPUT, P.EXTINPUT_GEN_INTERVAL)] == round(10 * 104 * 1.005)
    else:  # features the logic lacks are not written
        assert not {i for i in dvs if i >= 10}
        assert (P.MOD_EXTINPUT, P.EXTINPUT_GEN_INTERVAL) not in cfg
    assert cfg[(P.MOD_MUX, P.MUX_DROP_DVS_STALL)] == 1 and cfg[(P.MOD_DVS, P.DVS_WAIT_ON_STALL)] == 0
    # µs and 125 µs slices become logic / USB clock cycles (nominal x deviation / 1000)
    assert cfg[(P.MOD_EXTINPUT, P.EXTINPUT_PULSE_LENGTH)] == round(10 * 104 * 1.005)
    assert cfg[(P.MOD_USB, P.USB_EARLY_PACKET_DELAY)] == round(8 * 125 * 80 * 1.005)
    assert (cfg[(P.MOD_IMU, P.IMU_ACCEL_FULL_SCALE)], cfg[(P.MOD_IMU, P.IMU_GYRO_FULL_SCALE)]) == (1, 1)
