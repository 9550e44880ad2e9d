"""The core imports no plugin: no module of ``engine/`` (``tectum``), the
command line (``engine/cli/``) aside, imports ``tectum.plugins``,
``tectum.sources``, ``tectum.sinks`` or ``tectum.evaluation``, by an absolute
or a relative import, or by ``importlib.import_module("...")``. Plugins reach
the core through the registry, as pytest's plugins do."""

from __future__ import annotations

import ast
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[1]
ENGINE = ROOT / "engine"
FORBIDDEN = ("tectum.plugins", "tectum.sources", "tectum.sinks", "tectum.evaluation")


def imported_names(path: Path, root: Path = ENGINE) -> list[tuple[int, str]]:
    """(line, absolute module name) of every import in the file at ``path``
    under ``root`` (the folder of package ``tectum``), relative imports
    resolved; ``from X import a`` gives ``X`` and ``X.a`` (``a`` may be a
    module)."""
    tree = ast.parse(path.read_text(), str(path))
    package = ["tectum", *path.relative_to(root).parts[:-1]]  # of __init__.py too: the package itself
    out: list[tuple[int, str]] = []
    for node in ast.walk(tree):
        if isinstance(node, ast.Import):
            out += [(node.lineno, a.name) for a in node.names]
        elif isinstance(node, ast.ImportFrom):
            if node.level:
                base = package[: len(package) - (node.level - 1)]
                module = ".".join([*base, *([node.module] if node.module else [])])
            else:
                module = node.module or ""
            out.append((node.lineno, module))
            out += [(node.lineno, f"{module}.{a.name}") for a in node.names]
        elif (isinstance(node, ast.Call) and node.args and isinstance(node.args[0], ast.Constant)
              and isinstance(node.args[0].value, str)
              and (getattr(node.func, "attr", None) or getattr(node.func, "id", None)) in ("import_module", "__import__")):
            out.append((node.lineno, node.args[0].value))
    return out


def plugin_imports(path: Path, root: Path = ENGINE) -> list[str]:
    """``file:line: imports NAME`` for every import of a plugin package."""
    return [f"{path}:{line}: imports {name}" for line, name in imported_names(path, root)
            if any(name == f or name.startswith(f + ".") for f in FORBIDDEN)]


def core_modules() -> list[Path]:
    """Every module of ``engine/`` but those of the command line."""
    return sorted(p for p in ENGINE.rglob("*.py") if p.relative_to(ENGINE).parts[0] != "cli")


def test_the_core_imports_no_plugin():
    modules = core_modules()
    assert ENGINE / "_registry.py" in modules and ENGINE / "cli" / "bench.py" not in modules
    bad = [msg for p in modules for msg in plugin_imports(p)]
    assert not bad, "the core must not import plugins:\n" + "\n".join(bad)


@pytest.mark.parametrize("source, found", [
    ("from ..evaluation import harness", True),
    ("import tectum.sinks.null", True),
    ("from tectum.plugins.filter import Refractory", True),
    ("from tectum import evaluation", True),
    ("from . import sources", True),
    ("from .sinks.null import NullSink", True),
    ("importlib.import_module('tectum.evaluation.harness')", True),
    ("from tectum import EventPacket", False),
    ("from ._packet import EventPacket", False),
    ("import tectum.sourcesx", False),
])
def test_the_check_sees_every_kind_of_import(tmp_path, source, found):
    """Each line as written in ``engine/_mod.py`` (or, for ``..``, in a
    subpackage ``engine/sub/_mod.py``)."""
    f = tmp_path / ("sub/_mod.py" if source.startswith("from ..") else "_mod.py")
    f.parent.mkdir(exist_ok=True)
    f.write_text(source + "\n")
    assert bool(plugin_imports(f, tmp_path)) == found, imported_names(f, tmp_path)
