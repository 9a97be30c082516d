"""The replay page of a simulated run, and the pictures ``simulate --save-views`` keeps for it.

A tiny world (3k splats, 64x48 pixels, 3 slots). The saved pictures are checked against renders
made afresh (the reference scene, and the client's final rows, from the slot's true camera); the
page's data against the records it was written from; and the page itself in a real headless
Chromium (no console error, the slider changes the picture shown, the screenshot is a picture).
"""

from __future__ import annotations

import argparse
import io
import json
import shutil
import tempfile
import time
from html.parser import HTMLParser
from pathlib import Path

import numpy as np
import pytest
from hypothesis import HealthCheck, example, given, settings
from hypothesis import strategies as st
from PIL import Image

from l3gs_opt.cli.main import main
from l3gs_opt.cli.replay import register
from l3gs_opt.records import RecordFileError
from l3gs_opt.delivery.replay import PAGE_NAME, ReplayError, write_replay
from l3gs_opt.scene.bundle import write_bundle
from l3gs_opt.scene.procedural import make_scene
from l3gs_opt.scene.splats import write_ply
from l3gs_opt.simulator.client import views_folder
from l3gs_opt.simulator.render import render_image
from l3gs_opt.simulator.simulation import SimConfig, Simulation
from l3gs_opt.traces.poses import synthetic_poses, write_pose_log

SLOTS = 3
SIZES = (600, 1200, 2400)
CONFIG = SimConfig(width=64, height=48, samples_per_slot=1)
BANDWIDTH = [30_000, 7_000, 45_000]
L3GS = views_folder("l3gs", "bb")      # "l3gs__bb": l3gs's solver defaults to bb


class _Stop(Exception):
    pass


@pytest.fixture(scope="module")
def world(tmp_path_factory):
    root = tmp_path_factory.mktemp("replay")
    teacher = make_scene(3000, objects=3, sh_degree=1, seed=0)
    order = np.random.default_rng(0).permutation(teacher.num_splats)
    bounds = (0, *SIZES)
    write_bundle(root / "sort", [teacher.subset(order[bounds[i]:bounds[i + 1]]) for i in range(len(SIZES))],
                 variant="sort")
    log = write_pose_log(synthetic_poses("orbit", seconds=SLOTS + 1, rate_hz=30, seed=0), root / "viewer.log")
    teacher_ply = write_ply(teacher, root / "teacher.ply")
    return {"root": root, "teacher": teacher, "teacher_ply": teacher_ply, "log": log}


def _sim(world) -> Simulation:
    return Simulation(world["root"] / "sort", world["log"], BANDWIDTH, config=CONFIG, reference=world["teacher"])


def _png(path: Path) -> np.ndarray:
    with Image.open(path) as im:
        return np.asarray(im.convert("RGB"))


def _as_png(image: np.ndarray) -> np.ndarray:
    """A float image in [0, 1] as the 8 bits a PNG keeps."""
    return np.round(np.clip(image, 0, 1) * 255).astype(np.uint8)


@pytest.fixture(scope="module")
def run(world, tmp_path_factory):
    """l3gs with pictures (API), sort with pictures (CLI), greedy without: one run folder."""
    out = tmp_path_factory.mktemp("run")
    sim = _sim(world)
    result = sim.run("l3gs", out_dir=out, views_dir=out / "views")
    # The same viewer and reference scene (the pictures of the reference are shared by the folder's runs).
    code = main(["simulate", str(world["root"] / "sort"), "--trace", "lumos-throughput-mid-11", "--mbps", "0.2",
                 "--slots", str(SLOTS), "--path", str(world["log"]), "--width", "64", "--height", "48",
                 "--samples-per-slot", "1", "--no-progress", "--out", str(out), "--method", "sort", "--save-views",
                 "--teacher", str(world["teacher_ply"])])
    assert code == 0
    sim.run("greedy", out_dir=out)
    return {"dir": out, "sim": sim, "l3gs": result}


def _records(run_dir: Path) -> list[dict]:
    return [json.loads(x) for x in (run_dir / "slots.jsonl").read_text().splitlines()]


# ---------------------------------------------------------------------------------------- saved views
def test_saved_views_are_the_renders_scored(world, run, capsys):
    views = run["dir"] / "views"
    sim, result = run["sim"], run["l3gs"]
    assert sorted(p.name for p in (views / L3GS).glob("*.png")) == [f"{t:03d}.png" for t in range(SLOTS)]
    assert json.loads((views / L3GS / "views.json").read_text())["run_id"] == result.records[0]["run_id"]
    # Independent renders: the reference scene, and the client's final rows, from the true camera.
    for t in range(SLOTS):
        fresh = render_image(world["teacher"], sim.true_camera(t))
        assert np.array_equal(_png(views / "reference" / f"{t:03d}.png"), _as_png(fresh))
    last = render_image(sim.scene.subset(result.final_rows), sim.true_camera(SLOTS - 1))
    assert np.array_equal(_png(views / L3GS / f"{SLOTS - 1:03d}.png"), _as_png(last))
    # The CLI's --save-views: the sort run (no solver) under its plain name, three pictures.
    assert sorted(p.name for p in (views / "sort").glob("*.png")) == [f"{t:03d}.png" for t in range(SLOTS)]
    assert not (views / views_folder("greedy")).exists()
    code = main(["simulate", str(world["root"] / "sort"), "--trace", "lumos-throughput-mid-11", "--slots", "3",
                 "--path", str(world["log"]), "--method", "sort", "--save-views", "--no-progress"])
    err = capsys.readouterr().err
    assert code == 2 and err.startswith("error: save-views: needs --out") and err.count("\n") == 1


def test_views_folder_names():
    assert views_folder("sort") == "sort"
    assert views_folder("rolling:bb", None, "visibility") == "rolling-bb__visibility"
    assert views_folder("l3gs", "fptas:0.2", "eq1", 1) == "l3gs__fptas-0.2__c1"
    assert views_folder("reference") != "reference"   # never the reference pictures' folder


def test_views_survive_an_interrupt_and_a_fresh_run_drops_stale_ones(world, tmp_path, monkeypatch):
    from l3gs_opt.simulator import schedulers

    whole = tmp_path / "whole"
    _sim(world).run("l3gs", out_dir=whole, views_dir=whole / "views")
    cut = tmp_path / "cut"
    original = schedulers.SlotSolverScheduler.requests

    def stop(self, view):
        if view.slot == 2:
            raise _Stop
        return original(self, view)

    with monkeypatch.context() as m:
        m.setattr(schedulers.SlotSolverScheduler, "requests", stop)
        with pytest.raises(_Stop):
            _sim(world).run("l3gs", out_dir=cut, views_dir=cut / "views")
    assert sorted(p.name for p in (cut / "views" / L3GS).glob("*.png")) == ["000.png", "001.png"]
    assert not list((cut / "views" / L3GS).glob(".*"))   # no half-written picture left
    r = _sim(world).run("l3gs", out_dir=cut, views_dir=cut / "views", resume=True)
    assert r.summary["resumed_slots"] == 2
    for t in range(SLOTS):
        for folder in (L3GS, "reference"):
            assert (cut / "views" / folder / f"{t:03d}.png").read_bytes() == \
                (whole / "views" / folder / f"{t:03d}.png").read_bytes()
    # A fresh run of the same method does not keep pictures of slots it never reaches.
    Image.new("RGB", (4, 4)).save(cut / "views" / L3GS / "007.png")
    _sim(world).run("l3gs", out_dir=cut, views_dir=cut / "views")
    assert not (cut / "views" / L3GS / "007.png").exists()
    assert len(list((cut / "views" / L3GS).glob("*.png"))) == SLOTS


def test_views_folder_that_is_a_file_is_refused_and_frees_the_run(world, tmp_path):
    from l3gs_opt.simulator.simulation import SimulationError

    (tmp_path / "views").write_text("not a folder")
    with pytest.raises(SimulationError, match=r"views: .*views is a file: expected a folder"):
        _sim(world).run("l3gs", out_dir=tmp_path, views_dir=tmp_path / "views")
    # The run's record lock was released: the same run into the same folder goes on.
    assert len(_sim(world).run("l3gs", out_dir=tmp_path, views_dir=tmp_path / "pictures").records) == SLOTS


# ---------------------------------------------------------------------------------------- the page
class _Page(HTMLParser):
    """The page's <img> sources, <script> bodies, section ids and its text."""

    def __init__(self):
        super().__init__()
        self.imgs, self.scripts, self.sections, self.text = [], [], [], []
        self._script = None

    def handle_starttag(self, tag, attrs):
        a = dict(attrs)
        if tag == "img":
            self.imgs.append(a)
        elif tag == "section":
            self.sections.append(a.get("id"))
        elif tag == "script":
            self._script = [a.get("src"), a.get("type"), ""]
        for name in ("src", "href"):   # self-contained: nothing fetched from the network
            assert "://" not in (a.get(name) or ""), (tag, a)

    def handle_endtag(self, tag):
        if tag == "script":
            self.scripts.append(self._script)
            self._script = None

    def handle_data(self, data):
        if self._script is not None:
            self._script[2] += data
        else:
            self.text.append(data)


def _parse(path: Path) -> tuple[_Page, dict]:
    page = _Page()
    page.feed(path.read_text(encoding="utf-8"))
    data = json.loads(next(body for _, kind, body in page.scripts if kind == "application/json"))
    return page, data


def test_page_files_and_data(run, tmp_path):
    path = write_replay(run["dir"], tmp_path / "page")
    assert path == tmp_path / "page" / PAGE_NAME and path.is_file()
    page, data = _parse(path)
    assert all(src is None for src, _, _ in page.scripts)   # inline scripts only
    records = _records(run["dir"])
    labels = [r["label"] for r in data["runs"]]
    assert labels == ["l3gs (solver bb)", "sort", "greedy"] and page.sections == ["run-0", "run-1", "run-2"]
    assert data["slots"] == SLOTS
    for run_data, method in zip(data["runs"], ("l3gs", "sort", "greedy")):
        mine = sorted((r for r in records if r["method"] == method), key=lambda r: r["slot"])
        assert run_data["slots"] == list(range(SLOTS))
        assert [x["ssim"] for x in run_data["records"]] == [r["ssim"] for r in mine]
        assert [x["bytes_delivered"] for x in run_data["records"]] == [r["bytes_delivered"] for r in mine]
        # Arrivals: this slot's completed chunks are "3", all earlier ones "4" (a grid of objects x levels).
        grid = run_data["shape"]
        held = set()
        for r, states in zip(mine, run_data["states"]):
            assert len(states) == grid[0] * grid[1]
            now = {tuple(u) for u in r["completed"]}
            assert {divmod(k, grid[1]) for k, c in enumerate(states) if c == "3"} == now
            assert {divmod(k, grid[1]) for k, c in enumerate(states) if c == "4"} == held
            held |= now
    # Pictures: copied beside the page, byte for byte, linked relatively.
    for t in range(SLOTS):
        for folder, frames in ((L3GS, data["runs"][0]["frames"]), ("sort", data["runs"][1]["frames"]),
                               ("reference", data["reference"])):
            rel = f"views/{folder}/{t:03d}.png"
            assert frames[t] == rel
            assert (path.parent / rel).read_bytes() == (run["dir"] / rel).read_bytes()
    assert data["runs"][2]["frames"] == [None] * SLOTS
    assert "views were not saved" in data["runs"][2]["why"] and "views were not saved" in "".join(page.text)
    assert page.imgs[0]["src"] == f"views/{L3GS}/000.png"
    # The charts are drawn: one SSIM and one bytes chart per run, each with a cursor.
    html_text = path.read_text(encoding="utf-8")
    assert html_text.count('class="chart"') == 6 and html_text.count('class="cursor"') == 6


def test_page_in_the_run_folder_links_the_pictures_in_place(run, tmp_path):
    folder = tmp_path / "run"
    shutil.copytree(run["dir"], folder)
    before = sorted(p.relative_to(folder) for p in folder.rglob("*"))
    path = write_replay(folder, folder)
    assert sorted(p.relative_to(folder) for p in folder.rglob("*")) == sorted(before + [Path(PAGE_NAME)])
    _, data = _parse(path)
    assert all((folder / f).is_file() for f in data["runs"][0]["frames"] + data["reference"])


def test_page_without_views_and_with_views_of_another_run(run, tmp_path):
    folder = tmp_path / "run"
    shutil.copytree(run["dir"], folder, ignore=shutil.ignore_patterns("views"))
    _, data = _parse(write_replay(folder, tmp_path / "page"))
    assert all(r["frames"] == [None] * SLOTS for r in data["runs"]) and data["reference"] == [None] * SLOTS
    assert data["reference_why"] == "reference views were not saved"
    assert not (tmp_path / "page" / "views").exists()
    # Pictures whose views.json names another run are not passed off as this run's.
    shutil.copytree(run["dir"] / "views", folder / "views")
    (folder / "views" / L3GS / "views.json").write_text(json.dumps({"run_id": "0" * 16}))
    _, data = _parse(write_replay(folder, tmp_path / "page2"))
    assert data["runs"][0]["frames"] == [None] * SLOTS and "another run" in data["runs"][0]["why"]
    assert data["runs"][1]["frames"][0] == "views/sort/000.png"


def test_arrival_states_by_hand(tmp_path):
    """Chunks (object, level, form) on a 2 x 2 x 2 grid, states worked out by hand."""
    base = {"method": "distill", "solver": "bb", "ssim": 0.5, "bytes_delivered": 900, "bytes_trace": 1000}
    records = [dict(base, slot=0, requests=[[0, 0, 0], [1, 0, 0]], completed=[[0, 0, 0]], in_flight=[[1, 0, 0, 500]]),
               dict(base, slot=1, requests=[[0, 0, 1]], completed=[[1, 0, 0]], in_flight=[])]
    (tmp_path / "slots.jsonl").write_text("".join(json.dumps(r) + "\n" for r in records))
    (tmp_path / "summary.jsonl").write_text(json.dumps({"method": "distill", "solver": "bb", "units": [2, 2, 2],
                                                        "slot_s": 0.5}) + "\n")
    _, data = _parse(write_replay(tmp_path, tmp_path / "page"))
    # k = 4 * object + 2 * level + form; 3 arrived now, 2 partly, 1 requested, 4 held from before.
    assert data["runs"][0]["shape"] == [2, 2, 2] and data["slot_s"] == 0.5
    assert data["runs"][0]["states"] == ["30002000", "41003000"]
    assert data["runs"][0]["why"].startswith("views were not saved")


def test_bad_run_folders_are_one_line_errors(run, tmp_path, capsys):
    with pytest.raises(ReplayError, match="run_dir: .*no such folder"):
        write_replay(tmp_path / "nothing", tmp_path / "page")
    (tmp_path / "empty").mkdir()
    with pytest.raises(ReplayError, match=r"slots.jsonl: .*no such file"):
        write_replay(tmp_path / "empty", tmp_path / "page")
    (tmp_path / "empty" / "slots.jsonl").write_text("")
    with pytest.raises(ReplayError, match="slots.jsonl: .* holds no slot records"):
        write_replay(tmp_path / "empty", tmp_path / "page")
    bad = tmp_path / "bad"
    bad.mkdir()
    lines = _records(run["dir"])[:2]
    lines[1]["slot"] = -1
    (bad / "slots.jsonl").write_text("".join(json.dumps(x) + "\n" for x in lines))
    with pytest.raises(ReplayError, match=r"^slot\[2\]: -1 must be an integer >= 0"):
        write_replay(bad, tmp_path / "page")
    lines[1]["slot"], lines[1]["completed"] = 1, [[0, "a"]]
    (bad / "slots.jsonl").write_text("".join(json.dumps(x) + "\n" for x in lines))
    with pytest.raises(ReplayError, match=r"^completed\[2\]: \[0, 'a'\] is not a chunk label"):
        write_replay(bad, tmp_path / "page")
    (tmp_path / "file").write_text("x")
    with pytest.raises(ReplayError, match="out_dir: .* is a file"):
        write_replay(run["dir"], tmp_path / "file")
    # The subcommand (registered on a parser of its own: main's registration is not this file's).
    parser = argparse.ArgumentParser()
    register(parser.add_subparsers())
    args = parser.parse_args(["replay", str(run["dir"]), "--out", str(tmp_path / "cli")])
    assert args.func(args) == 0 and (tmp_path / "cli" / PAGE_NAME).is_file()
    assert str(tmp_path / "cli" / PAGE_NAME) in capsys.readouterr().out


_LABEL = st.lists(st.one_of(st.integers(-2, 5), st.just("x")), min_size=0, max_size=5)
_RECORD = st.fixed_dictionaries(
    {"method": st.one_of(st.sampled_from(["a", "b"]), st.none(), st.just("")),
     "slot": st.one_of(st.integers(-1, 6), st.floats(allow_nan=False), st.none(), st.booleans()),
     "ssim": st.one_of(st.none(), st.floats(-1, 1), st.text(max_size=2)),
     "bytes_delivered": st.one_of(st.integers(-5, 10**6), st.none()),
     "bytes_trace": st.integers(0, 10**6),
     "completed": st.one_of(st.lists(_LABEL, max_size=3), st.integers())},
    optional={"requests": st.lists(_LABEL, max_size=3), "in_flight": st.lists(_LABEL, max_size=3),
              "time_s": st.floats(0, 10), "psnr": st.one_of(st.none(), st.floats(0, 60)),
              "utility": st.text(max_size=3), "solver": st.one_of(st.none(), st.text(max_size=3))})


@settings(max_examples=60, deadline=None, suppress_health_check=[HealthCheck.too_slow])
@given(st.lists(_RECORD, min_size=1, max_size=4))
@example([{"method": "a", "slot": float("inf"), "ssim": None, "bytes_delivered": 1, "bytes_trace": 1,
           "completed": []}])   # found in CI: Infinity in a record line
def test_any_records_give_a_page_or_a_replay_error(records):
    """Whatever the records hold, the page is written, or a ReplayError names the field, or the record
    reader names the line that is not strict JSON: no traceback."""
    with tempfile.TemporaryDirectory() as tmp:
        folder = Path(tmp)
        (folder / "slots.jsonl").write_text("".join(json.dumps(r) + "\n" for r in records))
        try:
            path = write_replay(folder, folder / "page")
        except ReplayError as exc:
            assert exc.field in {"method", "slot", "ssim", "psnr", "bytes_delivered", "bytes_trace", "requests",
                                 "completed", "in_flight"}
        except RecordFileError as exc:
            # json.dumps writes inf as Infinity: not strict JSON, refused by the record reader, by line
            assert "Infinity is not JSON" in str(exc) and exc.field.startswith(str(folder / "slots.jsonl"))
        else:
            _, data = _parse(path)
            assert sum(len(r["slots"]) for r in data["runs"]) <= len(records)


# ---------------------------------------------------------------------------------------- in a browser
def _chrome():
    """A headless Chromium driven by Selenium, or a skip that says what is missing."""
    try:
        from selenium import webdriver
        from selenium.webdriver.chrome.service import Service
    except ImportError:
        pytest.skip("selenium is not installed (pip install selenium)")
    browser = next((shutil.which(n) for n in ("chromium", "chromium-browser", "google-chrome") if shutil.which(n)),
                   None)
    driver = shutil.which("chromedriver")
    if browser is None or driver is None:
        pytest.skip("needs chromium and chromedriver on PATH (Debian/Ubuntu: apt-get install chromium "
                    "chromium-driver)")
    options = webdriver.ChromeOptions()
    options.binary_location = browser
    for arg in ("--headless=new", "--no-sandbox", "--disable-gpu", "--disable-dev-shm-usage",
                "--window-size=1200,1400"):
        options.add_argument(arg)
    options.set_capability("goog:loggingPrefs", {"browser": "ALL"})
    # The driver's path given: Selenium Manager would otherwise look for one on the network.
    return webdriver.Chrome(service=Service(executable_path=driver), options=options)


def _console_errors(driver) -> list[dict]:
    """The console's errors and warnings since the last call (script errors, failed loads)."""
    return [e for e in driver.get_log("browser") if e.get("level") in ("SEVERE", "WARNING")]


def test_page_in_headless_chromium(run, tmp_path):
    path = write_replay(run["dir"], tmp_path / "page")
    started = time.perf_counter()
    driver = _chrome()
    try:
        from selenium.webdriver.common.by import By
        from selenium.webdriver.common.keys import Keys

        driver.set_page_load_timeout(15)
        driver.get(path.resolve().as_uri())
        assert _console_errors(driver) == []
        view = driver.find_element(By.CSS_SELECTOR, "#run-0 img.view")
        cursor = driver.find_element(By.CSS_SELECTOR, "#run-0 line.cursor")
        assert view.get_attribute("src").endswith(f"/views/{L3GS}/000.png")
        x0 = cursor.get_attribute("x1")
        # The picture loaded (a broken relative link gives naturalWidth 0).
        assert driver.execute_script("return arguments[0].complete && arguments[0].naturalWidth", view) == 64
        slider = driver.find_element(By.ID, "slot")
        slider.send_keys(Keys.END)   # a real key press: the browser fires the input event
        assert view.get_attribute("src").endswith(f"/views/{L3GS}/{SLOTS - 1:03d}.png")
        assert cursor.get_attribute("x1") != x0
        assert driver.find_element(By.ID, "slot-label").text.startswith(f"slot {SLOTS - 1}")
        slider.send_keys(Keys.ARROW_LEFT)
        assert view.get_attribute("src").endswith(f"/views/{L3GS}/{SLOTS - 2:03d}.png")
        missing = driver.find_element(By.CSS_SELECTOR, "#run-2 .view-missing")
        assert missing.is_displayed() and "not saved" in missing.text
        assert not driver.find_element(By.CSS_SELECTOR, "#run-2 img.view").is_displayed()
        cells = driver.find_elements(By.CSS_SELECTOR, "#run-0 td.unit")
        assert any("s3" in c.get_attribute("class") or "s4" in c.get_attribute("class") for c in cells)
        shot = np.asarray(Image.open(io.BytesIO(driver.get_screenshot_as_png())).convert("RGB"))
        assert shot.shape[0] > 100 and shot.shape[1] > 100
        assert len(np.unique(shot.reshape(-1, 3), axis=0)) > 50   # a page with pictures, not one colour
        assert _console_errors(driver) == []   # none after moving the slider either
    finally:
        driver.quit()
    assert time.perf_counter() - started < 20
