"""``usb:`` — live events from an iniVation camera (DVS128, DAVIS240/346,
DVXplorer and DVXplorer Lite).

Bulk reads run in a worker thread (``trio.to_thread``) with a bounded size
and a short timeout, so the trio loop never blocks and cancellation is
prompt. Events are released up to the device's newest timestamp; the few at
exactly that timestamp wait for the next read, so equal timestamps never
straddle two packets.
"""

from __future__ import annotations

import time
from collections.abc import AsyncIterator
from typing import Any, Literal

import numpy as np
import trio
import usb.core

from tectum import EventPacket, FramePacket, ImuPacket, Kind, Packet, Source
from tectum.errors import TectumError

from . import _protocol as P
from ._decode import Decoded, Frame
from ._device import Camera, DeviceDisconnected, UsbUnavailable, default_backend, find_cameras

__all__ = ["UsbSource"]

_MODEL_FILTER = {"": None, "dvs128": "dvs128", "davis": "davis", "davis240": "davis", "davis346": "davis",
                 "dvxplorer": "dvxplorer"}


class UsbSource(Source):
    """Events (and DAVIS IMU samples) from a camera on USB.

    ``usb:`` opens the first camera found; ``usb:davis`` / ``usb:dvs128`` /
    ``usb:dvxplorer`` restrict the model; ``serial`` picks one camera.

    Parameters (units): ``read_size`` bytes per bulk read; ``timeout_ms``
    per read; ``duration_us`` stop after this much camera time (0: until
    stopped); ``defaults`` send the default biases; ``on_disconnect``:
    ``error`` (raise :class:`DeviceDisconnected` after delivering what was
    read), ``end`` (end the stream cleanly, so files are kept) or
    ``reconnect`` (wait up to ``reconnect_s`` s for the camera to return,
    time goes on from where it was); ``idle_s`` ends the stream after that
    many seconds without data (0: never); ``emulate`` a model name (``davis346``,
    ``dvs128``, ``dvxplorer``, ``davis346:realtime``) plays an emulated camera;
    ``backend`` a pyusb backend object (Python API). DAVIS: ``frames`` runs
    the APS (8-bit frames, ``t`` mid-exposure, with ``exposure_start`` /
    ``exposure_end`` µs), ``exposure_us`` and ``frame_interval_us`` override
    libcaer's defaults (4 ms, 40 ms) when > 0.
    """

    name = "usb"
    schemes = ("usb",)
    produces = (Kind.EVENTS, Kind.IMU, Kind.FRAMES)

    def __init__(self, url: str = "usb:", serial: str = "", read_size: int = 65536, timeout_ms: int = 50,
                 duration_us: int = 0, defaults: bool = True,
                 on_disconnect: Literal["error", "end", "reconnect"] = "error", reconnect_s: float = 5.0,
                 idle_s: float = 0.0, emulate: str = "", backend: Any = None, frames: bool = True,
                 exposure_us: int = 0, frame_interval_us: int = 0) -> None:
        kind = url.split(":", 1)[1].strip("/").lower() if ":" in url else ""
        if kind not in _MODEL_FILTER:
            raise ValueError(f"unknown camera kind {kind!r} in {url!r}; "
                             "known: usb:, usb:davis, usb:dvs128, usb:dvxplorer")
        if not 512 <= read_size <= 1 << 22:
            raise ValueError("read_size must be within 512 B .. 4 MiB")
        if timeout_ms <= 0 or duration_us < 0 or reconnect_s < 0 or idle_s < 0 or exposure_us < 0 \
                or frame_interval_us < 0:
            raise ValueError("timeout_ms must be > 0; duration_us, reconnect_s, idle_s, exposure_us and "
                             "frame_interval_us >= 0")
        self.frames, self.exposure_us, self.frame_interval_us = frames, exposure_us, frame_interval_us
        self.protocol = _MODEL_FILTER[kind]
        self.serial, self.read_size, self.timeout_ms = serial, read_size, timeout_ms
        self.duration_us, self.defaults = duration_us, defaults
        self.on_disconnect, self.reconnect_s = on_disconnect, reconnect_s
        if emulate:
            from .emulated import emulated_backend

            backend = emulated_backend(emulate)
            idle_s = idle_s or 0.5  # an emulated camera's recording ends
        self.idle_s = idle_s
        self.backend = backend
        self.counts = {"bytes": 0, "reads": 0, "overruns": 0, "timeouts": 0, "disconnects": 0, "reconnects": 0}
        self.camera: Camera | None = None
        self.decoder: Any = None
        self._ev: list[Decoded] = []
        self._end = {Kind.EVENTS: None, Kind.IMU: None, Kind.FRAMES: None}  # type: dict[Kind, int | None]
        self._frames: list[Frame] = []
        self._t0: int | None = None

    # -- opening --------------------------------------------------------------
    def _backend(self) -> Any:
        if self.backend is None:
            be, why = default_backend()
            if be is None:
                raise UsbUnavailable(f"cannot open a USB camera: {why}")
            self.backend = be
        return self.backend

    def _find(self) -> Camera | None:
        for dev in find_cameras(self._backend()):
            cam = Camera(dev)
            if self.protocol and cam.model.protocol != self.protocol:
                continue
            cam.open()
            if self.serial and cam.serial != self.serial:
                cam.close(stop=False)
                continue
            return cam
        return None

    def _open(self) -> Camera:
        cam = self._find()
        if cam is None:
            what = f" with serial {self.serial!r}" if self.serial else ""
            raise UsbUnavailable(f"no {self.protocol or 'iniVation'} camera{what} is attached")
        if self.defaults:
            cam.send_defaults()
        if self.exposure_us or self.frame_interval_us:
            cam.set_frames(self.exposure_us or P.APS_DEFAULT_EXPOSURE_US,
                           self.frame_interval_us or P.APS_DEFAULT_INTERVAL_US)
        cam.start(frames=self.frames)
        self.serial = self.serial or cam.serial
        return cam

    @property
    def sensor(self) -> tuple[int, int]:
        return self.camera.sensor if self.camera else (0, 0)

    # -- streaming ------------------------------------------------------------
    async def apackets(self) -> AsyncIterator[Packet]:
        self.camera = await trio.to_thread.run_sync(self._open)
        self.decoder = self.camera.decoder()
        quiet_since = time.monotonic()
        while True:
            try:
                data = await trio.to_thread.run_sync(self.camera.read, self.read_size, self.timeout_ms)
            except DeviceDisconnected:
                self.counts["disconnects"] += 1
                for pkt in self._release(final=True):
                    yield pkt
                if self.on_disconnect == "end":
                    return
                if self.on_disconnect == "reconnect" and await self._reconnect():
                    continue
                raise
            except usb.core.USBError as e:
                if e.errno == 75 or getattr(e, "backend_error_code", 0) == -8:  # EOVERFLOW: transfer lost
                    self.counts["overruns"] += 1
                    continue
                raise TectumError(f"USB read failed: {e}") from e
            self.counts["reads"] += 1
            if not data:
                self.counts["timeouts"] += 1
                if self.idle_s and time.monotonic() - quiet_since > self.idle_s:
                    for pkt in self._release(final=True):
                        yield pkt
                    return
                continue
            quiet_since = time.monotonic()
            self.counts["bytes"] += len(data)
            self._ev.append(self.decoder.feed(data))
            done = self._past_duration()
            for pkt in self._release(final=done):
                yield pkt
            if done:
                return

    def _past_duration(self) -> bool:
        if not self.duration_us:
            return False
        now = self.decoder.device_now
        if self._t0 is None:
            firsts = [int(d.t[0]) for d in self._ev if len(d.t)]
            if not firsts:
                return False
            self._t0 = firsts[0]
        return now - self._t0 >= self.duration_us

    async def _reconnect(self) -> bool:
        assert self.camera is not None
        self.camera.close(stop=False)
        deadline = time.monotonic() + self.reconnect_s
        while time.monotonic() < deadline:
            await trio.sleep(0.05)
            try:
                cam = await trio.to_thread.run_sync(self._open)
            except (UsbUnavailable, usb.core.USBError):
                continue
            self.camera = cam
            self.decoder.rebase()
            self.counts["reconnects"] += 1
            return True
        return False

    def _release(self, final: bool) -> list[Packet]:
        """Packets of everything decoded before the device's current time
        (everything, when ``final``)."""
        if not self._ev:
            return self._release_frames(self.decoder.device_now, final) if self._frames else []
        ev = self._ev
        for d in ev:
            self._frames += d.frames
            d.frames = []
        t = np.concatenate([d.t for d in ev])
        it = np.concatenate([d.imu_t for d in ev])
        if final:
            cut = max(int(t[-1]) + 1 if len(t) else -1, int(it[-1]) + 1 if len(it) else -1, 0)
        else:
            cut = min(self.decoder.device_now, self.decoder.last_t)
        x = np.concatenate([d.x for d in ev])
        y = np.concatenate([d.y for d in ev])
        p = np.concatenate([d.p for d in ev])
        iv = np.concatenate([d.imu for d in ev])
        i = int(np.searchsorted(t, cut, side="left"))
        j = int(np.searchsorted(it, cut, side="left"))
        self._ev = [Decoded(t[i:], x[i:], y[i:], p[i:], it[j:], iv[j:])] if (i < len(t) or j < len(it)) else []
        out: list[Packet] = []
        s = self._end[Kind.EVENTS]
        start = s if s is not None else (int(t[0]) if i else cut)
        if cut > start or i:
            out.append(EventPacket(t[:i], x[:i], y[:i], p[:i], sensor=self.sensor, t_start=start,
                                   t_end=max(cut, start)))
            self._end[Kind.EVENTS] = max(cut, start)
        if j:
            s = self._end[Kind.IMU]
            start = s if s is not None else int(it[0])
            out.append(ImuPacket(it[:j], t_start=start, t_end=cut, accel=iv[:j, 0:3], gyro=iv[:j, 4:7],
                                 temperature=iv[:j, 3]))
            self._end[Kind.IMU] = cut
        out += self._release_frames(cut, final)
        return out

    def _release_frames(self, cut: int, final: bool) -> list[Packet]:
        """Complete frames before ``cut`` (and before the start of a frame
        still being read out, whose time may come before ``cut``), one
        FramePacket per run of equally sized frames."""
        fs = self._frames
        if not fs:
            return []
        if final:
            cut = max(cut, fs[-1].t + 1)
        else:
            since = self.decoder.frame_in_progress_since if hasattr(self.decoder, "frame_in_progress_since") else None
            if since is not None:
                cut = min(cut, since)
        ready = [f for f in fs if f.t < cut]
        self._frames = fs[len(ready):]
        out: list[Packet] = []
        i = 0
        while i < len(ready):
            j = i + 1
            while j < len(ready) and ready[j].image.shape == ready[i].image.shape:
                j += 1
            group = ready[i:j]
            start = self._end[Kind.FRAMES]
            start = group[0].t if start is None else start
            end = max(cut if j == len(ready) else group[-1].t + 1, group[-1].t + 1)
            out.append(FramePacket(np.array([f.t for f in group], np.int64), t_start=start, t_end=end,
                                   images=np.stack([f.image for f in group]),
                                   exposure_start=np.array([f.exposure_start for f in group], np.int64),
                                   exposure_end=np.array([f.exposure_end for f in group], np.int64),
                                   position=np.array([f.position for f in group], np.int16)))
            self._end[Kind.FRAMES] = end
            i = j
        return out

    def close(self) -> None:
        if self.camera is not None:
            self.camera.close()
            self.camera = None
