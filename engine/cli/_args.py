"""Parsing of the CLI's component arguments."""

from __future__ import annotations

from typing import Any
from urllib.parse import parse_qsl

from tectum.errors import PipelineError


def split_query(arg: str) -> tuple[str, dict[str, str]]:
    """``"out.npz?compress=true"`` -> ``("out.npz", {"compress": "true"})``.

    Parameters of sources and sinks follow a ``?`` as in a URL
    (``pattern:?speed=500&noise_hz=2``)."""
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
