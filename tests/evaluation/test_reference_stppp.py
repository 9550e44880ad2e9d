"""The adapter that runs the ST-PPP authors' code side by side with
``tracker.angular_velocity``: the ECD folder it writes, the command line it
gives, the output it reads back (with a stand-in for the reference that
follows the reference's README: same arguments, same output layout)."""

from __future__ import annotations

import textwrap

import numpy as np
import pytest

from tectum import EventPacket, concat
from tectum.evaluation.reference_stppp import find_stppp, run_stppp, write_ecd_folder

#: A stand-in for src/main.py: reads the folder as the reference does and
#: writes, per batch of -n events, "index t_ref t_end loss wx wy wz".
STAND_IN = textwrap.dedent('''
    import argparse, os
    import numpy as np
    a = argparse.ArgumentParser()
    for k in ("-p", "-s", "-m", "-t", "-n", "-o"):
        a.add_argument(k)
    args = a.parse_args()
    assert args.t == "rot" and args.m in ("cmax", "st-ppp")
    ev = np.loadtxt(os.path.join(args.p, args.s, "events.txt"), ndmin=2)
    calib = np.loadtxt(os.path.join(args.p, args.s, "calib.txt"))
    n = int(args.n)
    rows = []
    for k in range(len(ev) // n):
        b = ev[k * n:(k + 1) * n]
        rows.append([k + 1, b[0, 0], b[-1, 0], 0.5, calib[0] / 100, b[:, 3].mean(), -1.0 if args.m == "cmax" else 1.0])
        print("Duration:%.3fs" % (0.25 * (k + 1)))
    os.makedirs(os.path.join("output", args.s), exist_ok=True)
    np.savetxt(os.path.join("output", args.s, args.o), np.array(rows), fmt="%.9f")
''')


def _events(n: int) -> EventPacket:
    rng = np.random.default_rng(3)
    t = np.sort(rng.integers(1_000, 900_000, n))
    return EventPacket.from_arrays(t, rng.integers(0, 240, n), rng.integers(0, 180, n), rng.choice([-1, 1], n),
                                   sensor=(240, 180), t_start=0, t_end=1_000_000)


def test_the_ecd_folder_reads_back_as_the_same_events(tmp_path):
    ev = _events(500)
    write_ecd_folder(tmp_path / "seq", ev, 200.0, 119.5, 89.5)
    from tectum.sources.files import open_file

    src = open_file(str(tmp_path / "seq" / "events.txt"))
    try:
        back = concat([q for q in src.packets() if isinstance(q, EventPacket)])
    finally:
        src.close()
    assert np.array_equal(back.t, ev.t) and np.array_equal(back.x, ev.x) and np.array_equal(back.y, ev.y)
    assert np.array_equal(back.p > 0, ev.p > 0)
    assert np.loadtxt(tmp_path / "seq" / "calib.txt").tolist() == [200.0, 200.0, 119.5, 89.5, 0, 0, 0, 0, 0]


def test_batches_times_and_durations_come_back_per_window(tmp_path):
    root = tmp_path / "ref"
    (root / "src").mkdir(parents=True)
    (root / "src" / "main.py").write_text(STAND_IN)
    ev = _events(2_500)
    for method, wz in (("cmax", -1.0), ("st-ppp", 1.0)):
        got = run_stppp(root, ev, 200.0, 119.5, 89.5, method=method, ne=1_000)
        assert len(got.omega) == 2  # whole batches only
        assert got.t0.tolist() == [ev.t[0], ev.t[1_000]] and got.t1.tolist() == [ev.t[999], ev.t[1_999]]
        assert np.allclose(got.omega[:, 0], 2.0) and np.allclose(got.omega[:, 2], wz)
        assert np.allclose(got.omega[:, 1], [np.mean(ev.p[:1_000] > 0), np.mean(ev.p[1_000:2_000] > 0)])
        assert got.seconds.tolist() == [0.25, 0.5]
    with pytest.raises(ValueError, match="cmax or st-ppp"):
        run_stppp(root, ev, 200.0, 119.5, 89.5, method="adam")


def test_a_failing_reference_is_a_runtime_error_with_its_last_line(tmp_path):
    root = tmp_path / "ref"
    (root / "src").mkdir(parents=True)
    (root / "src" / "main.py").write_text("import sys\nsys.exit('ModuleNotFoundError: no torch here')\n")
    with pytest.raises(RuntimeError, match="no torch here"):
        run_stppp(root, _events(100), 200.0, 119.5, 89.5)


def test_where_it_cannot_run_the_bench_says_why(tmp_path, monkeypatch):
    monkeypatch.delenv("TECTUM_STPPP", raising=False)
    assert find_stppp()[0] is None and "TECTUM_STPPP" in find_stppp()[1]
    monkeypatch.setenv("TECTUM_STPPP", str(tmp_path))
    assert find_stppp()[0] is None and "main.py" in find_stppp()[1]
    (tmp_path / "src").mkdir()
    (tmp_path / "src" / "main.py").write_text("")
    root, why = find_stppp()
    import importlib.util

    if all(importlib.util.find_spec(m) for m in ("torch", "pandas", "sklearn", "cv2", "matplotlib")):
        assert root == tmp_path and why == ""
    else:
        assert root is None and "do not import" in why
