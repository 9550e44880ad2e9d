"""mutmut 2 hook for `.ci/mutation` (copied into the scratch copy it mutates).

Each mutant runs only the tests that guard the function it changes: the
mutated line is mapped to its enclosing top-level function (or class) in the
mutated file, and that name to test selections below. Lines outside any
function (constants, imports) run every selection of the file. Mutants of
``@njit(...)`` lines are skipped (cache/nogil/inline change nothing run as
Python), and so, when ``MUTATION_FUNCTIONS`` names some, are mutants outside
those functions.
"""

from __future__ import annotations

import ast
import functools
import os
import shlex
import sys

# file -> {function or class name -> pytest arguments}; "*" is the default for the file
FILES = "tests/sources/files/"
FILTERS = "tests/plugins/filter/"
TESTS: dict[str, dict[str, list[str]]] = {
    "sources/files/_kernels.py": {
        "decode_evt2": [FILES + "test_evt2_reference.py", FILES + "test_kernels.py"],
        "decode_evt3": [FILES + "test_evt3_reference.py", FILES + "test_kernels.py", FILES + "test_fast_path.py"],
        "_wrap_step": [FILES + "test_evt2_reference.py", FILES + "test_evt3_reference.py", FILES + "test_kernels.py"],
        "check_events": [FILES + "test_fast_path.py"],
        "longest_rise": [FILES + "test_fast_path.py", FILES + "test_resync.py"],
        "decode_dat": [FILES + "test_dat_reference.py", FILES + "test_kernels.py"],
        "decode_aedat2": [FILES + "test_aedat2_reference.py"],
    },
    "sources/files/_aedat4_kernels.py": {
        "*": [FILES + "test_aedat4_reference.py", FILES + "test_aedat4_codec.py", FILES + "test_aedat4.py"],
    },
    "plugins/filter/_state.py": {"*": [FILTERS + f"test_{m}.py" for m in (
        "kernels_as_python", "kernel_contracts", "select_filters", "refractory", "stcf", "background_activity",
        "hot_pixel")]},
    **{f"plugins/filter/{m}.py": {"*": [FILTERS + f"test_{t}.py"
                                        for t in (tests, "kernels_as_python", "kernel_contracts")]}
       for m, tests in [("background_activity", "background_activity"), ("stcf", "stcf"), ("refractory", "refractory"),
                        ("hot_pixel", "hot_pixel"), ("rate_limit", "select_filters")]},
}


@functools.cache
def _spans(path: str) -> list[tuple[int, int, str]]:
    """(first line, last line, name) of each top-level function and class (0-based lines)."""
    with open(path + ".bak" if os.path.exists(path + ".bak") else path) as f:
        tree = ast.parse(f.read())
    out = []
    for node in tree.body:
        if isinstance(node, (ast.FunctionDef, ast.ClassDef)):
            first = min([node.lineno] + [d.lineno for d in node.decorator_list])
            out.append((first - 1, (node.end_lineno or node.lineno) - 1, node.name))
    return out


def function_at(path: str, line: int) -> str | None:
    return next((n for a, b, n in _spans(path) if a <= line <= b), None)


def tests_for(path: str, line: int) -> list[str]:
    table = TESTS[path]
    name = function_at(path, line)
    if name in table:
        return table[name]
    if "*" in table:
        return table["*"]
    return sorted({t for ts in table.values() for t in ts})


def pre_mutation(context) -> None:  # type: ignore[no-untyped-def]
    # numba's decorator arguments (cache, nogil, inline) only matter compiled: skipped, not scored
    if context.current_source_line.lstrip().startswith("@njit"):
        context.skip = True
        return
    path = os.path.relpath(context.filename)
    only = os.environ.get("MUTATION_FUNCTIONS")  # comma-separated: mutate only these functions/classes
    if only and function_at(path, context.current_line_index) not in only.split(","):
        context.skip = True
        return
    tests = tests_for(path, context.current_line_index)
    args = " ".join(shlex.quote(t) for t in tests)
    context.config.test_command = f"{shlex.quote(sys.executable)} .ci/mutant_tests.py {args}"
