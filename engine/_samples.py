"""Typed sample streams: every non-event packet kind declares its fields.

A sample packet is ``t`` (int64 µs, one per sample, sorted) plus named
arrays whose first axis runs over the samples. Each kind lists its fields
as :class:`Field` records (dtype, trailing shape of one sample, unit,
optional or not), so that empty packets, concatenation, merging and slicing
are right for every stream, including its first and its empty packets:

* a required field must be present; an optional one may be absent from a
  packet; a field the kind does not declare may be added (an extra column,
  as on events) and keeps whatever dtype and shape it came with;
* a declared dtype is enforced (values are converted within their kind:
  int to int, float to float, int to float; anything else, NaN times
  included, is a :class:`PacketError`); a ``None`` dtype means "any numeric
  dtype, the same through a stream" (frames: uint8, uint16, float32);
* when packets of one stream are joined and an optional float field is
  present in some and absent from others, the missing rows are NaN (stated,
  not invented: NaN is "not measured"); an optional non-float field present
  in only some packets cannot be joined and raises :class:`PacketError`.

Plugins add kinds: subclass :class:`SamplePacket`, set ``kind =
Kind("name")`` and ``fields``, and register the class
(:func:`tectum.register_kind` or the ``tectum_register_kinds`` hook).
"""

from __future__ import annotations

from collections.abc import Mapping, Sequence
from dataclasses import dataclass
from types import MappingProxyType
from typing import Any, ClassVar

import numpy as np

from ._packet import Kind, Packet, as_times, builder, register_kind
from .errors import PacketError

__all__ = [
    "Field",
    "SamplePacket",
    "FramePacket",
    "ImuPacket",
    "PosePacket",
    "TriggerPacket",
    "ResultPacket",
    "AngularVelocityPacket",
    "TrackPacket",
    "ClusterPacket",
    "MapPacket",
    "PointPacket",
]


@dataclass(frozen=True)
class Field:
    """One field of a sample kind.

    dtype:
        numpy dtype string (``"f8"``, ``"i8"``, ``"O"``), or None for any
        numeric dtype (fixed within a stream).
    shape:
        Trailing shape of one sample: ``()`` a scalar, ``(3,)`` a vector,
        ``(None, None)`` an image of any size; ``None`` for any shape.
    unit:
        Unit of the values (``"rad/s"``, ``"m"``, ``"px"``, ``"µs"``), for
        docs, CSV headers and ``tectum plugins``.
    optional:
        May be absent from a packet.
    names:
        Column names of a ``(k,)`` field in text files (``("wx", "wy", "wz")``).
    doc:
        One line saying what the field holds.
    """

    dtype: str | None = "f8"
    shape: tuple[int | None, ...] | None = ()
    unit: str = ""
    optional: bool = False
    names: tuple[str, ...] = ()
    doc: str = ""

    def columns(self, name: str) -> tuple[str, ...]:
        """Column names of this field in a flat table (CSV): the field's own
        name for a scalar, ``names`` (or ``name_0``, ``name_1``...) for a vector."""
        if self.shape == ():
            return (name,)
        if self.names:
            return self.names
        if self.shape is not None and len(self.shape) == 1 and self.shape[0] is not None:
            return tuple(f"{name}_{i}" for i in range(self.shape[0]))
        raise ValueError(f"field {name!r} of shape {self.shape} has no flat columns")


def _field_array(cls: type, name: str, value: Any, spec: Field | None, n: int) -> np.ndarray:
    arr = value if isinstance(value, np.ndarray) else np.asarray(value)
    where = f"{cls.__name__} field {name!r}"
    if arr.ndim == 0 or arr.shape[0] != n:
        raise PacketError(f"{where} has shape {arr.shape}, expected {n} rows")
    if spec is None:
        return arr
    if spec.dtype is not None and arr.dtype != np.dtype(spec.dtype):
        want = np.dtype(spec.dtype)
        if want.kind == "O":
            raise PacketError(f"{where} must be an object array, got {arr.dtype}")
        if not np.can_cast(arr.dtype, want, "same_kind"):
            raise PacketError(f"{where} must be {want}, got {arr.dtype}")
        arr = arr.astype(want)
    elif spec.dtype is None and arr.dtype.kind not in "biuf":
        raise PacketError(f"{where} must be numeric, got {arr.dtype}")
    if spec.shape is not None:
        tail = arr.shape[1:]
        if len(tail) != len(spec.shape) or any(w is not None and w != g for w, g in zip(spec.shape, tail)):
            shown = tuple("any" if w is None else w for w in spec.shape)
            raise PacketError(f"{where} has samples of shape {tail}, expected {shown}")
    return arr


class SamplePacket(Packet):
    """Timestamped samples of one kind: ``t`` (int64 µs) plus named arrays
    whose first axis runs over the samples. Subclasses set ``kind`` and
    declare ``fields``; read a field as an attribute (``pkt.gyro``) or by
    name (``pkt["gyro"]``)."""

    __slots__ = ("t", "data")
    fields: ClassVar[Mapping[str, Field]] = MappingProxyType({})
    data: Mapping[str, np.ndarray]

    def __init__(self, t: Any, *, t_start: int | None = None, t_end: int | None = None, **data: Any) -> None:
        t = as_times(t)
        if t.ndim != 1:
            raise PacketError("'t' must be 1-D")
        fields = self.fields
        missing = [f for f, spec in fields.items() if not spec.optional and f not in data]
        if missing:
            raise PacketError(f"{type(self).__name__} needs fields {missing}")
        n = t.shape[0]
        cols = {name: _field_array(type(self), name, a, fields.get(name), n) for name, a in data.items()}
        object.__setattr__(self, "t", t)
        object.__setattr__(self, "data", MappingProxyType(cols))
        self._init_interval(t, t_start, t_end)
        self._check_times()

    @classmethod
    def _trusted(cls, t: np.ndarray, data: Mapping[str, np.ndarray], t_start: int, t_end: int) -> SamplePacket:
        """Internal: build from arrays known to satisfy the contract (views
        of a valid packet, or arrays an operator made of the declared dtypes
        and shapes). Skips the checks, not the copy of ``data``'s mapping
        (the packet owns its mapping; a mapping proxy, already read-only, is
        kept as it is). Built as :func:`tectum._packet._built` builds events:
        a mutable twin of the class (:func:`tectum._packet.builder`), plain stores, then
        the class swapped (~0.5 µs a packet instead of ~1)."""
        pkt: Any = builder(cls)()
        pkt.t = t
        pkt.data = data if type(data) is MappingProxyType else MappingProxyType(dict(data))
        pkt.t_start = int(t_start)
        pkt.t_end = int(t_end)
        pkt.__class__ = cls
        return pkt

    def __getattr__(self, name: str) -> np.ndarray:
        try:
            return object.__getattribute__(self, "data")[name]
        except KeyError:
            raise AttributeError(f"{type(self).__name__} has no field {name!r}") from None

    def __getitem__(self, name: str) -> np.ndarray:
        """A column by name: ``t`` or a field."""
        return self.t if name == "t" else self.data[name]

    @property
    def column_names(self) -> tuple[str, ...]:
        return ("t", *self.data)

    def validate(self) -> SamplePacket:
        """Check the contract (times in order inside the interval, one row
        per sample in every field, declared dtypes and shapes); raises
        :class:`PacketError`, returns self."""
        self._check_times()
        for name, a in self.data.items():
            _field_array(type(self), name, a, self.fields.get(name), self.t.shape[0])
        return self

    @classmethod
    def empty(cls, t_start: int, t_end: int | None = None, *, like: SamplePacket | None = None,
              **shapes: tuple[int, ...]) -> SamplePacket:
        """An empty packet (a tick) of this kind covering ``[t_start, t_end)``
        µs. Its fields have no rows; dtype and trailing shape come from
        ``like`` (another packet of the stream), else from the declaration
        (sizes it leaves open are 0 unless given by name: ``images=(260, 346)``)."""
        if like is not None:
            data = {f: a[:0] for f, a in like.data.items()}
        else:
            data = {}
            for f, spec in cls.fields.items():
                if spec.optional:
                    continue
                shape = shapes.get(f) or tuple(0 if w is None else w for w in (spec.shape or ()))
                data[f] = np.empty((0, *shape), dtype=spec.dtype or np.float64)
        t1 = t_start if t_end is None else t_end
        return cls._trusted(np.empty(0, np.int64), data, int(t_start), int(max(t1, t_start)))

    def _take_slice(self, i: int, j: int, t_start: int, t_end: int) -> SamplePacket:
        return self._trusted(self.t[i:j], {k: v[i:j] for k, v in self.data.items()}, t_start, t_end)

    def take(self, idx: np.ndarray) -> SamplePacket:
        """The samples at the increasing indices ``idx`` (a copy), same interval."""
        return self._trusted(self.t[idx], {k: v[idx] for k, v in self.data.items()}, self.t_start, self.t_end)

    def with_interval(self, t_start: int, t_end: int) -> SamplePacket:
        """The same samples with another interval (checked)."""
        pkt = self._trusted(self.t, self.data, t_start, t_end)
        if t_end < t_start:
            raise PacketError(f"interval [{t_start}, {t_end}) ends before it starts")
        pkt._check_times()
        return pkt

    def with_fields(self, **fields: Any) -> SamplePacket:
        """A new packet sharing every array, with these fields added or replaced."""
        data = dict(self.data)
        data.update(fields)
        return type(self)(self.t, t_start=self.t_start, t_end=self.t_end, **data)

    def __repr__(self) -> str:
        return (f"{type(self).__name__}({len(self)} samples, [{self.t_start}, {self.t_end}) µs, "
                f"fields={list(self.data)})")


def _fields(**fields: Field) -> Mapping[str, Field]:
    return MappingProxyType(fields)


_XYZ = ("x", "y", "z")


@register_kind
class FramePacket(SamplePacket):
    """Intensity frames (e.g. DAVIS APS): ``images`` is (N, H, W) or
    (N, H, W, C) in the sensor's units; ``t`` is each frame's timestamp in µs
    (mid-exposure unless said otherwise)."""

    kind = Kind.FRAMES
    fields = _fields(
        images=Field(None, None, "sensor units", doc="one image per sample, (H, W) or (H, W, C)"),
        exposure_start=Field("i8", (), "µs", optional=True, doc="start of exposure"),
        exposure_end=Field("i8", (), "µs", optional=True, doc="end of exposure"),
    )


@register_kind
class ImuPacket(SamplePacket):
    """IMU samples in the camera frame (OpenCV axes: x right, y down, z forward)."""

    kind = Kind.IMU
    fields = _fields(
        accel=Field("f8", (3,), "m/s²", names=("ax", "ay", "az"), doc="linear acceleration"),
        gyro=Field("f8", (3,), "rad/s", names=("gx", "gy", "gz"), doc="angular velocity"),
        temperature=Field("f8", (), "°C", optional=True, doc="sensor temperature"),
    )


@register_kind
class PosePacket(SamplePacket):
    """Poses, world-from-camera: ``position`` in metres, ``orientation`` a
    unit quaternion (x, y, z, w); optional velocities (linear in the world
    frame, angular in the camera frame) and ``lost`` (a tracker's flag: the
    row is a prediction, not a measurement)."""

    kind = Kind.POSES
    fields = _fields(
        position=Field("f8", (3,), "m", names=("tx", "ty", "tz"), doc="camera centre in the world"),
        orientation=Field("f8", (4,), "", names=("qx", "qy", "qz", "qw"), doc="world-from-camera rotation"),
        linear_velocity=Field("f8", (3,), "m/s", optional=True, names=("vx", "vy", "vz"), doc="world frame"),
        angular_velocity=Field("f8", (3,), "rad/s", optional=True, names=("wx", "wy", "wz"), doc="camera frame"),
        lost=Field("bool", (), "", optional=True,
                   doc="tracking lost: this pose is a prediction, not a measurement"),
    )


@register_kind
class TriggerPacket(SamplePacket):
    """External trigger / special events: ``channel`` (the input or trigger
    id of the format) and ``value`` (1 rising edge, 0 falling edge, or the
    format's own code), one per timestamp in µs."""

    kind = Kind.TRIGGERS
    fields = _fields(
        channel=Field("i8", (), "", doc="trigger input or code of the format"),
        value=Field("i8", (), "", doc="1 rising, 0 falling, or the format's code"),
    )


@register_kind
class AngularVelocityPacket(SamplePacket):
    """Camera angular velocity (rad/s, camera frame, OpenCV axes) estimated
    over a window ending at ``t``, with a confidence in [0, 1] and the
    number of events the estimate used."""

    kind = Kind.ANGULAR_VELOCITY
    fields = _fields(
        wx=Field("f8", (), "rad/s", doc="about the camera x axis (right)"),
        wy=Field("f8", (), "rad/s", doc="about the camera y axis (down)"),
        wz=Field("f8", (), "rad/s", doc="about the camera z axis (forward)"),
        confidence=Field("f8", (), "", optional=True, doc="0 (none) to 1"),
        events=Field("i8", (), "events", optional=True, doc="events in the window"),
    )


@register_kind
class TrackPacket(SamplePacket):
    """Feature or marker tracks: one row per track update at ``t``."""

    kind = Kind.TRACKS
    fields = _fields(
        id=Field("i8", (), "", doc="track id, unique within a stream"),
        x=Field("f8", (), "px", doc="column, sub-pixel, origin top-left"),
        y=Field("f8", (), "px", doc="row, sub-pixel, origin top-left"),
        quality=Field("f8", (), "", optional=True, doc="the tracker's confidence, higher is better"),
    )


@register_kind
class ClusterPacket(SamplePacket):
    """Moving-object clusters: one row per cluster update at ``t``."""

    kind = Kind.CLUSTERS
    fields = _fields(
        id=Field("i8", (), "", doc="cluster id"),
        x=Field("f8", (), "px", doc="centre column"),
        y=Field("f8", (), "px", doc="centre row"),
        vx=Field("f8", (), "px/s", optional=True, doc="velocity, x"),
        vy=Field("f8", (), "px/s", optional=True, doc="velocity, y"),
        radius=Field("f8", (), "px", optional=True, doc="size"),
        mass=Field("f8", (), "events", optional=True, doc="decaying event count"),
        width=Field("f8", (), "px", optional=True, doc="extent along x"),
        height=Field("f8", (), "px", optional=True, doc="extent along y"),
    )


@register_kind
class MapPacket(SamplePacket):
    """Maps: a log-intensity image and/or a depth map per sample, with a
    confidence, the intrinsics and the reference pose they are seen from
    (``pose`` = tx ty tz qx qy qz qw, world-from-camera)."""

    kind = Kind.MAPS
    fields = _fields(
        image=Field("f4", (None, None), "log intensity", optional=True, doc="log-intensity image"),
        depth=Field("f4", (None, None), "m", optional=True, doc="depth, NaN where unknown"),
        confidence=Field("f4", (None, None), "", optional=True, doc="per-pixel confidence"),
        K=Field("f8", (3, 3), "px", optional=True, doc="intrinsics of the map's view"),
        pose=Field("f8", (7,), "m, quaternion", optional=True, names=("tx", "ty", "tz", "qx", "qy", "qz", "qw"),
                   doc="reference pose, world-from-camera"),
    )


@register_kind
class PointPacket(SamplePacket):
    """3-D points (a point cloud: the rows sharing one ``t`` form one cloud)."""

    kind = Kind.POINTS
    fields = _fields(
        position=Field("f8", (3,), "m", names=_XYZ, doc="point in the world frame"),
        intensity=Field("f4", (), "", optional=True, doc="brightness or confidence"),
    )


@register_kind
class ResultPacket(SamplePacket):
    """Escape hatch for results no typed kind fits: ``items`` is an object
    array, one item per timestamp. No file or network sink writes it; prefer
    a typed kind (register your own with :func:`tectum.register_kind`)."""

    kind = Kind.RESULTS
    fields = _fields(items=Field("O", (), doc="any Python object"))

    def __init__(self, t: Any, items: Sequence[Any] | np.ndarray = (), **kw: Any) -> None:
        if not isinstance(items, np.ndarray) or items.dtype != object:
            arr = np.empty(len(items), dtype=object)
            for i, it in enumerate(items):
                arr[i] = it
            items = arr
        super().__init__(t, items=items, **kw)
