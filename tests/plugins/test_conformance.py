"""Every built-in operator passes the batch-invariance conformance check.

Operators are found in the registry (so a newly registered built-in is
checked without touching this file) and built with their defaults. An
operator that needs another input than events gives its own stream through
a class attribute ``conformance_stream`` (a callable returning a packet),
and one that has required parameters gives ``conformance_params`` (a dict);
windowed operators are checked the same way, since they emit when the
watermark passes a window's end. Operators with named ports give one packet
per port; each port is split on its own and the ports interleaved.
(``helpers.conformance_case`` picks the stream and parameters.)
"""

from __future__ import annotations

import pytest

from tectum.testing import assert_batch_invariant

from helpers import builtin_operators, conformance_case

BUILTIN = builtin_operators()


def test_there_are_builtin_operators():
    assert "filter.refractory" in BUILTIN


@pytest.mark.parametrize("name", BUILTIN)
def test_batch_invariance(name):
    cls, stream, params = conformance_case(name)
    assert_batch_invariant(lambda: cls(**params), stream, max_examples=8)
