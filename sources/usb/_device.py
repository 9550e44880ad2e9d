"""Finding, opening and driving iniVation cameras through pyusb."""

from __future__ import annotations

import errno
import struct
from dataclasses import asdict, dataclass
from typing import Any

import usb.core
import usb.util

from tectum.errors import TectumError

from . import _protocol as P
from ._decode import DavisDecoder, Dvs128Decoder
from ._dvx import DvxDecoder
from ._dvx_config import DvxConfig

__all__ = ["DeviceInfo", "Camera", "find_cameras", "default_backend", "DeviceDisconnected", "UsbUnavailable"]


class DeviceDisconnected(TectumError):
    """The camera left the bus (unplugged, or reset) while streaming."""


class UsbUnavailable(TectumError):
    """No USB access: libusb is missing, or no matching camera is attached."""


@dataclass(frozen=True)
class DeviceInfo:
    """An attached camera as ``tectum devices`` lists it."""

    model: str
    vid: int
    pid: int
    bus: int | None
    address: int | None
    serial: str
    firmware: int
    chip: str = ""
    sensor: tuple[int, int] | None = None
    logic_version: int | None = None
    error: str = ""

    def as_dict(self) -> dict[str, Any]:
        d = asdict(self)
        d["vid"], d["pid"] = f"{self.vid:04x}", f"{self.pid:04x}"
        return d


def default_backend() -> tuple[Any, str]:
    """pyusb's libusb-1.0 backend, found on the system or in the
    ``libusb-package`` wheel; ``(None, reason)`` when neither is there."""
    import usb.backend.libusb1 as libusb1

    try:
        be = libusb1.get_backend()
    except Exception as e:  # a broken library
        be, why = None, str(e)
    else:
        why = "libusb-1.0 was not found on the system"
    if be is None:
        try:
            import libusb_package

            be = libusb1.get_backend(find_library=libusb_package.find_library)
        except ImportError:
            why += " and the libusb-package wheel is not installed (pip install libusb-package)"
        except Exception as e:
            why += f"; libusb-package failed: {e}"
    return be, ("" if be is not None else why)


def find_cameras(backend: Any) -> list[usb.core.Device]:
    """Every attached iniVation camera of a known model."""
    found = usb.core.find(find_all=True, backend=backend, idVendor=P.VID,
                          custom_match=lambda d: d.idProduct in P.MODELS)
    return list(found or [])


def is_disconnect(e: usb.core.USBError) -> bool:
    return e.errno in (errno.ENODEV, errno.ENOENT, errno.ESHUTDOWN) or getattr(e, "backend_error_code", 0) == -4


class Camera:
    """One opened camera: configuration, start/stop and bulk reads.

    Not thread-safe: the source calls :meth:`read` from one worker thread at
    a time (through ``trio.to_thread``), everything else from the trio thread
    while no read runs.
    """

    def __init__(self, dev: usb.core.Device) -> None:
        self.dev = dev
        self.model = P.MODELS[dev.idProduct]
        self.serial = ""
        self.chip = ""
        self.sensor: tuple[int, int] = P.DVS128_SIZE
        self.invert_xy = False
        self.logic_version: int | None = None
        self.aps_size: tuple[int, int] | None = None
        self.aps_orientation = 0
        self.adc_clock_mhz = 0
        self.logic_clock_mhz = 0.0  # actual clocks (nominal x deviation / 1000)
        self.usb_clock_mhz = 0.0
        self.has: dict[str, bool] = {}  # optional FPGA features the device reports
        self.imu_flips = 0
        self.dvx: DvxConfig | None = None
        self._claimed = False

    # -- set-up -------------------------------------------------------------
    def open(self) -> None:
        dev = self.dev
        dev.set_configuration()
        usb.util.claim_interface(dev, 0)
        self._claimed = True
        try:
            self.serial = dev.serial_number or ""
        except (usb.core.USBError, ValueError):
            self.serial = ""
        if self.model.protocol == "davis":
            self.logic_version = self.config_get(P.MOD_SYSINFO, P.SYSINFO_LOGIC_VERSION)
            chip = self.config_get(P.MOD_SYSINFO, P.SYSINFO_CHIP_ID)
            self.chip = P.CHIP_NAMES.get(chip, f"chip {chip}")
            cols = self.config_get(P.MOD_DVS, P.DVS_SIZE_COLUMNS)
            rows = self.config_get(P.MOD_DVS, P.DVS_SIZE_ROWS)
            self.invert_xy = bool(self.config_get(P.MOD_DVS, P.DVS_ORIENTATION) & 0x04)
            if not (0 < cols <= 4096 and 0 < rows <= 4096):
                raise TectumError(f"{self.model.name}: the device reports a sensor of {cols}x{rows}")
            self.sensor = (rows, cols) if self.invert_xy else (cols, rows)
            acols = self.config_get(P.MOD_APS, P.APS_SIZE_COLUMNS)
            arows = self.config_get(P.MOD_APS, P.APS_SIZE_ROWS)
            self.aps_orientation = self.config_get(P.MOD_APS, P.APS_ORIENTATION) & 7
            if 0 < acols <= 4096 and 0 < arows <= 4096:
                self.aps_size = (arows, acols) if self.aps_orientation & 4 else (acols, arows)
            self.adc_clock_mhz = self.config_get(P.MOD_SYSINFO, P.SYSINFO_ADC_CLOCK)
            self._clocks_and_features()
        elif self.model.protocol == "dvxplorer":
            self._open_dvxplorer()
        else:
            self.chip = "DVS128"

    def _clocks_and_features(self) -> None:
        dev = self.config_get(P.MOD_SYSINFO, P.SYSINFO_CLOCK_DEVIATION) or 1000
        self.logic_clock_mhz = self.config_get(P.MOD_SYSINFO, P.SYSINFO_LOGIC_CLOCK) * dev / 1000
        self.usb_clock_mhz = self.config_get(P.MOD_SYSINFO, P.SYSINFO_USB_CLOCK) * dev / 1000
        feats = {"pixel_filter": (P.MOD_DVS, P.DVS_HAS_PIXEL_FILTER),
                 "ba_filter": (P.MOD_DVS, P.DVS_HAS_BA_FILTER), "roi_filter": (P.MOD_DVS, P.DVS_HAS_ROI_FILTER),
                 "skip_filter": (P.MOD_DVS, P.DVS_HAS_SKIP_FILTER),
                 "polarity_filter": (P.MOD_DVS, P.DVS_HAS_POLARITY_FILTER),
                 "generator": (P.MOD_EXTINPUT, P.EXTINPUT_HAS_GENERATOR)}
        if self.model.protocol == "dvxplorer":
            feats = {"generator": feats["generator"]}
        self.has = {k: bool(self.config_get(m, q)) for k, (m, q) in feats.items()}

    def _open_dvxplorer(self) -> None:
        """DVXplorer / DVXplorer Lite (FX3): read its identity, then
        initialise the chip as libcaer does at open."""
        if (self.dev.bcdDevice >> 8) == P.DVX_DEVICE_MIPI:
            raise TectumError("DVXplorer Mini (MIPI CX3 board) is not supported: its 32-bit event protocol is "
                              "a different one (libcaer's mipiCx3EventTranslator)")
        self.logic_version = self.config_get(P.MOD_SYSINFO, P.SYSINFO_LOGIC_VERSION)
        patch = self.config_get(P.MOD_SYSINFO, P.SYSINFO_LOGIC_PATCH)
        if (self.logic_version, patch) < P.DVX_REQUIRED_LOGIC:
            raise TectumError(f"DVXplorer logic {self.logic_version}.{patch} is too old: update the device's "
                              f"firmware/logic to {P.DVX_REQUIRED_LOGIC[0]}.{P.DVX_REQUIRED_LOGIC[1]} or newer")
        chip = self.config_get(P.MOD_SYSINFO, P.SYSINFO_CHIP_ID)
        self.chip = {P.DVX_CHIP_ID: "DVXplorer", P.DVX_LITE_CHIP_ID: "DVXplorer Lite"}.get(chip, f"chip {chip}")
        self._clocks_and_features()
        cols = self.config_get(P.MOD_DVS, P.DVS_SIZE_COLUMNS)
        rows = self.config_get(P.MOD_DVS, P.DVS_SIZE_ROWS)
        orient = self.config_get(P.MOD_DVS, P.DVS_ORIENTATION)
        self.invert_xy = bool(orient & 0x04)
        if not (0 < cols <= 4096 and 0 < rows <= 4096):
            raise TectumError(f"{self.model.name}: the device reports a sensor of {cols}x{rows}")
        self.sensor = (rows, cols) if self.invert_xy else (cols, rows)
        self.imu_flips = self.config_get(P.MOD_IMU, P.DVX_IMU_ORIENTATION) & 7
        self.dvx = DvxConfig(self.config_set, self.config_get, self.sensor, chip, flip_x=bool(orient & 2),
                             flip_y=bool(orient & 1), usb_clock_mhz=self.usb_clock_mhz,
                             logic_clock_mhz=self.logic_clock_mhz)
        self.dvx.init_chip()

    def info(self) -> DeviceInfo:
        return DeviceInfo(self.model.name, self.dev.idVendor, self.dev.idProduct, self.dev.bus, self.dev.address,
                          self.serial, self.dev.bcdDevice & 0xFF, self.chip, self.sensor, self.logic_version)

    def decoder(self) -> Dvs128Decoder | DavisDecoder | DvxDecoder:
        if self.model.protocol == "dvs128":
            return Dvs128Decoder()
        if self.model.protocol == "dvxplorer":
            return DvxDecoder(self.sensor, self.invert_xy, imu_flips=self.imu_flips)
        return DavisDecoder(self.sensor, self.invert_xy, aps_size=self.aps_size or self.sensor,
                            aps_orientation=self.aps_orientation, davis240=self.chip.startswith("DAVIS240"))

    def config_set(self, module: int, param: int, value: int) -> None:
        """DAVIS: write one 32-bit configuration value (sent big-endian)."""
        self.dev.ctrl_transfer(0x40, P.REQ_CONFIG, module, param, struct.pack(">I", value & 0xFFFFFFFF))

    def config_get(self, module: int, param: int) -> int:
        """DAVIS: read one 32-bit configuration value."""
        got = self.dev.ctrl_transfer(0xC0, P.REQ_CONFIG, module, param, 4)
        if len(got) != 4:
            raise TectumError(f"{self.model.name}: config read ({module}, {param}) returned {len(got)} bytes")
        return int(struct.unpack(">I", bytes(got))[0])

    def send_defaults(self) -> None:
        """libcaer's default configuration. DAVIS: every bias of the chip
        family (coarse/fine, VDAC, shifted source) and the chip's shift
        register, the FPGA's DVS filters where the logic has them (pixel
        filters parked outside the array, background-activity filter on
        at 2 ms, refractory filter off at 250 µs, full-array ROI, skip and
        polarity filters off), drop DVS data on USB stalls, the APS (global
        shutter when the chip has one, full-array ROI, 4 ms exposure, 40 ms
        frame interval, in ADC clock cycles), the IMU (1 kHz, ±4 g,
        ±500 °/s, low-pass 1), the external-input detector (pulses, 10 µs
        in logic clock cycles) and a 1 ms early-packet delay (in USB clock
        cycles). DVXplorer: see :class:`DvxConfig`."""
        if self.model.protocol == "dvs128":
            payload = b"".join(v.to_bytes(3, "big") for v in P.DVS128_DEFAULT_BIASES)
            self.dev.ctrl_transfer(0x40, P.DVS128_REQ_BIASES, 0, 0, payload)
            return
        if self.model.protocol == "dvxplorer":
            assert self.dvx is not None
            self.dvx.defaults(self.has.get("generator", False))
            return
        family = "DAVIS240" if self.chip.startswith("DAVIS240") else "DAVIS346"
        for param, value in P.DAVIS_FULL_BIASES[family].items():
            self.config_set(P.MOD_BIAS, param, value)
        for param, value in P.DAVIS_CHIP_DEFAULTS.items():
            if family == "DAVIS240" and param == 144:  # ADC test: DAVIS346/640 only
                continue
            self.config_set(P.MOD_BIAS, param, value)
        for (module, param), value in self.davis_fpga_defaults().items():
            self.config_set(module, param, value)
        self._aps_defaults()

    def davis_fpga_defaults(self) -> dict[tuple[int, int], int]:
        """(module, parameter) -> value of libcaer's DAVIS FPGA defaults
        (without the APS, which :meth:`_aps_defaults` sends)."""
        w, h = self.sensor
        out = {(P.MOD_MUX, P.MUX_TS_RESET): 0, (P.MOD_MUX, P.MUX_DROP_EXT_STALL): 1,
               (P.MOD_MUX, P.MUX_DROP_DVS_STALL): 1, (P.MOD_DVS, P.DVS_WAIT_ON_STALL): 0,
               (P.MOD_DVS, P.DVS_EXTERNAL_AER_CONTROL): 0}
        if self.has.get("pixel_filter"):
            for k in range(8):  # rows/columns past the array: no pixel filtered
                out[(P.MOD_DVS, P.DVS_FILTER_PIXEL_0_ROW + 2 * k)] = h
                out[(P.MOD_DVS, P.DVS_FILTER_PIXEL_0_ROW + 2 * k + 1)] = w
        if self.has.get("ba_filter"):
            out.update({(P.MOD_DVS, P.DVS_FILTER_BA): 1, (P.MOD_DVS, P.DVS_FILTER_BA_TIME): 8,  # x 250 µs
                        (P.MOD_DVS, P.DVS_FILTER_REFRACTORY): 0, (P.MOD_DVS, P.DVS_FILTER_REFRACTORY_TIME): 1})
        if self.has.get("roi_filter"):
            out.update({(P.MOD_DVS, P.DVS_ROI_START_COLUMN): 0, (P.MOD_DVS, P.DVS_ROI_START_ROW): 0,
                        (P.MOD_DVS, P.DVS_ROI_END_COLUMN): w - 1, (P.MOD_DVS, P.DVS_ROI_END_ROW): h - 1})
        if self.has.get("skip_filter"):
            out.update({(P.MOD_DVS, P.DVS_SKIP_EVENTS): 0, (P.MOD_DVS, P.DVS_SKIP_EVENTS_EVERY): 5})
        if self.has.get("polarity_filter"):
            out.update({(P.MOD_DVS, P.DVS_POLARITY_FLATTEN): 0, (P.MOD_DVS, P.DVS_POLARITY_SUPPRESS): 0,
                        (P.MOD_DVS, P.DVS_POLARITY_SUPPRESS_TYPE): 0})
        out.update({(P.MOD_IMU, P.IMU_SAMPLE_RATE_DIVIDER): 0, (P.MOD_IMU, P.IMU_ACCEL_DLPF): 1,
                    (P.MOD_IMU, P.IMU_ACCEL_FULL_SCALE): 1, (P.MOD_IMU, P.IMU_GYRO_DLPF): 1,
                    (P.MOD_IMU, P.IMU_GYRO_FULL_SCALE): 1})
        cyc = self.logic_clock_mhz
        out.update({(P.MOD_EXTINPUT, P.EXTINPUT_DETECT_RISING): 0, (P.MOD_EXTINPUT, P.EXTINPUT_DETECT_FALLING): 0,
                    (P.MOD_EXTINPUT, P.EXTINPUT_DETECT_PULSES): 1, (P.MOD_EXTINPUT, P.EXTINPUT_PULSE_POLARITY): 1,
                    (P.MOD_EXTINPUT, P.EXTINPUT_PULSE_LENGTH): round(10 * cyc)})
        if self.has.get("generator"):
            out.update({(P.MOD_EXTINPUT, P.EXTINPUT_RUN_GENERATOR): 0, (P.MOD_EXTINPUT, P.EXTINPUT_GEN_POLARITY): 1,
                        (P.MOD_EXTINPUT, P.EXTINPUT_GEN_INTERVAL): round(10 * cyc),
                        (P.MOD_EXTINPUT, P.EXTINPUT_GEN_LENGTH): round(5 * cyc),
                        (P.MOD_EXTINPUT, P.EXTINPUT_GEN_ON_RISING): 0, (P.MOD_EXTINPUT, P.EXTINPUT_GEN_ON_FALLING): 0})
        out[(P.MOD_USB, P.USB_EARLY_PACKET_DELAY)] = round(8 * 125 * self.usb_clock_mhz)
        return out

    def _aps_defaults(self) -> None:
        if self.aps_size is None:
            return
        cols, rows = self.aps_size[::-1] if self.aps_orientation & 4 else self.aps_size
        gs = self.config_get(P.MOD_APS, P.APS_HAS_GLOBAL_SHUTTER)
        clock = self.adc_clock_mhz or 30  # cycles per µs
        for param, value in ((P.APS_WAIT_ON_STALL, 1), (P.APS_GLOBAL_SHUTTER, 1 if gs else 0),
                             (P.APS_START_COLUMN, 0), (P.APS_START_ROW, 0), (P.APS_END_COLUMN, cols - 1),
                             (P.APS_END_ROW, rows - 1), (P.APS_EXPOSURE, P.APS_DEFAULT_EXPOSURE_US * clock),
                             (P.APS_FRAME_INTERVAL, P.APS_DEFAULT_INTERVAL_US * clock)):
            self.config_set(P.MOD_APS, param, value)

    def set_frames(self, exposure_us: int, interval_us: int) -> None:
        """DAVIS: APS exposure and frame interval (µs)."""
        clock = self.adc_clock_mhz or 30
        self.config_set(P.MOD_APS, P.APS_EXPOSURE, exposure_us * clock)
        self.config_set(P.MOD_APS, P.APS_FRAME_INTERVAL, interval_us * clock)

    def start(self, frames: bool = True) -> None:
        """Start streaming (DAVIS: DVS, IMU and, if ``frames``, the APS)."""
        if self.model.protocol == "dvs128":
            self.dev.ctrl_transfer(0x40, P.DVS128_REQ_START, 0, 0, b"")
            return
        if self.dvx is not None:
            self.dvx.start()
            return
        self.config_set(P.MOD_MUX, P.MUX_RUN_CHIP, 1)
        self.config_set(P.MOD_USB, P.USB_RUN, 1)
        self.config_set(P.MOD_MUX, P.MUX_TS_RUN, 1)
        self.config_set(P.MOD_MUX, P.MUX_RUN, 1)
        self.config_set(P.MOD_DVS, P.DVS_RUN, 1)
        for p in (P.IMU_RUN_ACCEL, P.IMU_RUN_GYRO, P.IMU_RUN_TEMP):
            self.config_set(P.MOD_IMU, p, 1)
        if frames and self.aps_size is not None:
            self.config_set(P.MOD_APS, P.APS_RUN, 1)

    def stop(self) -> None:
        if self.model.protocol == "dvs128":
            self.dev.ctrl_transfer(0x40, P.DVS128_REQ_STOP, 0, 0, b"")
            return
        if self.dvx is not None:
            self.dvx.stop()
            return
        for mod, p in ((P.MOD_APS, P.APS_RUN), (P.MOD_DVS, P.DVS_RUN), (P.MOD_MUX, P.MUX_RUN),
                       (P.MOD_USB, P.USB_RUN)):
            self.config_set(mod, p, 0)

    # -- data -----------------------------------------------------------------
    def read(self, size: int, timeout_ms: int) -> bytes:
        """One bulk read of at most ``size`` bytes; b"" on timeout. Raises
        :class:`DeviceDisconnected`, or ``usb.core.USBError`` (EOVERFLOW ...)."""
        try:
            return bytes(self.dev.read(self.model.endpoint, size, timeout_ms))
        except usb.core.USBError as e:
            if e.errno == errno.ETIMEDOUT or isinstance(e, usb.core.USBTimeoutError):
                return b""
            if is_disconnect(e):
                raise DeviceDisconnected(f"{self.model.name} {self.serial or ''} was disconnected ({e})") from e
            raise

    def close(self, stop: bool = True) -> None:
        try:
            if stop:
                self.stop()
        except usb.core.USBError:
            pass
        finally:
            try:
                if self._claimed:
                    usb.util.release_interface(self.dev, 0)
                usb.util.dispose_resources(self.dev)
            except usb.core.USBError:
                pass


def list_devices(backend: Any) -> list[DeviceInfo]:
    """Describe every attached camera (opening each briefly to read its
    serial number and sensor; a camera that cannot be opened is listed with
    the reason)."""
    out = []
    for dev in find_cameras(backend):
        cam = Camera(dev)
        try:
            cam.open()
            out.append(cam.info())
        except (usb.core.USBError, TectumError) as e:
            out.append(DeviceInfo(cam.model.name, dev.idVendor, dev.idProduct, dev.bus, dev.address, "",
                                  dev.bcdDevice & 0xFF, error=str(e)))
        finally:
            cam.close(stop=False)
    return out
