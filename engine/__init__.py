"""tectum: an asynchronous streaming engine with plugins for event cameras.

The public API, re-exported from the private modules that implement it.
"""

from . import camera as camera
from ._adapters import from_structured as from_structured
from ._adapters import to_structured as to_structured
from ._boundary import Guard as Guard
from ._boundary import Repair as Repair
from ._edge import Edge as Edge
from ._embed import Stepper as Stepper
from ._embed import ThreadedPipeline as ThreadedPipeline
from ._macro import Delayed as Delayed
from ._macro import Expansion as Expansion
from ._macro import Macro as Macro
from ._operator import Operator as Operator
from ._operator import Port as Port
from ._operator import Sink as Sink
from ._operator import Source as Source
from ._operator import same_sensor as same_sensor
from ._packet import (
    EventPacket as EventPacket,
)
from ._packet import (
    Kind as Kind,
)
from ._packet import (
    Packet as Packet,
)
from ._packet import (
    accepts as accepts,
)
from ._packet import (
    packet_class as packet_class,
)
from ._packet import (
    register_kind as register_kind,
)
from ._pipeline import BatchPolicy as BatchPolicy
from ._pipeline import Pipeline as Pipeline
from ._pipeline import Plan as Plan
from ._registry import Registry as Registry
from ._registry import get_registry as get_registry
from ._samples import (
    AngularVelocityPacket as AngularVelocityPacket,
)
from ._samples import (
    ClusterPacket as ClusterPacket,
)
from ._samples import (
    Field as Field,
)
from ._samples import (
    FramePacket as FramePacket,
)
from ._samples import (
    ImuPacket as ImuPacket,
)
from ._samples import (
    MapPacket as MapPacket,
)
from ._samples import (
    PointPacket as PointPacket,
)
from ._samples import (
    PosePacket as PosePacket,
)
from ._samples import (
    ResultPacket as ResultPacket,
)
from ._samples import (
    SamplePacket as SamplePacket,
)
from ._samples import (
    TrackPacket as TrackPacket,
)
from ._samples import (
    TriggerPacket as TriggerPacket,
)
from ._scheduler import RunningPipeline as RunningPipeline
from ._scheduler import arun as arun
from ._scheduler import open_pipeline as open_pipeline
from ._stats import Stats as Stats
from ._stream import concat as concat
from ._stream import empty_like as empty_like
from ._stream import interleave as interleave
from ._stream import merge as merge
from .calibration import calibrate as calibrate
from .errors import (
    DuplicateNameError as DuplicateNameError,
)
from .errors import (
    FormatError as FormatError,
)
from .errors import (
    NodeError as NodeError,
)
from .errors import (
    PacketError as PacketError,
)
from .errors import (
    PipelineError as PipelineError,
)
from .errors import (
    RegistryError as RegistryError,
)
from .errors import (
    TectumError as TectumError,
)
from .hookspecs import hookimpl as hookimpl
from .scale import run as run

__version__ = "0.1.0"


def __getattr__(name: str) -> object:
    """``tectum.testing`` (test helpers, which import hypothesis) is loaded on
    first use, so ``import tectum`` stays light and the README's check works."""
    if name == "testing":
        import importlib

        return importlib.import_module(".testing", __name__)
    raise AttributeError(f"module {__name__!r} has no attribute {name!r}")
