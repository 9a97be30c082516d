"""Algorithms that are not a generic ILP.

Today: the brute-force reference. The exact MCKP solvers, heuristics and rolling-horizon
schedulers of the solvers issue land here, each returning the same :class:`~l3gs_opt.Solution`.
"""

from .brute_force import MAX_SCHEDULES, solve_brute_force

__all__ = ["MAX_SCHEDULES", "solve_brute_force"]
