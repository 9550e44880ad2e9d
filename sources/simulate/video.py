"""Video and image sequences as a scene: frames up-sampled in time by
interpolation in log space (v2e-style, no learned interpolation).

Between two frames at ``t_a`` and ``t_b`` a pixel's log intensity is
``L(t) = (1 - a) L_a + a L_b``, ``a = (t - t_a) / (t_b - t_a)``, with
``L = log(I + eps)`` (the sensor's ``eps``); the rendered linear intensity is
``exp(L(t)) - eps``. Since ``L`` is then linear in time between frames, and
the simulator never steps across a frame time, the DVS model's crossings
are exact for this interpolation. Before the first frame the first is held,
after the last the last.

``video`` scene keys: ``path`` (a video file read with ``cv2.VideoCapture``,
a folder of images in name order, or an image list ``images.txt`` of lines
``t_seconds path`` as in the UZH event-camera dataset; a folder holding an
``images.txt`` uses it), ``fps`` (frames per second: overrides the
container's rate; required for a bare folder), ``gamma`` (intensity =
(DN / 255) ** gamma; default 1: pixel values taken as linear), ``start_frame``
(frames skipped at the start). The sensor is the frames' size unless the
scene's ``sensor`` asks for another (frames are resized, area-averaged).
Frames are read lazily and forgotten once behind the released windows, so
memory stays bounded.
"""

from __future__ import annotations

import bisect
import os
from collections.abc import Iterator, Mapping
from typing import Any

import cv2
import numpy as np
from numba import njit

__all__ = ["VIDEO_EXTENSIONS", "is_video_spec", "FrameReader", "VideoLayer"]

VIDEO_EXTENSIONS = (".mp4", ".avi", ".mov", ".mkv", ".webm", ".m4v", ".mpg", ".mpeg", ".wmv", ".gif")
IMAGE_EXTENSIONS = (".png", ".jpg", ".jpeg", ".bmp", ".tif", ".tiff", ".pgm", ".ppm", ".webp")
_KEYS = {"path", "fps", "gamma", "start_frame"}


def is_video_spec(text: str) -> bool:
    """Whether a scene argument names a video, an image folder or an image list."""
    low = text.lower()
    if os.path.isdir(text):
        return True
    return os.path.isfile(text) and (low.endswith(VIDEO_EXTENSIONS) or low.endswith(".txt"))


def _image_list(path: str) -> tuple[list[float], list[str]]:
    """``(t_seconds, paths)`` from an images.txt (``t path`` per line, ``#`` comments)."""
    base = os.path.dirname(path)
    ts: list[float] = []
    files: list[str] = []
    with open(path, encoding="utf-8") as f:
        for lineno, line in enumerate(f, 1):
            line = line.strip()
            if not line or line.startswith("#"):
                continue
            parts = line.split()
            if len(parts) < 2:
                raise ValueError(f"{path}:{lineno}: expected 'timestamp path', got {line!r}")
            try:
                t = float(parts[0])
            except ValueError:
                raise ValueError(f"{path}:{lineno}: bad timestamp {parts[0]!r}") from None
            if ts and t < ts[-1]:
                raise ValueError(f"{path}:{lineno}: timestamp {t} goes back in time")
            ts.append(t)
            files.append(os.path.join(base, parts[1]))
    if not files:
        raise ValueError(f"{path}: no images listed")
    return ts, files


class FrameReader:
    """Frames of a video file, an image folder or an image list, in order:
    iterate for ``(t_us, intensity)`` with ``intensity`` float64 (h, w), 1 =
    full scale, ``t_us`` from 0 at the first frame (see the module doc for
    the parameters). ``size`` is the output ``(w, h)``; ``duration_us`` the
    last frame's time (from the container's frame count for video files)."""

    def __init__(self, path: str, fps: float = 0.0, gamma: float = 1.0, start_frame: int = 0,
                 size: tuple[int, int] | None = None) -> None:
        self.path, self.gamma, self.start = str(path), float(gamma), int(start_frame)
        self._files: list[str] | None = None
        self._times: list[float] | None = None
        if os.path.isdir(self.path):
            lst = os.path.join(self.path, "images.txt")
            if os.path.isfile(lst):
                self._times, self._files = _image_list(lst)
            else:
                self._files = sorted(os.path.join(self.path, n) for n in os.listdir(self.path)
                                     if n.lower().endswith(IMAGE_EXTENSIONS))
                if not self._files:
                    raise ValueError(f"{self.path}: no images ({', '.join(IMAGE_EXTENSIONS)}) in the folder")
        elif self.path.lower().endswith(".txt"):
            self._times, self._files = _image_list(self.path)
        if self._times is not None and fps <= 0:
            t0 = self._times[self.start] if self.start < len(self._times) else 0.0
            self._us: list[float] | None = [(t - t0) * 1e6 for t in self._times[self.start:]]
            n_frames = len(self._us)
        else:
            if self._files is None:
                cap = cv2.VideoCapture(self.path)
                if not cap.isOpened():
                    raise ValueError(f"{self.path}: cv2.VideoCapture cannot open it")
                fps = fps if fps > 0 else float(cap.get(cv2.CAP_PROP_FPS) or 0.0)
                n_frames = max(int(cap.get(cv2.CAP_PROP_FRAME_COUNT) or 0) - self.start, 1)
                cap.release()
            else:
                n_frames = len(self._files) - self.start
            if fps <= 0:
                raise ValueError(f"{self.path}: no frame rate known: give the scene's video.fps")
            self._us = None
            self.fps = float(fps)
        if n_frames < 1:
            raise ValueError(f"{self.path}: no frames after start_frame={self.start}")
        first = next(iter(self._raw()), None)
        if first is None:
            raise ValueError(f"{self.path}: no frame could be read")
        h0, w0 = first.shape
        self.native_size = (w0, h0)
        self.size = (int(size[0]), int(size[1])) if size is not None else (w0, h0)
        self.duration_us = self._time(n_frames - 1)

    def _time(self, k: int) -> float:
        return self._us[k] if self._us is not None else k / self.fps * 1e6

    def _raw(self) -> Iterator[np.ndarray]:
        """Grey frames (uint8 or uint16, h x w) after ``start_frame``."""
        if self._files is not None:
            for fn in self._files[self.start:]:
                img = cv2.imread(fn, cv2.IMREAD_UNCHANGED)
                if img is None:
                    raise ValueError(f"{fn}: cannot read the image")
                yield _grey(img)
            return
        cap = cv2.VideoCapture(self.path)
        try:
            k = 0
            while True:
                ok, img = cap.read()
                if not ok:
                    return
                if k >= self.start:
                    yield _grey(img)
                k += 1
        finally:
            cap.release()

    def __iter__(self) -> Iterator[tuple[float, np.ndarray]]:
        w, h = self.size
        for k, img in enumerate(self._raw()):
            if self._us is not None and k >= len(self._us):
                return
            full = 65535.0 if img.dtype == np.uint16 else 255.0
            if (img.shape[1], img.shape[0]) != (w, h):
                img = cv2.resize(img.astype(np.float32), (w, h), interpolation=cv2.INTER_AREA)
            x = np.asarray(img, np.float64) / full
            if self.gamma != 1.0:
                x = x ** self.gamma
            yield self._time(k), x


def _grey(img: np.ndarray) -> np.ndarray:
    if img.ndim == 3 and img.shape[2] == 4:
        return cv2.cvtColor(img, cv2.COLOR_BGRA2GRAY)
    if img.ndim == 3:
        return cv2.cvtColor(img, cv2.COLOR_BGR2GRAY)
    return img


@njit(cache=True)
def _lerp_log(La: np.ndarray, Lb: np.ndarray, a: float, eps: float, out: np.ndarray) -> None:
    """``out = exp((1 - a) La + a Lb) - eps`` element by element."""
    for i in range(out.shape[0]):
        out[i] = np.exp((1.0 - a) * La[i] + a * Lb[i]) - eps


class VideoLayer:
    """The frames of a :class:`FrameReader` as a function of time, with
    the frames read lazily (see the module doc)."""

    def __init__(self, reader: FrameReader, eps: float) -> None:
        self.reader, self.eps = reader, float(eps)
        self._it = iter(reader)
        self._t: list[float] = []
        self._L: list[np.ndarray] = []
        self._done = False
        self._read()
        if not self._t:
            raise ValueError(f"{reader.path}: no frame could be read")

    def _read(self) -> bool:
        if self._done:
            return False
        nxt = next(self._it, None)
        if nxt is None:
            self._done = True
            return False
        t, img = nxt
        self._t.append(float(t))
        self._L.append(np.log(np.maximum(img, 0.0) + self.eps).ravel())
        return True

    def _cover(self, t_us: float) -> None:
        while self._t[-1] <= t_us and self._read():
            pass

    def next_frame_after(self, t_us: float) -> float:
        """The first frame time after ``t_us`` (µs), or inf past the last."""
        self._cover(t_us)
        k = bisect.bisect_right(self._t, t_us)
        return self._t[k] if k < len(self._t) else float("inf")

    def render(self, t_us: float, out: np.ndarray) -> None:
        """Write the linear intensity at ``t_us`` into ``out`` (h, w)."""
        self._cover(t_us)
        k = bisect.bisect_right(self._t, t_us) - 1
        flat = out.reshape(-1)
        if k < 0:
            k, a = 0, 0.0
        if k >= len(self._t) - 1:
            _lerp_log(self._L[-1], self._L[-1], 0.0, self.eps, flat)
            return
        a = (t_us - self._t[k]) / (self._t[k + 1] - self._t[k])
        _lerp_log(self._L[k], self._L[k + 1], a, self.eps, flat)

    def forget_before(self, t_us: float) -> None:
        """Drop frames no longer needed for times >= ``t_us``."""
        k = bisect.bisect_right(self._t, t_us) - 1
        if k > 0:
            del self._t[:k], self._L[:k]


def video_spec(spec: Mapping[str, Any] | str) -> dict[str, Any]:
    """A validated ``video`` scene section."""
    d = {"path": spec} if isinstance(spec, str) else dict(spec)
    bad = set(d) - _KEYS
    if bad:
        raise ValueError(f"unknown video keys {sorted(bad)}; known: {sorted(_KEYS)}")
    if "path" not in d:
        raise ValueError("the video section needs a path")
    return d
