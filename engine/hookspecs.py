"""Every hook specification of tectum, in one place.

Plugins are found through the ``tectum`` entry-point group (built-ins go
through the same group). Each hook receives a *registry* object and calls its
``add_operator`` / ``add_source`` / ``add_sink`` / ``add_macro`` / ``add_bench_suite`` methods; hooks run once, when
the registry is built, never per event. A name registered twice fails at
start-up with both owners named.
"""

from __future__ import annotations

from typing import TYPE_CHECKING

import pluggy

if TYPE_CHECKING:
    from ._registry import RegistryView

PROJECT = "tectum"
hookspec = pluggy.HookspecMarker(PROJECT)
hookimpl = pluggy.HookimplMarker(PROJECT)


@hookspec
def tectum_register_operators(registry: RegistryView) -> None:
    """Register operator classes with ``registry.add_operator(cls)``.

    Each class is a :class:`tectum.Operator` subclass whose ``name`` is
    ``family.method`` with family one of ``filter``, ``flow``, ``lifetime``,
    ``map``, ``tracker``, ``repr``.
    """


@hookspec
def tectum_register_macros(registry: RegistryView) -> None:
    """Register pipeline macros with ``registry.add_macro(cls)``.

    ``cls`` is a :class:`tectum.Macro` subclass named ``family.method`` like
    an operator (a name is an operator or a macro, not both): one name
    that validation expands into several nodes and their wiring (see
    :meth:`tectum.Macro.expand`). Macros are registered after operators.
    """


@hookspec
def tectum_register_kinds(registry: RegistryView) -> None:
    """Register new kinds of sample stream with ``registry.add_kind(cls)``.

    ``cls`` is a :class:`tectum.SamplePacket` subclass with ``kind =
    tectum.Kind("name")`` and its ``fields`` declared as
    :class:`tectum.Field` records (dtype, trailing shape, unit, optional), so
    that the engine can make empty packets, concatenate, merge and slice the
    stream, and the CSV/npz sinks can write it. Kinds are registered before
    operators, sources and sinks, which may then name them.
    """


@hookspec
def tectum_register_sources(registry: RegistryView) -> None:
    """Register source classes with ``registry.add_source(cls)``.

    A source declares the URL ``schemes`` and file ``extensions`` it opens and
    may recognise files by content through ``sniff(head)``.
    """


@hookspec
def tectum_register_sinks(registry: RegistryView) -> None:
    """Register sink classes with ``registry.add_sink(cls)``, chosen the same
    way as sources (scheme, then extension)."""


@hookspec
def tectum_register_bench_suites(registry: RegistryView) -> None:
    """Register suites of ``tectum bench`` with
    ``registry.add_bench_suite(name, run, description)``.

    ``name`` is the word on the command line (``tectum bench NAME``) and
    ``description`` the line ``tectum bench --list`` shows beside it.
    ``run(out: Path, quick: bool) -> dict`` measures on this machine, prints
    its tables, may write charts into the folder ``out`` and returns the
    numbers (JSON-serialisable), which ``tectum bench`` writes to
    ``out/bench-NAME.json``; ``quick`` asks for smaller inputs and fewer
    repeats. A suite that states targets returns them under ``"targets"`` as
    :func:`tectum.evaluation.harness.target` records, which the command
    reports as met or MISSED. Import heavy modules inside ``run``, not at
    registration: the hook runs every time the registry is built.
    """
