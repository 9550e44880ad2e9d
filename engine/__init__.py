"""tectum: an asynchronous streaming engine with plugins for event cameras.

The public API, re-exported from the private modules that implement it.
"""

from . import camera as camera
from ._adapters import from_structured as from_structured, to_structured as to_structured
from ._boundary import Guard as Guard, Repair as Repair
from ._edge import Edge as Edge
from ._embed import Stepper as Stepper, ThreadedPipeline as ThreadedPipeline
from ._operator import Operator as Operator, Port as Port, Sink as Sink, Source as Source
from ._packet import (
    EventPacket as EventPacket,
    Kind as Kind,
    Packet as Packet,
    accepts as accepts,
    packet_class as packet_class,
    register_kind as register_kind,
)
from ._samples import (
    AngularVelocityPacket as AngularVelocityPacket,
    ClusterPacket as ClusterPacket,
    Field as Field,
    FramePacket as FramePacket,
    ImuPacket as ImuPacket,
    MapPacket as MapPacket,
    PointPacket as PointPacket,
    PosePacket as PosePacket,
    ResultPacket as ResultPacket,
    SamplePacket as SamplePacket,
    TrackPacket as TrackPacket,
    TriggerPacket as TriggerPacket,
)
from ._stream import concat as concat, empty_like as empty_like, interleave as interleave, merge as merge
from ._pipeline import BatchPolicy as BatchPolicy, Pipeline as Pipeline, Plan as Plan
from ._registry import Registry as Registry, get_registry as get_registry
from ._scheduler import RunningPipeline as RunningPipeline, arun as arun, open_pipeline as open_pipeline, run as run
from ._stats import Stats as Stats
from .errors import (
    DuplicateNameError as DuplicateNameError,
    FormatError as FormatError,
    NodeError as NodeError,
    PacketError as PacketError,
    PipelineError as PipelineError,
    RegistryError as RegistryError,
    TectumError as TectumError,
)
from .hookspecs import hookimpl as hookimpl

__version__ = "0.1.0"


def __getattr__(name: str) -> object:
    """``tectum.testing`` (test helpers, which import hypothesis) is loaded on
    first use, so ``import tectum`` stays light and the README's check works."""
    if name == "testing":
        import importlib

        return importlib.import_module(".testing", __name__)
    raise AttributeError(f"module {__name__!r} has no attribute {name!r}")
