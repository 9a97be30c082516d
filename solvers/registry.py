"""The one method table: every method name, for both instance forms, resolved to a function.

``resolve(name)`` returns ``function(instance, *, backend, form, slot, time_limit_s, presolve,
options) -> Solution`` for an :class:`~l3gs_opt.problem.instance.Instance`, ``resolve(name,
items=True)`` the same for an :class:`~l3gs_opt.problem.items.ItemInstance`. Parametrised names
(``"fptas:0.01"``, ``"rolling:bb"``, ``"rolling-future:fptas:0.1"``, ``"mpc:5"``) are parsed here
and nowhere else; :func:`l3gs_opt.solve`, the simulator and the bench ask this table.

Each :class:`MethodEntry` says which of ``solve``'s options the method uses (``uses``): the others
are accepted and ignored, and :func:`l3gs_opt.solve` warns when one is given away from its default.
Its ``kind`` says what it schedules: ``slot`` (one slot's MCKP only: ``bb``, ``dp``, ``greedy``,
``fptas:EPS``; they need ``slot`` unless the instance has one slot), ``horizon`` (the whole
horizon only: ``exact``, ``rolling:*``, ``rolling-future:*``, ``mpc:H``, ``progressive``,
``slope``, ``static``, ``link-dp``, ``anneal``; they refuse a ``slot``) or ``either`` (``ilp``, ``lp``,
``brute``).
"""

from __future__ import annotations

import functools
import warnings
from dataclasses import dataclass
from typing import Any, Callable, Mapping

from l3gs_opt.errors import SolveError
from l3gs_opt.problem.solution import Solution

__all__ = ["MethodEntry", "SolverFn", "entry", "names", "resolve"]

SolverFn = Callable[..., Solution]
#: ``solve``'s options a method may use beyond ``slot`` and ``time_limit_s``.
MODEL_OPTIONS = ("backend", "form", "presolve")


@dataclass(frozen=True)
class MethodEntry:
    """One method family of the table.

    ``name``: as listed (``fptas:EPS`` for a parametrised one); ``kind``: ``slot``, ``horizon`` or
    ``either`` (see the module doc); ``uses``: the options of :data:`MODEL_OPTIONS` it uses;
    ``instance`` / ``items``: ``build(parameter) -> SolverFn`` for each instance form, ``None``
    where the method does not apply (``parameter`` is the text after the first ``:``, or ``""``).
    """

    name: str
    kind: str
    uses: tuple[str, ...]
    instance: Callable[[str], SolverFn] | None
    items: Callable[[str], SolverFn] | None


def _with_bound(options: Mapping[str, Any] | None) -> bool:
    """``options={"bound": False}`` skips the LP bound of the multi-slot heuristics."""
    if options and "bound" in options:
        return bool(options["bound"])
    return True


# -- builders: parameter text -> solver function -------------------------------------------------------

def _model(relax: bool, items: bool) -> Callable[[str], SolverFn]:
    def build(_param: str) -> SolverFn:
        from l3gs_opt.models import solve_ilp, solve_items_ilp

        def run(instance: Any, *, backend: str = "highs", form: str = "standard", slot: int | None = None,
                time_limit_s: float | None = None, presolve: bool = True, options: Any = None) -> Solution:
            fn = solve_items_ilp if items else solve_ilp
            return fn(instance, backend=backend, form=form, slot=slot, time_limit_s=time_limit_s,
                      presolve=presolve, relax=relax, options=options)

        return run

    return build


#: Options of ``exact`` (passed as ``options={...}``).
EXACT_OPTIONS = ("branching", "lns_width", "heuristics", "max_nodes")


def _exact(_param: str) -> SolverFn:
    from .exact.search import solve_exact

    def run(instance: Any, *, slot: int | None = None, time_limit_s: float | None = None, options: Any = None,
            **_unused: Any) -> Solution:
        opts = dict(options or {})
        for key in [k for k in opts if k not in EXACT_OPTIONS]:
            warnings.warn(f"method 'exact': option {key!r} is unknown (known: {', '.join(EXACT_OPTIONS)}); "
                          "ignored", stacklevel=4)
            opts.pop(key)
        return solve_exact(instance, slot=slot, time_limit_s=time_limit_s, **opts)

    return run


def _brute(items: bool) -> Callable[[str], SolverFn]:
    def build(_param: str) -> SolverFn:
        def run(instance: Any, *, slot: int | None = None, **_unused: Any) -> Solution:
            if items:
                from .items import solve_items_brute_force

                return solve_items_brute_force(instance, slot=slot)
            from .brute_force import solve_brute_force

            return solve_brute_force(instance, slot=slot)

        return run

    return build


def _single(name: str, items: bool) -> Callable[[str], SolverFn]:
    def build(param: str) -> SolverFn:
        from . import mckp
        from .rolling import parse_eps

        label = f"{name}:{param}" if name == "fptas" else name
        eps = parse_eps(label) if name == "fptas" else None

        def run(instance: Any, *, slot: int | None = None, time_limit_s: float | None = None,
                backend: str = "highs", **_unused: Any) -> Solution:
            if items:
                from .items import solve_items_slot

                return solve_items_slot(instance, label, slot=slot, time_limit_s=time_limit_s, backend=backend)
            if eps is not None:
                return mckp.solve_fptas(instance, eps, slot=slot, time_limit_s=time_limit_s)
            fn = {"bb": mckp.solve_bb, "dp": mckp.solve_dp, "greedy": mckp.solve_greedy}[name]
            return fn(instance, slot=slot, time_limit_s=time_limit_s)

        run.__name__ = f"solve_{name}"
        return run

    return build


def _order(kind: str) -> Callable[[str], SolverFn]:
    def build(_param: str) -> SolverFn:
        from . import heuristics

        fn = {"progressive": heuristics.solve_progressive, "slope": heuristics.solve_slope,
              "static": heuristics.solve_static}[kind]

        def run(instance: Any, *, slot: int | None = None, time_limit_s: float | None = None,
                options: Any = None, **_unused: Any) -> Solution:
            return fn(instance, slot=slot, time_limit_s=time_limit_s, with_bound=_with_bound(options))

        return run

    return build


def _rolling(future: bool, items: bool) -> Callable[[str], SolverFn]:
    prefix = "rolling-future" if future else "rolling"

    def build(solver: str) -> SolverFn:
        from . import rolling

        if not solver:
            raise SolveError(f"method '{prefix}:': give the per-slot solver, e.g. {prefix}:bb")
        rolling.slot_picker(solver)   # validate the per-slot solver name now

        def run(instance: Any, *, slot: int | None = None, time_limit_s: float | None = None,
                backend: str = "highs", options: Any = None, **_unused: Any) -> Solution:
            if items:
                from .items import solve_items_rolling as fn
            else:
                fn = rolling.solve_rolling
            return fn(instance, solver, future=future, slot=slot, time_limit_s=time_limit_s, backend=backend,
                      with_bound=_with_bound(options))

        return run

    return build


def _mpc(text: str) -> SolverFn:
    from . import rolling

    try:
        horizon = int(text)
    except ValueError:
        raise SolveError(f"method 'mpc:{text}': H = {text!r} must be a positive integer (slots)") from None
    if horizon < 1:
        raise SolveError(f"method 'mpc:{text}': H = {horizon} must be a positive integer (slots)")

    def run(instance: Any, *, slot: int | None = None, time_limit_s: float | None = None,
            backend: str = "highs", options: Any = None, **_unused: Any) -> Solution:
        # solve_mpc takes either instance form.
        return rolling.solve_mpc(instance, horizon, slot=slot, time_limit_s=time_limit_s, backend=backend,
                                 with_bound=_with_bound(options))

    return run


def _anneal(_param: str) -> SolverFn:
    def run(instance: Any, *, slot: int | None = None, time_limit_s: float | None = None, options: Any = None,
            **_unused: Any) -> Solution:
        from .exact.anneal import solve_anneal

        return solve_anneal(instance, slot=slot, time_limit_s=time_limit_s, with_bound=_with_bound(options))

    return run


def _link_dp(_param: str) -> SolverFn:
    def run(instance: Any, *, slot: int | None = None, time_limit_s: float | None = None,
            **_unused: Any) -> Solution:
        from .link_dp import solve_link_dp

        if slot is not None:
            raise SolveError("method 'link-dp' schedules every slot; it takes no slot")
        return solve_link_dp(instance, time_limit_s=time_limit_s)

    return run


def _entries() -> dict[str, MethodEntry]:
    E = MethodEntry
    rows = [
        E("ilp", "either", MODEL_OPTIONS, _model(False, False), _model(False, True)),
        E("lp", "either", MODEL_OPTIONS, _model(True, False), _model(True, True)),
        E("exact", "horizon", (), _exact, None),
        E("brute", "either", (), _brute(False), _brute(True)),
        *(E(n, "slot", (), _single(n, False), _single(n, True)) for n in ("bb", "dp", "greedy")),
        E("fptas:EPS", "slot", (), _single("fptas", False), _single("fptas", True)),
        E("rolling:SOLVER", "horizon", ("backend",), _rolling(False, False), _rolling(False, True)),
        E("rolling-future:SOLVER", "horizon", ("backend",), _rolling(True, False), _rolling(True, True)),
        E("mpc:H", "horizon", ("backend",), _mpc, _mpc),
        *(E(n, "horizon", (), _order(n), None) for n in ("progressive", "slope", "static")),
        E("link-dp", "horizon", (), _link_dp, None),
        E("anneal", "horizon", (), _anneal, None),
    ]
    return {e.name.split(":", 1)[0]: e for e in rows}


#: Family (the name before any ``:``) -> its entry.
TABLE: dict[str, MethodEntry] = _entries()


def names(*, items: bool = False) -> list[str]:
    """Method names of one instance form, as listed (``ilp`` and ``lp`` first, then sorted;
    parametrised ones with their parameter, e.g. ``fptas:EPS``)."""
    listed = [e.name for e in TABLE.values() if (e.items if items else e.instance) is not None]
    return ["ilp", "lp", *sorted(n for n in listed if n not in ("ilp", "lp"))]


def entry(name: str) -> MethodEntry:
    """The table entry of a method name (``"fptas:0.1"`` -> the ``fptas:EPS`` entry).

    Raises
    ------
    SolveError
        Not a string, or no such method.
    """
    if not isinstance(name, str):
        raise SolveError(f"method {name!r} must be a string")
    family, sep, _ = name.partition(":")
    found = TABLE.get(family)
    if found is None or bool(sep) != (":" in found.name):
        raise SolveError(f"method {name!r} is not one of {', '.join(names())}")
    return found


@functools.lru_cache(maxsize=128)
def resolve(name: str, *, items: bool = False) -> SolverFn:
    """The function behind a method name for the ``Instance`` form (``items=False``) or the item
    form; unknown or malformed names, and methods that do not take that form, are a
    :class:`SolveError`."""
    found = entry(name)
    build = found.items if items else found.instance
    if build is None:
        raise SolveError(f"method {name!r} does not take an item instance (l3gs-opt/items@1); item methods: "
                         f"{', '.join(names(items=True))}")
    return build(name.partition(":")[2])
