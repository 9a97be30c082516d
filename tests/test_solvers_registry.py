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
