"""Choose and build the model an instance and a request call for."""

from __future__ import annotations

from l3gs_opt.errors import SolveError
from l3gs_opt.problem.arguments import check_slot
from l3gs_opt.problem.instance import Instance
from l3gs_opt.problem.presolve import presolve

from .gap import build_gap
from .layered import build_layered
from .linear import LinearModel
from .mckp import build_mckp
from .separate import build_separate

__all__ = ["FORMS", "build_model"]

FORMS = ("standard", "gap")


def build_model(instance: Instance, *, form: str = "standard", slot: int | None = None,
                presolve_enabled: bool = True) -> LinearModel:
    """The ILP for ``instance``: Problem I-IV (``form="standard"``), A (``form="gap"``), or the
    single-slot MCKP at ``slot`` given ``held`` (``form`` must then be "standard").

    Raises
    ------
    SolveError
        Unknown form, GAP form of a separate instance, slot out of range.
    """
    if form not in FORMS:
        raise SolveError(f"form {form!r} is not one of {', '.join(FORMS)}")
    if slot is not None:
        slot = check_slot(slot, instance.T)
        if form != "standard":
            raise SolveError("a single-slot problem (slot) has no GAP form")
        return build_mckp(instance, slot, presolved=presolve_enabled)
    reduction = presolve(instance, enabled=presolve_enabled)
    if form == "gap":
        return build_gap(instance, reduction, presolved=presolve_enabled)
    if instance.layered:
        return build_layered(instance, reduction, presolved=presolve_enabled)
    return build_separate(instance, reduction, presolved=presolve_enabled)
