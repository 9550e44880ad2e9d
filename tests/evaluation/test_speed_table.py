"""The README's speed table is made from bench JSON: a ratio target met or
missed shows as such, with its spread; a 2x row past the memory limit is
judged by the limit row."""

from __future__ import annotations

import json
from pathlib import Path

from tectum.evaluation.harness import target, versus
from tectum.evaluation.speed_table import speed_table


def _result(events: int, wall: list[float], cpu: list[float]) -> dict[str, object]:
    return {"events": events, "mev_s": events / sorted(wall)[len(wall) // 2] / 1e6,
            "cpu_mev_s": events / sorted(cpu)[len(cpu) // 2] / 1e6, "wall_s": wall, "cpu_s": cpu}


def test_rows_from_bench_json(tmp_path: Path) -> None:
    ours, dv = _result(10**6, [1.0, 1.0, 1.0], [1.0, 1.1, 0.9]), _result(10**6, [3.0, 3.0, 3.0], [2.5, 2.5, 2.5])
    slow = _result(10**6, [3.0, 3.0, 3.0], [3.0, 3.0, 3.0])
    filters = [versus("BA dt 6 ms @ 1 Mev/s", ours, dv, 2.0, clock=c, peer_name="dv-processing") for c in ("wall", "cpu")]
    filters += [versus("BA dt 1 ms @ 1 Mev/s", slow, dv, 2.0, clock=c, peer_name="dv-processing") for c in ("wall", "cpu")]
    io = [versus("dat decode", ours, dv, 2.0, clock="cpu", peer_name="expelliarmus"),
          versus("dat decode", ours, dv, 2.0, clock="wall", peer_name="expelliarmus")]
    io[0]["met"] = False
    io.append(target("dat decode within 1.5x of the memory limit 300 Mev/s (cpu)", 250.0, 200.0, "Mev/s"))
    for suite, res in (("filters", {"targets": filters}), ("io", {"targets": io})):
        (tmp_path / f"bench-{suite}.json").write_text(json.dumps({"results": res}))
    lines = speed_table(tmp_path).splitlines()
    ba = next(x for x in lines if x.startswith("| background activity"))
    assert ba.endswith("| 0.83-2.50 (median 1.67) | 1.00-3.00 | >= 2x | MISSED (1 of 2 met) |")
    dat = next(x for x in lines if x.startswith("| dat decode vs expelliarmus"))
    assert "2.50 (2.27-2.78)" in dat and dat.endswith("| met (250 Mev/s per CPU s) |")
    assert not any(x.startswith("| event by event") for x in lines)  # no engine JSON: no engine rows


def test_frame_rows_and_their_memory_limit(tmp_path: Path) -> None:
    """The event frame and the 8-bit count image each get a row against dv;
    where 2x dv is past the memory limit of the frame bytes the limit
    targets get a row of their own, met or missed."""
    ours, dv = _result(10**6, [4.0] * 3, [4.0] * 3), _result(10**6, [1.0] * 3, [1.0] * 3)
    filters = [versus(f"{what} @ 0.1 Mev/s", ours, dv, 2.0, clock=c, peer_name="dv-processing")
               for what in ("event frame", "count image uint8") for c in ("wall", "cpu")]
    filters += [target("event frame @ 0.1 Mev/s within 1.5x of the memory limit 16 Mev/s (cpu)", 12.0, 10.6, "Mev/s"),
                target("event frame @ 1 Mev/s within 1.5x of the memory limit 150 Mev/s (cpu)", 66.0, 100.0,
                       "Mev/s")]
    (tmp_path / "bench-filters.json").write_text(json.dumps({"results": {"targets": filters}}))
    lines = speed_table(tmp_path).splitlines()
    assert next(x for x in lines if x.startswith("| event frame (int32")).endswith("| MISSED (0 of 1 met) |")
    assert next(x for x in lines if x.startswith("| count image uint8")).endswith("| MISSED (0 of 1 met) |")
    limit = next(x for x in lines if "memory limit of the frame bytes" in x)
    assert "12, 66" in limit and limit.endswith("| MISSED (1 of 2 met) |")
