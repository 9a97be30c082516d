"""What a slot's units are worth, and the order of the splats inside a unit, by a named utility.

Two choices, made separately (:class:`Valuation`): the utility that values the units the scheduler
picks from (``SimConfig.utility``, or a run's own) and the one that orders the splats inside a
unit as it streams (``SimConfig.order_utility``; by default the same). Any registered
:mod:`l3gs_opt.pipeline.utilities` name works for either.

* Per-splat values are the utility's mean over the slot's predicted viewpoints. A held-free
  utility's values depend on the slot only and are computed once per (slot, utility) for every
  run on the simulation; a held-aware one (``visibility-held``, ``coverage``, ``counterfactual``)
  is recomputed for each client from the splats it shows at the slot's start.
* A unit's value is the sum of its splats' values, or (a utility with its own
  :meth:`~l3gs_opt.pipeline.utilities.SplatUtility.chunk_values`, e.g. ``counterfactual``) what
  that gives for the unit's rows. ``distill`` units split each splat's value between its compact
  form and its SH upgrade (``sh_upgrade_utility``).
* ``utility_mode="table"``: unit values are looked up in a precomputed viewpoint table of the
  utility (held-free utilities only), built on a 3 x 3 grid over the viewer's positions.
"""

from __future__ import annotations

import dataclasses
import time
from typing import Any

import numpy as np

from l3gs_opt.pipeline.utilities import SplatUtility
from l3gs_opt.simulator.catalog import Catalog
from l3gs_opt.simulator.config import SimulationError

__all__ = ["Valuation"]


class Valuation:
    """Unit values and splat order of one (utility, order utility) pair on a simulation."""

    def __init__(self, sim: Any, utility: str, order_utility: str):
        from l3gs_opt.pipeline.utilities import UtilityNameError, get_utility

        try:
            self.utility = get_utility(utility)
            self.order = get_utility(order_utility)
        except UtilityNameError as exc:
            raise SimulationError("utility", str(exc)) from None
        if sim.config.utility_mode == "table" and self.utility.held_aware:
            raise SimulationError("utility_mode", f"'table': utility {utility!r} depends on what is held and "
                                                  "cannot be tabulated; use utility_mode 'exact'")
        self.sim = sim

    @property
    def held_aware(self) -> bool:
        """Whether either utility depends on what the client holds."""
        return self.utility.held_aware or self.order.held_aware

    # -- per-splat values ---------------------------------------------------------------------------
    def splat_values(self, which: Any, t: int, held: np.ndarray | None) -> np.ndarray:
        """Mean per-splat values of utility ``which`` over slot ``t``'s predicted viewpoints."""
        sim = self.sim
        cams = sim.prediction(t)["cameras"]
        if not which.held_aware:
            key = (t, which.name)
            if key not in sim.values_cache:
                sim.values_cache[key] = which.splat_values(sim.prepared(which), cams)
            return sim.values_cache[key]
        return which.splat_values(sim.prepared(which), cams, held=held)

    # -- unit values ----------------------------------------------------------------------------------
    def unit_values(self, t: int, cat: Catalog, held: np.ndarray | None) -> tuple[np.ndarray, float]:
        """Predicted value per unit (shape ``cat.grid``) and the seconds it took."""
        t0 = time.perf_counter()
        J, L = cat.shape
        u = None
        if self.sim.config.utility_mode == "table":
            cams = self.sim.prediction(t)["cameras"]
            got = np.mean([self._table(cat).lookup(c) for c in cams], axis=0)
            cells = np.zeros((J, L))
            cells[:got.shape[0], :got.shape[1]] = got[:J, :L]
        elif type(self.utility).chunk_values is not SplatUtility.chunk_values:   # its own chunk values
            cams = self.sim.prediction(t)["cameras"]
            by_cell = np.argsort(cat.unit_of_row, kind="stable")
            ends = np.cumsum(np.bincount(cat.unit_of_row, minlength=J * L))
            chunks = np.split(by_cell, ends[:-1])
            cells = self.utility.chunk_values(self.sim.prepared(self.utility), cams, chunks,
                                              held=held).reshape(J, L)
        else:
            u = self.splat_values(self.utility, t, held)
            cells = np.bincount(cat.unit_of_row, weights=u, minlength=J * L).reshape(J, L)
        if len(cat.forms) == 1:
            return cells, time.perf_counter() - t0
        f = self.sim.distill_arrays()[1]
        if u is not None:
            upgrade = np.bincount(cat.unit_of_row, weights=u * f, minlength=J * L).reshape(J, L)
        else:   # no per-splat values: each cell's mean share
            n = np.bincount(cat.unit_of_row, minlength=J * L)
            share = np.bincount(cat.unit_of_row, weights=f, minlength=J * L) / np.maximum(n, 1)
            upgrade = cells * share.reshape(J, L)
        return np.stack([np.clip(cells - upgrade, 0.0, None), upgrade], axis=-1), time.perf_counter() - t0

    def _table(self, cat: Catalog):
        sim = self.sim
        # distill and hierarchy units sit on the object view's (object, level) cells
        name = (self.utility.name, "object" if cat.view in ("distill", "hierarchy") else cat.view)
        if name in sim.tables:
            return sim.tables[name]
        if name in sim.given_tables:    # given for this utility and view
            sim.tables[name] = sim.given_tables[name]
            return sim.tables[name]
        if self.utility.name == "eq1" and name[1] in sim.given_tables:
            sim.tables[name] = sim.given_tables[name[1]]
            return sim.tables[name]
        from l3gs_opt.pipeline.utilities import tabulate

        J, L = cat.shape
        labelled = dataclasses.replace(sim.scene, object_ids=(cat.unit_of_row // L).astype(np.int32),
                                       layers=(cat.unit_of_row % L).astype(np.int32))
        centres = np.array([c.center for c in sim.cameras_of(sim.poses.features)])
        lo, hi = centres.min(axis=0), centres.max(axis=0)
        up = int(np.argmin(hi - lo))   # the axis the viewer moves least along: its height
        axes = [a for a in range(3) if a != up]
        grid = []
        for a in np.linspace(lo[axes[0]], hi[axes[0]], 3):
            for b in np.linspace(lo[axes[1]], hi[axes[1]], 3):
                p = np.empty(3)
                p[axes[0]], p[axes[1]], p[up] = a, b, centres[:, up].mean()
                grid.append(p)
        cfg = sim.config
        sim.tables[name] = tabulate(self.utility, labelled, np.array(grid), yaw_steps=12,
                                    pitches_deg=(-20.0, 0.0, 20.0), up_axis=up, width=cfg.width, height=cfg.height,
                                    fov_deg=cfg.fov_deg)
        return sim.tables[name]

    # -- splat order ----------------------------------------------------------------------------------
    def value_source(self, t: int, cat: Catalog, held: np.ndarray | None):
        """``() -> float array [N]``: the value utility's per-splat values for slot ``t``, computed
        on the first call (for ``last_chunk="prefix"``, which sums a unit's first splats).

        Raises
        ------
        SimulationError
            No per-splat values to sum: ``utility_mode="table"``, a utility with its own chunk
            values, or units with forms (``distill``).
        """
        if self.sim.config.utility_mode == "table" or len(cat.forms) > 1 \
                or type(self.utility).chunk_values is not SplatUtility.chunk_values:
            why = ("utility_mode 'table' has no per-splat values" if self.sim.config.utility_mode == "table" else
                   "distill units split each splat between two forms" if len(cat.forms) > 1 else
                   f"utility {self.utility.name!r} values whole chunks, not splats")
            raise SimulationError("last_chunk", f"'prefix' counts a chunk's first splats: {why}")
        box: dict = {}

        def values() -> np.ndarray:
            if not box:
                box["value"] = self.splat_values(self.utility, t, held)
            return box["value"]

        return values

    def splat_order(self, t: int, cat: Catalog, k: int, held: np.ndarray | None) -> np.ndarray:
        """Rows of unit ``k`` in descending predicted value of its form by the order utility (stable:
        ties keep the bundle's order)."""
        rows = cat.rows[k]
        if self.sim.config.utility_mode == "table" and self.order.name == "eq1":
            # no per-splat values in table mode: Eq. 1 of this chunk's splats only
            from l3gs_opt.pipeline.splat_utility import splat_utility

            sub = self.sim.scene.subset(rows)
            u_rows = np.mean([splat_utility(sub, c) for c in self.sim.prediction(t)["cameras"]], axis=0)
        else:
            u_rows = self.splat_values(self.order, t, held)[rows]
        if len(cat.forms) > 1:
            f = self.sim.distill_arrays()[1][rows]
            u_rows = u_rows * (f if k % len(cat.forms) == 1 else 1.0 - f)
        return rows[np.argsort(-u_rows, kind="stable")]

