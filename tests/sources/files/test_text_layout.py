"""Text files: the time unit and column order come from the header's names
and the form of the values, and ``tectum info`` says which were assumed."""

from __future__ import annotations

import json
from pathlib import Path

import pytest

from tectum.cli import main
from tectum.sources.files._text_layout import text_layout

ROWS = [(0, 0, 0, 1), (1000, 5, 3, 0), (2500, 7, 1, 1), (999_000, 9, 9, 0)]  # t in µs


@pytest.mark.parametrize("head, unit", [
    (b"t,x,y,p\n0,1,2,1\n15,1,2,0\n", "us"),  # integers: µs
    (b"0.000015 1 2 1\n0.000020 3 4 0\n", "s"),  # decimals: seconds (RPG events.txt)
    (b"1700000000000000000,1,2,1\n", "ns"),  # 19 digits: ns since the epoch
    (b"1700000000000000,1,2,1\n", "us"),  # 16 digits: µs since the epoch
    (b"t_ms,x,y,p\n0,1,2,1\n", "ms"),  # the header names it
    (b"timestamp [ns],x,y,polarity\n0.5,1,2,1\n", "ns"),  # the header beats the form
    (b"time (s),x,y,p\n1,1,2,1\n", "s"),
    (b"ts_us x y p\n0.5 1 2 1\n", "us"),
    (b"# a comment\n%another\n7 1 2 1\n", "us"),
])
def test_time_unit_from_header_or_values(head: bytes, unit: str) -> None:
    assert text_layout(head).time_unit == unit
    assert text_layout(head, time_unit="ms").time_unit == "ms"  # the option beats both


def test_column_order_from_the_header() -> None:
    assert text_layout(b"x,y,timestamp_us,polarity\n1,2,0,1\n").columns == "xytp"
    assert text_layout(b"t,x@320,y@240,on\n0,0,0,1\n").columns == "txyp"
    assert text_layout(b"x,y,ts,p\n", columns="txyp").columns == "txyp"
    assert text_layout(b"a,b,c,d\n1,2,3,1\n").columns == "txyp"


def _info(path: Path, capsys: pytest.CaptureFixture[str]) -> tuple[dict, str]:
    capsys.readouterr()
    assert main(["info", str(path), "--json"]) == 0
    js = json.loads(capsys.readouterr().out)
    assert main(["info", str(path)]) == 0
    return js, capsys.readouterr().out


@pytest.mark.parametrize("header, fmt, unit", [("t,x@320,y@240,on", "{t},{x},{y},{p}", "us"),
                                               ("", "{s:.6f} {x} {y} {p}", "s"),
                                               ("x,y,p,t_ns", "{x},{y},{p},{ns}", "ns")])
def test_info_gives_the_right_duration_and_says_the_unit(tmp_path: Path, capsys: pytest.CaptureFixture[str],
                                                         header: str, fmt: str, unit: str) -> None:
    f = tmp_path / "events.csv"
    lines = [fmt.format(t=t, s=t / 1e6, ns=t * 1000, x=x, y=y, p=p) for t, x, y, p in ROWS]
    f.write_text("\n".join(([header] if header else []) + lines) + "\n")
    js, table = _info(f, capsys)
    assert js["duration_us"] == 999_000 and js["events"] == 4
    assert js["time_unit"].startswith(unit + " (")
    assert f"time unit: {unit} (" in table and "0.999000 s" in table


def test_shared_csv_is_one_second_long(shared: Path, capsys: pytest.CaptureFixture[str]) -> None:
    js, table = _info(shared / "other/dvs.csv", capsys)  # integer µs: the same events as dvs.es, 1 s
    assert js["duration_us"] == 999_000 and js["events"] == 473_225, js
    assert "time unit: us (the times are integers: µs)" in table
