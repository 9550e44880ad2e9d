"""Sample streams as flat tables in files: what the file readers and writers
of sample streams share (CSV, TUM poses, PLY point clouds).

* **Column layout.** A sample kind's fields map onto named columns:
  ``t`` first, then every field present in declaration order, a scalar as
  one column named after it, a ``(k,)`` vector as ``Field.columns`` names it
  (``accel`` -> ``ax, ay, az``), then undeclared extra fields the same way
  (``name_0``, ``name_1`` ... for a vector). :func:`layout` gives it for a
  packet, :func:`header_layout` reads it back from a header row, and
  :func:`kinds_for_header` says which registered kinds a header fits.
* **Kind line.** Tectum's CSV files start with ``# tectum KIND`` followed by
  the dtypes of the extra fields (``# tectum tracks score=float32
  v=float64[3]``), so undeclared fields come back with their dtype.
* **Exact numbers.** :func:`us_text` prints integer µs as a decimal in a
  coarser unit (seconds: ``12.000034``) and :func:`parse_us` reads such a
  decimal back into integer µs with integer arithmetic (never through a
  float; digits below 1 µs round half up, on the magnitude); :func:`float_text`
  prints a float with the fewest digits that read back to the same float64.
* **Poses.** :func:`pose_problem` says why a row of a pose table is no
  pose: a non-finite number or a quaternion whose norm is off 1 by more
  than :data:`QUATERNION_TOLERANCE`.
* **PLY.** :func:`ply_header` writes a header with one ``vertex`` element,
  :func:`parse_ply_header` reads any PLY header (ASCII or binary, every
  element and property type, list properties).
"""

from __future__ import annotations

import math
import re
from collections.abc import Iterable, Mapping, Sequence
from dataclasses import dataclass
from typing import IO

import numpy as np

from ._packet import Kind, packet_class
from ._samples import ResultPacket, SamplePacket

__all__ = ["Group", "layout", "header_layout", "kinds_for_header", "flat_kinds", "kind_line", "parse_kind_line",
           "us_text", "parse_us", "float_text", "pose_problem", "QUATERNION_TOLERANCE", "PlyElement", "PlyHeader",
           "PLY_TYPES", "ply_header", "parse_ply_header"]

#: How far the norm of a pose's quaternion may be from 1.
QUATERNION_TOLERANCE = 1e-3


@dataclass(frozen=True)
class Group:
    """The columns of one field: ``columns`` names them in file order;
    ``dtype`` and ``width`` (None for a scalar, k for a ``(k,)`` vector)
    give the field's array."""

    field: str
    columns: tuple[str, ...]
    dtype: np.dtype
    width: int | None

    @property
    def extra_text(self) -> str:
        """``name=dtype`` or ``name=dtype[k]`` for the kind line."""
        return f"{self.field}={self.dtype.name}" + ("" if self.width is None else f"[{self.width}]")


def _columns(cls: type[SamplePacket], name: str, width: int | None) -> tuple[str, ...]:
    spec = cls.fields.get(name)
    if spec is not None:
        return spec.columns(name)
    return (name,) if width is None else tuple(f"{name}_{i}" for i in range(width))


def layout(cls: type[SamplePacket], data: Mapping[str, np.ndarray]) -> list[Group]:
    """The column groups of ``data`` (a packet's fields): declared fields in
    declaration order, then undeclared ones in their order. Raises
    ValueError for a field that is no scalar and no vector (an image)."""
    names = [f for f in cls.fields if f in data] + [f for f in data if f not in cls.fields]
    out = []
    for name in names:
        a = data[name]
        if a.ndim == 1:
            width = None
        elif a.ndim == 2:
            width = a.shape[1]
        else:
            raise ValueError(f"{cls.__name__} field {name!r} holds arrays of shape {a.shape[1:]}: a table has "
                             "only scalar and vector columns (write images and maps to .npz)")
        if a.dtype.kind not in "biuf":
            raise ValueError(f"{cls.__name__} field {name!r} is {a.dtype}, not numbers")
        cols = _columns(cls, name, width)
        if len(cols) != (1 if width is None else width):
            raise ValueError(f"{cls.__name__} field {name!r} has {width} values per sample, its columns are {cols}")
        out.append(Group(name, cols, a.dtype, width))
    return out


def header_layout(cls: type[SamplePacket], header: Sequence[str],
                  extras: Mapping[str, tuple[np.dtype, int | None]] | None = None) -> list[Group]:
    """The groups a header row (``t`` first) holds for kind ``cls``: the
    declared fields whose columns are all there (in declaration order),
    then the other columns as extra fields (typed by ``extras``, from the
    kind line, else float64 scalars). ValueError when a required field is
    missing, a field is there in part, or a name repeats."""
    if not header or header[0] != "t":
        raise ValueError(f"the first column must be 't' (µs), got {header[0] if header else 'nothing'!r}")
    names = list(header[1:])
    if len(set(names)) != len(names) or "t" in names:
        raise ValueError(f"column names repeat: {list(header)}")
    left = set(names)
    out = []
    for name, spec in cls.fields.items():
        try:
            cols = spec.columns(name)
        except ValueError:
            cols = ()
        have = [c for c in cols if c in left]
        if cols and len(have) == len(cols):
            width = None if spec.shape == () else len(cols)
            out.append(Group(name, cols, np.dtype(spec.dtype or "f8"), width))
            left -= set(cols)
        elif have:
            raise ValueError(f"{cls.kind} field {name!r} needs columns {list(cols)}, the header has only {have}")
        elif not spec.optional:
            raise ValueError(f"{cls.kind} needs field {name!r} (columns {list(cols) or 'none: not a table'})")
    extras = dict(extras or {})
    for name, (dtype, width) in extras.items():
        cols = _columns(cls, name, width)
        if not set(cols) <= left:
            raise ValueError(f"the kind line declares field {name!r} but the header lacks its columns {list(cols)}")
        out.append(Group(name, cols, dtype, width))
        left -= set(cols)
    out.extend(Group(c, (c,), np.dtype(np.float64), None) for c in names if c in left)
    return out


def flat_kinds() -> list[Kind]:
    """Registered sample kinds whose fields, optional ones too, all fit in
    a table (scalars and vectors): not frames, nor maps (whose fields are
    all optional images)."""
    out = []
    for k in Kind:
        cls = packet_class(k)
        if not issubclass(cls, SamplePacket) or cls is ResultPacket:
            continue
        try:
            for name, spec in cls.fields.items():
                spec.columns(name)
        except ValueError:
            continue
        out.append(k)
    return out


def kinds_for_header(header: Sequence[str]) -> list[Kind]:
    """The flat kinds whose declared columns hold exactly this header
    (``t`` first, every required field, nothing undeclared)."""
    out = []
    for k in flat_kinds():
        cls = packet_class(k)
        try:
            groups = header_layout(cls, header)  # type: ignore[arg-type]
        except ValueError:
            continue
        if all(g.field in cls.fields for g in groups):  # type: ignore[attr-defined]
            out.append(k)
    return out


_KIND_LINE = "# tectum "
_EXTRA = re.compile(r"^([A-Za-z_][A-Za-z0-9_]*)=([a-z0-9]+)(?:\[(\d+)\])?$")


def kind_line(kind: str, groups: Iterable[Group], cls: type[SamplePacket]) -> str:
    """``# tectum KIND`` and the dtypes of the undeclared fields in ``groups``."""
    extras = [g.extra_text for g in groups if g.field not in cls.fields]
    return " ".join([_KIND_LINE + str(kind), *extras])


def parse_kind_line(line: str) -> tuple[str, dict[str, tuple[np.dtype, int | None]]] | None:
    """``(kind, extras)`` from a ``# tectum KIND ...`` line, None for any
    other line; ValueError for an extra that is no ``name=dtype[k]``."""
    if not line.startswith(_KIND_LINE):
        return None
    words = line[len(_KIND_LINE):].split()
    if not words:
        raise ValueError("'# tectum' names no kind")
    extras: dict[str, tuple[np.dtype, int | None]] = {}
    for w in words[1:]:
        m = _EXTRA.match(w)
        if not m:
            raise ValueError(f"extra field {w!r} is not NAME=DTYPE or NAME=DTYPE[K]")
        try:
            dtype = np.dtype(m.group(2))
        except TypeError:
            raise ValueError(f"extra field {w!r}: {m.group(2)!r} is no numpy dtype") from None
        if dtype.kind not in "biuf":
            raise ValueError(f"extra field {w!r} is not numeric")
        extras[m.group(1)] = (dtype, None if m.group(3) is None else int(m.group(3)))
    return words[0], extras


def us_text(t: int, digits: int = 6) -> str:
    """Integer µs as a decimal in a unit of ``10**digits`` µs, exactly
    (``us_text(12_000_034) == "12.000034"``)."""
    t = int(t)
    if digits == 0:
        return str(t)
    sign = "-" if t < 0 else ""
    whole, frac = divmod(abs(t), 10**digits)
    return f"{sign}{whole}.{frac:0{digits}d}"


_DECIMAL = re.compile(rb"^\s*([+-]?)(\d*)(?:\.(\d*))?(?:[eE]([+-]?\d{1,4}))?\s*$")


def parse_us(text: bytes | str, digits: int = 6) -> int:
    """A decimal number in a unit of ``10**digits`` µs (seconds: 6) as
    integer µs, computed exactly from its digits (exponents allowed: ``1.4e9``).
    Digits below 1 µs round half up on the magnitude. ValueError for anything
    that is not a finite decimal number."""
    raw = text.encode("latin1") if isinstance(text, str) else bytes(text)
    m = _DECIMAL.match(raw)
    if not m or not (m.group(2) or m.group(3)):
        raise ValueError(f"{raw[:40]!r} is not a decimal number")
    frac = m.group(3) or b""
    mantissa = int((m.group(2) or b"0") + frac)
    shift = digits + int(m.group(4) or 0) - len(frac)  # value in µs = mantissa * 10**shift
    if shift >= 0:
        us = mantissa * 10**shift
    else:
        q, r = divmod(mantissa, 10**-shift)
        us = q + (1 if 2 * r >= 10**-shift else 0)
    if us >= 1 << 63:
        raise ValueError(f"{raw[:40]!r} is out of the int64 µs range")
    return -us if m.group(1) == b"-" else us


def float_text(x: float) -> str:
    """The shortest decimal that reads back to the same float64 (``repr``;
    ``nan``, ``inf``, ``-inf`` as Python spells them)."""
    return repr(float(x))


def pose_problem(position: Sequence[float], orientation: Sequence[float]) -> str | None:
    """Why one pose (``tx ty tz``, ``qx qy qz qw``) is none, or None: a
    number that is NaN or infinite, or a quaternion whose norm is off 1 by
    more than :data:`QUATERNION_TOLERANCE`."""
    if not all(math.isfinite(v) for v in (*position, *orientation)):
        return "a number is NaN or infinite"
    norm = math.sqrt(sum(v * v for v in orientation))
    if abs(norm - 1.0) > QUATERNION_TOLERANCE:
        return f"quaternion norm {norm:.6g} is not 1 (within {QUATERNION_TOLERANCE:g})"
    return None


# -- PLY ----------------------------------------------------------------------------------------------------------

#: PLY scalar type names (both spellings) and their numpy type characters.
PLY_TYPES = {"char": "i1", "uchar": "u1", "short": "i2", "ushort": "u2", "int": "i4", "uint": "u4", "float": "f4",
             "double": "f8", "int8": "i1", "uint8": "u1", "int16": "i2", "uint16": "u2", "int32": "i4",
             "uint32": "u4", "float32": "f4", "float64": "f8"}
_PLY_FORMATS = {"ascii": "", "binary_little_endian": "<", "binary_big_endian": ">"}


@dataclass(frozen=True)
class PlyElement:
    """One element of a PLY header: its name, row count and properties;
    a property is ``(name, type)`` or, for a list, ``(name, (count type,
    item type))`` (numpy type characters)."""

    name: str
    count: int
    properties: tuple[tuple[str, str | tuple[str, str]], ...]

    def dtype(self, order: str) -> np.dtype | None:
        """The packed record of one row (byte order ``<`` or ``>``), None
        when a list property makes rows vary in size."""
        if any(not isinstance(t, str) for _, t in self.properties):
            return None
        return np.dtype([(n, order + t) for n, t in self.properties])  # type: ignore[operator]


@dataclass(frozen=True)
class PlyHeader:
    """A parsed PLY header: ``format`` (``ascii``, ``binary_little_endian``,
    ``binary_big_endian``), the elements in file order, the comments and the
    header's size in bytes (where the data start)."""

    format: str
    elements: tuple[PlyElement, ...]
    comments: tuple[str, ...]
    size: int

    @property
    def byte_order(self) -> str:
        return _PLY_FORMATS[self.format]


def ply_header(binary: bool, count: int, properties: Sequence[tuple[str, str]], comments: Sequence[str] = (),
               size: int | None = None) -> bytes:
    """A PLY header with one ``vertex`` element of ``count`` rows and the
    scalar ``properties`` ``(name, PLY type)``, little-endian when binary.
    With ``size``, padded to exactly that many bytes by a last comment line
    (ValueError when it does not fit)."""
    lines = ["ply", "format " + ("binary_little_endian" if binary else "ascii") + " 1.0"]
    lines += [f"comment {c}" for c in comments]
    lines.append(f"element vertex {int(count)}")
    lines += [f"property {t} {n}" for n, t in properties]
    head = "\n".join(lines) + "\n"
    tail = "end_header\n"
    if size is None:
        return (head + tail).encode("ascii")
    pad = size - len(head) - len(tail) - len("comment \n")
    if pad < 0:
        raise ValueError(f"a PLY header of {len(head) + len(tail)} bytes does not fit in {size}")
    return (head + "comment " + " " * pad + "\n" + tail).encode("ascii")


def parse_ply_header(f: IO[bytes], limit: int = 1 << 16) -> PlyHeader:
    """Read a PLY header from the binary file ``f`` (left at the first data
    byte). ValueError naming the header line for anything malformed."""
    first = f.readline(16)
    if first.rstrip(b"\r\n") != b"ply":
        raise ValueError("not a PLY file (no 'ply' first line)")
    size = len(first)
    fmt: str | None = None
    elements: list[tuple[str, int, list[tuple[str, str | tuple[str, str]]]]] = []
    comments: list[str] = []
    line_no = 1
    while True:
        raw = f.readline(limit)
        line_no += 1
        size += len(raw)
        if not raw.endswith(b"\n") or size > limit:
            raise ValueError(f"header line {line_no}: the header does not end (no 'end_header' in {limit} bytes)")
        words = raw.decode("latin1").split()
        where = f"header line {line_no} ({raw.strip()[:60]!r})"
        if not words:
            continue
        key = words[0]
        if key == "end_header":
            break
        if key in ("comment", "obj_info"):
            comments.append(raw.decode("latin1").strip()[len(key) + 1:])
        elif key == "format":
            if len(words) != 3 or words[1] not in _PLY_FORMATS or words[2] != "1.0":
                raise ValueError(f"{where}: unknown format (ascii or binary_little/big_endian 1.0)")
            fmt = words[1]
        elif key == "element":
            if len(words) != 3 or not words[2].isdigit():
                raise ValueError(f"{where}: expected 'element NAME COUNT'")
            elements.append((words[1], int(words[2]), []))
        elif key == "property":
            if not elements:
                raise ValueError(f"{where}: a property before any element")
            if len(words) == 5 and words[1] == "list" and words[2] in PLY_TYPES and words[3] in PLY_TYPES:
                elements[-1][2].append((words[4], (PLY_TYPES[words[2]], PLY_TYPES[words[3]])))
            elif len(words) == 3 and words[1] in PLY_TYPES:
                elements[-1][2].append((words[2], PLY_TYPES[words[1]]))
            else:
                raise ValueError(f"{where}: expected 'property TYPE NAME' or 'property list TYPE TYPE NAME'")
        else:
            raise ValueError(f"{where}: unknown keyword {key!r}")
    if fmt is None:
        raise ValueError("the header has no 'format' line")
    return PlyHeader(fmt, tuple(PlyElement(n, c, tuple(p)) for n, c, p in elements), tuple(comments), size)
