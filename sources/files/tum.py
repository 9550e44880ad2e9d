"""Poses from TUM trajectory files (``.tum``).

One pose per line, eight numbers separated by spaces or tabs::

    # t[s] tx ty tz qx qy qz qw
    1.000000 0.1 -0.2 1.5 0 0 0 1

``t`` in seconds (parsed exactly from its digits into integer µs, never
through a float; digits below 1 µs round half up), the camera position in
metres and its orientation as a unit quaternion ``(qx, qy, qz, qw)``,
world-from-camera. ``#`` lines are comments. The UZH event-camera dataset's
``groundtruth.txt`` has the same layout and opens here too.

A row with a token that is no number, a wrong number of columns, a NaN or
infinite number, a quaternion whose norm is off 1 by more than 1e-3, or a
time before the previous row's is a :class:`tectum.FormatError` naming the
line, or with ``skip_bad=true`` dropped and counted.
"""

from __future__ import annotations

from collections.abc import Iterator, Sequence
from typing import Any

from tectum import Kind, Packet, PosePacket
from tectum.tables import header_layout, parse_us, pose_problem

from ._rows import RowParser, RowStream, SampleFileSource, text_lines
from ._text_head import plain_events_head
from ._text_layout import first_lines

__all__ = ["TumSource", "TUM_COLUMNS"]

#: The columns of a TUM line.
TUM_COLUMNS = ("t", "tx", "ty", "tz", "qx", "qy", "qz", "qw")


def _pose_check(row: Sequence[Any]) -> str | None:
    return pose_problem(row[1:4], row[4:8])


class TumSource(SampleFileSource):
    """Poses (``PosePacket``: position m, orientation quaternion x y z w)
    from a TUM trajectory file."""

    name = "tum"
    format = "tum"
    extensions = (".tum",)
    produces = (Kind.POSES,)

    @classmethod
    def sniff(cls, head: bytes) -> bool:
        """:meth:`_sniff_text`, which is False at once for a first line
        starting with ``%`` (its first word is no number): a
        Prophesee header (RAW, DAT), whose sniffers come after this one's
        (~20-40 us of an open right after another program's decode)."""
        return head[:1] != b"%" and cls._sniff_text(head)

    @classmethod
    def _sniff_text(cls, head: bytes) -> bool:
        """The first lines that are not comments are 8 numbers each, the last
        four a unit quaternion."""
        if plain_events_head(head):
            return False  # lines of 4 numbers: events
        lines = first_lines(head, 1, comments=(b"#",))  # the first alone rules out most files
        if not lines or len(lines[0].split()) != 8:
            return False
        lines = first_lines(head, 20, comments=(b"#",))
        for ln in lines:
            words = ln.split()
            if len(words) != 8:
                return False
            try:
                vals = [float(w) for w in words]
            except ValueError:
                return False
            if pose_problem(vals[1:4], vals[4:8]) is not None:
                return False
        return True

    def _packets(self) -> Iterator[Packet]:
        f = self._open()
        groups = header_layout(PosePacket, TUM_COLUMNS)
        parser = RowParser(self, groups, [[1, 2, 3], [4, 5, 6, 7]], 8, bytes.split, parse_us, _pose_check)
        stream = RowStream(self, PosePacket)
        for lines in text_lines(f, self.chunk_bytes):
            t, data = parser.parse(lines)
            yield from stream.push(t, data, lines[0].offset)
        yield from stream.finish()
