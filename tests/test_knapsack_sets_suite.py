"""The ``knapsack-sets`` bench suite and ``bb``'s exact 0-1 path (solvers/_kp01.py).

Checked against independent answers: brute force over every subset (small random instances with
capacities and profits up to 1e10 and 2**40), the published optima of real Jooken and Pisinger
files (skipped without ../shared), and the report's counts on hand-made records.
"""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from l3gs_opt.bench.report import known_optima_summary
from l3gs_opt.bench.suites import KNAPSACK_DIR_ENV, default_methods, suite_specs
from l3gs_opt.methods import solve
from l3gs_opt.problem.instance import Instance
from l3gs_opt.solvers import _kp01
from solver_helpers import kp01_brute

SHARED = Path(__file__).resolve().parents[2] / "shared" / "data" / "reference" / "knapsack"
needs_shared = pytest.mark.skipif(not SHARED.is_dir(), reason=f"{SHARED} is absent (the public knapsack sets)")


@st.composite
def _instances(draw):
    n = draw(st.integers(1, 10))
    scale = draw(st.sampled_from([10, 10**6, 10**10]))
    w = draw(st.lists(st.integers(1, scale), min_size=n, max_size=n))
    # Profits near the weights (Jooken-like) or free, up to 2**40.
    if draw(st.booleans()):
        p = [max(0, wi + draw(st.integers(-200, 200))) for wi in w]
    else:
        p = draw(st.lists(st.integers(0, 2**40), min_size=n, max_size=n))
    c = draw(st.integers(0, sum(w)))
    units = draw(st.sampled_from([4, 64, 1 << 18]))
    return w, p, c, units


@settings(max_examples=150, deadline=None)
@given(_instances())
def test_kp01_equals_brute_force(case):
    w, p, c, units = case
    res = _kp01.solve_kp01(np.array(w), np.array(p, dtype=float), c, units=units)
    opt = kp01_brute(w, p, c)
    assert res.optimal and res.value == opt == res.bound
    assert int(np.array(w)[res.take].sum()) <= c and int(np.array(p)[res.take].sum()) == opt


@settings(max_examples=60, deadline=None)
@given(_instances())
def test_kp01_out_of_time_at_once_skips_the_optional_set_up_and_keeps_a_valid_bound(case):
    # A limit already spent: one scale tried, neither start DP (a 2,000-item set used to take 2 s of
    # set-up under a 1 s limit); the answer is still feasible below a valid bound.
    w, p, c, units = case
    res = _kp01.solve_kp01(np.array(w), np.array(p, dtype=float), c, units=units, time_limit_s=1e-9)
    opt = kp01_brute(w, p, c)
    assert res.value <= opt <= res.bound and (not res.optimal or res.value == opt)
    assert int(np.array(w)[res.take].sum()) <= c
    if "scale" in res.stats:   # it got past the trivial cases to the DP set-up
        assert res.stats["scales_tried"] <= 1
        assert "rounded_up" not in res.stats and "rounded_up" in res.stats["skipped"]


@settings(max_examples=60, deadline=None)
@given(_instances())
def test_kp01_stopped_early_keeps_a_valid_bound(case):
    w, p, c, units = case
    res = _kp01.solve_kp01(np.array(w), np.array(p, dtype=float), c, units=units, max_states=2)
    opt = kp01_brute(w, p, c)
    assert res.value <= opt <= res.bound
    assert not res.optimal or res.value == opt


@settings(max_examples=60, deadline=None)
@given(_instances())
def test_bb_on_one_layer_instances_equals_brute_force(case):
    w, p, c, _ = case
    inst = Instance("layered", bandwidth=[c], cost=np.array(w)[:, None], utility=np.array(p, dtype=float)[None, :, None])
    sol = solve(inst, "bb", slot=0)
    opt = kp01_brute(w, p, c)
    assert sol.status.value == "optimal" and sol.objective == opt and sol.bound >= opt


@settings(max_examples=100, deadline=None)
@given(_instances(), st.integers(2, 300))
def test_rounded_dps_bracket_the_optimum(case, K):
    """At any scale K / (c + 1): weights rounded down give an upper bound (and the relaxation's own
    optimum, of that value), weights rounded up a feasible solution."""
    w, p, c, _ = case
    w, p = np.array(w, dtype=np.int64), np.array(p, dtype=np.int64)
    opt = kp01_brute(w.tolist(), p.tolist(), c)
    den, m = c + 1, K * c // (c + 1)
    down = K * w // den
    assert _kp01._dp_value(down, p, m) >= opt
    relaxed = _kp01._dp_solution(down, p, m)
    assert int(p[relaxed].sum()) == _kp01._dp_value(down, p, m) and int(down[relaxed].sum()) <= m
    up = _kp01._dp_solution(-(-K * w // den), p, m)
    assert int(w[up].sum()) <= c and int(p[up].sum()) <= opt


def test_scale_just_below_the_groups_proves_at_the_root():
    """Items a few bytes above capacity / 2^i (Jooken's groups) and profits near the weights: the
    scale units / (c + 1) sees that the knapsack cannot be filled to its last unit; the scale
    1 / ceil(c / units) rounds every group item down a unit and overestimates."""
    rng = np.random.default_rng(3)
    c, units = 10**6, 64
    w = [c // 2**i + int(rng.integers(1, 6)) for i in range(1, 7) for _ in range(2)] + [3, 4, 5, 7]
    p = [wi + int(rng.integers(-3, 4)) for wi in w]
    opt = kp01_brute(w, p, c)
    res = _kp01.solve_kp01(np.array(w), np.array(p, dtype=float), c, units=units)
    assert res.optimal and res.value == opt and res.stats["stages"] == 0 and res.stats["root_bound"] == opt
    delta = -(-c // units)
    old = _kp01._dp_value(np.array(w) // delta, np.array(p), c // delta)
    assert old > opt + c // 2**7


def test_least_loss_scale_proves_at_the_root_where_powers_of_two_do_not():
    """Groups at ``(1/2^i + eps) capacity``: every power-of-two table loses ``frac(eps K)`` of a unit
    per item and the relaxation fits one item too many; a table size picked by least rounding loss
    (not a power of two) proves the brute-force optimum before any state is built."""
    rng = np.random.default_rng(2)
    c, eps = 10**6, 0.0134
    w = [int((1 / 2**i + eps) * c) + int(rng.integers(1, 6)) for i in range(1, 6) for _ in range(2)] + [3, 4, 5]
    p = [wi + int(rng.integers(-3, 4)) for wi in w]
    opt = kp01_brute(w, p, c)
    res = _kp01.solve_kp01(np.array(w), np.array(p, dtype=float), c, units=1024)
    num = int(res.stats["scale"].split("/")[0])
    assert res.optimal and res.value == opt and res.stats["stages"] == 0 and res.stats["root_bound"] == opt
    assert num & (num - 1) != 0                                     # not a power of two
    W, P = np.array(w), np.array(p)
    assert min(_kp01._dp_value(K * W // (c + 1), P, K * c // (c + 1)) for K in (2**j for j in range(4, 11))) > opt


@settings(max_examples=40, deadline=None)
@given(st.lists(st.integers(1, 10**10), min_size=1, max_size=40), st.integers(10**10, 10**11),
       st.sampled_from([64, 1000, 1 << 12]))
def test_least_loss_scales_lose_no_more_than_the_powers_of_two_they_replace(w, c, units):
    """The picked sizes lie in [units / 4, units] and lose (float64, all items, within the named
    1e-6 relative tolerance of the float scoring) no more bytes per item than any power of two there."""
    w = np.array(w, dtype=np.int64)
    den = c + 1

    def loss(K):
        return sum((K * wi % den) / K for wi in w.tolist()) / len(w)

    picked = _kp01._least_loss_scales(w, den, units)
    powers = [K for K in (2**j for j in range(units.bit_length())) if units // 4 <= K <= units]
    assert picked and all(units // 4 <= K <= units for K in picked)
    assert loss(picked[0]) <= min(loss(K) for K in powers) * (1 + 1e-6) + 1e-6


def test_fits_kp01_refuses_fractions_and_huge_totals():
    assert _kp01.fits_kp01(np.array([1, 2]), np.array([3.0, 4.0]))
    assert not _kp01.fits_kp01(np.array([1, 2]), np.array([3.5, 4.0]))
    assert not _kp01.fits_kp01(np.array([1, 2]), np.array([2.0**61, 2.0**61]))


def test_suite_absent_folder_says_so_in_one_line(monkeypatch, capsys, tmp_path):
    monkeypatch.setenv(KNAPSACK_DIR_ENV, str(tmp_path / "missing"))
    assert suite_specs("knapsack-sets") == []
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and "is absent" in err[0] and KNAPSACK_DIR_ENV in err[0]


def test_suite_specs_from_a_folder(monkeypatch, tmp_path):
    (tmp_path / "pisinger").mkdir()
    (tmp_path / "jooken").mkdir()
    (tmp_path / "pisinger" / "knapPI_1_3_10_1.txt").write_text("3 10\n5 4\n4 5\n3 6\n")
    (tmp_path / "pisinger" / "knapPI_1_3_10_1.opt").write_text("9\n")
    (tmp_path / "jooken" / "tiny.in").write_text("2\n0 7 6\n1 5 5\n10\n")
    (tmp_path / "jooken" / "optima.csv").write_text("name,optimum\ntiny,7\n")
    monkeypatch.setenv(KNAPSACK_DIR_ENV, str(tmp_path))
    specs = suite_specs("knapsack-sets")
    assert [(s.instance_id, s.params["set"], s.params["optimum"]) for s in specs] == [
        ("pisinger/knapPI_1_3_10_1", "pisinger", 9), ("jooken/tiny", "jooken", 7)]
    assert all(s.single_slot for s in specs)
    assert default_methods(specs[0]) == [m for m in ["bb", "ilp/highs", "ilp/cbc", "ilp/cpsat"]
                                         if m in default_methods(specs[0])]
    assert "bb" in default_methods(specs[0])
    for spec in specs:
        sol = solve(spec.build(), "bb", slot=0)
        assert sol.objective == spec.params["optimum"] and sol.status.value == "optimal"


def _record(method, status, objective, optimum, runtime=1.0, bound=None):
    return {"suite": "knapsack-sets", "method": method, "status": status, "objective": objective, "bound": bound,
            "runtime_s": runtime, "feasible": True, "objective_ok": True,
            "spec": {"params": {"set": "jooken", "optimum": optimum}}}


def test_known_optima_summary_counts():
    recs = [_record("bb", "optimal", 10.0, 10), _record("bb", "optimal", 9.0, 10, bound=9.0),
            _record("bb", "time_limit", 10.0, 10, runtime=25.0), _record("bb", "optimal", 10.0, 10, runtime=30.0)]
    s = known_optima_summary(recs)[("knapsack-sets", "jooken", "bb")]
    assert (s["records"], s["reached"], s["proven"], s["wrong_optimal"], s["bound_below_optimum"]) == (4, 3, 2, 1, 1)
    assert s["not_proven_within"] == 3 and s["max_time_s"] == 30.0


_REAL = ["jooken/n_400_c_1000000_g_2_f_0.2_eps_0.01_s_100.in", "jooken/n_1000_c_100000000_g_6_f_0.2_eps_1e-05_s_200.in",
         "jooken/n_600_c_10000000000_g_2_f_0.1_eps_0.1_s_200.in", "pisinger/knapPI_3_1000_1000_1.txt"]


@needs_shared
@pytest.mark.parametrize("name", _REAL)
def test_bb_meets_published_optima(name):
    from l3gs_opt.problem.knapsack_sets import load_knapsack

    path = SHARED / name
    if not path.exists():
        pytest.skip(f"{path} is absent")
    ks = load_knapsack(path)
    sol = solve(ks.instance, "bb", slot=0, time_limit_s=20)
    assert sol.bound >= ks.optimum
    if sol.status.value == "optimal":
        assert sol.objective == ks.optimum
    assert sol.status.value == "optimal"


@needs_shared
def test_bb_short_limit_never_labels_a_wrong_value_optimal():
    from l3gs_opt.problem.knapsack_sets import load_knapsack

    ks = load_knapsack(SHARED / "jooken" / "n_1000_c_10000000000_g_10_f_0.2_eps_0_s_200.in")
    sol = solve(ks.instance, "bb", slot=0, time_limit_s=0.5)
    assert sol.objective <= ks.optimum <= sol.bound
    assert sol.status.value != "optimal" or sol.objective == ks.optimum
