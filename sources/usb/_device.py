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
        else:
            self.chip = "DVS128"

    def info(self) -> DeviceInfo:
        return DeviceInfo(self.model.name, self.dev.idVendor, self.dev.idProduct, self.dev.bus, self.dev.address,
                          self.serial, self.dev.bcdDevice & 0xFF, self.chip, self.sensor, self.logic_version)

    def decoder(self) -> Dvs128Decoder | DavisDecoder:
        if self.model.protocol == "dvs128":
            return Dvs128Decoder()
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
        """Default biases and settings, as libcaer's defaults where they
        matter here: the main DVS biases, drop-free USB transfers, the APS
        (global shutter when the chip has one, full-array ROI, 4 ms exposure,
        40 ms frame interval, both in ADC clock cycles) and the IMU (1 kHz,
        ±4 g, ±500 °/s, low-pass filter 1)."""
        if self.model.protocol == "dvs128":
            payload = b"".join(v.to_bytes(3, "big") for v in P.DVS128_DEFAULT_BIASES)
            self.dev.ctrl_transfer(0x40, P.DVS128_REQ_BIASES, 0, 0, payload)
            return
        family = "DAVIS240" if self.chip.startswith("DAVIS240") else "DAVIS346"
        for param, value in P.DAVIS_DEFAULT_BIASES[family].items():
            self.config_set(P.MOD_BIAS, param, value)
        self.config_set(P.MOD_MUX, P.MUX_DROP_DVS_STALL, 0)
        self.config_set(P.MOD_DVS, P.DVS_WAIT_ON_STALL, 1)
        self.config_set(P.MOD_USB, P.USB_EARLY_PACKET_DELAY, 8)  # x 125 µs: 1 ms
        self._aps_defaults()
        for param, value in ((P.IMU_SAMPLE_RATE_DIVIDER, 0), (P.IMU_ACCEL_DLPF, 1), (P.IMU_ACCEL_FULL_SCALE, 1),
                             (P.IMU_GYRO_DLPF, 1), (P.IMU_GYRO_FULL_SCALE, 1)):
            self.config_set(P.MOD_IMU, param, value)

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
