"""``http://HOST:PORT`` — a live view of the events in the browser.

The sink renders frames (see :mod:`.render`) and serves them from a tiny
HTTP/1.1 server on trio sockets, run in its own thread (so a slow browser
never holds the pipeline back: it only ever gets the newest frame):

* ``/`` an HTML page (:mod:`._page`): the newest frame scaled to the window,
  a legend for the mode, what each panel shows, and the stats, refreshed by
  script within the one page load; maps (``map.*`` operators' output) are
  shown as pictures (:mod:`.maps`), with their own caption and legend, and
  so are frames (:mod:`.frames`: a ``repr.*`` operator's images) when no
  events come;
* ``/frame.png`` the newest frame; ``/stream.mjpg`` an MJPEG stream;
  ``/legend.png`` the colour wheel of the ``flow_wheel`` mode;
* ``/stats.json`` events and packets seen, event rate, frames, stream time,
  and (``pipeline``) the whole run's stats: per node packets and events in
  and out, drops, busy time, counters, latency percentiles.

Frames are made at ``fps`` per second of event time; to watch a recording
at its own speed, run the pipeline paced (``--pace 1``).
"""

from __future__ import annotations

import json
import threading
import time
from typing import Any

import cv2
import numpy as np
import trio

from tectum import EventPacket, FramePacket, MapPacket, Packet

from ._page import page
from .files import _Rendering
from .frames import frame_caption
from .maps import map_caption
from .render import Mode, flow_wheel_legend

__all__ = ["LiveViewSink"]


class LiveViewSink(_Rendering):
    """Serve a live rendering of the events over HTTP (see the module
    docstring). ``mode`` polarity, time_surface, flow_wheel or flow_arrows;
    ``tau_us`` decay of the time surface; ``flow_max_px_s`` the flow speed
    drawn in full colour; ``scale`` enlarges the served image by an integer
    factor (the page scales it to the window anyway); ``frames`` draws the
    frames of a frames stream instead of the events (by default when no
    events come: a ``repr.*`` operator's images)."""

    name = "display"
    schemes = ("http",)

    def __init__(self, url: str = "http://127.0.0.1:8080", fps: float = 30.0, mode: Mode = "polarity",
                 tau_us: float = 30_000.0, scale: int = 1, flow_max_px_s: float = 500.0,
                 frames: bool | None = None) -> None:
        from urllib.parse import urlsplit

        u = urlsplit(url)
        if u.scheme != "http" or not u.hostname or u.port is None:
            raise ValueError(f"{url!r}: expected http://HOST:PORT")
        if not 1 <= scale <= 8:
            raise ValueError("scale must be 1..8")
        super().__init__(fps, mode, tau_us, flow_max_px_s, frames)
        self.host, self.port = u.hostname, u.port
        self.scale = scale
        self._lock = threading.Lock()
        self._png: bytes | None = None
        self._jpeg: bytes | None = None
        self._frame_id = 0
        self._stats: dict[str, Any] = {"events": 0, "packets": 0, "frames": 0, "t_us": 0, "rate_ev_s": 0.0,
                                       "requests": 0, "maps": 0}
        self._t_wall0: float | None = None
        self._thread: threading.Thread | None = None
        self._token: trio.lowlevel.TrioToken | None = None
        self._cancel: trio.CancelScope | None = None
        self._ready = threading.Event()
        self._error: BaseException | None = None
        self._run_stats: Any = None

    def bind_stats(self, stats: Any) -> None:
        """The run's :class:`tectum.Stats`, shown on the page."""
        self._run_stats = stats

    # -- pipeline side ----------------------------------------------------
    def open(self) -> None:
        self._thread = threading.Thread(target=self._serve_thread, name="tectum-liveview", daemon=True)
        self._thread.start()
        if not self._ready.wait(10.0) or self._error is not None:
            raise OSError(f"live view could not listen on {self.host}:{self.port}: {self._error}")

    def write(self, packet: Packet) -> None:
        frames = self._frames(packet)
        st = self._stats
        if isinstance(packet, MapPacket) and frames:
            st["maps"] += len(frames)
            st["t_us"] = int(packet.t[-1])
            st["view"] = {"title": "Map", "caption": map_caption(packet)}
        elif isinstance(packet, FramePacket) and frames:
            st["t_us"] = int(packet.t[-1])
            st["view"] = {"title": "Frames", "caption": frame_caption(packet.data["images"][-1], st["t_us"])}
        if isinstance(packet, EventPacket):
            if self._t_wall0 is None:
                self._t_wall0 = time.perf_counter()
            st["events"] += len(packet)
            st["packets"] += 1
            st["t_us"] = packet.t_end
            st["rate_ev_s"] = st["events"] / max(1e-6, time.perf_counter() - self._t_wall0)
        if frames:
            img = frames[-1][1]
            if self.scale > 1:
                img = cv2.resize(img, None, fx=self.scale, fy=self.scale, interpolation=cv2.INTER_NEAREST)
            ok, png = cv2.imencode(".png", img)
            ok2, jpg = cv2.imencode(".jpg", img)
            with self._lock:
                self._png, self._jpeg = png.tobytes(), jpg.tobytes()
                self._frame_id += 1
                st["frames"] = self._frame_id

    def close(self) -> None:
        if self._token is not None and self._cancel is not None:
            try:  # thread-safe and non-blocking (close runs inside the pipeline's own trio loop)
                self._token.run_sync_soon(self._cancel.cancel)
            except trio.RunFinishedError:
                pass
        if self._thread is not None:
            self._thread.join(5.0)
            self._thread = None

    # -- server side ------------------------------------------------------
    def _serve_thread(self) -> None:
        try:
            trio.run(self._serve)
        except BaseException as e:  # reported by open()
            self._error = e
            self._ready.set()

    async def _serve(self) -> None:
        self._token = trio.lowlevel.current_trio_token()
        listeners = await trio.open_tcp_listeners(self.port, host=self.host)
        self.port = listeners[0].socket.getsockname()[1]
        with trio.CancelScope() as scope:
            self._cancel = scope
            self._ready.set()
            await trio.serve_listeners(self._handle, listeners)

    async def _handle(self, stream: trio.SocketStream) -> None:
        try:
            with trio.move_on_after(30):
                req = b""
                while b"\r\n\r\n" not in req and len(req) < 8192:
                    chunk = await stream.receive_some(4096)
                    if not chunk:
                        return
                    req += chunk
                parts = req.split(b" ", 2)
                path = parts[1].decode("latin1", "replace").split("?")[0] if len(parts) > 2 else ""
                self._stats["requests"] += 1
                if path == "/stream.mjpg":
                    await self._mjpeg(stream)
                    return
                await stream.send_all(self._response(path))
        except (trio.BrokenResourceError, trio.ClosedResourceError, OSError):
            pass
        finally:
            await stream.aclose()

    def _response(self, path: str) -> bytes:
        r = self.renderer or self._new_renderer((1, 1))  # its settings, before the first events
        if path in ("/", "/index.html"):
            body = page(r, self.renderer.sensor if self.renderer else None, max(20, int(1000 / self.fps)))
            return _http(200, "text/html; charset=utf-8", body)
        if path == "/legend.png":
            return _http(200, "image/png", cv2.imencode(".png", flow_wheel_legend(96, r.flow_max))[1].tobytes())
        if path == "/frame.png":
            with self._lock:
                png = self._png
            if png is None:
                ok, buf = cv2.imencode(".png", np.full((8, 8, 3), 40, np.uint8))
                png = buf.tobytes()
            return _http(200, "image/png", png)
        if path == "/stats.json":
            stats = dict(self._stats, tracks=len(r.tracks) + len(self._tracks))
            if self._run_stats is not None:
                try:
                    stats["pipeline"] = self._run_stats.as_dict()
                except RuntimeError:  # a dict changed size while the pipeline runs: next time
                    pass
            return _http(200, "application/json", json.dumps(stats, default=float).encode())
        return _http(404, "text/plain", b"not found\n")

    async def _mjpeg(self, stream: trio.SocketStream) -> None:
        await stream.send_all(b"HTTP/1.1 200 OK\r\nContent-Type: multipart/x-mixed-replace; boundary=frame\r\n"
                              b"Cache-Control: no-store\r\nConnection: close\r\n\r\n")
        seen = -1
        while True:
            with self._lock:
                fid, jpg = self._frame_id, self._jpeg
            if jpg is not None and fid != seen:
                seen = fid
                await stream.send_all(b"--frame\r\nContent-Type: image/jpeg\r\nContent-Length: "
                                      + str(len(jpg)).encode() + b"\r\n\r\n" + jpg + b"\r\n")
            await trio.sleep(1 / self.fps)


def _http(code: int, ctype: str, body: bytes) -> bytes:
    reason = {200: "OK", 404: "Not Found"}[code]
    head = (f"HTTP/1.1 {code} {reason}\r\nContent-Type: {ctype}\r\nContent-Length: {len(body)}\r\n"
            "Cache-Control: no-store\r\nConnection: close\r\n\r\n")
    return head.encode() + body
