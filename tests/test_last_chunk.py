"""The per-slot MCKP whose bytes may end inside one chunk (``SimConfig.last_chunk="prefix"``).

Checked against brute force over every whole-chunk choice and partial chunk (hypothesis), against
the single-slot ``bb`` solver where a chunk is worth nothing until complete, and in the simulator
against the splats that actually arrive (oracle bandwidth and viewport: the plan's predicted value
is the value of what the viewer holds after the slot).
"""

from __future__ import annotations

import itertools

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

import l3gs_opt.simulator.last_chunk as last_chunk
from l3gs_opt.checks import ArgumentError
from l3gs_opt.problem.instance import Instance
from l3gs_opt.methods import solve
from l3gs_opt.simulator.last_chunk import plan_last_chunk
from l3gs_opt.simulator.simulation import SimConfig, Simulation, SimulationError
from cli_helpers import one_error_line, tiny_sort_bundle

REL = 1e-9


@st.composite
def slots(draw, signed=True, all_or_nothing=False):
    J, L = draw(st.integers(1, 4)), draw(st.integers(1, 3))   # J = 4: two levels of _all_but_one
    bps = draw(st.sampled_from([1, 2, 3, 6]))
    splats = np.array(draw(st.lists(st.integers(1, 6), min_size=J * L, max_size=J * L))).reshape(J, L)
    per = np.array(draw(st.lists(st.sampled_from([bps, 2 * bps]), min_size=J * L, max_size=J * L))).reshape(J, L)
    empty = np.array(draw(st.lists(st.booleans(), min_size=J * L, max_size=J * L))).reshape(J, L) \
        if draw(st.booleans()) else np.zeros((J, L), bool)
    held_levels = [draw(st.integers(0, L)) for _ in range(J)]
    held = np.array([[l < h for l in range(L)] for h in held_levels])
    low = -5.0 if signed else 0.0
    values = {(j, l): np.array(draw(st.lists(st.floats(low, 10.0), min_size=int(splats[j, l]),
                                             max_size=int(splats[j, l]))))
              for j in range(J) for l in range(L)}
    if all_or_nothing:
        prefix = {k: np.concatenate([np.zeros(len(v)), [v.sum()]]) for k, v in values.items()}
    else:
        prefix = {k: np.concatenate([[0.0], np.cumsum(v)]) for k, v in values.items()}
    utility = np.array([[prefix[(j, l)][-1] for l in range(L)] for j in range(J)])
    cost = splats * per
    capacity = draw(st.integers(0, int(cost.sum()) + 3))
    return dict(cost=cost, utility=np.where(empty, 0.0, utility), held=held, empty=empty, capacity=capacity,
                prefix=lambda unit: prefix[unit], bytes_per_splat=per)


def brute(s) -> float:
    """Best value over every choice of whole layers per object and at most one partial layer."""
    cost, util, held, empty, cap = s["cost"], s["utility"], s["held"], s["empty"], s["capacity"]
    J, L = cost.shape
    start = [int(np.cumprod(held[j] | empty[j]).sum()) for j in range(J)]
    best = 0.0
    for ks in itertools.product(*[range(L - start[j] + 1) for j in range(J)]):
        layers = [(j, l) for j in range(J) for l in range(start[j], start[j] + ks[j]) if not empty[j, l]]
        used = sum(int(cost[u]) for u in layers)
        if used > cap:
            continue
        value = sum(float(util[u]) for u in layers)
        best = max(best, value)
        for j in range(J):
            nxt = [l for l in range(start[j] + ks[j], L) if not empty[j, l]]
            if not nxt or any(not empty[j, m] for m in range(start[j] + ks[j], nxt[0])):
                continue
            p = (j, nxt[0])
            pre = s["prefix"](p)
            n = min((cap - used) // int(s["bytes_per_splat"][p]), len(pre) - 1)
            best = max(best, value + float(pre[n]))
    return best


def evaluate(s, plan) -> tuple[float, int]:
    """The plan's value and whole-chunk bytes, summed from the slot as given."""
    used = sum(int(s["cost"][u]) for u in plan.picks)
    value = sum(float(s["utility"][u]) for u in plan.picks)
    if plan.partial is not None:
        pre = s["prefix"](plan.partial)
        value += float(pre[min((s["capacity"] - used) // int(s["bytes_per_splat"][plan.partial]), len(pre) - 1)])
    return value, used


def closed(s, plan) -> bool:
    """Every pick and the partial have their lower non-empty layers held or picked."""
    have = {u for u in plan.picks}
    units = [*plan.picks, *([plan.partial] if plan.partial else [])]
    return all(s["held"][j, m] or s["empty"][j, m] or (j, m) in have for j, l in units for m in range(l))


@settings(max_examples=300, deadline=None)
@given(slots())
def test_plan_matches_brute_force(s):
    plan = plan_last_chunk(**s)
    want = brute(s)
    assert plan.value == pytest.approx(want, rel=REL, abs=1e-9)
    value, used = evaluate(s, plan)
    assert used <= s["capacity"] and closed(s, plan)
    assert value == pytest.approx(plan.value, rel=REL, abs=1e-9)
    assert plan.whole_value <= plan.value + 1e-9
    assert plan.partial is None or plan.partial not in plan.picks


@settings(max_examples=150, deadline=None)
@given(slots(signed=False, all_or_nothing=True))
def test_chunks_worth_nothing_until_complete_give_the_single_slot_mckp(s):
    """The identity: with no value before a chunk completes, the plan is the paper's MCKP (bb)."""
    plan = plan_last_chunk(**s)
    cost = np.where(s["empty"], 0, s["cost"])
    if s["empty"].any() or s["capacity"] == 0:
        return   # (the instance form has no empty layers of cost 0 and no zero budget)
    inst = Instance("layered", bandwidth=[s["capacity"]], cost=cost, utility=s["utility"][None],
                    held=s["held"])
    sol = solve(inst, "bb", slot=0)
    held_value = float(s["utility"][s["held"]].sum())   # (the instance's objective counts what is held)
    assert plan.value + held_value == pytest.approx(sol.objective, rel=1e-7, abs=1e-7)


@settings(max_examples=100, deadline=None)
@given(slots())
def test_a_coarse_grid_still_fits_the_bytes(s):
    exact = plan_last_chunk(**s)
    old = last_chunk.MAX_GRID
    last_chunk.MAX_GRID = 2
    try:
        coarse = plan_last_chunk(**s)
    finally:
        last_chunk.MAX_GRID = old
    value, used = evaluate(s, coarse)
    assert used <= s["capacity"] and closed(s, coarse)
    assert value <= exact.value + 1e-9   # (the partial may get more bytes than planned: no lower bound)


# -- in the simulator ---------------------------------------------------------------------------
@pytest.fixture(scope="module")
def world(tmp_path_factory):
    w = tiny_sort_bundle(tmp_path_factory.mktemp("lastchunk"), "sort")
    return {**w, "teacher": w["scene"]}


def _sim(world, bandwidth, **kw):
    config = SimConfig(width=64, height=48, samples_per_slot=1, viewport="oracle", bandwidth_predictor="oracle",
                       utility="visibility", **kw)
    return Simulation(world["bundle"], world["log"], bandwidth, config=config, reference=world["teacher"])


@pytest.mark.parametrize("splat_order", ["method", "stored"])
def test_one_slot_holds_what_the_plan_valued(world, splat_order):
    """Oracle bandwidth and viewport: after one slot the viewer holds the plan's whole chunks and
    the partial's first splats in streaming order, and their values (summed independently over
    the rows shown) are the plan's value, at least the whole-chunk plan's."""
    cat_sim = _sim(world, [1], splat_order=splat_order)
    cat = cat_sim.catalog("object")
    J, L = cat.shape
    small = int(min(cat.bytes[k] for k in range(J * L) if cat.splats[k])) // 2 + 7   # less than any chunk
    got = {}
    for mode in ("whole", "prefix"):
        sim = _sim(world, [small], splat_order=splat_order, last_chunk=mode, fill=False)
        r = sim.run("l3gs", utility="visibility")
        u = sim.splat_values(0, "visibility")
        got[mode] = float(u[r.final_rows].sum())
    # The slot's picks only (no fill), a slot smaller than every chunk: whole chunks buy nothing,
    # the prefix plan starts the chunk whose first splats are worth the most.
    assert got["whole"] == 0.0 and got["prefix"] > 0.0
    sim = _sim(world, [3 * small], splat_order=splat_order, last_chunk="prefix")
    r = sim.run("l3gs", utility="visibility")
    first = r.records[0]
    u = sim.splat_values(0, "visibility")
    shown = float(u[r.final_rows].sum())
    whole = _sim(world, [3 * small], splat_order=splat_order).run("l3gs", utility="visibility")
    # What the whole-chunk plan and its fill showed is one of the prefix plan's candidates (whole
    # chunks, then one cut off): the prefix plan shows at least as much.
    assert shown >= float(u[whole.final_rows].sum()) - 1e-9
    assert first["in_flight"], first   # the slot ended inside a chunk: the partial carries over


def test_bad_last_chunk_settings(world, capsys):
    with pytest.raises(SimulationError, match=r"^last_chunk: 'half' is not one of whole, prefix"):
        SimConfig(last_chunk="half")
    sim = _sim(world, [5000], last_chunk="prefix")
    for method, solver in (("progressive", None), ("sort", None), ("l3gs", "greedy")):
        with pytest.raises(SimulationError, match=r"^last_chunk: 'prefix' "):
            sim.run(method, solver=solver)
    for kw in (dict(utility_mode="table", utility="eq1"),):
        with pytest.raises(SimulationError, match=r"^last_chunk: 'prefix' counts a chunk's first splats"):
            Simulation(world["bundle"], world["log"], [5000],
                       config=SimConfig(width=64, height=48, samples_per_slot=1, last_chunk="prefix", **kw),
                       reference=world["teacher"]).run("l3gs")
    line = one_error_line(capsys, "simulate", world["bundle"], "--trace", "lumos-throughput-mid-11",
                          "--path", world["log"], "--method", "sort", "--last-chunk", "prefix", "--slots", "2",
                          "--width", "32", "--height", "24")
    assert line.startswith("error: --last-chunk: 'prefix' changes the per-slot MCKP of l3gs and l3gs-noseg"), line


def test_plan_last_chunk_refuses_bad_arguments():
    ok = dict(cost=[[4, 4]], utility=[[1.0, 0.5]], held=np.zeros((1, 2), bool), empty=np.zeros((1, 2), bool),
              capacity=6, prefix=lambda unit: np.arange(5.0), bytes_per_splat=[[1, 1]])
    assert plan_last_chunk(**ok).partial is not None
    as_lists = {k: (v.tolist() if isinstance(v, np.ndarray) else v) for k, v in ok.items()}
    assert plan_last_chunk(**as_lists) == plan_last_chunk(**ok)   # plain lists work as arrays do
    for change, match in ((dict(cost=[[4, 4, 4]]), r"^utility: has shape \(1, 2\), expected \[J, L\] = \(1, 3\)"),
                          (dict(utility=[[1.0, float("nan")]]), r"^utility: must be finite"),
                          (dict(cost=[[0, 4]]), r"^cost: must be whole bytes >= 1"),
                          (dict(bytes_per_splat=[[1.5, 1]]), r"^bytes_per_splat: must be whole bytes"),
                          (dict(capacity=-1), r"^capacity: -1: must be an integer in \[0, "),
                          (dict(capacity=2.5), r"^capacity: 2\.5: must be an integer"),
                          (dict(held=[[0, 1]]), r"^held: must be a bool array"),
                          (dict(prefix=None), r"^prefix: None: must be a function")):
        with pytest.raises(ArgumentError, match=match):
            plan_last_chunk(**{**ok, **change})
