"""DVXplorer configuration as libcaer sends it (read, not copied).

The FPGA modules (mux 0, DVS 1, IMU 3, external input 4, system info 6,
USB 9) take 32-bit values through vendor request 0xBF like DAVIS. The
Samsung chip's own 8-bit registers are reached through the same request
with module 5 and the 16-bit register address as ``wIndex``; libcaer's
host-side "modules" (chip, cropper, activity decision, biases) become
writes of those registers, some read-modify-write. This module turns our
defaults into those writes, in libcaer's order.
"""

from __future__ import annotations

from collections.abc import Callable

from . import _protocol as P

__all__ = ["DvxConfig"]

Set = Callable[[int, int, int], None]
Get = Callable[[int, int], int]


class DvxConfig:
    """Writes a DVXplorer's configuration through ``set(module, param,
    value)`` / ``get(module, param)`` (the camera's vendor requests).
    ``size`` is (columns, rows) as delivered (after any x/y swap)."""

    def __init__(self, set_: Set, get: Get, size: tuple[int, int], chip_id: int, flip_x: bool = False,
                 flip_y: bool = False, usb_clock_mhz: float = 0.0, logic_clock_mhz: float = 0.0) -> None:
        self.set, self.get = set_, get
        self.size, self.chip_id, self.flip_x, self.flip_y = size, chip_id, flip_x, flip_y
        self.usb_clock, self.logic_clock = usb_clock_mhz, logic_clock_mhz

    # -- chip registers ------------------------------------------------------
    def reg(self, address: int, value: int) -> None:
        self.set(P.DVX_DEVICE_DVS, address, value & 0xFF)

    def reg16(self, address: int, value: int) -> None:
        """A 16-bit value over two registers, high byte first."""
        self.reg(address, value >> 8)
        self.reg(address + 1, value)

    def reg_bits(self, address: int, mask: int, on: bool) -> None:
        cur = self.get(P.DVX_DEVICE_DVS, address) & 0xFF
        self.reg(address, (cur | mask) if on else (cur & ~mask))

    def _ms_us(self, address: int, us: int) -> None:
        """A time as ms (1 register) then µs within the ms (2 registers)."""
        self.reg(address, us // 1000)
        self.reg16(address + 1, us % 1000)

    def biases_simple_default(self) -> None:
        """libcaer's "default" of its five simple bias presets."""
        self.reg(P.R_BIAS_AMP, 0x04)
        self.reg(P.R_BIAS_RANGE_LOGALOGD_MONITOR, 0x14)
        self.reg(P.R_BIAS_RANGE_LOGSFONREST, 0x06)
        self.reg(P.R_BIAS_LEVEL_SFOFF, 0x7D)
        self.reg(P.R_BIAS_ON, 0x00)
        self.reg(P.R_BIAS_OFF, 0x08)

    # -- phases -------------------------------------------------------------
    def init_chip(self) -> None:
        """At open: the chip out of reset, bias reset and pins, default
        biases, clocks, MGROUP packet format, 1 ms timestamp reference with
        µs sub-units at the 50 MHz system clock, histogram off."""
        self.set(P.MOD_MUX, P.MUX_RUN_CHIP, 1)
        self.reg(P.R_BIAS_OTP_TRIM, 0x24)
        for address, value in ((P.R_BIAS_PINS_DBGP, 0x07), (P.R_BIAS_PINS_DBGN, 0xFF), (P.R_BIAS_PINS_BUFP, 0x03),
                               (P.R_BIAS_PINS_BUFN, 0x7F), (P.R_BIAS_PINS_DOB, 0x00)):
            self.reg(address, value)
        self.biases_simple_default()
        for address, value in ((P.R_CLOCK_DIVIDER_SYS, 0xA0), (P.R_PARALLEL_OUT_CONTROL, 0x00),
                               (P.R_PARALLEL_OUT_ENABLE, 0x01), (P.R_PACKET_FORMAT, 0x80),
                               (P.R_MODE_CONTROL, 0x0C), (P.R_BOOT_SEQUENCE, 0x08)):
            self.reg(address, value)
        self.reg16(P.R_TS_REFUNIT, 999)  # 1000 µs
        clk = P.DVX_SYS_CLK_MHZ
        for address, value in ((P.R_TS_SUBUNIT, clk - 1), (P.R_DTAG_REFERENCE, clk), (P.R_GH_COUNT_FINE, clk),
                               (P.R_GRS_COUNT_FINE, clk), (P.R_GRS_END_FINE, clk), (P.R_SPATIAL_HISTOGRAM_OFF, 1)):
            self.reg(address, value)

    def defaults(self, has_generator: bool) -> None:
        """libcaer's default configuration (sendDefaultConfig)."""
        s = self.set
        s(P.MOD_MUX, P.MUX_TS_RESET, 0)
        s(P.MOD_MUX, P.MUX_DROP_EXT_STALL, 1)
        s(P.MOD_MUX, P.MUX_DROP_DVS_STALL, 0)
        for param, value in P.DVX_IMU_DEFAULTS.items():
            s(P.MOD_IMU, param, value)
        cyc = self.logic_clock
        for param, value in ((P.EXTINPUT_DETECT_RISING, 0), (P.EXTINPUT_DETECT_FALLING, 0),
                             (P.EXTINPUT_DETECT_PULSES, 1), (P.EXTINPUT_PULSE_POLARITY, 1),
                             (P.EXTINPUT_PULSE_LENGTH, round(10 * cyc))):
            s(P.MOD_EXTINPUT, param, value)
        if has_generator:
            for param, value in ((P.EXTINPUT_RUN_GENERATOR, 0), (P.EXTINPUT_GEN_POLARITY, 1),
                                 (P.EXTINPUT_GEN_INTERVAL, round(10 * cyc)), (P.EXTINPUT_GEN_LENGTH, round(5 * cyc)),
                                 (P.EXTINPUT_GEN_ON_RISING, 0), (P.EXTINPUT_GEN_ON_FALLING, 0)):
                s(P.MOD_EXTINPUT, param, value)
        s(P.MOD_USB, P.USB_EARLY_PACKET_DELAY, round(8 * 125 * self.usb_clock))  # 1 ms in USB clock cycles
        self.biases_simple_default()
        self.reg(P.R_EXTERNAL_TRIGGER, 0)  # trigger = timestamp reset
        self.reg_bits(P.R_MODE_CONTROL, 0x01, True)  # global hold
        self.reg_bits(P.R_MODE_CONTROL, 0x02, False)  # global reset
        self.reg(P.R_GLOBAL_RESET_READOUT, 0)
        self.reg(P.R_FIXED_READ_TIME, 0)
        for mask in (0x40, 0x20, 0x10):  # flatten, ON only, OFF only: off
            self.reg_bits(P.R_PACKET_FORMAT, mask, False)
        self.reg_bits(P.R_DIGITAL_ENABLE, 0x04, True)  # subsampling off (bit set = disabled)
        self.reg_bits(P.R_DIGITAL_ENABLE, 0x02, True)  # area blocking off
        if self.chip_id != P.DVX_LITE_CHIP_ID:
            self.reg(P.R_DUAL_BINNING, 0)
        lite = 1 if self.chip_id == P.DVX_LITE_CHIP_ID else 0  # the Lite's ratios: (n << 1) | 1
        cur = self.get(P.DVX_DEVICE_DVS, P.R_SUBSAMPLE_RATIO) & 0xFF
        self.reg(P.R_SUBSAMPLE_RATIO, (cur & ~0x38) | (lite << 3))
        cur = self.get(P.DVX_DEVICE_DVS, P.R_SUBSAMPLE_RATIO) & 0xFF
        self.reg(P.R_SUBSAMPLE_RATIO, (cur & ~0x07) | lite)
        for k in range(20):
            self.reg16(P.R_AREA_BLOCK + 2 * k, 0x7FFF)
        self._ms_us(P.R_GH_COUNT, 2)  # timing: ED
        self._ms_us(P.R_GRS_COUNT, 0)  # GH2GRS
        self._ms_us(P.R_GRS_END, 1)  # GRS
        for address, value in ((P.R_FIRST_SELX_START, 4), (P.R_SELX_WIDTH, 6), (P.R_AY_START, 4), (P.R_AY_END, 6),
                               (P.R_R_START, 8), (P.R_R_END, 10)):
            self.reg(address, value)
        self.reg16(P.R_NEXT_SELX_START, 15)
        self.reg(P.R_MAX_EVENT_NUM, 15 - 5)  # NEXT_SEL - 5, at most 60
        self.reg(P.R_NEXT_GH_CNT, 4)
        self.reg16(P.R_READ_TIME_INTERVAL, 45000)
        self.reg(P.R_CROPPER_BYPASS, 1)
        w, h = self.size
        self.crop_x(0, w - 1)
        self.crop_y(0, h - 1)
        self.reg(P.R_ACTIVITY_BYPASS, 1)
        self.reg16(P.R_ACTIVITY_POS_THRESHOLD, 300)
        self.reg16(P.R_ACTIVITY_NEG_THRESHOLD, 20)
        self.reg(P.R_ACTIVITY_DEC_RATE, 1)
        self.reg(P.R_ACTIVITY_DEC_TIME, 3)
        self.reg16(P.R_ACTIVITY_POS_MAX_COUNT, 300)
        self.reg(P.R_DIGITAL_RESTART, 2)  # DTAG restart after configuration

    def crop_x(self, start: int, end: int) -> None:
        w = self.size[0]
        if self.flip_x:
            start, end = w - 1 - end, w - 1 - start
        self.reg16(P.R_CROPPER_X_START, start)
        self.reg16(P.R_CROPPER_X_END, end)

    def crop_y(self, start: int, end: int) -> None:
        """Rows as start group / mask and end group / mask (8 rows a group;
        when both are in one group only the end mask counts)."""
        h = self.size[1]
        if self.flip_y:
            start, end = h - 1 - end, h - 1 - start
        sg, sm = start // 8, (0xFF << (start % 8)) & 0xFF
        eg, em = end // 8, 0xFF >> (7 - end % 8)
        if sg == eg:
            em, sm = sm & em, 0xFF
        for address, value in ((P.R_CROPPER_Y_START_GROUP, sg), (P.R_CROPPER_Y_START_MASK, sm),
                               (P.R_CROPPER_Y_END_GROUP, eg), (P.R_CROPPER_Y_END_MASK, em)):
            self.reg(address, value)

    def start(self) -> None:
        s = self.set
        s(P.MOD_USB, P.USB_RUN, 1)
        s(P.MOD_MUX, P.MUX_TS_RUN, 1)
        s(P.MOD_MUX, P.MUX_RUN, 1)
        s(P.MOD_DVS, P.DVS_RUN, 1)
        for param in (P.IMU_RUN_ACCEL, P.IMU_RUN_GYRO, P.IMU_RUN_TEMP):
            s(P.MOD_IMU, param, 1)
        s(P.MOD_EXTINPUT, P.EXTINPUT_RUN_DETECTOR, 1)
        self.reg(P.R_TS_RESET, 1)  # the chip's timestamp reset: a pulse
        self.reg(P.R_TS_RESET, 0)
        self.reg(P.R_CONTROL_MODE, P.DVX_MODE_STREAM)

    def stop(self) -> None:
        s = self.set
        self.reg(P.R_CONTROL_MODE, P.DVX_MODE_OFF)
        s(P.MOD_DVS, P.DVS_RUN, 0)
        for param in (P.IMU_RUN_ACCEL, P.IMU_RUN_GYRO, P.IMU_RUN_TEMP):
            s(P.MOD_IMU, param, 0)
        s(P.MOD_EXTINPUT, P.EXTINPUT_RUN_DETECTOR, 0)
        s(P.MOD_MUX, P.MUX_RUN, 0)
        s(P.MOD_MUX, P.MUX_TS_RUN, 0)
        s(P.MOD_USB, P.USB_RUN, 0)
