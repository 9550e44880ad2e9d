"""Every exception tectum raises on purpose.

Each class says when it is raised; all derive from :class:`TectumError`, so an
application can catch the family in one clause.
"""

from __future__ import annotations


class TectumError(Exception):
    """Base class of all tectum errors."""


class PacketError(TectumError, ValueError):
    """A packet breaks the packet contract (dtype, order, interval, geometry).

    Raised at the boundary where data enters (sources, adapters), never deep in
    a kernel. ``index`` is the first offending event, when there is one.
    """

    def __init__(self, message: str, *, index: int | None = None) -> None:
        super().__init__(message)
        self.index = index


class RegistryError(TectumError):
    """A plugin registers something invalid, or a name is unknown."""


class DuplicateNameError(RegistryError):
    """Two plugins register the same component name; both owners are named."""


class PipelineError(TectumError):
    """A pipeline declaration is invalid (cycle, unknown name, bad parameter,
    kind mismatch). Raised by validation, before anything runs."""


class NodeError(TectumError):
    """A node failed while the pipeline ran. ``node`` is its id; the original
    exception is chained as ``__cause__``."""

    def __init__(self, node: str, cause: BaseException) -> None:
        super().__init__(f"node {node!r} failed: {type(cause).__name__}: {cause}")
        self.node = node


class FormatError(TectumError, ValueError):
    """A file or stream does not decode: names the file and the byte offset."""

    def __init__(self, message: str, *, path: str | None = None, offset: int | None = None) -> None:
        where = ""
        if path is not None:
            where = f"{path}"
            if offset is not None:
                where += f" at byte {offset}"
            where += ": "
        super().__init__(where + message)
        self.path = path
        self.offset = offset
