"""Parsing of the CLI's component arguments."""

from __future__ import annotations

from typing import Any
from urllib.parse import parse_qsl

from tectum.errors import PipelineError

__all__ = ["split_query", "split_op", "open_source"]


def split_query(arg: str) -> tuple[str, dict[str, Any]]:
    """``"out.npz?compress=true"`` -> ``("out.npz", {"compress": "true"})``.

    Parameters of sources and sinks follow a ``?`` as in a URL
    (``pattern:?speed=500&noise_hz=2``); the values are strings, which
    pipeline validation converts to the parameters' types."""
    if "?" not in arg:
        return arg, {}
    base, q = arg.split("?", 1)
    try:
        return base, dict(parse_qsl(q, keep_blank_values=True, strict_parsing=True))
    except ValueError:
        raise PipelineError(f"bad parameters in {arg!r}: expected ?k=v&k2=v2") from None


def split_op(arg: str) -> tuple[str, dict[str, Any]]:
    """``"filter.refractory:period_us=500,x=1"`` -> name and parameters."""
    if ":" not in arg:
        return arg, {}
    name, rest = arg.split(":", 1)
    params: dict[str, Any] = {}
    for kv in filter(None, rest.split(",")):
        if "=" not in kv:
            raise PipelineError(f"bad operator parameter {kv!r} in {arg!r}: expected k=v")
        k, v = kv.split("=", 1)
        params[k.strip()] = v.strip()
    return name, params


def open_source(arg: str, sink: str | None = None, **flags: Any) -> tuple[Any, Any]:
    """The source for ``arg`` (a path or URL, parameters after ``?``) and the
    sink for ``sink`` fed from it, made as ``tectum run`` makes them: chosen
    by the registry, parameters (``?k=v`` and the ``flags`` of the command
    line that are not None) checked and converted by pipeline validation.
    Returns ``(source, sink or None)``, not yet opened."""
    from tectum import Pipeline

    p = Pipeline()
    uri, params = split_query(arg)
    p.source(uri, id="input", **params, **{k: v for k, v in flags.items() if v is not None})
    if sink is not None:
        out, sparams = split_query(sink)
        p.sink(out, "input", id="output", **sparams)
    plan = p.validate()
    return plan.nodes["input"].instantiate(), plan.nodes["output"].instantiate() if sink is not None else None
