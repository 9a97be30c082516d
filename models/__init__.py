"""Exact formulations (Problems I-IV, the GAP form, the single-slot MCKP, the item form) and their backends.

Each problem is one module building a backend-neutral :class:`LinearModel`; backends
(``cbc``, ``highs``, ``cpsat``, ``scip``) translate and solve it. Nothing here knows scenes or torch.
"""

from .backends import Backend, BackendResult, installed_backends, is_installed, solve_model
from .build import FORMS, build_model
from .ilp import solve_ilp
from .items import build_items_model, solve_items_ilp
from .linear import LinearModel, ModelBuilder

__all__ = [
    "Backend",
    "BackendResult",
    "FORMS",
    "LinearModel",
    "ModelBuilder",
    "build_items_model",
    "build_model",
    "installed_backends",
    "is_installed",
    "solve_ilp",
    "solve_items_ilp",
    "solve_model",
]
