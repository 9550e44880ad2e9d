"""Structured .npy files whose coordinates do not fit pixels (negative, or
past 65535 in a wider integer field) are named by byte offset, or skipped
and counted: never wrapped into a wrong pixel."""

from __future__ import annotations

import io
import re
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


def npy_bytes(t_descr: str, rows: int = 3) -> bytes:
    """A version 1.0 .npy file of ``rows`` zero records whose ``t`` field has
    the type ``t_descr`` as written in the header, as numpy lays one out."""
    text = (f"{{'descr': [('t', {t_descr}), ('x', '<u2'), ('y', '<u2'), ('p', '|i1')], "
            f"'fortran_order': False, 'shape': ({rows},), }}")
    pad = -(10 + len(text) + 1) % 64
    header = (text + " " * pad + "\n").encode("latin1")
    return b"\x93NUMPY\x01\x00" + len(header).to_bytes(2, "little") + header + bytes(rows * 13)


@pytest.mark.abuse
@pytest.mark.parametrize("descr, message", [
    ("'0<i8'", "'t' is an array of shape (0,)"),  # drawn by the fuzz test once: ValueError from numpy
    ("('<i8', (2,))", "'t' is an array of shape (2,)"),
    ("'<f8'", "'t' is of type float64, not an integer"),
])
def test_field_that_is_not_a_scalar_integer(tmp_path: Path, descr: str, message: str) -> None:
    """A header whose ``t`` field is a sub-array or float: a FormatError
    naming the field, not numpy's ValueError from deep inside."""
    f = tmp_path / "h.npy"
    f.write_bytes(npy_bytes(descr))
    with pytest.raises(FormatError, match=re.escape(message)) as e:
        list(NpySource(str(f), sensor="64x48").packets())
    assert e.value.path == str(f)


def test_npy_bytes_reads_back_in_numpy() -> None:
    a = np.load(io.BytesIO(npy_bytes("'<i8'")))
    assert a.shape == (3,) and a.dtype.names == ("t", "x", "y", "p") and not a["t"].any()
