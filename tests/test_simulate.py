"""The trace-driven simulator on a tiny procedural room (3k splats, 64x48 pixels, a few slots).

Checked against identities (the link moves exactly the trace's bytes; infinite bandwidth ends at
the full model, rendered bit for bit like ``preload``; zero bandwidth shows the background) and
against independent computations (a chunk's splats stream in descending Eq. 1 utility; table
lookups at grid viewpoints equal the exact utilities).
"""

from __future__ import annotations

import dataclasses
import json

import numpy as np
import pytest

from l3gs_opt.scene.bundle import read_bundle, write_bundle
from l3gs_opt.scene.camera_paths import orbit_path
from l3gs_opt.cli.main import main
from l3gs_opt.errors import L3gsError
from l3gs_opt.traces.poses import synthetic_poses, write_pose_log
from l3gs_opt.renderer.metrics import ssim
from l3gs_opt.renderer.render import render_scene
from l3gs_opt.renderer.distill import distill_sh
from l3gs_opt.pipeline.build import hierarchy_parents
from l3gs_opt.scene.procedural import make_scene
from l3gs_opt.simulator.render import RenderCache, render_image
from l3gs_opt.simulator.simulation import (ItemSlotView, MethodSpec, SimConfig, Simulation, SimulationError, SlotView,
                               build_catalog, method_spec, order_requests)
from l3gs_opt.pipeline.splat_utility import splat_utility

SLOTS = 5
BPS = 92            # bytes per splat at SH degree 1 (56 + 36)
#: Bytes per splat of each bundle's full model: distill = compact (degree 0, 56) + SH upgrade (48),
#: hierarchy = full + the 4-byte parent field.
FULL_BPS = {"sort": BPS, "separate": BPS, "distill": 56 + 48, "hierarchy": BPS + 4}
SIZES = (600, 1200, 2400)
CONFIG = SimConfig(width=64, height=48, samples_per_slot=1)
LAYERED_METHODS = ("l3gs", "l3gs-noseg", "sort", "greedy", "fptas:0.2", "rolling:bb", "rolling-future:bb", "slope",
                   "progressive", "static", "mpc:2")
SEPARATE_METHODS = ("separate", "bb", "rolling:bb")
DISTILL_METHODS = ("distill", "l3gs")
HIERARCHY_METHODS = ("hierarchy", "separate")
PLANS = (("sort", LAYERED_METHODS), ("separate", SEPARATE_METHODS), ("distill", DISTILL_METHODS),
         ("hierarchy", HIERARCHY_METHODS))


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
    layers = [teacher.subset(order[bounds[i]:bounds[i + 1]]) for i in range(len(SIZES))]
    cams = orbit_path(6, width=64, height=48)
    write_bundle(root / "distill", layers, variant="distill",
                 compact_sh=[distill_sh(lv.means, lv.sh, cams, 0) for lv in layers])
    versions = [teacher.subset(order[:d]) for d in SIZES]
    write_bundle(root / "hierarchy", versions, variant="hierarchy",
                 parents=[None] + [hierarchy_parents(versions[i - 1], versions[i]) for i in range(1, len(SIZES))])
    log = write_pose_log(synthetic_poses("orbit", seconds=SLOTS + 1, rate_hz=30, seed=0), root / "viewer.log")
    return {"root": root, "teacher": teacher, "log": log}


def _sim(world, bundle, bandwidth, config=CONFIG):
    return Simulation(world["root"] / bundle, world["log"], bandwidth, config=config, reference=world["teacher"])


@pytest.fixture(scope="module")
def runs(world):
    """Every method on both bundles at 30 kB per slot (the model is 221 kB: it never all arrives)."""
    out = {}
    for bundle, methods in PLANS:
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


def test_carry_head_keeps_a_request_with_no_byte_in_flight(world):
    """A cut exactly at a unit's first byte: the default rule drops the unit and re-plans, ``head``
    keeps it first in flight (its remaining bytes its size), as if the cut fell one byte later."""
    sim = _sim(world, "sort", [30_000] * SLOTS)
    (o, lv, remaining), = sim.run("l3gs").records[0]["in_flight"]
    cat = sim.catalog("object")
    size = int(cat.bytes[cat.unit((o, lv))])
    at_start = 30_000 - (size - remaining)           # slot 0 ends where that unit begins
    runs = {}
    for carry, extra in (("started", 0), ("head", 0), ("head", 1)):
        cfg = dataclasses.replace(CONFIG, carry=carry)
        runs[carry, extra] = _sim(world, "sort", [at_start + extra] + [30_000] * (SLOTS - 1), config=cfg).run("l3gs")
    assert runs["started", 0].records[0]["in_flight"] == []
    assert runs["head", 0].records[0]["in_flight"] == [[o, lv, size]]
    assert runs["head", 1].records[0]["in_flight"] == [[o, lv, size - 1]]
    # Slot 1 starts with that unit in both head runs, and the two runs ask for the same units after it.
    for extra in (0, 1):
        rec = runs["head", extra].records[1]
        assert (rec["completed"] or rec["in_flight"])[0][:2] == [o, lv]
    assert runs["head", 0].records[1]["requests"] == runs["head", 1].records[1]["requests"]
    with pytest.raises(SimulationError, match="carry: 'tail'"):
        SimConfig(carry="tail")


def test_preload_is_the_upper_reference(runs):
    for bundle, results in runs.items():
        top = results["preload"].ssim_per_s
        assert results["preload"].summary["bytes_delivered"] == 0
        for method, r in results.items():
            assert len(r.ssim_per_s) == SLOTS
            for t in range(SLOTS):
                assert top[t] >= r.ssim_per_s[t] - 1e-12, (bundle, method, t)
        assert max(top) < 1.0


@pytest.mark.parametrize("bundle, methods", PLANS)
def test_infinite_bandwidth_reaches_the_full_model(world, bundle, methods):
    sim = _sim(world, bundle, [10**9] * 3)
    full = sim.run("preload")
    assert full.final_rows.size == SIZES[-1]
    # Independent: the bundle's largest model rendered here, scored against the teacher.
    top = read_bundle(world["root"] / bundle).scene(len(SIZES) - 1)
    cam = sim.true_camera(2)
    expected = ssim(render_image(top, cam), render_image(world["teacher"], cam))
    assert full.ssim_per_s[2] == pytest.approx(expected, abs=1e-6)
    for method in methods:
        r = sim.run(method)
        assert np.array_equal(r.final_rows, full.final_rows), method
        assert r.ssim_per_s == full.ssim_per_s, method        # the same splats render the same image
        if bundle in ("sort", "distill"):
            assert r.summary["bytes_delivered"] == SIZES[-1] * FULL_BPS[bundle] and r.summary["bytes_wasted"] == 0
        else:   # every version delivered before the top one was replaced by it
            s = r.summary
            assert s["bytes_wasted"] == s["bytes_replaced"] == s["bytes_delivered"] - SIZES[-1] * FULL_BPS[bundle]
        if method == "distill":   # every splat ends with its full SH
            assert r.records[-1]["splats_full_sh"] == SIZES[-1]


@pytest.mark.parametrize("bundle, methods", PLANS)
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
    r = runs["distill"]["distill"]
    s, last = r.summary, r.records[-1]
    # Useful bytes: every shown splat's compact record, plus the SH record of those upgraded.
    assert s["bytes_delivered"] - s["bytes_wasted"] == 56 * s["splats_final"] + 48 * last["splats_full_sh"]
    assert 0 <= s["bytes_wasted"] < 56 + 48
    full = [rec["splats_full_sh"] for rec in r.records]
    assert full == sorted(full) and all(f <= rec["splats_shown"] for f, rec in zip(full, r.records))


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
    sim = _sim(world, "sort", [30_000] * 2, SimConfig(width=64, height=48, utility_mode="table"))
    cat = sim.catalog("object")
    table = sim.valuation()._table(cat)
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
    # distill in table mode: the object view's table split by each cell's mean upgrade share.
    sim = _sim(world, "distill", [30_000] * 2, SimConfig(width=64, height=48, utility_mode="table"))
    split, whole = sim.catalog("distill"), sim.catalog("object")
    val = sim.valuation()
    np.testing.assert_allclose(val.unit_values(0, split, None)[0].sum(-1), val.unit_values(0, whole, None)[0])
    r = sim.run("distill")
    assert r.summary["bytes_delivered"] == 60_000 and r.records[-1]["splats_shown"] > 0


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
    from l3gs_opt.scene.bundle import read_bundle

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
    ("sort", "rolling:bb", "bb", "solver: applies to l3gs, l3gs-noseg, separate, distill and hierarchy only"),
    ("sort", "l3gs", "rolling:bb", "solver: 'rolling:bb' does not solve one slot's MCKP"),
    ("sort", "l3gs", "exact", "solver: 'exact' does not solve one slot's MCKP"),
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
    assert code == 2 and err.startswith("error: --method: 'separate' needs a separate bundle") and err.count("\n") == 1


# ---------------------------------------------------------------------------------------- distill
def test_upgrade_fraction_proxies():
    from l3gs_opt.renderer.sh import eval_sh
    from l3gs_opt.simulator.catalog import upgrade_fraction

    rng = np.random.default_rng(0)
    full = rng.normal(size=(50, 9, 3))
    full[0] = 0.0
    trunc = full.copy()
    trunc[:, 1:] = 0.0
    # A truncated compact form misses exactly the higher bands.
    np.testing.assert_allclose(upgrade_fraction(full, trunc, "residual", 1), upgrade_fraction(full, trunc, "bands", 1))
    assert upgrade_fraction(full, trunc, 0.25, 1).tolist() == [0.25] * 50
    compact = full.copy()
    compact[:, :4] += rng.normal(scale=0.3, size=(50, 4, 3))     # a fit of degree 1 that is off
    compact[:, 4:] = 0.0
    f = upgrade_fraction(full, compact, "residual", 4)
    assert f[0] == 0.0 and np.all((f >= 0) & (f <= 1))
    # Independent: residual = the relative mean squared colour error over all view directions
    # (real SH are orthonormal), by quadrature on a Fibonacci sphere.
    import torch

    n = 20_000
    z = 1 - (2 * np.arange(n) + 1) / n
    phi = np.pi * (3 - np.sqrt(5)) * np.arange(n)
    d = torch.tensor(np.stack([np.sqrt(1 - z * z) * np.cos(phi), np.sqrt(1 - z * z) * np.sin(phi), z], 1))
    for i in (1, 7, 30):
        colour = lambda sh: eval_sh(2, torch.tensor(sh[i])[None].expand(n, -1, -1), d).numpy()  # noqa: E731
        err = np.mean((colour(full) - colour(compact)) ** 2) / np.mean(colour(full) ** 2)
        assert f[i] == pytest.approx(min(err, 1.0), rel=2e-3)


def test_distill_catalog_and_utility_split(world):
    sim = _sim(world, "distill", [30_000] * 2)
    split, whole = sim.catalog("distill"), sim.catalog("object")
    J, L = whole.shape
    assert split.grid == (J, L, 2) and split.forms == ("compact", "sh_upgrade")
    objects = sim.bundle.manifest["objects"]
    for c in sim.bundle.manifest["chunks"]:
        k = split.unit((objects.index(c["object"]), c["level"], split.forms.index(c["sh_form"])))
        assert split.bytes[k] == c["bytes"] and split.splats[k] == c["splats"]
    assert np.array_equal(split.bytes.reshape(J, L, 2).sum(-1), whole.bytes.reshape(J, L))
    # The split keeps Eq. 1: compact + upgrade utility of a layer = its utility in the object view.
    u_split, _ = sim.valuation().unit_values(0, split, None)
    u_whole, _ = sim.valuation().unit_values(0, whole, None)
    np.testing.assert_allclose(u_split.sum(-1), u_whole, rtol=1e-12)
    assert np.all(u_split[..., 1] > 0)


def _views(sim, view, budget, held=None):
    """The slot-0 SlotView of the object view and the ItemSlotView of ``view`` with ``budget`` bytes."""
    out = []
    for name in ("object", view):
        cat = sim.catalog(name)
        u, _ = sim.valuation().unit_values(0, cat, None)
        h = np.zeros(cat.grid, bool) if held is None else held(cat)
        kw = dict(slot=0, slots_left=1, representation=cat.representation, cost=cat.cost, utility=u,
                  predicted_bytes=budget, bank_bytes=0, in_flight_bytes=0, held=h,
                  in_flight=np.zeros(cat.grid, bool), empty=cat.empty, budget="per_slot")
        out.append(SlotView(**kw) if name == "object" else ItemSlotView(variant=view, **kw))
    return out


def test_distill_item_mckp_dominates_whole_layers(world):
    """Sending a layer compact and upgrading later is an option more: the item MCKP's optimum is at
    least the layered MCKP's (a whole layer is its compact chunk and its upgrade together)."""
    from l3gs_opt import solve

    sim = _sim(world, "distill", [30_000] * 2)
    strict = 0
    for budget in (3_000, 10_000, 30_000, 80_000, 10**7):
        layered, items = _views(sim, "distill", budget)
        a = solve(layered.instance(1), "dp", slot=0)
        b = solve(items.instance(1), "dp", slot=0)
        assert b.objective >= a.objective - 1e-9 * max(1.0, a.objective)
        strict += b.objective > a.objective * (1 + 1e-9)
        picks = order_requests(items, [u for u, _ in items.arrival_units(b)], fill=False)
        assert sum(int(items.cost[u]) for u in picks) <= budget   # the picks fit, prerequisites included
    assert strict >= 1
    full = items.instance(1)
    assert full.names[:2] == ("o0_l0_compact", "o0_l0_sh_upgrade") and full.requires.shape[0] > 0


def test_distill_shows_compact_sh_until_upgraded(world):
    """A client holding every compact chunk and no upgrade shows the bundle's compact scene; an
    upgrade cut off streams its splats in descending upgrade utility."""
    class Compact:
        name = "compact-first"

        def requests(self, view):
            J, L, _ = view.cost.shape
            taken = view.taken()
            out = [(j, l, 0) for j in range(J) for l in range(L) if not taken[j, l, 0]]
            return out + [(0, 0, 1)] if not taken[0, 0, 1] else out

    from l3gs_opt.simulator.client import Client, drive

    config = SimConfig(width=64, height=48, samples_per_slot=1, viewport="oracle")
    sim = _sim(world, "distill", [10**9], config)
    cat = sim.catalog("distill")
    compact_bytes = int(cat.bytes[0::2].sum())
    spec = MethodSpec("compact-first", None, "distill", "utility", Compact())
    sim = _sim(world, "distill", [compact_bytes + 10 * 48 + 5], config)
    client = Client(sim, spec)
    drive([client], sim.link_bytes)
    rec = client.records[0]
    assert rec["splats_shown"] == SIZES[-1] and rec["splats_full_sh"] == 10
    assert rec["in_flight"] == [[0, 0, 1, int(cat.bytes[1]) - 10 * 48 - 5]]
    # Independent: the 10 rows upgraded are those with the largest Eq. 1 utility x upgrade share.
    rows = cat.rows[1]
    u = splat_utility(sim.scene.subset(rows), sim.prediction(0)["cameras"][0]) * sim.distill_arrays()[1][rows]
    shown, _, full = sim.shown_rows(cat, client.got, client.complete, client.order, False)
    upgraded = np.isin(rows, shown[full])
    assert upgraded.sum() == 10 and u[upgraded].min() >= u[~upgraded].max() and u[upgraded].min() > 0
    # Every compact chunk and no upgrade: the bundle's compact scene (its own API), the same image.
    full[:] = False
    compact_scene = read_bundle(world["root"] / "distill").scene(len(SIZES) - 1, sh_form="compact")
    cam = sim.true_camera(0)
    image, _ = sim.client_image(shown, full, cam)
    np.testing.assert_allclose(image, render_image(compact_scene, cam), atol=1e-6)   # float32 sums, other order
    assert np.abs(image - render_image(sim.scene, cam)).max() > 1e-3               # and not the full-SH one


# ---------------------------------------------------------------------------------------- hierarchy
def test_hierarchy_item_mckp_equals_problem_ii(world):
    """The hierarchy item form (one replacement group per object) and Problem II's MCKP are two
    statements of one problem: equal optima, with nothing held and with versions held."""
    from l3gs_opt import solve

    sim = _sim(world, "hierarchy", [30_000] * 2)

    def some_held(cat):
        h = np.zeros(cat.grid, bool)
        h[0, 0] = h[1, 1] = True
        return h

    for held in (None, some_held):
        for budget in (2_000, 9_000, 25_000, 60_000, 10**7):
            problem_ii, items = _views(sim, "hierarchy", budget, held)
            a = solve(problem_ii.instance(1), "dp", slot=0)
            b = solve(items.instance(1), "dp", slot=0)
            assert b.objective == pytest.approx(a.objective, rel=1e-12, abs=1e-9)


@pytest.mark.parametrize("bundle, method, solver", [("distill", "distill", "rolling:bb"), ("distill", "distill", "mpc:2"),
                                                    ("hierarchy", "hierarchy", "rolling-future:bb"),
                                                    ("hierarchy", "hierarchy", "greedy")])
def test_item_methods_take_item_solvers(world, bundle, method, solver):
    bandwidth = [30_000, 0, 45_000]
    r = _sim(world, bundle, bandwidth).run(method, solver=solver)
    assert r.summary["solver"] == solver and r.summary["view"] == bundle
    assert [rec["bytes_delivered"] for rec in r.records] == bandwidth     # kept busy: every byte used
    with pytest.raises(SimulationError, match=f"solver: 'slope' does not schedule an item instance; '{method}'"):
        _sim(world, bundle, bandwidth).run(method, solver="slope")
    other = "hierarchy" if method == "distill" else "distill"
    with pytest.raises(SimulationError, match=f"method: '{other}' needs"):
        _sim(world, bundle, bandwidth).run(other)


# ---------------------------------------------------------------------------------------- re-planning
def _slot_value(sim, client):
    """Predicted utility shown at the end of slot 0 (separate: each object's best complete version)."""
    cat = client.cat
    U, _ = sim.valuation().unit_values(0, cat, None)
    J, L = cat.shape
    done = client.complete.reshape(J, L) & ~cat.empty
    return sum(max([U[j, l] for l in range(L) if done[j, l]], default=0.0) for j in range(J))


def test_replanning_never_worse_within_a_slot(world):
    """Over-optimistic predictions, one slot, whole versions, an exact solver: re-planning after
    each quarter with the bytes measured is never worse at the slot's end (the plan it replaces
    stays feasible at every re-plan, and the estimate of the bytes left is exact), and here it is
    better at least once."""
    from l3gs_opt.simulator.client import Client, drive

    better = 0
    for budget in (8_000, 20_000, 40_000, 60_000, 100_000):
        for bias in (1.0, 2.0, 3.0, 5.0):
            values = []
            for parts in (1, 4):
                config = SimConfig(width=64, height=48, samples_per_slot=1, substeps=parts, bandwidth_bias=bias)
                sim = _sim(world, "hierarchy", [budget], config)
                client = Client(sim, sim.spec("hierarchy", "dp"))
                drive([client], sim.link_bytes)
                assert client.records[0]["bytes_delivered"] == budget
                values.append(_slot_value(sim, client))
            assert values[1] >= values[0] - 1e-9, (budget, bias)
            better += values[1] > values[0] + 1e-9
    assert better >= 1


@pytest.mark.parametrize("bundle, method", [("sort", "l3gs"), ("distill", "distill"), ("hierarchy", "hierarchy"),
                                            ("sort", "rolling:bb")])
def test_substeps_deterministic_and_feasible(world, bundle, method):
    config = SimConfig(width=64, height=48, samples_per_slot=1, substeps=3, bandwidth_bias=2.5)
    bandwidth = [30_000, 0, 45_001, 12_000]
    a = _sim(world, bundle, bandwidth, config).run(method)
    b = _sim(world, bundle, bandwidth, config).run(method)
    assert [r["substep_requests"] for r in a.records] == [r["substep_requests"] for r in b.records]
    assert a.ssim_per_s == b.ssim_per_s and np.array_equal(a.final_rows, b.final_rows)
    for rec, bw in zip(a.records, bandwidth):
        assert rec["bytes_delivered"] == bw and sum(rec["substep_bytes"]) == bw and len(rec["substep_bytes"]) == 3
        assert rec["requests"] == [u for part in rec["substep_requests"] for u in part]
    assert a.records[2]["substep_predicted"][0] == a.records[2]["predicted_bytes"]


# ---------------------------------------------------------------------------------------- shared link
def _strip(record):
    drop = ("timings_s", "run_id", "client", "clients", "render_reused")
    return {k: v for k, v in record.items() if k not in drop}


def test_shared_link_one_client_is_a_plain_run(world):
    from l3gs_opt.simulator.shared import run_shared

    bandwidth = [30_000, 0, 45_000, 12_000, 30_000]
    sim = _sim(world, "sort", bandwidth)
    for method in ("l3gs", "rolling:bb"):
        alone = sim.run(method)
        (shared,) = run_shared([sim], [method])
        assert [_strip(r) for r in shared.records] == [_strip(r) for r in alone.records]
        assert np.array_equal(shared.final_rows, alone.final_rows)
        assert shared.summary["clients"] == 1 and shared.summary["bytes_share"] == sum(bandwidth)


def test_shared_link_splits_the_trace(world, tmp_path):
    from l3gs_opt.simulator.shared import run_shared, simulate_shared

    bandwidth = [30_000, 0, 45_000, 12_000, 30_000]
    walker = write_pose_log(synthetic_poses("walk", seconds=SLOTS + 1, rate_hz=30, seed=1), tmp_path / "walk.log")
    rs = simulate_shared(world["root"] / "sort", [world["log"], walker, world["log"]], bandwidth,
                         ["l3gs", "sort", "preload"], config=CONFIG, reference=world["teacher"], out_dir=tmp_path)
    # Preload asks for nothing: the others split every byte (the model is larger than the trace).
    assert rs[2].summary["bytes_share"] == 0 and rs[2].summary["bytes_delivered"] == 0
    for t, bw in enumerate(bandwidth):
        assert sum(r.records[t]["bytes_share"] for r in rs) == bw
        assert sum(r.records[t]["bytes_delivered"] for r in rs) == bw
        assert abs(rs[0].records[t]["bytes_share"] - rs[1].records[t]["bytes_share"]) <= 1
    lines = [json.loads(x) for x in (tmp_path / "slots.jsonl").read_text().splitlines()]
    assert sorted((x["client"], x["slot"]) for x in lines) == [(i, t) for i in range(3) for t in range(SLOTS)]
    # Two identical clients get half each and see the same.
    sim = _sim(world, "sort", bandwidth)
    a, b = run_shared([sim, sim], ["l3gs", "l3gs"])
    assert [r["bytes_share"] for r in a.records] == [bw // 2 for bw in bandwidth]
    assert [_strip(r) for r in a.records] == [_strip(r) for r in b.records]
    with pytest.raises(SimulationError, match=r"simulations\[1\]: its bandwidth differs"):
        run_shared([sim, _sim(world, "sort", [1] * SLOTS)], ["l3gs", "l3gs"])


# ---------------------------------------------------------------------------------------- resume
class _Stop(Exception):
    pass


def _interrupt_at(monkeypatch, slot):
    """Make every built-in scheduler stop the run when it is asked about ``slot``."""
    from l3gs_opt.simulator import schedulers as sim_schedulers

    for cls in (sim_schedulers.SlotSolverScheduler, sim_schedulers.HorizonScheduler):
        original = cls.requests

        def requests(self, view, _original=original):
            if view.slot == slot:
                raise _Stop
            return _original(self, view)

        monkeypatch.setattr(cls, "requests", requests)


def _same_run(a, b):
    strip = lambda r: {k: v for k, v in r.items() if k not in ("timings_s", "render_reused")}  # noqa: E731
    assert [strip(r) for r in a.records] == [strip(r) for r in b.records]
    assert np.array_equal(a.final_rows, b.final_rows)
    drop = ("timings_mean_s", "run_s", "loadavg_start", "loadavg_end", "renders", "resumed_slots")
    keep = lambda s: {k: v for k, v in s.items() if k not in drop}  # noqa: E731
    assert keep(a.summary) == keep(b.summary)


@pytest.mark.parametrize("bundle, method, budget, parts", [("sort", "l3gs", "per_slot", 1),
                                                            ("distill", "distill", "cumulative", 2),
                                                            ("hierarchy", "hierarchy", "per_slot", 1),
                                                            ("sort", "mpc:2", "cumulative", 1)])
def test_resume_after_interrupt_equals_uninterrupted(world, tmp_path, monkeypatch, bundle, method, budget, parts):
    config = SimConfig(width=64, height=48, samples_per_slot=1, budget=budget, substeps=parts, fill=parts == 1)
    bandwidth = [30_000, 7_000, 45_000, 12_000, 30_000]
    whole = _sim(world, bundle, bandwidth, config).run(method)
    with monkeypatch.context() as m:
        _interrupt_at(m, 3)
        with pytest.raises(_Stop):
            _sim(world, bundle, bandwidth, config).run(method, out_dir=tmp_path)
    lines = (tmp_path / "slots.jsonl").read_text().splitlines()
    assert [json.loads(x)["slot"] for x in lines] == [0, 1, 2]
    carried = [json.loads(x)["in_flight"] or json.loads(x)["bytes_banked"] for x in lines]
    assert any(carried), "pick a case whose state carries over (a chunk in flight, banked bytes)"
    with open(tmp_path / "slots.jsonl", "a") as fh:   # as a write cut by the interruption leaves it
        fh.write('{"method": "' + method + '", "slo')
    resumed = _sim(world, bundle, bandwidth, config).run(method, out_dir=tmp_path, resume=True)
    assert resumed.summary["resumed_slots"] == 3
    _same_run(resumed, whole)
    lines = [json.loads(x) for x in (tmp_path / "slots.jsonl").read_text().splitlines()]
    assert [x["slot"] for x in lines] == list(range(SLOTS))
    # Resuming a finished run replays everything and renders nothing new.
    again = _sim(world, bundle, bandwidth, config).run(method, out_dir=tmp_path, resume=True)
    _same_run(again, whole)
    assert again.summary["resumed_slots"] == SLOTS and again.summary["renders"]["view"] == 0


def test_resume_refuses_other_inputs_and_altered_records(world, tmp_path):
    bandwidth = [30_000, 7_000, 45_000]
    _sim(world, "sort", bandwidth).run("l3gs", out_dir=tmp_path)
    with pytest.raises(SimulationError, match="resume: .* from a run with other inputs"):
        _sim(world, "sort", [30_000, 7_000, 45_001]).run("l3gs", out_dir=tmp_path, resume=True)
    lines = [json.loads(x) for x in (tmp_path / "slots.jsonl").read_text().splitlines()]
    lines[1]["completed"] = lines[1]["completed"] + [[9, 9]]
    (tmp_path / "slots.jsonl").write_text("".join(json.dumps(x) + "\n" for x in lines))
    with pytest.raises(SimulationError, match=r"resume: slot 1: replaying the recorded requests gives completed"):
        _sim(world, "sort", bandwidth).run("l3gs", out_dir=tmp_path, resume=True)
    with pytest.raises(SimulationError, match="resume: needs out_dir"):
        _sim(world, "sort", bandwidth).run("l3gs", resume=True)


# ---------------------------------------------------------------------------------------- render cache
def test_reference_rendered_once_per_camera(world, tmp_path):
    from l3gs_opt.simulator.render import render_backend

    cache = RenderCache()
    bandwidth = [30_000] * 3
    sims = [Simulation(world["root"] / "sort", world["log"], bandwidth, config=CONFIG, reference=world["teacher"],
                       render_cache=cache) for _ in range(2)]
    first, second = sims[0].run("l3gs"), sims[1].run("sort")
    assert first.summary["renders"]["reference"] == 3 and second.summary["renders"]["reference"] == 0
    for t in range(3):   # a hit is the very image a render gives
        assert np.array_equal(sims[1].reference_image(t)[0], render_image(world["teacher"], sims[1].true_camera(t)))
    # On disk: a new process (a new cache object on the same folder) renders none either.
    disk = [Simulation(world["root"] / "sort", world["log"], bandwidth, config=CONFIG, reference=world["teacher"],
                       render_cache=RenderCache(directory=tmp_path)) for _ in range(2)]
    assert disk[0].run("l3gs").summary["renders"]["reference"] == 3
    r = disk[1].run("l3gs")
    assert r.summary["renders"]["reference"] == 0 and r.ssim_per_s == first.ssim_per_s
    assert len(list(tmp_path.glob("*.npy"))) == 3
    pytest.importorskip("numba")
    assert render_backend() == "numba" and first.summary["render_backend"] == "numba"


def test_client_view_not_rendered_again_when_nothing_new(world):
    from l3gs_opt.traces.poses import PoseTrace

    n = 30 * (SLOTS + 1)
    still = PoseTrace(time_s=np.arange(n) / 30.0, position=np.tile([3.0, 1.6, 0.0], (n, 1)),
                      rotation_deg=np.tile([10.0, -90.0, 0.0], (n, 1)))
    sim = Simulation(world["root"] / "sort", still, [30_000, 0, 0, 20_000, 0], config=CONFIG,
                     reference=world["teacher"], view_cache=RenderCache())
    r = sim.run("l3gs")
    assert [rec["render_reused"] for rec in r.records] == [False, True, True, False, True]
    assert r.summary["renders"]["view"] == 2 and r.summary["renders"]["view_reused"] == 3
    # Independent: the held splats rendered afresh score the same.
    cam = sim.true_camera(4)
    assert r.ssim_per_s[4] == ssim(render_image(sim.scene.subset(r.final_rows), cam), sim.reference_image(4)[0])


# ---------------------------------------------------------------------------------------- CLI
def test_cli_simulate_resume_and_new_options(world, tmp_path, monkeypatch, capsys):
    args = ["simulate", str(world["root"] / "distill"), "--trace", "lumos-throughput-mid-11", "--mbps", "0.3",
            "--slots", "4", "--path", str(world["log"]), "--width", "64", "--height", "48", "--no-progress",
            "--method", "distill", "--solver", "dp", "--substeps", "2", "--bandwidth-bias", "1.5",
            "--sh-upgrade-utility", "0.3", "--json"]
    assert main(args + ["--out", str(tmp_path / "whole")]) == 0
    whole = json.loads(capsys.readouterr().out)
    assert whole["config"]["substeps"] == 2 and whole["config"]["sh_upgrade_utility"] == 0.3
    assert len(list((tmp_path / "whole" / "reference-cache").glob("*.npy"))) == 4
    from l3gs_opt.simulator.schedulers import SlotSolverScheduler

    with monkeypatch.context() as m:
        def stop(self, view, _original=SlotSolverScheduler.requests):
            if view.slot == 2:
                raise KeyboardInterrupt
            return _original(self, view)

        m.setattr("l3gs_opt.simulator.schedulers.SlotSolverScheduler.requests", stop)
        assert main(args + ["--out", str(tmp_path / "cut")]) == 130
    capsys.readouterr()
    assert main(args + ["--out", str(tmp_path / "cut"), "--resume"]) == 0
    resumed = json.loads(capsys.readouterr().out)
    assert resumed["resumed_slots"] == 2 and resumed["ssim_per_s"] == whole["ssim_per_s"]
    strip = lambda x: {k: v for k, v in json.loads(x).items() if k not in ("timings_s", "render_reused")}  # noqa: E731
    assert [strip(x) for x in (tmp_path / "cut" / "slots.jsonl").read_text().splitlines()] == \
        [strip(x) for x in (tmp_path / "whole" / "slots.jsonl").read_text().splitlines()]
    code = main(args[:-1] + ["--resume"])
    assert code == 2 and capsys.readouterr().err.startswith("error: --resume: needs --out")
    code = main(args[:-1] + ["--sh-upgrade-utility", "1.5"])
    assert code == 2 and "--sh-upgrade-utility: 1.5" in capsys.readouterr().err


def test_summary_is_typed_and_is_the_record_on_disk(world, tmp_path):
    """The run summary is a frozen, typed RunSummary; its JSON form is the line in summary.jsonl."""
    import dataclasses

    from l3gs_opt.simulator.records import RunSummary

    r = _sim(world, "sort", [30_000] * 3).run("l3gs", out_dir=tmp_path)
    s = r.summary
    assert isinstance(s, RunSummary)
    assert isinstance(s.bytes_delivered, int) and s.slots == 3 and len(s.ssim_per_s) == 3
    with pytest.raises(dataclasses.FrozenInstanceError):
        s.bytes_delivered = 0
    (line,) = [json.loads(x) for x in (tmp_path / "summary.jsonl").read_text().splitlines()]
    assert line == json.loads(json.dumps(s.to_dict()))
    assert "client" not in line and s["ssim_mean"] == s.ssim_mean == line["ssim_mean"]


# ---------------------------------------------------------------------------------------- utilities
@pytest.mark.parametrize("utility", ["visibility", "visibility-held", "coverage", "counterfactual"])
def test_a_run_by_another_utility_is_its_own_record(world, tmp_path, utility):
    config = SimConfig(width=64, height=48, samples_per_slot=1)
    sim = _sim(world, "sort", [30_000] * 3, config)
    eq1 = sim.run("l3gs", out_dir=tmp_path)
    other = sim.run("l3gs", utility=utility, out_dir=tmp_path)
    assert (eq1.summary.utility, other.summary.utility, other.summary.order_utility) == ("eq1", utility, utility)
    assert all(r["utility"] == utility for r in other.records)
    lines = [json.loads(x) for x in (tmp_path / "summary.jsonl").read_text().splitlines()]
    assert sorted(x["utility"] for x in lines) == sorted(["eq1", utility])   # neither replaced the other
    assert eq1.summary.run_id != other.summary.run_id
    again = sim.run("l3gs", utility=utility, out_dir=tmp_path, resume=True)
    assert again.summary.resumed_slots == 3 and again.ssim_per_s == other.ssim_per_s


def test_held_aware_values_with_everything_held_are_visibility(world):
    sim = _sim(world, "sort", [30_000] * 2, SimConfig(width=64, height=48, samples_per_slot=2))
    cat = sim.catalog("object")
    everything = np.ones(sim.scene.num_splats, bool)
    plain, _ = sim.valuation("visibility").unit_values(0, cat, None)
    held, _ = sim.valuation("visibility-held").unit_values(0, cat, everything)
    np.testing.assert_array_equal(plain, held)
    nothing, _ = sim.valuation("visibility-held").unit_values(0, cat, np.zeros(sim.scene.num_splats, bool))
    assert np.all(nothing >= plain - 1e-9) and nothing.sum() > plain.sum()   # no occluders: worth more


def test_order_utility_is_a_separate_choice(world):
    sim = _sim(world, "sort", [30_000] * 2, SimConfig(width=64, height=48, samples_per_slot=1))
    cat = sim.catalog("object")
    val = sim.valuation("eq1", "visibility")
    vis = sim.splat_values(0, "visibility")
    for k in range(cat.units):
        rows = cat.rows[k]
        got = val.splat_order(0, cat, k, None)
        assert np.array_equal(got, rows[np.argsort(-vis[rows], kind="stable")])
    r = sim.run("l3gs", order_utility="visibility")
    assert (r.summary.utility, r.summary.order_utility) == ("eq1", "visibility")


def test_visibility_table_matches_the_utility_at_grid_viewpoints(world):
    sim = _sim(world, "sort", [30_000] * 2, SimConfig(width=64, height=48, utility="visibility",
                                                      utility_mode="table"))
    cat = sim.catalog("object")
    val = sim.valuation()
    table = val._table(cat)
    prep = sim.prepared(val.utility)
    for p, o in ((0, 0), (4, 7)):
        cam = table.camera(p, o)
        exact = np.bincount(cat.unit_of_row, weights=val.utility.splat_values(prep, [cam]), minlength=cat.units)
        got = np.zeros(cat.shape)
        part = table.lookup(cam)
        got[:part.shape[0], :part.shape[1]] = part
        np.testing.assert_allclose(got.ravel(), exact, rtol=1e-9, atol=1e-9)
    with pytest.raises(SimulationError, match="utility_mode: 'table': utility 'coverage' depends on what is held"):
        _sim(world, "sort", [30_000] * 2, SimConfig(width=64, height=48, utility="coverage",
                                                    utility_mode="table")).run("l3gs")


@pytest.mark.parametrize("kw, match", [
    ({"utility": "table"}, "utility: 'table' is a utility mode: use utility_mode='table'"),
    ({"utility": "nope"}, "utility: utility 'nope' is not one of eq1, visibility"),
    ({"order_utility": "nope"}, "order_utility: utility 'nope'"),
    ({"utility_mode": "grid"}, "utility_mode: 'grid' is not one of exact, table"),
    ({"utility": "no_such_module_xyz:f"}, "cannot import 'f' from 'no_such_module_xyz'"),
])
def test_bad_utility_settings_are_named(kw, match):
    with pytest.raises(SimulationError, match=match):
        SimConfig(**kw)


def test_cli_simulate_same_viewer_as_camera_path_and_mahimahi_trace(world, tmp_path, capsys):
    """The viewer given as 4x4 camera matrices (--path-format cameras) and the trace as Mahimahi
    packet times (--trace-format mahimahi) drive the same run as the pose log and the Lumos file."""
    from l3gs_opt.pipeline.scene_instance import Z_UP_MAPPING
    from l3gs_opt.traces.bandwidth import bundled_traces, read_bandwidth_trace, write_mahimahi
    from l3gs_opt.traces.poses import read_pose_log, write_camera_path

    log = read_pose_log(world["log"])
    step = np.diff(log.time_s)
    assert np.allclose(step, 1 / 30, atol=1e-3)
    write_camera_path(Z_UP_MAPPING.world_to_camera(log.position, log.rotation_deg), tmp_path / "path.txt")
    lumos = read_bandwidth_trace(bundled_traces()["lumos-throughput-mid-11"])
    write_mahimahi(lumos.scaled(2.0)[0], tmp_path / "trace.mm")   # 2 Mbit/s: ~10k lines a minute
    common = ["--mbps", "0.2", "--slots", "3", "--width", "64", "--height", "48", "--no-progress", "--json",
              "--method", "l3gs", "--no-cache"]
    runs = []
    for trace, path in ((["--trace", "lumos-throughput-mid-11"], ["--path", str(world["log"])]),
                        (["--trace", str(tmp_path / "trace.mm"), "--trace-format", "mahimahi"],
                         ["--path", str(tmp_path / "path.txt"), "--path-format", "cameras", "--path-rate", "30"])):
        assert main(["simulate", str(world["root"] / "sort"), *trace, *path, *common]) == 0
        runs.append(json.loads(capsys.readouterr().out))
    a, b = runs
    # Mahimahi counts whole 1500-byte packets: each second's rate within one packet of the original.
    assert b["bytes_trace"] == pytest.approx(a["bytes_trace"], rel=0.02)
    np.testing.assert_allclose(b["ssim_per_s"], a["ssim_per_s"], atol=0.02)
