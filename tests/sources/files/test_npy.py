"""Structured .npy files whose coordinates do not fit pixels (negative, or
past 65535 in a wider integer field) are named by byte offset, or skipped
and counted: never wrapped into a wrong pixel."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest

from tectum import FormatError
from tectum.sources.files.npy import NpySource


@pytest.mark.parametrize("field, value", [("x", -65000), ("y", 70000)])
def test_coordinate_that_is_no_pixel(tmp_path: Path, field: str, value: int) -> None:
    a = np.zeros(6, dtype=[("t", "<i8"), ("x", "<i4"), ("y", "<i4"), ("p", "<i1")])
    a["t"] = np.arange(6)
    a[field][3] = value
    f = tmp_path / "e.npy"
    np.save(f, a)
    data = f.read_bytes()
    at = len(data) - 3 * a.dtype.itemsize  # record 3 of 6
    with pytest.raises(FormatError, match="not a pixel coordinate") as e:
        list(NpySource(str(f), sensor="640x480").packets())
    assert e.value.offset == at
    src = NpySource(str(f), sensor="640x480", skip_bad=True)
    assert sum(len(q) for q in src.packets()) == 5 and src.skipped_events == 1
