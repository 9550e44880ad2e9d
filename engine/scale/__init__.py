"""Beyond one process: a pipeline over long recordings in time shards, and
over many recordings, on a process pool or a Dask cluster.

``tectum.run(p, shards=8, executor=client)`` cuts the recording into time
shards, starts each a warm-up earlier (the sum of its operators' declared
memories, :meth:`tectum.Operator.memory_us`), drops what the warm-up emits
and joins the outputs in order: identical to one sequential run. Operators
that cannot state a finite memory refuse, saying why (:class:`NotShardable`).
:func:`run_many` runs one pipeline per recording (``tectum run "corpus/*.raw"
--sink "out/{stem}.h5"``). Shards travel as small task descriptions (file,
time range, pipeline as a dict); a shard that fails for bad input fails the
run naming the file and time range (:class:`ShardFailed`), and no output is
left half-written.
"""

from ._executors import DaskExecutor as DaskExecutor
from ._executors import LocalExecutor as LocalExecutor
from ._executors import ShardFailed as ShardFailed
from ._memory import NotShardable as NotShardable
from ._memory import Warmup as Warmup
from ._memory import warmup_of as warmup_of
from ._plan import Shard as Shard
from ._plan import plan_shards as plan_shards
from ._run import ShardedStats as ShardedStats
from ._run import expand as expand
from ._run import run as run
from ._run import run_many as run_many
from ._task import ShardTask as ShardTask
from ._task import pipeline_dict as pipeline_dict
from ._task import run_shard as run_shard
