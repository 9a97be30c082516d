"""A client that starts with only the index and the server's utility tables (``fetch --catalogue
tables``): table files round-trip and refuse damage by name, the server serves them unpaced, and a
fetch that renders only the bytes that arrived shows, slot by slot, exactly the pictures the
simulator shows given the same tables, order and bytes."""

from __future__ import annotations

import dataclasses
import json
import shutil

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

aiohttp = pytest.importorskip("aiohttp")

from l3gs_opt.delivery.fetch import FetchError, fetch  # noqa: E402
from l3gs_opt.delivery.server import start_server  # noqa: E402
from l3gs_opt.delivery.tables import TABLES_NAME, TablesError, export_tables, load_table, read_tables  # noqa: E402
from l3gs_opt.pipeline.table_files import TableFileError, read_utility_table, utility_table_bytes  # noqa: E402
from l3gs_opt.scene.bundle import write_bundle  # noqa: E402
from l3gs_opt.scene.procedural import make_scene  # noqa: E402
from l3gs_opt.scene.stream_index import export_stream, read_stream, stream_bundle  # noqa: E402
from l3gs_opt.traces.poses import synthetic_poses, write_pose_log  # noqa: E402

SIZES = (300, 600, 1200)
TRACE = (60_000, 30_000, 50_000)


@pytest.fixture(scope="module")
def world(tmp_path_factory):
    """A 1200-splat ``sort`` bundle of 3 objects exported as one file, with Eq. 1 object tables."""
    root = tmp_path_factory.mktemp("tables")
    teacher = make_scene(1500, objects=3, sh_degree=1, seed=0)
    order = np.random.default_rng(0).permutation(teacher.num_splats)
    bounds = (0, *SIZES)
    write_bundle(root / "bundle", [teacher.subset(order[bounds[i]:bounds[i + 1]]) for i in range(len(SIZES))],
                 variant="sort")
    plain = export_stream(root / "bundle", root / "plain", pack="single").parent
    served = root / "served"
    shutil.copytree(plain, served)
    export_tables(served, utility="eq1", views=("object", "scene"), counts=(3, 3, 1), yaw_steps=8,
                  pitches_deg=(-10.0, 10.0), width=32, height=24)
    log = write_pose_log(synthetic_poses("orbit", seconds=6, rate_hz=30, seed=0), root / "viewer.log")
    trace = root / "trace.txt"
    trace.write_text("".join(f"{b * 8 / 1e6}\n" for b in TRACE))     # Mbit/s of 60, 30, 50 kB per s
    return {"root": root, "plain": plain, "served": served, "log": log, "teacher": teacher, "trace": trace}


def _tables(folder):
    return {(e["utility"], e["view"]): load_table(e, (folder / e["file"]).read_bytes()) for e in read_tables(folder)}


def test_table_file_round_trip(world):
    tables = _tables(world["served"])
    assert set(tables) == {("eq1", "object"), ("eq1", "scene")}
    t = tables[("eq1", "object")]
    again, meta = read_utility_table(utility_table_bytes(t, utility="eq1", view="object"))
    assert meta == {"utility": "eq1", "view": "object"}
    assert np.array_equal(again.values.toarray(), t.values.toarray()) and again.shape_jl == t.shape_jl
    assert np.array_equal(again.positions, t.positions) and again.intrinsics == t.intrinsics
    # The object table's cells add up to the scene table's per level (one view's cells regroup the other's).
    obj, scene = t.values.toarray(), tables[("eq1", "scene")].values.toarray()
    J, L = t.shape_jl
    assert np.allclose(obj.reshape(len(obj), J, L).sum(axis=1), scene, rtol=1e-9, atol=1e-12)


def test_table_files_refuse_damage_by_name(world):
    t = _tables(world["served"])[("eq1", "object")]
    good = utility_table_bytes(t, utility="eq1", view="object")
    with pytest.raises(TableFileError, match="file"):
        read_utility_table(good[: len(good) // 2])
    bad = dataclasses.replace(t, values=t.values.copy())
    bad.values.data[:1] = -1.0
    with pytest.raises(TableFileError, match="data: holds a negative utility"):
        read_utility_table(utility_table_bytes(bad, utility="eq1", view="object"))
    entry = next(e for e in read_tables(world["served"]) if e["view"] == "object")
    with pytest.raises(TablesError, match="not the manifest's"):
        load_table(entry, good + b"x")
    manifest = json.loads((world["served"] / TABLES_NAME).read_text())
    for broken, match in [({**manifest, "schema": "x"}, "schema"),
                          ({**manifest, "tables": [{**manifest["tables"][0], "file": "../index.json"}]},
                           r"tables\[0\]: file"),
                          ({**manifest, "tables": [{**manifest["tables"][0], "view": "distill"}]}, r"tables\[0\]")]:
        with pytest.raises(TablesError, match=match):
            read_tables(json.dumps(broken).encode())


@settings(max_examples=60, deadline=None)
@given(st.binary(max_size=400))
def test_table_reader_fuzz_valid_or_named_error(data):
    try:
        read_utility_table(data)
    except TableFileError as exc:
        assert "\n" not in str(exc)


def test_server_serves_tables_unpaced(world):
    import asyncio

    async def get(url, path):
        async with aiohttp.ClientSession() as s:
            async with s.get(f"{url}/{path}", headers={"X-L3gs-Client": "t"}) as r:
                return r.status, await r.read()

    with start_server(world["served"], trace=[1000] * 5) as h:   # 1 kB/s: a paced 20 kB file takes 20 s
        for e in read_tables(world["served"]):
            status, body = asyncio.run(asyncio.wait_for(get(h.url, e["file"]), 5))
            assert status == 200 and body == (world["served"] / e["file"]).read_bytes()
    with start_server(world["plain"]) as h:
        assert asyncio.run(get(h.url, TABLES_NAME))[0] == 404


def test_fetch_with_tables_shows_what_the_simulator_shows(world, tmp_path):
    """The client knows the index and the tables only; after each slot its scene is the bytes that
    arrived. The simulator, given the same tables, the stored order and the bytes fetch measured,
    makes the same requests and renders the same pictures (equal SSIM, bit for bit)."""
    from l3gs_opt.simulator.client import Client, drive
    from l3gs_opt.simulator.simulation import SimConfig, Simulation

    config = SimConfig(width=32, height=24, samples_per_slot=1)
    out = tmp_path / "out"
    with start_server(world["served"], trace=str(world["trace"]), shape_anonymous=False) as h:
        fetch(h.url, str(world["trace"]), world["log"], "l3gs", out, slots=3, config=config, catalogue="tables",
              reference=world["teacher"])
    recs = [json.loads(line) for line in (out / "slots.jsonl").read_text().splitlines()]
    measured = [r["fetch"]["bytes_received"] for r in recs]
    assert sum(measured) > 0
    table_cfg = dataclasses.replace(config, utility_mode="table", splat_order="stored")
    sim = Simulation(stream_bundle(read_stream(world["plain"])), world["log"], list(TRACE), config=table_cfg,
                     reference=world["teacher"], utility_tables=_tables(world["served"]))
    client = Client(sim, sim.spec("l3gs"))
    drive([client], measured)
    for mine, theirs in zip(recs, client.records):
        for key in ("requests", "completed", "in_flight", "bytes_delivered", "splats_shown", "ssim"):
            assert mine[key] == theirs[key], (mine["slot"], key)
    summary = json.loads((out / "summary.jsonl").read_text().splitlines()[-1])
    assert "tables" in json.dumps(summary)


def test_fetch_tables_needs_the_servers_tables(world, tmp_path):
    from l3gs_opt.simulator.simulation import SimConfig

    config = SimConfig(width=32, height=24, samples_per_slot=1)
    with start_server(world["plain"]) as h:
        with pytest.raises(FetchError, match="catalogue: 'tables': the server has no tables.json"):
            fetch(h.url, str(world["trace"]), world["log"], "l3gs", tmp_path / "a", slots=1, config=config,
                  catalogue="tables")
    with start_server(world["served"]) as h:
        with pytest.raises(FetchError, match="utility: 'visibility' for the 'object' view"):
            fetch(h.url, str(world["trace"]), world["log"], "l3gs", tmp_path / "b", slots=1,
                  config=dataclasses.replace(config, utility="visibility"), catalogue="tables")
    with pytest.raises(FetchError, match="catalogue: 'most'"):
        fetch("http://127.0.0.1:9", str(world["trace"]), world["log"], "l3gs", tmp_path / "c", slots=1,
              catalogue="most")


def test_cli_bundle_tables_and_fetch_tables(world, tmp_path, capsys):
    """``bundle tables`` writes what ``fetch --catalogue tables`` reads; a bad --grid is one line, exit 2."""
    from l3gs_opt.cli.main import main

    served = tmp_path / "served"
    shutil.copytree(world["plain"], served)
    assert main(["bundle", "tables", str(served), "--utility", "eq1", "--grid", "2,2,1", "--yaw-steps", "4",
                 "--pitches", "0", "--width", "32", "--height", "24", "--no-progress"]) == 0
    assert "utility-eq1-object.npz" in capsys.readouterr().out
    assert [e["view"] for e in read_tables(served)] == ["object"]
    with start_server(served, trace=str(world["trace"]), shape_anonymous=False) as h:
        assert main(["fetch", h.url, "--trace", str(world["trace"]), "--path", str(world["log"]), "--method", "l3gs",
                     "--out", str(tmp_path / "o"), "--slots", "2", "--width", "32", "--height", "24",
                     "--samples-per-slot", "1", "--catalogue", "tables", "--json", "--no-progress"]) == 0
    summary = json.loads(capsys.readouterr().out)
    assert summary["slots"] == 2 and summary["catalogue"] == "tables" and summary["metadata_bytes"] > 0
    assert main(["bundle", "tables", str(served), "--grid", "2,x,1"]) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and "--grid" in err[0]


def test_splat_order_is_validated_and_recorded(world, tmp_path):
    from l3gs_opt.simulator.simulation import SimConfig, SimulationError, simulate

    with pytest.raises(SimulationError, match="splat_order: 'random' is not one of method, stored"):
        SimConfig(splat_order="random")
    cfg = SimConfig(width=32, height=24, samples_per_slot=1, splat_order="stored")
    r = simulate(stream_bundle(read_stream(world["plain"])), world["log"], list(TRACE), "sort", config=cfg,
                 out_dir=tmp_path / "s")
    summary = json.loads((tmp_path / "s" / "summary.jsonl").read_text().splitlines()[-1])
    assert summary["config"]["splat_order"] == "stored" and r.summary["slots"] == 3


def test_tables_merge_by_utility_and_refuse_another_index(world, tmp_path):
    folder = tmp_path / "s"
    shutil.copytree(world["served"], folder)
    export_tables(folder, utility="visibility", views=("object",), counts=(2, 2, 1), yaw_steps=4,
                  pitches_deg=(0.0,), width=32, height=24)
    assert sorted((e["utility"], e["view"]) for e in read_tables(folder)) == \
        [("eq1", "object"), ("eq1", "scene"), ("visibility", "object")]
    t = _tables(folder)[("visibility", "object")]
    assert t.shape_jl == _tables(folder)[("eq1", "object")].shape_jl and t.values.nnz > 0
    # The export written again differently (per-chunk files): its index changes, the tables are stale.
    export_stream(world["root"] / "bundle", folder, pack="per-chunk")
    with pytest.raises(TablesError, match="index_sha256: the tables were made from another index.json"):
        read_tables(folder)
    with pytest.raises(Exception, match="index_sha256"):
        start_server(folder)


def test_decision_time_costs_link_time(world):
    """decision_s: at each slot after the first, the planning time's bytes go to the carried-over unit
    or are lost; 0 is the default model; fetch refuses it (it measures its own)."""
    from l3gs_opt.simulator.simulation import SimConfig, SimulationError, simulate

    with pytest.raises(SimulationError, match="decision_s"):
        SimConfig(decision_s=-0.1)
    with pytest.raises(SimulationError, match="decision_s"):
        SimConfig(decision_s=0.6, substeps=2)
    bundle = stream_bundle(read_stream(world["plain"]))
    runs = {}
    for d in (0.0, 0.5):
        cfg = SimConfig(width=32, height=24, samples_per_slot=1, decision_s=d)
        runs[d] = simulate(bundle, world["log"], [20_000] * 5, "l3gs", config=cfg).records
    assert runs[0.0][0]["bytes_delivered"] == runs[0.5][0]["bytes_delivered"]   # slot 0: no planning head
    for r in runs[0.5]:
        assert r["bytes_delivered"] + r["bytes_idle"] == r["bytes_capacity"]
    assert sum(r["bytes_delivered"] for r in runs[0.5]) < sum(r["bytes_delivered"] for r in runs[0.0])
    with pytest.raises(FetchError, match="decision_s"):
        fetch("http://127.0.0.1:9", str(world["trace"]), world["log"], "l3gs", None, slots=1,
              config=SimConfig(decision_s=0.1))


def test_reload_scene_refuses_a_bundle_that_moves_rows(world, tmp_path):
    """The fetch client's scene is reloaded as bytes arrive; a bundle whose rows sit in other objects
    or levels (not the one the catalogues were built on) is refused by name."""
    from l3gs_opt.simulator.simulation import SimConfig, Simulation, SimulationError

    sim = Simulation(stream_bundle(read_stream(world["plain"])), world["log"], list(TRACE),
                     config=SimConfig(width=32, height=24, samples_per_slot=1))
    sim.reload_scene(stream_bundle(read_stream(world["plain"])))           # the same rows: accepted
    other = make_scene(1000, objects=3, sh_degree=1, seed=1)
    write_bundle(tmp_path / "b", [other.subset(np.arange(0, 300)), other.subset(np.arange(300, 900))], variant="sort")
    with pytest.raises(SimulationError, match="bundle: a reloaded bundle moved rows"):
        sim.reload_scene(stream_bundle(read_stream(export_stream(tmp_path / "b", tmp_path / "s").parent)))
