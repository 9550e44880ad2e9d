"""Packaging: every package folder is listed; a plain wheel install imports."""

from __future__ import annotations

import os
import subprocess
import sys
import tomllib
import zipfile
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
MAPPING = {"engine": "tectum", "plugins": "tectum.plugins", "sources": "tectum.sources", "sinks": "tectum.sinks",
           "evaluation": "tectum.evaluation"}


def _config() -> dict:
    return tomllib.loads((ROOT / "pyproject.toml").read_text())


def test_every_package_folder_is_listed():
    cfg = _config()["tool"]["setuptools"]
    assert cfg["package-dir"] == {v: k for k, v in MAPPING.items()}
    found = set()
    for folder, pkg in MAPPING.items():
        for init in (ROOT / folder).rglob("__init__.py"):
            rel = init.parent.relative_to(ROOT / folder).parts
            if "__pycache__" not in rel:
                found.add(".".join((pkg, *rel)))
    assert set(cfg["packages"]) == found


def test_every_plugin_entry_point_imports():
    import importlib

    for target in _config()["project"]["entry-points"]["tectum"].values():
        importlib.import_module(target)


def test_a_plain_wheel_install_imports(tmp_path):
    wheels = tmp_path / "wheels"
    subprocess.run([sys.executable, "-m", "pip", "wheel", "-q", "--no-deps", "--no-build-isolation",
                    "-w", str(wheels), str(ROOT)], check=True, capture_output=True)
    (wheel,) = wheels.glob("tectum-*.whl")
    names = zipfile.ZipFile(wheel).namelist()
    assert "tectum/__init__.py" in names and "tectum/plugins/filter/__init__.py" in names
    site = tmp_path / "site"
    subprocess.run([sys.executable, "-m", "pip", "install", "-q", "--no-deps", "--target", str(site), str(wheel)],
                   check=True, capture_output=True)
    code = ("import tectum, tectum.plugins, tectum.sources, tectum.sinks, tectum.cli, tectum.evaluation.harness;"
            "print(tectum.__file__); print(sorted(tectum.get_registry().operators))")
    env = dict(os.environ, PYTHONPATH=str(site))
    out = subprocess.run([sys.executable, "-c", code], env=env, capture_output=True, text=True, cwd=tmp_path)
    assert out.returncode == 0, out.stderr
    assert out.stdout.splitlines()[0].startswith(str(site))
    assert "filter.refractory" in out.stdout
