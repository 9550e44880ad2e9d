"""File sinks: ECD text/CSV, AEDAT 4.0, Prophesee EVT 2.0/3.0 and DAT, HDF5
(DSEC layout), structured ``.npy``, Event Stream 2.0 ``.es`` (DVS) and N-MNIST
``.bin``. Each streams into a temporary file beside the target and renames it
into place on close; abort removes it."""

from __future__ import annotations

from typing import TYPE_CHECKING

from tectum.hookspecs import hookimpl

if TYPE_CHECKING:
    from tectum import Sink

    from ._common import FileSink
    from .hdf5 import Hdf5Sink

__all__ = ["SINKS", "SAMPLE_SINKS"]


def _classes() -> list[type[FileSink] | type[Hdf5Sink]]:  # each made from a path
    from .aedat4 import Aedat4Sink
    from .event_stream import EventStreamSink
    from .hdf5 import Hdf5Sink
    from .nmnist import NmnistSink
    from .npy import NpySink
    from .prophesee import DatSink, Evt2Sink, Evt3Sink
    from .text import TextSink

    return [TextSink, Aedat4Sink, Evt2Sink, Evt3Sink, DatSink, Hdf5Sink, NpySink, EventStreamSink, NmnistSink]


SINKS = _classes()


def _sample_classes() -> list[type[Sink]]:
    from .ply import PlySink
    from .samples_csv import CsvSink
    from .tum import TumSink

    return [CsvSink, TumSink, PlySink]


#: Sinks of one sample stream per file (CSV of any flat kind, TUM poses, PLY point clouds).
SAMPLE_SINKS = _sample_classes()


@hookimpl
def tectum_register_sinks(registry) -> None:  # type: ignore[no-untyped-def]
    for cls in (*SINKS, *SAMPLE_SINKS):
        registry.add_sink(cls)
