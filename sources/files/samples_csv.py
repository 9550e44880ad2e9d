"""Sample streams from CSV files (IMU, poses, triggers, angular velocity,
tracks, clusters, points, and any kind a plugin registers whose fields are
scalars and vectors).

Layout, as :class:`tectum.sinks.files.samples_csv.CsvSink` writes it::

    # tectum imu
    t,ax,ay,az,gx,gy,gz
    1000,0.01,-9.81,0.2,0.001,0.002,-0.003

* an optional first line ``# tectum KIND`` names the kind, followed by the
  dtypes of undeclared extra fields (``score=float32``, ``v=float64[3]``);
  other ``#`` lines are comments;
* a header row: ``t`` first, in integer µs, then the columns of the kind's
  fields (:mod:`tectum.tables`: ``Field.columns``, e.g. ``accel`` -> ``ax,
  ay, az``), in any order; columns the kind does not declare are extra
  fields (float64 unless the kind line types them);
* one sample per row, comma-separated; integers for integer fields, any
  float text (``nan`` and ``inf`` too) for float fields.

Without the kind line, the kind is the one registered kind whose columns the
header holds exactly (``?kind=`` settles a header that fits several, such as
``t,id,x,y``: tracks or clusters). Event CSVs (``t,x,y,p``) fit no kind and
open in the text source.

Bad rows (a token of the wrong type, a wrong column count, a time before the
previous row's, for poses a non-finite number or a non-unit quaternion): a
:class:`tectum.FormatError` naming the line, or with ``skip_bad=true``
dropped and counted.
"""

from __future__ import annotations

import itertools
from collections.abc import Iterator, Mapping, Sequence
from typing import Any

from tectum import FormatError, Kind, Packet, SamplePacket, packet_class
from tectum.tables import Group, flat_kinds, header_layout, kinds_for_header, parse_kind_line, pose_problem

from ._rows import Line, RowCheck, RowParser, RowStream, SampleFileSource, text_lines, whole_us
from ._text_head import plain_events_head
from ._text_layout import first_lines

__all__ = ["CsvSource"]


def _split(text: bytes) -> list[bytes]:
    return text.split(b",")


def _header(head: bytes) -> tuple[str | None, list[str] | None]:
    """The kind line's text (if the file starts with one) and the header row's
    names (of the first complete line that is no comment nor blank;
    :func:`first_lines` splits no more of a 64 kB head than it needs)."""
    kind_line = None
    if head.startswith(b"# tectum "):
        kind_line = head.split(b"\n", 1)[0].rstrip(b"\r").decode("latin1")
    first = first_lines(head, 1, comments=(b"#",))
    if first:
        return kind_line, [c.strip() for c in first[0].decode("latin1").split(",")]
    return kind_line, None


class CsvSource(SampleFileSource):
    """One sample stream from a CSV file with a header row (see the module
    docstring).

    Parameters (besides :class:`FileSource`'s)
    ------------------------------------------
    kind:
        The stream kind (``imu``, ``tracks`` ...), for a header that fits
        several kinds; must agree with the file's ``# tectum`` line.
    """

    name = "csv"
    format = "csv"
    extensions = ()  # found by content: a .csv of events goes to the text source
    produces = tuple(flat_kinds())  # the kinds registered when this module is imported

    def __init__(self, path: str, kind: str | None = None, **kw: Any) -> None:
        super().__init__(path, **kw)
        self.kind = kind

    @classmethod
    def sniff(cls, head: bytes) -> bool:
        """:meth:`_sniff_text`, which is False at once for a first line
        starting with ``%`` (it is no kind line, and its first name is not t): a
        Prophesee header (RAW, DAT), whose sniffers come after this one's
        (~20-40 us of an open right after another program's decode)."""
        return head[:1] != b"%" and cls._sniff_text(head)

    @classmethod
    def _sniff_text(cls, head: bytes) -> bool:
        if plain_events_head(head):
            return False  # event lines: no kind line, no header row
        kind_line, names = _header(head)
        if kind_line is not None:
            try:
                parsed = parse_kind_line(kind_line)
            except ValueError:
                return False
            return parsed is not None and parsed[0] in flat_kinds()
        # a header row starts with t (kinds_for_header says so too, after trying every kind)
        return names is not None and names[:1] == ["t"] and bool(kinds_for_header(names))

    @classmethod
    def kinds_for(cls, arg: str, params: Mapping[str, Any]) -> tuple[Kind, ...]:
        """The one kind the file holds (the kind option, the kind line, or
        the kind its header fits)."""
        if params.get("kind"):
            return (Kind(params["kind"]),)
        try:
            with open(arg, "rb") as f:
                kind_line, names = _header(f.read(1 << 16))
            parsed = parse_kind_line(kind_line) if kind_line is not None else None
        except (OSError, ValueError):
            return cls.produces  # opening will say what is wrong
        fits = [parsed[0]] if parsed is not None else kinds_for_header(names or [])
        return (Kind(fits[0]),) if len(fits) == 1 and fits[0] in flat_kinds() else cls.produces

    def _layout(self, kind_line: str | None, names: list[str], line: Line) -> tuple[type[SamplePacket], list[Group]]:
        extras: dict[str, Any] = {}
        kind = self.kind
        if kind_line is not None:
            try:
                parsed = parse_kind_line(kind_line)
            except ValueError as e:
                raise FormatError(f"line 1: {e}", path=self.path, offset=0) from None
            assert parsed is not None
            found, extras = parsed
            if kind is not None and kind != found:
                raise FormatError(f"line 1: the file holds {found}, the kind option says {kind}", path=self.path,
                                  offset=0)
            kind = found
        if kind is None:
            fits = kinds_for_header(names)
            if len(fits) != 1:
                what = f"fits {' and '.join(fits)}: say which with ?kind=" if fits else "fits no stream kind"
                raise FormatError(f"line {line.number}: the header {','.join(names)} {what}", path=self.path,
                                  offset=line.offset)
            kind = fits[0]
        if kind not in flat_kinds():
            raise FormatError(f"{kind!r} is no stream kind a CSV holds (those are: {', '.join(flat_kinds())})",
                              path=self.path, offset=0)
        cls = packet_class(kind)
        assert issubclass(cls, SamplePacket)
        try:
            return cls, header_layout(cls, names, extras)
        except ValueError as e:
            raise FormatError(f"line {line.number}: {e}", path=self.path, offset=line.offset) from None

    def _packets(self) -> Iterator[Packet]:
        f = self._open()
        first = f.readline()
        kind_line = first.rstrip(b"\r\n").decode("latin1") if first.startswith(b"# tectum ") else None
        f.seek(0)
        chunks = text_lines(f, self.chunk_bytes)
        lines = next(chunks, [])
        if not lines:
            raise FormatError("no header row", path=self.path, offset=0)
        head, lines = lines[0], lines[1:]
        names = [c.strip() for c in head.text.decode("latin1").split(",")]
        cls, groups = self._layout(kind_line, names, head)
        where = {c: i for i, c in enumerate(names)}
        positions = [[where[c] for c in g.columns] for g in groups]
        parser = RowParser(self, groups, positions, len(names), _split, whole_us, _check(cls, groups))
        stream = RowStream(self, cls)
        for chunk in itertools.chain([lines] if lines else [], chunks):
            t, data = parser.parse(chunk)
            yield from stream.push(t, data, chunk[0].offset)
        yield from stream.finish()


def _check(cls: type[SamplePacket], groups: Sequence[Group]) -> RowCheck | None:
    """The row check of a kind: poses must be poses."""
    if cls.kind != Kind.POSES:
        return None
    start = {}
    k = 1
    for g in groups:
        start[g.field] = k
        k += len(g.columns)
    p, q = start["position"], start["orientation"]

    def check(row: Sequence[Any]) -> str | None:
        return pose_problem(row[p:p + 3], row[q:q + 4])

    return check
