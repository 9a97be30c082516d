"""Method names: the registry parses them, ``l3gs_opt.solve`` and the CLI reach every one."""

from __future__ import annotations

import json

import numpy as np
import pytest

import l3gs_opt
from l3gs_opt.methods import method_names
from l3gs_opt.errors import SolveError
from l3gs_opt.problem.instance import Instance
from l3gs_opt.solvers.registry import names, resolve


def test_names_list_every_method() -> None:
    assert set(names()) >= {"bb", "dp", "fptas:EPS", "greedy", "rolling:SOLVER", "rolling-future:SOLVER", "mpc:H",
                            "progressive", "slope", "static", "brute"}
    assert {"ilp", "lp", "bb", "mpc:H"} <= set(method_names())


@pytest.mark.parametrize("name, message", [
    ("nope", r"method 'nope' is not one of ilp, lp, "),
    ("fptas:0", r"EPS = 0.0 must be in \(0, 1\)"),
    ("fptas:", r"EPS = '' must be a number"),
    ("rolling:", r"give the per-slot solver, e.g. rolling:bb"),
    ("rolling:cplex", r"per-slot solver 'cplex' is not one of bb, dp, fptas:EPS, greedy, ilp"),
    ("rolling-future:fptas:2", r"EPS = 2.0 must be in \(0, 1\)"),
    ("mpc:0", r"H = 0 must be a positive integer"),
    ("mpc:two", r"H = 'two' must be a positive integer"),
])
def test_malformed_names_are_solve_errors(name: str, message: str) -> None:
    with pytest.raises(SolveError, match=message):
        resolve(name)


def test_solve_passes_backend_and_ignores_unused_options() -> None:
    inst = Instance(representation="layered", bandwidth=[3, 3], cost=[[2, 2]], utility=np.ones((2, 1, 2)))
    for method in ("rolling:ilp", "mpc:2"):
        sol = l3gs_opt.solve(inst, method=method, backend="cbc", form="gap", presolve=False)
        assert sol.method == method
        assert sol.arrivals == ((0, 0, 0), (0, 1, 1))
    one = Instance(representation="layered", bandwidth=[3], cost=[[2, 2]], utility=np.ones((1, 1, 2)))
    for method in ("bb", "dp", "greedy", "fptas:0.25"):
        sol = l3gs_opt.solve(one, method=method, backend="cpsat", form="gap", presolve=False, options={"x": 1})
        assert sol.method == method and sol.problem == "MCKP" and sol.slot == 0


def test_cli_solve_reaches_the_solvers(tmp_path, capsys) -> None:
    from l3gs_opt.cli.main import main

    inst = Instance(representation="layered", bandwidth=[3, 3], cost=[[2, 2]], utility=np.ones((2, 1, 2)))
    path = tmp_path / "inst.json"
    path.write_text(json.dumps(inst.to_dict()))
    for method in ("rolling:bb", "slope"):
        assert main(["solve", str(path), "--method", method]) == 0
    assert main(["solve", str(path), "--method", "bb", "--slot", "1"]) == 0
    out = capsys.readouterr().out
    assert "rolling:bb" in out or "feasible" in out


#: A parameter for each parametrised family of the table.
_PARAMS = {"EPS": "0.25", "SOLVER": "bb", "H": "2"}


def _concrete(listed: str) -> str:
    family, sep, param = listed.partition(":")
    return f"{family}:{_PARAMS[param]}" if sep else family


def test_one_table_serves_both_instance_forms() -> None:
    """The item form's methods come from the same table; the Problem I/II-only ones refuse it by name."""
    from l3gs_opt.problem.items import items_from_instance

    assert set(method_names(items=True)) == {"ilp", "lp", "brute", "bb", "dp", "greedy", "fptas:EPS",
                                             "rolling:SOLVER", "rolling-future:SOLVER", "mpc:H"}
    assert set(method_names(items=True)) < set(method_names())
    inst = Instance(representation="layered", bandwidth=[3, 3], cost=[[2, 2]], utility=np.ones((2, 1, 2)))
    items = items_from_instance(inst)
    for name in set(method_names()) - set(method_names(items=True)):
        with pytest.raises(SolveError, match=rf"method '{_concrete(name)}' does not take an item instance"):
            l3gs_opt.solve(items, _concrete(name))


@pytest.mark.parametrize("listed", [n for n in names() if n != "link-dp"])
def test_kind_says_whether_a_method_takes_a_slot(listed: str) -> None:
    """``kind`` in the table agrees with what the method does with ``slot`` (two slots, so a
    single-slot method cannot default to the only one)."""
    from l3gs_opt.solvers.registry import entry

    name = _concrete(listed)
    kind = entry(name).kind
    inst = Instance(representation="layered", bandwidth=[3, 3], cost=[[2, 2]], utility=np.ones((2, 1, 2)))
    if kind in ("slot", "either"):
        assert l3gs_opt.solve(inst, name, slot=1).slot == 1
    else:
        with pytest.raises(SolveError):
            l3gs_opt.solve(inst, name, slot=1)
    if kind in ("horizon", "either"):
        assert l3gs_opt.solve(inst, name).slot is None
    else:
        with pytest.raises(SolveError):
            l3gs_opt.solve(inst, name)
