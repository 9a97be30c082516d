"""l3gs-opt: optimization models and solvers for delivering layered 3D Gaussian splat scenes.

Quick start::

    import l3gs_opt
    inst = l3gs_opt.load_instance("instance.json")
    sol = l3gs_opt.solve(inst, method="ilp", backend="highs")
    print(sol.status, sol.objective, sol.bound, sol.gap)
"""

from .errors import BackendUnavailableError, InstanceError, L3gsError, SolveError
from .instance import MAX_BYTES, SCHEMA, Instance, Options
from .instance_io import instance_from_dict, load_instance, save_instance
from .evaluate import evaluate_objective, feasibility_violations, is_feasible
from .solution import GAP_TOL, ModelSize, Solution, Status, relative_gap
from .presolve import presolve
from .api import METHODS, method_names, solve

__version__ = "0.1.0"

__all__ = [
    "BackendUnavailableError",
    "GAP_TOL",
    "Instance",
    "InstanceError",
    "L3gsError",
    "MAX_BYTES",
    "METHODS",
    "ModelSize",
    "Options",
    "SCHEMA",
    "Solution",
    "SolveError",
    "Status",
    "evaluate_objective",
    "feasibility_violations",
    "instance_from_dict",
    "is_feasible",
    "load_instance",
    "method_names",
    "presolve",
    "relative_gap",
    "save_instance",
    "solve",
]
