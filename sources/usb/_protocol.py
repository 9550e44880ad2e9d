"""USB identities and vendor requests of iniVation cameras.

Numbers as libcaer's public source uses them (read, not copied): vendor id
0x152A; the DVS128 takes 4-byte address/timestamp words on endpoint 0x86
and its biases as one 36-byte vendor request; DAVIS boards (FX2 and FX3
USB chips) send 16-bit words on endpoint 0x82 and are configured through
an SPI-like request ``0xBF`` (``wValue`` = module, ``wIndex`` = parameter,
4 data bytes big-endian).
"""

from __future__ import annotations

from dataclasses import dataclass

VID = 0x152A

# DVS128
DVS128_PID = 0x8400
DVS128_ENDPOINT = 0x86
DVS128_SIZE = (128, 128)
DVS128_REQ_START = 0xB3
DVS128_REQ_STOP = 0xB4
DVS128_REQ_BIASES = 0xB8
DVS128_REQ_RESET_TS = 0xBB
#: The 12 biases (24-bit, big-endian, 3 bytes each) in the order the device
#: takes them: cas, injGnd, reqPd, puX, diffOff, req, refr, puY, diffOn,
#: diff, foll, Pr ("fast" defaults).
DVS128_DEFAULT_BIASES = (1992, 1108364, 16777215, 8159221, 132, 309590, 969, 16777215, 209996, 13125, 271, 217)

# DAVIS
DAVIS_FX2_PID = 0x841B
DAVIS_FX3_PID = 0x841A
DAVIS_ENDPOINT = 0x82
REQ_CONFIG = 0xBF

MOD_MUX, MOD_DVS, MOD_APS, MOD_IMU, MOD_EXTINPUT, MOD_BIAS, MOD_SYSINFO, MOD_USB = 0, 1, 2, 3, 4, 5, 6, 9
MUX_RUN, MUX_TS_RUN, MUX_TS_RESET, MUX_RUN_CHIP, MUX_DROP_EXT_STALL, MUX_DROP_DVS_STALL = 0, 1, 2, 3, 4, 5
DVS_SIZE_COLUMNS, DVS_SIZE_ROWS, DVS_ORIENTATION, DVS_RUN, DVS_WAIT_ON_STALL = 0, 1, 2, 3, 4
(APS_SIZE_COLUMNS, APS_SIZE_ROWS, APS_ORIENTATION, APS_COLOR_FILTER, APS_RUN, APS_WAIT_ON_STALL,
 APS_HAS_GLOBAL_SHUTTER, APS_GLOBAL_SHUTTER, APS_START_COLUMN, APS_START_ROW, APS_END_COLUMN, APS_END_ROW,
 APS_EXPOSURE, APS_FRAME_INTERVAL) = range(14)
IMU_TYPE, IMU_RUN_ACCEL, IMU_RUN_GYRO, IMU_RUN_TEMP = 0, 2, 3, 4
IMU_SAMPLE_RATE_DIVIDER, IMU_ACCEL_DLPF, IMU_ACCEL_FULL_SCALE, IMU_GYRO_DLPF, IMU_GYRO_FULL_SCALE = 5, 6, 7, 9, 10
EXTINPUT_RUN_DETECTOR = 0
SYSINFO_LOGIC_VERSION, SYSINFO_CHIP_ID, SYSINFO_IS_MASTER, SYSINFO_LOGIC_PATCH = 0, 1, 2, 7
SYSINFO_LOGIC_CLOCK, SYSINFO_ADC_CLOCK = 3, 4
#: libcaer's APS defaults: exposure and frame interval in µs (sent in ADC clock cycles)
APS_DEFAULT_EXPOSURE_US, APS_DEFAULT_INTERVAL_US = 4000, 40000
USB_RUN, USB_EARLY_PACKET_DELAY = 0, 1

CHIP_DAVIS240C, CHIP_DAVIS346B = 2, 5
CHIP_NAMES = {0: "DAVIS240A", 1: "DAVIS240B", 2: "DAVIS240C", 3: "DAVIS128", 5: "DAVIS346B",
              6: "DAVIS640", 7: "DAVIS640H", 8: "DAVIS208", 9: "DAVIS346Cbsi"}


def coarse_fine(coarse: int, fine: int, *, n_type: bool) -> int:
    """A coarse/fine bias word: enabled, sex (N/P), normal type, normal
    current level, fine (0..255) in bits 4-11, coarse (0..7) in bits 12-14."""
    v = 0x01 | (0x02 if n_type else 0) | 0x04 | 0x08
    return v | ((fine & 0xFF) << 4) | ((coarse & 0x07) << 12)


#: Main DVS biases (module 5) per chip: parameter address -> value, as
#: libcaer's defaults (DiffBn, OnBn, OffBn, PrBp, PrSfBp, RefrBp).
DAVIS_DEFAULT_BIASES = {
    "DAVIS240": {0: coarse_fine(4, 39, n_type=True), 1: coarse_fine(5, 255, n_type=True),
                 2: coarse_fine(4, 0, n_type=True), 8: coarse_fine(2, 58, n_type=False),
                 9: coarse_fine(1, 16, n_type=False), 10: coarse_fine(4, 25, n_type=False)},
    "DAVIS346": {10: coarse_fine(4, 39, n_type=True), 11: coarse_fine(5, 255, n_type=True),
                 12: coarse_fine(4, 1, n_type=True), 14: coarse_fine(2, 58, n_type=False),
                 15: coarse_fine(1, 16, n_type=False), 16: coarse_fine(4, 25, n_type=False)},
}


@dataclass(frozen=True)
class Model:
    """A camera family: its product id, data endpoint and protocol."""

    name: str
    pid: int
    endpoint: int
    protocol: str  # "dvs128" or "davis"


MODELS = {
    DVS128_PID: Model("DVS128", DVS128_PID, DVS128_ENDPOINT, "dvs128"),
    DAVIS_FX2_PID: Model("DAVIS FX2", DAVIS_FX2_PID, DAVIS_ENDPOINT, "davis"),
    DAVIS_FX3_PID: Model("DAVIS FX3", DAVIS_FX3_PID, DAVIS_ENDPOINT, "davis"),
}
