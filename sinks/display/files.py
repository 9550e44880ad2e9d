"""Rendered events to a video file (``.mp4``, ``.avi`` through OpenCV) or
to PNG snapshots, and to a Python callback. Frames (:class:`tectum.FramePacket`:
the ``repr.*`` operators' images, APS frames) are drawn one picture each (see
:mod:`.frames`) when no events reach the sink (``frames=None``, decided when
the pipeline is validated; a sink built in Python with ``frames=None`` draws
frames until events come); with events the pictures are of the events and
the frames are counted as not written. Maps (:class:`tectum.MapPacket`,
``map.*`` operators) are drawn as pictures, one per sample (see
:mod:`.maps`): ``out.png`` keeps the last map of a map stream. Feature
tracks (:class:`tectum.TrackPacket`: features, LED markers) are drawn over
the events, or alone (see :mod:`.tracks`); moving-object clusters
(:class:`tectum.ClusterPacket`) over the events (see :mod:`.clusters`)."""

from __future__ import annotations

import os
from collections.abc import Callable
from typing import Any

import cv2
import numpy as np

from tectum import ClusterPacket, EventPacket, FramePacket, Kind, MapPacket, Packet, ResultPacket, Sink, TrackPacket
from tectum.sinks.files._common import count_unwritten, temp_beside

from .clusters import ClusterOverlay, as_tracks
from .frames import frame_picture
from .maps import map_picture
from .render import MODES, Mode, Renderer
from .tracks import TrackFrames

__all__ = ["VideoSink", "PngSink", "FrameCallbackSink"]


class _Rendering(Sink):
    # frames and maps: pictures of their own; tracks, clusters and results: over the events
    consumes = (Kind.EVENTS, Kind.FRAMES, Kind.RESULTS, Kind.MAPS, Kind.TRACKS, Kind.CLUSTERS)
    holds = "pictures of the events or of the frames (frames=true), not both"

    def __init__(self, fps: float, mode: Mode, tau_us: float, flow_max_px_s: float = 500.0,
                 frames: bool | None = None) -> None:
        if mode not in MODES:
            raise ValueError(f"mode must be one of {MODES}, got {mode!r}")
        self.fps, self.mode, self.tau_us, self.flow_max_px_s = fps, mode, tau_us, flow_max_px_s
        self.draw_frames = frames
        self.not_written: dict[str, int] = {}
        self.renderer: Renderer | None = None
        self.frames = 0
        self._tracks: list[ResultPacket] = []
        self.last_map: MapPacket | None = None
        self.track_frames = TrackFrames(fps)  # TrackPackets: over the events, or alone (see .tracks)
        self.clusters = ClusterOverlay()  # ClusterPackets: over the events (see .clusters)

    @classmethod
    def planned_params(cls, params: dict[str, Any], upstream: frozenset[Kind]) -> dict[str, Any]:
        """At validation: with no ``frames`` given, frames are drawn when no events reach the sink."""
        if params.get("frames") is None:
            return {**params, "frames": Kind.EVENTS not in upstream}
        return params

    def _skip(self, packet: Packet) -> list[tuple[int, np.ndarray]]:
        count_unwritten(self.not_written, packet)
        return []

    def _frames(self, packet: Packet) -> list[tuple[int, np.ndarray]]:
        if isinstance(packet, FramePacket):
            if self.draw_frames is None:
                self.draw_frames = self.renderer is None  # built in Python: frames until events come
            if not self.draw_frames:
                return self._skip(packet)
            images = packet.data["images"]
            pics = [(int(t), frame_picture(images[i], int(t))) for i, t in enumerate(packet.t)]
            self.frames += len(pics)
            return pics
        if isinstance(packet, MapPacket):
            maps = [(int(t), map_picture(packet, i)) for i, t in enumerate(packet.t)]
            if maps:
                self.last_map = packet
            self.frames += len(maps)
            return maps
        if isinstance(packet, TrackPacket):
            if self.renderer is None:
                alone = self.track_frames.add(packet)
                self.frames += len(alone)
                return alone
            self.track_frames.overlay.add(packet)
            return []
        if isinstance(packet, ClusterPacket):
            if self.renderer is None:  # clusters alone: their centres' trails on a canvas
                alone = self.track_frames.add(as_tracks(packet))
                self.frames += len(alone)
                return alone
            self.clusters.add(packet)
            return []
        if isinstance(packet, ResultPacket):
            if self.renderer is None:
                self._tracks.append(packet)
            else:
                self.renderer.add_tracks(packet)
            return []
        assert isinstance(packet, EventPacket)
        if self.draw_frames:
            return self._skip(packet)
        if self.renderer is None:
            self.renderer = self._new_renderer(packet.sensor)
            for r in self._tracks:
                self.renderer.add_tracks(r)
            self._tracks = []
        tracks = self.track_frames.overlay
        got = [(t, self.clusters.draw(tracks.draw(img, t), t)) for t, img in self.renderer.add(packet)]
        self.frames += len(got)
        return got

    def _new_renderer(self, sensor: tuple[int, int]) -> Renderer:
        return Renderer(sensor, self.fps, self.mode, self.tau_us, flow_max_px_s=self.flow_max_px_s)


class VideoSink(_Rendering):
    """A video of the events at ``fps`` frames per second of event time
    (``mode`` polarity or time_surface, ``tau_us`` decay), or of the frames
    of a frames stream, one picture each (``frames``: by default when no
    events come, as after a ``repr.*`` operator). ``.mp4`` is
    written with the mp4v codec, ``.avi`` with MJPG; the file appears
    (atomically) when the run ends well."""

    name = "video"
    extensions = (".mp4", ".avi")

    def __init__(self, path: str, fps: float = 30.0, mode: Mode = "polarity", tau_us: float = 30_000.0,
                 frames: bool | None = None) -> None:
        super().__init__(fps, mode, tau_us, frames=frames)
        self.path = path
        self._writer: cv2.VideoWriter | None = None
        self._tmp: str | None = None
        self._size: tuple[int, ...] = ()

    def write(self, packet: Packet) -> None:
        for _t, img in self._frames(packet):
            if self._writer is None:
                ext = os.path.splitext(self.path)[1].lower()
                fd, self._tmp = temp_beside(self.path, ext)
                os.close(fd)
                fourcc = cv2.VideoWriter.fourcc(*("mp4v" if ext == ".mp4" else "MJPG"))
                h, w = img.shape[:2]
                self._writer = cv2.VideoWriter(self._tmp, fourcc, self.fps, (w, h))
                if not self._writer.isOpened():
                    raise OSError(f"OpenCV cannot write {ext} video here (codec missing)")
                self._size = img.shape
            elif img.shape != self._size:
                raise ValueError(f"video {self.path}: a frame of {img.shape[1]}x{img.shape[0]} px after frames of "
                                 f"{self._size[1]}x{self._size[0]} (events and maps, or maps of different sizes, "
                                 "cannot share one video)")
            self._writer.write(img)

    def close(self) -> None:
        if self._writer is not None:
            self._writer.release()
            self._writer = None
            assert self._tmp is not None
            os.replace(self._tmp, self.path)
            self._tmp = None

    def abort(self) -> None:
        if self._writer is not None:
            self._writer.release()
            self._writer = None
        if self._tmp and os.path.exists(self._tmp):
            os.remove(self._tmp)
        self._tmp = None


class PngSink(_Rendering):
    """PNG snapshots: the last frame of the run (``out.png``; of a map
    stream, its last map), or every frame when the path holds a ``%d``
    pattern (``frames/f%05d.png``)."""

    name = "png"
    extensions = (".png",)

    def __init__(self, path: str, fps: float = 30.0, mode: Mode = "polarity", tau_us: float = 30_000.0,
                 frames: bool | None = None) -> None:
        super().__init__(fps, mode, tau_us, frames=frames)
        self.path = path
        self.every = "%" in path
        self._n = 0
        self._last: np.ndarray | None = None

    def write(self, packet: Packet) -> None:
        for _t, img in self._frames(packet):
            if self.every:
                _write_png(self.path % self._n, img)
                self._n += 1
            self._last = img

    def close(self) -> None:
        if not self.every:
            img = self._last
            if img is None and self.renderer is not None:
                img = self.renderer.render(self.renderer.next_t or 0)
            if img is not None:
                _write_png(self.path, img)


def _write_png(path: str, img: np.ndarray) -> None:
    ok, buf = cv2.imencode(".png", img)
    if not ok:
        raise OSError("PNG encoding failed")
    tmp = path + ".tmp"
    with open(tmp, "wb") as f:
        f.write(buf.tobytes())
    os.replace(tmp, path)


class FrameCallbackSink(_Rendering):
    """Calls ``callback(t_us, image)`` for each rendered frame (BGR uint8,
    (H, W, 3)), in the pipeline's thread: for applications that draw
    themselves. Python API only: ``p.sink(FrameCallbackSink(fn), node)``."""

    name = "frame_callback"

    def __init__(self, callback: Callable[[int, np.ndarray], None], fps: float = 30.0,
                 mode: Mode = "polarity", tau_us: float = 30_000.0, frames: bool | None = None) -> None:
        super().__init__(fps, mode, tau_us, frames=frames)
        self.callback = callback

    def write(self, packet: Packet) -> None:
        for t, img in self._frames(packet):
            self.callback(t, img)
