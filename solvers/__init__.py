"""Algorithms that are not a generic ILP.

Single slot (the paper's Lemma 3 MCKP): exact branch-and-bound (``bb``) and DP (``dp``), the
``fptas:EPS`` approximation and the LP-greedy (``greedy``). Multi-slot (Problems I-IV):
rolling-horizon schedulers (``rolling:SOLVER``, ``rolling-future:SOLVER``, ``mpc:H``) and the
order heuristics (``progressive``, ``slope``, ``static``), each reporting the LP relaxation as
a certified bound. ``exact`` (Problems I/III) is branch-and-price on the GAP form: Lagrangian
bounds with per-slot knapsacks, column generation, fixing and branching (next to HiGHS on the
reduced model), LNS and a CP-SAT repair on the primal side, certified gaps under a time limit. Brute force is the reference every one of them is tested against. Item instances
(``l3gs-opt/items@1``: precedence DAG, replacement groups) have their own per-slot MCKP over
precedence-closed item sets, rolling schedulers and brute force (:mod:`.items`).
"""

from .brute_force import MAX_SCHEDULES, solve_brute_force
from .bounds import lp_bound
from .heuristics import slope_fractional_value, solve_progressive, solve_slope, solve_static
from .mckp import solve_bb, solve_dp, solve_fptas, solve_greedy
from .rolling import solve_mpc, solve_rolling
from .exact import solve_exact
from .items import (solve_items_brute_force, solve_items_mpc, solve_items_rolling,
                    solve_items_slot)
from .exact.lagrange import gap_data, lagrangian_value, lp_multipliers, subgradient

__all__ = [
    "MAX_SCHEDULES",
    "lp_bound",
    "slope_fractional_value",
    "solve_bb",
    "solve_brute_force",
    "solve_dp",
    "solve_fptas",
    "solve_greedy",
    "solve_items_brute_force",
    "solve_items_mpc",
    "solve_items_rolling",
    "solve_items_slot",
    "solve_mpc",
    "solve_progressive",
    "solve_rolling",
    "solve_slope",
    "solve_static",
    "solve_exact",
    "gap_data",
    "lagrangian_value",
    "lp_multipliers",
    "subgradient",
]
