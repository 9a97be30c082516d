"""Simulator method names -> how the method sees the bundle and who schedules (:class:`MethodSpec`)."""

from __future__ import annotations

from dataclasses import dataclass
from typing import Any

from l3gs_opt.errors import SolveError
from l3gs_opt.simulator.config import SimConfig, SimulationError
from l3gs_opt.simulator.schedulers import FixedOrderScheduler, HorizonScheduler, PreloadScheduler, SlotSolverScheduler

__all__ = ["SIM_METHODS", "SLOT_SOLVERS", "ITEM_SOLVERS", "MethodSpec", "method_spec"]

#: The simulator's own methods; every solver method name is accepted too.
SIM_METHODS = ("l3gs", "l3gs-noseg", "separate", "sort", "preload", "distill", "hierarchy")
#: Solver names that solve one slot's MCKP (``--solver`` of l3gs, l3gs-noseg, separate).
SLOT_SOLVERS = ("bb", "dp", "greedy", "fptas:EPS", "ilp", "brute")
#: ``--solver`` of distill and hierarchy: the item MCKP of one slot, or an item method over the
#: rest of the run (whose first slot is sent first).
ITEM_SOLVERS = ("bb", "dp", "greedy", "fptas:EPS", "ilp", "brute", "rolling:SOLVER", "rolling-future:SOLVER",
                "mpc:H")


@dataclass(frozen=True)
class MethodSpec:
    """How a method sees the bundle and who schedules.

    ``view``: ``object``, ``scene``, ``distill`` or ``hierarchy`` units (see
    :mod:`l3gs_opt.simulator.catalog`; the last two give the scheduler an :class:`ItemSlotView`);
    ``order``: ``utility`` (a chunk's splats in descending predicted utility), ``bundle``
    (the catalogue's order) or ``file`` (the chunks' file order, ``SimConfig.splat_order="stored"``); ``preload``: start with the largest model; ``utility`` / ``order_utility``:
    the splat utilities that value units and order splats (None: the simulation's config decides,
    see :meth:`~l3gs_opt.simulator.simulation.Simulation.spec`).
    """

    name: str
    solver: str | None
    view: str
    order: str
    scheduler: Any
    preload: bool = False
    utility: str | None = None
    order_utility: str | None = None


def _is_slot_solver(name: str) -> bool:
    """Whether the method table says ``name`` solves one slot's problem (``kind`` slot or either)."""
    from l3gs_opt.methods import METHODS

    found = METHODS.get(name.partition(":")[0])
    return found is not None and found.kind != "horizon"


def _check_solver_name(name: str, field: str, *, items: bool = False) -> None:
    from l3gs_opt.methods import resolve_method

    if name == "lp":
        raise SimulationError(field, "'lp' is a bound (a relaxation), not a schedule")
    try:
        resolve_method(name, items=items)
    except SolveError as exc:
        raise SimulationError(field, str(exc)) from None


def _item_spec(name: str, solver: str | None, kw: dict, config: SimConfig) -> MethodSpec:
    solver = solver or "bb"
    if not isinstance(solver, str) or not solver:
        raise SimulationError("solver", f"{solver!r} must be a solver name")
    if _is_slot_solver(solver):
        _check_solver_name(solver, "solver", items=True)
        return MethodSpec(name, solver, name, "utility", SlotSolverScheduler(solver, name=name, **kw))
    if solver.startswith(("rolling:", "rolling-future:", "mpc:")):
        _check_solver_name(solver, "solver", items=True)
        return MethodSpec(name, solver, name, "utility",
                          HorizonScheduler(solver, horizon=config.horizon, name=name, **kw))
    raise SimulationError("solver", f"{solver!r} does not schedule an item instance; {name!r} takes one of "
                                    f"{', '.join(ITEM_SOLVERS)}")


def method_spec(name: str, *, solver: str | None = None, representation: str = "layered", variant: str = "layered",
                config: SimConfig = SimConfig()) -> MethodSpec:
    """Resolve a simulator method name for a bundle of ``representation`` and ``variant``.

    Raises
    ------
    SimulationError
        Unknown method or solver; a method that does not apply to the bundle (``l3gs`` on a
        separate bundle, ``separate`` on a layered one, ``sort`` on a bundle not built as ``sort``,
        ``distill`` on one not built as ``distill``, ``hierarchy`` on a layered one); ``solver``
        given to a method that has its own.
    """
    if not isinstance(name, str) or not name:
        raise SimulationError("method", f"{name!r} must be a method name")
    kw = dict(time_limit_s=config.time_limit_s, backend=config.backend, fill=config.fill)
    if config.last_chunk != "whole" and name not in ("l3gs", "l3gs-noseg"):
        # Other methods do not solve the per-slot MCKP (and a separate version shows only when complete).
        raise SimulationError("last_chunk", f"{config.last_chunk!r} changes the per-slot MCKP of l3gs and l3gs-noseg "
                                            f"only, not method {name!r}")
    if name in ("l3gs", "l3gs-noseg", "separate"):
        solver = solver or "bb"
        _check_solver_name(solver, "solver")
        if not _is_slot_solver(solver):
            raise SimulationError("solver", f"{solver!r} does not solve one slot's MCKP; use one of "
                                            f"{', '.join(SLOT_SOLVERS)} (or pass {solver!r} as the method)")
        if name == "separate" and representation != "separate":
            raise SimulationError("method", f"'separate' needs a separate bundle (variant separate or hierarchy), "
                                            f"not {variant!r}")
        if name != "separate" and representation != "layered":
            raise SimulationError("method", f"{name!r} needs a layered bundle (variant layered, sort or distill), "
                                            f"not {variant!r}; use method 'separate'")
        if config.last_chunk != "whole" and solver != "bb":
            raise SimulationError("last_chunk", f"{config.last_chunk!r} is its own exact programme: it replaces the "
                                                f"solver, so solver {solver!r} would not be used (leave it out)")
        view = "object" if name == "l3gs" else "scene"
        return MethodSpec(name, solver, view, "utility",
                          SlotSolverScheduler(solver, name=name, last_chunk=config.last_chunk, **kw))
    if name == "distill":
        if variant != "distill":
            raise SimulationError("method", f"'distill' needs a bundle built as variant distill (compact SH and "
                                            f"SH upgrades), not {variant!r}")
        return _item_spec(name, solver, kw, config)
    if name == "hierarchy":
        if representation != "separate":
            raise SimulationError("method", f"'hierarchy' needs a separate bundle (variant hierarchy or separate), "
                                            f"not {variant!r}")
        return _item_spec(name, solver, kw, config)
    if solver is not None:
        raise SimulationError("solver", f"applies to l3gs, l3gs-noseg, separate, distill and hierarchy only, not to "
                                        f"method {name!r}")
    if name == "sort":
        if variant != "sort":
            raise SimulationError("method", f"'sort' needs a bundle built as variant sort (global-significance "
                                            f"order), not {variant!r}")
        return MethodSpec(name, None, "scene", "bundle", FixedOrderScheduler())
    if name == "preload":
        return MethodSpec(name, None, "scene", "bundle", PreloadScheduler(), preload=True)
    _check_solver_name(name, "method")
    if _is_slot_solver(name) and name not in ("ilp", "brute"):
        return MethodSpec(name, None, "object", "utility", SlotSolverScheduler(name, name=name, **kw))
    return MethodSpec(name, None, "object", "utility", HorizonScheduler(name, horizon=config.horizon, **kw))
