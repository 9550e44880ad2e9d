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

# -- DAVIS: libcaer's full default configuration ---------------------------
def vdac(voltage: int, current: int) -> int:
    """A VDAC bias word: voltage (0..63) in bits 0-5, current (0..7) in bits 6-8."""
    return (voltage & 0x3F) | ((current & 0x07) << 6)


def shifted_source(ref: int, reg: int, *, tied_to_rail: bool = False) -> int:
    """A shifted-source bias word (split-gate level): operating mode in bits
    0-1 (0 shifted source, 2 tied to rail), ref in bits 4-9, reg in 10-15."""
    return (0x02 if tied_to_rail else 0) | ((ref & 0x3F) << 4) | ((reg & 0x3F) << 10)


def cascode(coarse: int, fine: int) -> int:
    """An N-type cascode coarse/fine bias (as :func:`coarse_fine` without
    the "normal type" bit)."""
    return coarse_fine(coarse, fine, n_type=True) & ~0x04


def _off(v: int) -> int:
    return v & ~0x01


_N, _P = (lambda c, f: coarse_fine(c, f, n_type=True)), (lambda c, f: coarse_fine(c, f, n_type=False))

#: Every bias (module 5) libcaer sends by default, per chip family:
#: parameter address -> 16-bit value.
DAVIS_FULL_BIASES = {
    "DAVIS240": {0: _N(4, 39), 1: _N(5, 255), 2: _N(4, 0), 3: cascode(5, 185), 4: cascode(5, 115), 5: _N(6, 219),
                 6: _N(5, 164), 7: _N(6, 144), 8: _P(2, 58), 9: _P(1, 16), 10: _P(4, 25), 11: _N(6, 91),
                 12: _N(5, 49), 13: _P(4, 80), 14: _P(7, 152), 15: _N(5, 255), 16: _N(5, 255), 17: _N(7, 215),
                 18: _N(6, 253), 19: _N(5, 254), 20: shifted_source(1, 33), 21: shifted_source(1, 33)},
    "DAVIS346": {0: vdac(27, 6), 1: vdac(21, 6), 2: vdac(32, 7), 3: vdac(1, 7), 4: vdac(21, 7),
                 8: _N(5, 164), 9: _off(_N(7, 215)), 10: _N(4, 39), 11: _N(5, 255), 12: _N(4, 1), 13: _N(6, 144),
                 14: _P(2, 58), 15: _P(1, 16), 16: _P(4, 25), 17: _P(6, 20), 18: _N(6, 219), 19: _P(5, 20),
                 20: _N(0, 1), 21: _P(6, 60), 22: _N(5, 49), 23: _N(6, 91), 24: _P(4, 80), 25: _P(7, 152),
                 26: _N(5, 255), 27: _N(5, 255), 34: _N(5, 254), 35: shifted_source(1, 33),
                 36: shifted_source(1, 33)},
}
#: Chip shift-register defaults (module 5, addresses 128..): muxes 0,
#: ResetCalibNeuron, ResetTestPixel, SelectGrayCounter on; the rest off.
DAVIS_CHIP_DEFAULTS = {128: 0, 129: 0, 130: 0, 131: 0, 132: 0, 133: 0, 134: 0, 135: 0, 136: 1, 137: 0, 138: 1,
                       140: 0, 141: 0, 139: 0, 143: 1, 144: 0}
DVS_EXTERNAL_AER_CONTROL = 5
DVS_HAS_PIXEL_FILTER, DVS_FILTER_PIXEL_0_ROW = 10, 11
DVS_HAS_BA_FILTER, DVS_FILTER_BA, DVS_FILTER_BA_TIME = 30, 31, 32
DVS_FILTER_REFRACTORY, DVS_FILTER_REFRACTORY_TIME = 33, 34
DVS_HAS_ROI_FILTER, DVS_ROI_START_COLUMN, DVS_ROI_START_ROW, DVS_ROI_END_COLUMN, DVS_ROI_END_ROW = 40, 41, 42, 43, 44
DVS_HAS_SKIP_FILTER, DVS_SKIP_EVENTS, DVS_SKIP_EVENTS_EVERY = 50, 51, 52
DVS_HAS_POLARITY_FILTER, DVS_POLARITY_FLATTEN, DVS_POLARITY_SUPPRESS, DVS_POLARITY_SUPPRESS_TYPE = 60, 61, 62, 63
(EXTINPUT_DETECT_RISING, EXTINPUT_DETECT_FALLING, EXTINPUT_DETECT_PULSES, EXTINPUT_PULSE_POLARITY,
 EXTINPUT_PULSE_LENGTH) = 1, 2, 3, 4, 5
(EXTINPUT_HAS_GENERATOR, EXTINPUT_RUN_GENERATOR, EXTINPUT_GEN_POLARITY, EXTINPUT_GEN_INTERVAL, EXTINPUT_GEN_LENGTH,
 EXTINPUT_GEN_ON_RISING, EXTINPUT_GEN_ON_FALLING) = 10, 11, 12, 13, 14, 15, 16
SYSINFO_USB_CLOCK, SYSINFO_CLOCK_DEVIATION = 5, 6

# -- DVXplorer (Samsung DVS chip behind an FX3 + FPGA) -----------------------
DVX_PID = 0x8419
DVX_CHIP_ID, DVX_LITE_CHIP_ID = 20, 19
DVX_REQUIRED_LOGIC = (18, 2)  # logic version, patch level
DVX_DEVICE_MIPI = 4  # bcdDevice high byte of the MIPI CX3 variant (DVXplorer Mini)
DVX_DEVICE_DVS = 5  # module of the chip's own registers (wIndex = 16-bit register address)
DVX_SYS_CLK_MHZ = 50
DVX_IMU_ORIENTATION = 1
(DVX_IMU_ACCEL_RATE, DVX_IMU_ACCEL_FILTER, DVX_IMU_ACCEL_RANGE, DVX_IMU_GYRO_RATE, DVX_IMU_GYRO_FILTER,
 DVX_IMU_GYRO_RANGE) = 5, 6, 7, 8, 9, 10
#: Bosch BMI160 settings libcaer picks: 800 Hz, normal filter, ±4 g, ±500 °/s
DVX_IMU_DEFAULTS = {DVX_IMU_ACCEL_RATE: 6, DVX_IMU_ACCEL_FILTER: 2, DVX_IMU_ACCEL_RANGE: 1, DVX_IMU_GYRO_RATE: 5,
                    DVX_IMU_GYRO_FILTER: 2, DVX_IMU_GYRO_RANGE: 2}
# chip registers (all 8-bit)
R_BIAS_RANGE_LOGSFONREST, R_BIAS_RANGE_LOGALOGD_MONITOR, R_BIAS_OTP_TRIM = 0x000B, 0x000C, 0x000D
R_BIAS_PINS_DBGP, R_BIAS_PINS_DBGN, R_BIAS_LEVEL_SFOFF, R_BIAS_PINS_BUFP = 0x000F, 0x0010, 0x0012, 0x0013
R_BIAS_PINS_BUFN, R_BIAS_PINS_DOB, R_BIAS_AMP, R_BIAS_ON, R_BIAS_OFF = 0x0014, 0x0015, 0x0018, 0x001C, 0x001E
R_CONTROL_MODE, R_CLOCK_DIVIDER_SYS, R_PARALLEL_OUT_CONTROL, R_PARALLEL_OUT_ENABLE = 0x3000, 0x3011, 0x3019, 0x301E
R_PACKET_FORMAT = 0x3067
R_DIGITAL_ENABLE, R_DIGITAL_RESTART, R_DUAL_BINNING, R_SUBSAMPLE_RATIO, R_AREA_BLOCK = (
    0x3200, 0x3201, 0x3202, 0x3204, 0x3205)
R_TS_SUBUNIT, R_TS_REFUNIT, R_TS_RESET, R_DTAG_REFERENCE = 0x3234, 0x3235, 0x3238, 0x323D
R_FIRST_SELX_START, R_GH_COUNT, R_GH_COUNT_FINE, R_GRS_COUNT, R_GRS_COUNT_FINE = 0x323C, 0x3240, 0x3243, 0x3244, 0x3247
R_GLOBAL_RESET_READOUT, R_NEXT_GH_CNT, R_SELX_WIDTH, R_AY_START, R_AY_END = 0x3248, 0x324B, 0x324C, 0x324E, 0x324F
R_MAX_EVENT_NUM, R_R_START, R_R_END, R_MODE_CONTROL, R_GRS_END, R_GRS_END_FINE = (
    0x3251, 0x3253, 0x3254, 0x3255, 0x3256, 0x3259)
R_FIXED_READ_TIME, R_READ_TIME_INTERVAL, R_EXTERNAL_TRIGGER, R_NEXT_SELX_START, R_BOOT_SEQUENCE = (
    0x325C, 0x325D, 0x3260, 0x3261, 0x3266)
R_CROPPER_BYPASS, R_CROPPER_Y_START_GROUP, R_CROPPER_Y_START_MASK = 0x3300, 0x3301, 0x3302
R_CROPPER_Y_END_GROUP = 0x3303
R_CROPPER_Y_END_MASK, R_CROPPER_X_START, R_CROPPER_X_END = 0x3304, 0x3305, 0x3307
R_ACTIVITY_BYPASS, R_ACTIVITY_POS_THRESHOLD, R_ACTIVITY_NEG_THRESHOLD = 0x3500, 0x3501, 0x3503
R_ACTIVITY_DEC_RATE, R_ACTIVITY_DEC_TIME, R_ACTIVITY_POS_MAX_COUNT = 0x3505, 0x3506, 0x3513
R_SPATIAL_HISTOGRAM_OFF = 0x3600
DVX_MODE_OFF, DVX_MODE_STREAM = 0, 2

MODELS[DVX_PID] = Model("DVXplorer", DVX_PID, DAVIS_ENDPOINT, "dvxplorer")
