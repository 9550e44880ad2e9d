"""The order :func:`tectum.evaluation.harness.interleaved` runs its functions
in: fixed (a, b, c every round) by default; with ``shuffle``, every function
once a round in a seeded order, so no function always runs just after the
same one (what it leaves in the caches would fall on that one alone)."""

from __future__ import annotations

from tectum.evaluation.harness import interleaved


def _order(shuffle: bool, repeat: int, names: str = "abc") -> list[str]:
    calls: list[str] = []
    fns = {k: (lambda k=k: calls.append(k)) for k in names}
    r = interleaved(fns, 1000, repeat=repeat, warmup=1, shuffle=shuffle)
    assert all(len(r[k]["cpu_s"]) == len(r[k]["wall_s"]) == repeat for k in names)
    return calls[len(names):]  # after the warm-up round


def test_fixed_order_by_default() -> None:
    assert _order(False, 3) == list("abcabcabc")


def test_shuffled_rounds_each_once_in_varied_orders_that_repeat() -> None:
    calls = _order(True, 12)
    rounds = ["".join(calls[i:i + 3]) for i in range(0, len(calls), 3)]
    assert all(sorted(r) == list("abc") for r in rounds)  # every function once a round
    assert len(set(rounds)) >= 3
    # each function runs just after each other one at least once (within a round or across two)
    after = {(x, y) for x, y in zip(calls, calls[1:]) if x != y}
    assert after == {(x, y) for x in "abc" for y in "abc" if x != y}
    assert _order(True, 12) == calls  # seeded: the same orders each run
