"""The README's Python example runs as written."""

from __future__ import annotations

import re
from pathlib import Path

README = Path(__file__).resolve().parents[1] / "README.md"


def test_python_example_runs(tmp_path, monkeypatch):
    blocks = re.findall(r"```python\n(.*?)```", README.read_text(), re.S)
    assert blocks and len(blocks[0].splitlines()) <= 16
    monkeypatch.chdir(tmp_path)
    exec(compile(blocks[0].replace("duration_us=500_000", "duration_us=50_000"), "README.md", "exec"), {})
    assert (tmp_path / "clean.npz").exists()
