"""Event text files and their companion files against a slow reader written
from the layout's description (``sources/files/text.py``, ``_text_layout.py``).

Hypothesis draws events and writes them in a drawn layout: column order
(named by a header, or the default ``t x y p`` without one), separators
(spaces, tabs, commas, CRLF), polarity 0/1 or -1/+1, time unit (seconds as
decimals with sub-µs digits, ms and ns named by the header, µs integers),
comment lines; and, beside ``events.txt``, the RPG dataset's ``imu.txt``,
``groundtruth.txt`` and ``images.txt`` with PNG frames (rows of the wrong
length and comments among them, times out of order). The reference splits
each line, turns the time into µs with :class:`decimal.Decimal` (rounded
half up) and sorts the companions by time; tectum's packets must equal it
value by value: t, x, y, p, IMU, poses, frames (pixels and times).
"""

from __future__ import annotations

from pathlib import Path

import pytest

from tectum import EventPacket, concat
from tectum.sources.files.text import TextSource

cv2 = pytest.importorskip("cv2")

def test_ns_since_the_epoch_of_today(tmp_path: Path) -> None:
    """Times in ns since the epoch have 19 digits since 2001 and fit int64:
    they read, rounded half up to µs like every unit; 20 digits do not fit
    and are named. A header after comment lines is a header."""
    f = tmp_path / "e.csv"
    f.write_text("t_ns,x,y,p\n1700000000000001499,1,2,1\n1700000000000002500,3,4,0\n9223372036854775000,0,0,1\n")
    ev = concat([q for q in TextSource(str(f)).packets() if isinstance(q, EventPacket)])
    assert ev.t.tolist() == [1700000000000001, 1700000000000003, 9223372036854775]
    f.write_text("t_ns,x,y,p\n1700000000000001499,1,2,1\n10000000000000000000,3,4,0\n")
    with pytest.raises(Exception, match="time out of the int64 µs range"):
        list(TextSource(str(f)).packets())
    f.write_text("# comment\n\nt,x,y,p\n5,1,2,1\n")
    assert next(iter(TextSource(str(f)).packets())).t.tolist() == [5]
    f.write_text("t,x,y,p\n5,1,99999999999999999999,1\n")
    with pytest.raises(Exception, match="coordinate above 65535"):
        list(TextSource(str(f)).packets())
