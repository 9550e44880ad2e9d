"""File sources for every common event format, recognised by content.

One module per format (see each for its layout and conventions): Prophesee
RAW EVT 2.0/3.0 and DAT (:mod:`.prophesee`), jAER AEDAT 2.0 (:mod:`.aedat2`),
AEDAT 3.1 (:mod:`.aedat31`), AEDAT 4.0 (:mod:`.aedat4`, codec in
:mod:`.aedat4_codec`), text/CSV (:mod:`.text`), HDF5 (:mod:`.hdf5`),
structured ``.npy`` (:mod:`.npy`), ROS 1/2 bags (:mod:`.rosbag`), Event Stream 2.x ``.es`` DVS and
ATIS (:mod:`.event_stream`, codec in :mod:`.event_stream_codec`) and the N-MNIST/N-Caltech101 40-bit
``.bin`` (:mod:`.nmnist`: no magic number, chosen by its extension). All output tectum's conventions:
absolute µs, top-left origin, polarity ±1 (see :mod:`._common`).
"""

from __future__ import annotations

from typing import Any

from tectum.hookspecs import hookimpl

__all__ = ["SOURCES", "SAMPLE_SOURCES", "open_file"]


def _classes() -> list[type]:
    from .aedat2 import Aedat2Source
    from .aedat4 import Aedat4Source
    from .aedat31 import Aedat31Source
    from .event_stream import EventStreamSource
    from .hdf5 import Hdf5Source
    from .nmnist import NmnistSource
    from .npy import NpySource
    from .prophesee import DatSource, Evt2Source, Evt3Source
    from .rosbag import RosbagSource
    from .text import TextSource

    return [Evt2Source, Evt3Source, DatSource, Aedat2Source, Aedat31Source, Aedat4Source, Hdf5Source,
            NpySource, RosbagSource, EventStreamSource, NmnistSource, TextSource]


SOURCES = _classes()


def _sample_classes() -> list[type]:
    from .ply import PlySource
    from .samples_csv import CsvSource
    from .tum import TumSource

    return [TumSource, CsvSource, PlySource]


#: Sources of sample-stream files (TUM poses, CSV of any flat kind, PLY point clouds),
#: registered before :data:`SOURCES` so a sample CSV is sniffed before event text.
SAMPLE_SOURCES = _sample_classes()


def open_file(path: str, **kw: Any) -> Any:
    """A source for ``path``, chosen as everywhere else in tectum by
    :meth:`tectum.Registry.source_for` (URL scheme, file content, then
    extension), so this also opens tectum's own ``.npz``."""
    from tectum import get_registry

    cls: Any = get_registry().source_for(path)  # a file source: constructed from its path
    return cls(path, **kw)


@hookimpl
def tectum_register_sources(registry) -> None:  # type: ignore[no-untyped-def]
    for cls in (*SAMPLE_SOURCES, *SOURCES):
        registry.add_source(cls)


@hookimpl
def tectum_register_kinds(registry) -> None:  # type: ignore[no-untyped-def]
    from .event_stream import ExposurePacket

    registry.add_kind(ExposurePacket)
