"""Failures of a sharded run: a worker dying mid-shard is retried and the run
says which shards ran twice; bad input fails the run naming the file and the
time range, and leaves no output and no scratch behind."""

from __future__ import annotations

import glob
import os
import re
import signal
import threading
import time
from pathlib import Path
from typing import Any

import numpy as np
import pytest
from shards import assert_same_output, chain, write_dat

import tectum
from tectum.scale import ShardFailed

from helpers import bars

OPS = [("flow.plane_fit", {"robust": True, "radius": 3})]


@pytest.fixture(scope="module")
def busy(tmp_path_factory: pytest.TempPathFactory) -> Path:
    """A recording whose shards take a while (so a worker can die in one)."""
    ev = bars(duration_us=300_000, sensor="96x72", noise_hz=40.0, speed=400.0)
    return write_dat(tmp_path_factory.mktemp("busy") / "busy.dat", ev)


def _kill_one_when_started(scratch: Path, done: threading.Event) -> list[int]:
    """Once a shard has started, SIGKILL the worker running it (the pid its
    attempt marker holds: any other worker may be idle, and then nothing
    needs to run twice)."""
    killed: list[int] = []
    while not done.is_set():
        for marker in glob.glob(str(scratch / ".tectum-shards-*" / "attempt-*")):
            text = Path(marker).read_text()
            if text:
                pid = int(text)
                os.kill(pid, signal.SIGKILL)
                killed.append(pid)
                return killed
        time.sleep(0.002)
    return killed


def _run_and_kill(p: tectum.Pipeline, scratch: Path, **kw: Any) -> tuple[Any, list[int]]:
    done = threading.Event()
    out: dict[str, Any] = {}

    def go() -> None:
        try:
            out["stats"] = tectum.run(p, scratch=str(scratch), **kw)
        except BaseException as e:  # raised in the test's thread below
            out["error"] = e
        finally:
            done.set()

    t = threading.Thread(target=go)
    t.start()
    killed = _kill_one_when_started(scratch, done)
    t.join(300)
    if "error" in out:
        raise out["error"]
    return out["stats"], killed


def test_a_worker_dying_on_the_process_pool(busy, tmp_path):
    seq_p, seq = chain(busy, OPS)
    tectum.run(seq_p)
    sh_p, sharded = chain(busy, OPS)
    stats, killed = _run_and_kill(sh_p, tmp_path, shards=4, executor="local", workers=2)
    assert killed, "no shard started"
    assert_same_output(seq, sharded)
    assert stats.rerun and all(line.endswith(": 2 runs") for line in stats.rerun)
    assert "ran 2 times" in stats.report()
    assert os.listdir(tmp_path) == []  # the scratch folder is gone


@pytest.mark.slow
def test_a_worker_dying_on_dask(busy, tmp_path):
    distributed = pytest.importorskip("distributed", reason="dask.distributed is not installed (pip install '.[dask]')")
    seq_p, seq = chain(busy, OPS)
    tectum.run(seq_p)
    sh_p, sharded = chain(busy, OPS)
    with distributed.LocalCluster(n_workers=2, threads_per_worker=1, processes=True,
                                  dashboard_address=":0") as cluster, distributed.Client(cluster) as client:
        client.run(os.getpid)  # the workers are up
        stats, killed = _run_and_kill(sh_p, tmp_path, shards=4, executor=client)
    assert killed, "no shard started"
    assert_same_output(seq, sharded)
    assert stats.rerun, "a shard whose worker died must be reported as run twice"


def _damaged(src: Path, dst: Path) -> tuple[int, int]:
    """``src`` with one record's time set to 0 two thirds in (a time going
    back: the reader refuses it); the original time of that record and its
    byte offset."""
    raw = bytearray(src.read_bytes())
    start = raw.index(b"\n", raw.rindex(b"\n% ") + 1) + 1 + 2  # after the header and the type/size bytes
    n = (len(raw) - start) // 8
    at = start + (2 * n // 3) * 8
    t = int.from_bytes(raw[at:at + 4], "little")
    raw[at:at + 4] = (0).to_bytes(4, "little")
    dst.write_bytes(bytes(raw))
    return t, at


@pytest.mark.parametrize("executor", ["local", "dask"])
def test_bad_input_fails_the_run_naming_file_and_range(busy, tmp_path, executor):
    if executor == "dask":
        pytest.importorskip("distributed", reason="dask.distributed is not installed (pip install '.[dask]')")
        import distributed

        client = distributed.Client(processes=False, n_workers=2, threads_per_worker=1, dashboard_address=":0")
    bad = tmp_path / "bad.dat"
    t_bad, at = _damaged(busy, bad)
    p = tectum.Pipeline()
    p.sink(str(tmp_path / "out.npz"), p.op("filter.background_activity", p.source(str(bad))))
    try:
        with pytest.raises(ShardFailed) as err:
            tectum.run(p, shards=3, executor=client if executor == "dask" else "local")
    finally:
        if executor == "dask":
            client.close()
    msg = str(err.value)
    assert str(bad) in msg and f"at byte {at}: timestamp decreases" in msg
    m = re.search(r"\[(\w+), (\w+)\) µs(?: \(read from ([\w ]+)\))?: ", msg)
    assert m is not None, msg
    first = m[3] or m[1]
    # the shard named read from before the damaged record (the reader checks
    # a whole chunk, which may reach past the shard's end: then it is named)
    assert (int(first) if first.isdigit() else 0) <= t_bad, msg
    assert sorted(os.listdir(tmp_path)) == ["bad.dat"]  # no output, no scratch


def test_sequential_and_sharded_agree_on_a_good_file(busy):
    """The busy recording itself shards exactly (the failures above are the failures')."""
    seq_p, seq = chain(busy, [("filter.background_activity", {})])
    tectum.run(seq_p)
    sh_p, sharded = chain(busy, [("filter.background_activity", {})])
    tectum.run(sh_p, shards=3, executor="local", workers=2)
    assert_same_output(seq, sharded)
    assert len(np.unique(seq.events().t)) > 10_000
