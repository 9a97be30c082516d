"""``exact``: Problem I/III (and A) solved to proven optimality by decomposition.

``search`` runs it (start heuristics, the column-generation root, repair and LNS, the reduced MIP
and branch-and-price side by side); ``lagrange`` holds Problem A's data, the Lagrangian bound and
its LP multipliers; ``colgen`` the column-generation master over per-slot fillings; ``lns`` the
window LNS and the reduced MIP; ``repair`` the level-keeping repair.
"""

from .search import solve_exact

__all__ = ["solve_exact"]
