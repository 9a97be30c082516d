"""The trace-driven simulator on a tiny procedural room (3k splats, 64x48 pixels, a few slots).

Checked against identities (the link moves exactly the trace's bytes; infinite bandwidth ends at
the full model, rendered bit for bit like ``preload``; zero bandwidth shows the background) and
against independent computations (a chunk's splats stream in descending Eq. 1 utility; table
lookups at grid viewpoints equal the exact utilities).
"""

from __future__ import annotations

import json

import numpy as np
import pytest

from l3gs_opt.bundle import write_bundle
from l3gs_opt.cli import main
from l3gs_opt.errors import L3gsError
from l3gs_opt.poses import synthetic_poses, write_pose_log
from l3gs_opt.renderer.metrics import ssim
from l3gs_opt.renderer.render import render_scene
from l3gs_opt.scene_make import make_scene
from l3gs_opt.simulate import (MethodSpec, SimConfig, Simulation, SimulationError, SlotView, build_catalog,
                               method_spec, order_requests)
from l3gs_opt.utility import splat_utility

SLOTS = 5
BPS = 92            # bytes per splat at SH degree 1 (56 + 36)
SIZES = (600, 1200, 2400)
CONFIG = SimConfig(width=64, height=48, samples_per_slot=1)
LAYERED_METHODS = ("l3gs", "l3gs-noseg", "sort", "greedy", "fptas:0.2", "rolling:bb", "rolling-future:bb", "slope",
                   "progressive", "static", "mpc:2")
SEPARATE_METHODS = ("separate", "bb", "rolling:bb")


@pytest.fixture(scope="module")
def world(tmp_path_factory):
    root = tmp_path_factory.mktemp("sim")
    teacher = make_scene(3000, objects=3, sh_degree=1, seed=0)
    # A random order so that every prefix holds some of every object; the top model (2400 splats)
    # is smaller than the teacher, so even preload does not reach SSIM 1.
    order = np.random.default_rng(0).permutation(teacher.num_splats)
    bounds = (0, *SIZES)
    write_bundle(root / "sort", [teacher.subset(order[bounds[i]:bounds[i + 1]]) for i in range(len(SIZES))],
                 variant="sort")
    write_bundle(root / "separate", [teacher.subset(order[:d]) for d in SIZES], variant="separate")
    log = write_pose_log(synthetic_poses("orbit", seconds=SLOTS + 1, rate_hz=30, seed=0), root / "viewer.log")
    return {"root": root, "teacher": teacher, "log": log}


def _sim(world, bundle, bandwidth, config=CONFIG):
    return Simulation(world["root"] / bundle, world["log"], bandwidth, config=config, reference=world["teacher"])


@pytest.fixture(scope="module")
def runs(world):
    """Every method on both bundles at 30 kB per slot (the model is 221 kB: it never all arrives)."""
    out = {}
    for bundle, methods in (("sort", LAYERED_METHODS), ("separate", SEPARATE_METHODS)):
        sim = _sim(world, bundle, [30_000] * SLOTS)
        out[bundle] = {m: sim.run(m) for m in (*methods, "preload")}
    return out


def test_link_delivers_exactly_the_trace(world):
    bandwidth = [30_000, 0, 45_000, 12_000, 30_000]   # 117 kB < the 221 kB model: always something to send
    for bundle, method in (("sort", "l3gs"), ("sort", "rolling:bb"), ("separate", "separate")):
        r = _sim(world, bundle, bandwidth).run(method)
        assert [rec["bytes_delivered"] for rec in r.records] == bandwidth
        assert [rec["bytes_trace"] for rec in r.records] == bandwidth
        assert r.summary["bytes_delivered"] == sum(bandwidth) and r.summary["bytes_idle"] == 0


def test_preload_is_the_upper_reference(runs):
    for bundle, results in runs.items():
        top = results["preload"].ssim_per_s
        assert results["preload"].summary["bytes_delivered"] == 0
        for method, r in results.items():
            assert len(r.ssim_per_s) == SLOTS
            for t in range(SLOTS):
                assert top[t] >= r.ssim_per_s[t] - 1e-12, (bundle, method, t)
        assert max(top) < 1.0


@pytest.mark.parametrize("bundle, methods", [("sort", LAYERED_METHODS), ("separate", SEPARATE_METHODS)])
def test_infinite_bandwidth_reaches_the_full_model(world, bundle, methods):
    sim = _sim(world, bundle, [10**9] * 3)
    full = sim.run("preload")
    assert full.final_rows.size == SIZES[-1]
    for method in methods:
        r = sim.run(method)
        assert np.array_equal(r.final_rows, full.final_rows), method
        assert r.ssim_per_s == full.ssim_per_s, method        # the same splats render the same image
        if bundle == "sort":
            assert r.summary["bytes_delivered"] == SIZES[-1] * BPS and r.summary["bytes_wasted"] == 0
        else:   # every version delivered before the top one was replaced by it
            s = r.summary
            assert s["bytes_wasted"] == s["bytes_replaced"] == s["bytes_delivered"] - SIZES[-1] * BPS


@pytest.mark.parametrize("bundle, methods", [("sort", LAYERED_METHODS), ("separate", SEPARATE_METHODS)])
def test_zero_bandwidth_shows_the_background(world, bundle, methods):
    sim = _sim(world, bundle, [0] * 3)
    # Independent: the teacher rendered from the viewer's true pose against a black image.
    expected = [ssim(np.zeros((48, 64, 3)), np.clip(render_scene(world["teacher"], sim.true_camera(t)).image.numpy(),
                                                    0, 1)) for t in range(3)]
    for method in methods:
        r = sim.run(method)
        assert r.summary["bytes_delivered"] == 0 and r.final_rows.size == 0
        assert all(rec["splats_shown"] == 0 for rec in r.records)
        assert r.ssim_per_s == pytest.approx(expected, abs=1e-12)


def test_deterministic(world):
    def strip(summary):
        return {k: v for k, v in summary.items() if k not in ("timings_mean_s", "run_s", "loadavg_start",
                                                             "loadavg_end")}

    for method in ("l3gs", "rolling:bb"):
        a = _sim(world, "sort", [30_000] * SLOTS).run(method)
        b = _sim(world, "sort", [30_000] * SLOTS).run(method)
        assert strip(a.summary) == strip(b.summary)
        assert [r["requests"] for r in a.records] == [r["requests"] for r in b.records]


def test_layered_holdings_are_whole_splats(runs):
    for method, r in runs["sort"].items():
        if method == "preload":
            continue
        s = r.summary
        assert s["bytes_delivered"] - s["bytes_wasted"] == BPS * s["splats_final"]
        assert 0 <= s["bytes_wasted"] < BPS * 3     # at most a part-splat per cut-off unit (one in flight)
        shown = [rec["splats_shown"] for rec in r.records]
        assert shown == sorted(shown)               # layered holdings only grow


def test_chunk_streams_in_descending_utility(world):
    config = SimConfig(width=64, height=48, samples_per_slot=1, viewport="oracle")
    sim = _sim(world, "sort", [60 * BPS + 17], config)     # 60 splats and a part of one
    r = sim.run("l3gs", solver="dp")
    assert r.final_rows.size == 60 and r.summary["bytes_wasted"] == 17
    cat = sim.catalog("object")
    (j, l, remaining), = r.records[0]["in_flight"]          # the one unit cut off
    rows = cat.rows[j * cat.shape[1] + l]
    assert 0 < np.isin(rows, r.final_rows).sum() < rows.size
    # Independent: Eq. 1 on the unit's splats alone, from the slot's (oracle) viewpoint.
    u = splat_utility(sim.scene.subset(rows), sim.prediction(0)["cameras"][0])
    chosen = np.isin(rows, r.final_rows)
    assert u[chosen].min() >= u[~chosen].max()
    assert u[chosen].min() > 0


def test_table_lookup_matches_exact_at_grid_viewpoints(world):
    sim = _sim(world, "sort", [30_000] * 2, SimConfig(width=64, height=48, utility="table"))
    cat = sim.catalog("object")
    table = sim._table(cat)
    for p, o in ((0, 0), (4, 7), (8, 20)):
        cam = table.camera(p, o)
        exact = np.bincount(cat.unit_of_row, weights=splat_utility(sim.scene, cam), minlength=cat.units)
        got = table.lookup(cam)
        padded = np.zeros(cat.shape)
        padded[:got.shape[0], :got.shape[1]] = got
        # float32 projections of the same splats, summed in different orders
        np.testing.assert_allclose(padded.ravel(), exact, rtol=1e-5, atol=1e-9)
    r = sim.run("l3gs")
    assert len(r.records) == 2 and r.summary["bytes_delivered"] == 60_000


@pytest.mark.parametrize("budget", ["per_slot", "cumulative"])
def test_idle_bytes_lost_or_banked(world, budget):
    config = SimConfig(width=64, height=48, samples_per_slot=1, budget=budget, fill=False)
    bandwidth = [5_000, 9_000, 20_000, 3_000, 40_000]
    r = _sim(world, "sort", bandwidth, config).run("l3gs")
    delivered = [rec["bytes_delivered"] for rec in r.records]
    idle = [rec["bytes_idle"] for rec in r.records]
    assert any(idle)                               # without fill the link idles here
    if budget == "per_slot":
        assert all(rec["bytes_banked"] == 0 for rec in r.records)
        assert sum(delivered) + sum(idle) == sum(bandwidth)
    else:   # idle bytes of a slot are part of the next slot's capacity
        assert [rec["bytes_capacity"] for rec in r.records[1:]] == [b + rec["bytes_banked"] for b, rec in
                                                                     zip(bandwidth[1:], r.records)]
        assert sum(delivered) + idle[-1] == sum(bandwidth)


def _view(**kw):
    base = dict(slot=0, slots_left=3, representation="layered", cost=np.array([[10, 20, 40], [5, 5, 50]]),
                utility=np.array([[1.0, 8.0, 1.0], [2.0, 0.5, 30.0]]), predicted_bytes=10, bank_bytes=5,
                in_flight_bytes=18, held=np.array([[True, False, False], [False, False, False]]),
                in_flight=np.zeros((2, 3), bool), empty=np.zeros((2, 3), bool), budget="per_slot")
    base.update(kw)
    return SlotView(**base)


def test_order_requests_precedence_and_fill():
    view = _view()
    out = order_requests(view, [(1, 1)], fill=False)
    assert out == [(1, 0), (1, 1)]                       # its lower layer first
    out = order_requests(view, [(1, 1)])
    # then the rest by utility per byte: (0,1) 0.4, (1,2) 0.6 -> (1,2) first; (0,2) last
    assert out == [(1, 0), (1, 1), (1, 2), (0, 1), (0, 2)]
    sep = _view(representation="separate", held=np.array([[False, True, False], [False, False, False]]))
    # separate: versions above the best held or requested one, by level, then utility per byte
    assert order_requests(sep, [(1, 0)]) == [(1, 0), (1, 1), (1, 2), (0, 2)]


def test_slot_view_instance_accounting():
    view = _view()
    inst = view.instance(3)
    # 10 predicted per slot, 5 banked into slot 0, the 18 in-flight bytes taken from the first slots
    assert inst.bandwidth.tolist() == [0, 7, 10] and inst.T == 3
    assert view.available_bytes == 0
    gap = _view(held=np.array([[True, False, False], [False, False, False]]),
                empty=np.array([[False, False, True], [False, True, False]]))
    # an empty unit above a missing layer does not count as held (layered holds a prefix)
    assert gap.instance(1).held.tolist() == [[True, False, False], [False, False, False]]


def test_catalog_units_match_manifest_chunks(world):
    from l3gs_opt.bundle import read_bundle

    bundle = read_bundle(world["root"] / "sort")
    by_object = build_catalog(bundle, "object")
    whole = build_catalog(bundle, "scene")
    objects = bundle.manifest["objects"]
    J, L = by_object.shape
    assert (J, L) == (len(objects), len(SIZES)) and whole.shape == (1, len(SIZES))
    for c in bundle.manifest["chunks"]:
        assert by_object.bytes[objects.index(c["object"]) * L + c["level"]] == c["bytes"]
    assert whole.bytes.tolist() == [by_object.bytes.reshape(J, L)[:, level].sum() for level in range(L)]
    # every splat in exactly one unit of each view
    for cat in (by_object, whole):
        rows = np.concatenate(cat.rows)
        assert np.array_equal(np.sort(rows), np.arange(SIZES[-1]))


@pytest.mark.parametrize("bundle, method, solver, match", [
    ("sort", "nope", None, r"method: method 'nope' is not one of"),
    ("sort", "separate", None, "'separate' needs a separate bundle"),
    ("separate", "l3gs", None, "'l3gs' needs a layered bundle"),
    ("separate", "sort", None, "'sort' needs a bundle built as variant sort"),
    ("sort", "rolling:bb", "bb", "solver: applies to l3gs, l3gs-noseg and separate only"),
    ("sort", "l3gs", "rolling:bb", "solver: 'rolling:bb' does not solve one slot's MCKP"),
    ("sort", "l3gs", "fptas:2", "solver: method 'fptas:2'"),
    ("sort", "lp", None, "method: 'lp' is a bound"),
])
def test_method_errors(world, bundle, method, solver, match):
    sim = _sim(world, bundle, [10] * 2)
    with pytest.raises(SimulationError, match=match):
        sim.run(method, solver=solver)


class _Bad:
    name = "bad"

    def __init__(self, requests):
        self._requests = requests

    def requests(self, view):
        return self._requests


@pytest.mark.parametrize("requests, match", [
    ([(0, 1)], r"requests\[0\]: \(0, 1\) before its layer 0"),
    ([(0, 0), (0, 0)], r"requests\[1\]: \(0, 0\) is requested twice"),
    ([(7, 0)], r"requests\[0\]: \(7, 0\) is outside"),
    (["x"], r"requests\[0\]"),
])
def test_scheduler_requests_are_checked(world, requests, match):
    sim = _sim(world, "sort", [10] * 2)
    spec = MethodSpec("bad", None, "object", "utility", _Bad(requests))
    with pytest.raises(SimulationError, match=match):
        sim.run(spec)


def test_bad_inputs(world):
    assert issubclass(SimulationError, L3gsError)
    with pytest.raises(SimulationError, match="width: 5x48"):
        SimConfig(width=5, height=48)
    with pytest.raises(SimulationError, match="viewport: 'psychic'"):
        SimConfig(viewport="psychic")
    with pytest.raises(SimulationError, match="path: the poses end at"):
        _sim(world, "sort", [10] * 60)
    with pytest.raises(L3gsError, match=r"bandwidth\[1\] = -3"):
        _sim(world, "sort", [10, -3])
    assert method_spec("mpc:3").scheduler.method == "mpc:3"


def test_cli_simulate_json_and_records(world, tmp_path, capsys):
    args = ["simulate", str(world["root"] / "sort"), "--trace", "lumos-throughput-mid-11", "--mbps", "0.2",
            "--slots", "3", "--path", str(world["log"]), "--width", "64", "--height", "48", "--no-progress",
            "--out", str(tmp_path), "--json"]
    assert main(args + ["--method", "l3gs"]) == 0
    s = json.loads(capsys.readouterr().out)
    for key in ("ssim_mean", "ssim_per_s", "bytes_delivered", "bytes_wasted", "slots", "timings_mean_s"):
        assert key in s
    assert s["slots"] == 3 and len(s["ssim_per_s"]) == 3 and s["ssim_mean"] == pytest.approx(np.mean(s["ssim_per_s"]))
    assert set(s["timings_mean_s"]) == {"prediction", "utility", "scheduling", "rendering", "reference", "metrics"}
    assert main(args + ["--method", "sort"]) == 0
    with open(tmp_path / "slots.jsonl", "a") as fh:   # as an interrupted write leaves it
        fh.write('{"method": "sort", "slo')
    assert main(args + ["--method", "l3gs"]) == 0    # a re-run replaces its own lines only (and the cut one)
    capsys.readouterr()
    lines = [json.loads(x) for x in (tmp_path / "slots.jsonl").read_text().splitlines()]
    assert sorted((x["method"], x["slot"]) for x in lines) == [(m, t) for m in ("l3gs", "sort") for t in range(3)]
    assert len((tmp_path / "summary.jsonl").read_text().splitlines()) == 2


def test_cli_simulate_error_is_one_line(world, capsys):
    code = main(["simulate", str(world["root"] / "sort"), "--trace", "lumos-throughput-mid-11", "--slots", "3",
                 "--path", str(world["log"]), "--method", "separate", "--no-progress"])
    err = capsys.readouterr().err
    assert code == 2 and err.startswith("error: method: 'separate' needs a separate bundle") and err.count("\n") == 1
