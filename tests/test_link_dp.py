"""``link-dp``: the exact optimum of cumulative-budget instances, checked against brute force (which
shares no code with it) and the ILP, and its refusals."""

from __future__ import annotations

import zlib

import numpy as np
import pytest

from l3gs_opt.methods import solve
from l3gs_opt.errors import SolveError
from l3gs_opt.problem.evaluate import evaluate_objective, feasibility_violations
from l3gs_opt.problem.instance import Instance, Options
from l3gs_opt.problem.solution import Status
from l3gs_opt.solvers import solve_brute_force
from l3gs_opt.solvers.link_dp import link_dp_states, solve_link_dp


def _random_instance(rng, representation: str, *, availability: str = "same_slot", held: bool = False) -> Instance:
    J, L, T = int(rng.integers(1, 3)), int(rng.integers(1, 4)), int(rng.integers(1, 4))
    cost = rng.integers(1, 10, (J, L))
    utility = rng.random((T, J, L)) * (rng.random((T, J, L)) > 0.2)   # some zero utilities
    bandwidth = rng.integers(0, 15, T)
    h = np.zeros((J, L), bool)
    if held:
        if representation == "layered":
            h[:, 0] = True
        else:
            h[0, L - 1] = True
    return Instance(representation, bandwidth=bandwidth, cost=cost, utility=utility, held=h,
                    options=Options(budget="cumulative", availability=availability))


@pytest.mark.parametrize("representation", ["layered", "separate"])
@pytest.mark.parametrize("availability", ["same_slot", "next_slot"])
@pytest.mark.parametrize("held", [False, True])
def test_link_dp_equals_brute_force(representation, availability, held):
    rng = np.random.default_rng(zlib.crc32(f"{representation}/{availability}/{held}".encode()))   # fixed seeds
    for _ in range(12):
        inst = _random_instance(rng, representation, availability=availability, held=held)
        got = solve_link_dp(inst)
        ref = solve_brute_force(inst)
        assert got.status is Status.OPTIMAL
        assert feasibility_violations(inst, got.arrivals) == []
        # 1e-9 relative: both are float64 sums of the same few terms in different orders.
        assert got.objective == pytest.approx(ref.objective, rel=1e-9, abs=1e-12)
        assert got.objective == pytest.approx(evaluate_objective(inst, got.arrivals), rel=1e-12)


def test_link_dp_agrees_with_the_ilp_on_a_larger_instance():
    rng = np.random.default_rng(7)
    J, L, T = 3, 3, 8
    inst = Instance("layered", bandwidth=rng.integers(5, 40, T), cost=rng.integers(5, 30, (J, L)),
                    utility=rng.random((T, J, L)), options=Options(budget="cumulative"))
    dp, ilp = solve_link_dp(inst), solve(inst, "ilp", backend="highs", time_limit_s=60)
    assert ilp.status is Status.OPTIMAL
    assert dp.objective == pytest.approx(ilp.objective, rel=1e-7)
    assert dp.details["states"] == link_dp_states(inst) == (L + 1) ** J


def test_link_dp_refuses_what_it_cannot_solve():
    inst = Instance("layered", bandwidth=[5, 5], cost=[[2, 3]], utility=np.ones((2, 1, 2)))
    with pytest.raises(SolveError, match="needs options.budget 'cumulative'"):
        solve_link_dp(inst)
    strict = Instance("layered", bandwidth=[5, 5], cost=[[2, 3]], utility=np.ones((2, 1, 2)),
                      options=Options(budget="cumulative", same_slot_layers=False))
    with pytest.raises(SolveError, match="strict layers"):
        solve_link_dp(strict)
    big = Instance("separate", bandwidth=[5], cost=np.ones((3, 4), int), utility=np.ones((1, 3, 4)),
                   options=Options(budget="cumulative"))
    with pytest.raises(SolveError, match="4096 states exceed max_states = 100"):
        solve_link_dp(big, max_states=100)


def test_link_dp_is_a_method_of_solve():
    """Registered as ``link-dp``: through :func:`l3gs_opt.solve` it equals the ILP; it refuses a slot."""
    rng = np.random.default_rng(7)
    inst = _random_instance(rng, "layered")
    via_api = solve(inst, "link-dp")
    ilp = solve(inst, "ilp")
    assert via_api.status is Status.OPTIMAL and ilp.status is Status.OPTIMAL
    assert via_api.objective == pytest.approx(ilp.objective, rel=1e-9)
    with pytest.raises(SolveError, match="link-dp"):
        solve(inst, "link-dp", slot=0)
