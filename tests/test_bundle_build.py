"""``build_bundle`` / ``scene build``: every variant on a tiny scene, checkpoints and resume, size errors."""

from __future__ import annotations

import argparse
import json

import numpy as np
import pytest

from l3gs_opt.scene.bundle import read_bundle
from l3gs_opt.scene.cameras import save_cameras
from l3gs_opt.cli.scene import register
from l3gs_opt.renderer.progressive import SizeError
from l3gs_opt.pipeline.build import BuildError, BuildSchedule, build_bundle
from l3gs_opt.scene.splats import write_ply
from renderer_helpers import make_camera, random_scene

TINY = BuildSchedule(max_width=24, prune_ratio=0.5, recovery_iterations=2, finetune_iterations=2,
                     layer_iterations=2)
SIZES = [8, 20, 30]


@pytest.fixture(scope="module")
def setup(tmp_path_factory):
    tmp = tmp_path_factory.mktemp("build")
    scene = random_scene(40, sh_degree=1, seed=3, object_ids=True, log_scale=(-2.5, -1.2), logit=(0.0, 3.0))
    cams = [make_camera(32, 24, eye=e) for e in [(0.3, -4.0, 1.2), (3.5, -1.5, 1.0), (-3.0, -2.5, 0.5)]]
    write_ply(scene, tmp / "t.ply")
    save_cameras(cams, tmp / "cams.json")
    return tmp, scene, cams


@pytest.mark.parametrize("variant", ["layered", "separate", "sort", "distill", "hierarchy"])
def test_every_variant_builds_exact_sizes(setup, variant):
    tmp, scene, cams = setup
    res = build_bundle(tmp / "t.ply", cams, SIZES, variant, tmp / variant, schedule=TINY, show_progress=False)
    b = read_bundle(tmp / variant)
    m = b.manifest
    assert m["variant"] == variant and m["segmented"]
    sep = variant in ("separate", "hierarchy")
    assert [lv["cumulative_splats"] for lv in m["levels"]] == SIZES
    assert [lv["splats"] for lv in m["levels"]] == (SIZES if sep else [8, 12, 10])
    for lvl, d in enumerate(SIZES):
        assert b.scene(lvl).num_splats == d
    assert m["build"]["train_resolution"] == [24, 18]
    assert res.total_seconds > 0
    if variant == "distill":
        assert m["compact_sh_degree"] == 0
        assert b.scene(2, sh_form="compact").sh_degree == 0 and b.scene(2).sh_degree == 1
    if variant == "hierarchy":
        for j in m["objects"]:
            for lvl in (1, 2):
                try:
                    par = b.parents(lvl, j)
                except Exception:
                    continue  # object absent from this version
                lower = [c for c in m["chunks"] if c["object"] == j and c["level"] == lvl - 1]
                assert ((par >= -1) & (par < (lower[0]["splats"] if lower else 0))).all()
                assert (par >= 0).all() or not lower


def test_resume_skips_finished_stages(setup):
    tmp, scene, cams = setup
    out = tmp / "res"
    build_bundle(tmp / "t.ply", cams, SIZES, "layered", out, schedule=TINY, show_progress=False)
    state_path = out / ".build" / "state.json"
    state = json.loads(state_path.read_text())
    del state["done"]["layer_2"]  # as if interrupted before the last stage
    state_path.write_text(json.dumps(state))
    first = read_bundle(out).scene(1)
    lines = []
    build_bundle(tmp / "t.ply", cams, SIZES, "layered", out, schedule=TINY, show_progress=False, resume=True,
                 log=lines.append)
    # the default base layer is the pruned chain's last version (separate's first), then the layers
    assert [s for s in lines if "resumed" in s] == ["prune_30: resumed from checkpoint",
                                                   "version_1: resumed from checkpoint",
                                                   "version_0: resumed from checkpoint",
                                                   "layer_1: resumed from checkpoint"]
    assert any(s.startswith("layer_2: 30 splats") for s in lines)
    again = read_bundle(out).scene(1)
    assert again.means.tobytes() == first.means.tobytes()  # resumed layers are the checkpointed ones
    with pytest.raises(BuildError, match="--resume: .* different sizes"):
        build_bundle(tmp / "t.ply", cams, [8, 20], "layered", out, schedule=TINY, show_progress=False, resume=True)


def test_a_prune_stage_resumes_between_rounds(setup, monkeypatch):
    """Prune2TargetSize 40 -> 8 runs rounds (recovery, recovery, finetune); interrupted after its
    first round's checkpoint, the build resumes from that round and ends bit-equal to an
    uninterrupted one (each round's training is seeded by the schedule)."""
    from l3gs_opt.pipeline import build as build_module

    tmp, scene, cams = setup
    whole = build_bundle(tmp / "t.ply", cams, [8], "separate", tmp / "r-whole", schedule=TINY, show_progress=False)
    real = build_module._Stages.save_partial
    calls = []

    def save_then_stop(self, name, sc, rounds, seconds):
        real(self, name, sc, rounds, seconds)
        calls.append(len(rounds))
        raise KeyboardInterrupt

    monkeypatch.setattr(build_module._Stages, "save_partial", save_then_stop)
    with pytest.raises(KeyboardInterrupt):
        build_bundle(tmp / "t.ply", cams, [8], "separate", tmp / "r-cut", schedule=TINY, show_progress=False)
    monkeypatch.setattr(build_module._Stages, "save_partial", real)
    state = json.loads((tmp / "r-cut" / ".build" / "state.json").read_text())
    assert calls == [1] and len(state["partial"]["version_0"]["rounds"]) == 1 and not state["done"]
    lines = []
    res = build_bundle(tmp / "t.ply", cams, [8], "separate", tmp / "r-cut", schedule=TINY, show_progress=False,
                       resume=True, log=lines.append)
    assert any(s.startswith("version_0: resumed after round 1") for s in lines)
    a, b = read_bundle(tmp / "r-whole").scene(0), read_bundle(tmp / "r-cut").scene(0)
    assert a.means.tobytes() == b.means.tobytes() and a.sh.tobytes() == b.sh.tobytes()
    assert res.stage_seconds["version_0"] > 0 and whole.stage_seconds["version_0"] > 0
    state = json.loads((tmp / "r-cut" / ".build" / "state.json").read_text())
    assert state["partial"] == {} and not (tmp / "r-cut" / ".build" / "version_0.partial.ply").exists()


def _cli(*argv):
    parser = argparse.ArgumentParser()
    register(parser.add_subparsers(dest="command", required=True))
    args = parser.parse_args([str(a) for a in argv])
    return args.func(args)


@pytest.mark.parametrize("layers, msg", [("20,8", r"--layers\[1\]: 8 must be greater"),
                                         ("0,8", r"--layers\[0\]: 0 must be > 0"),
                                         ("8,41", r"--layers\[1\]: 41 is more than the 40 splats"),
                                         ("8,x", r"--layers\[1\]: 'x' is not an integer")])
def test_cli_bad_sizes(setup, layers, msg):
    tmp, _, _ = setup
    with pytest.raises(SizeError, match=msg):
        _cli("scene", "build", tmp / "t.ply", "--cameras", tmp / "cams.json", "--layers", layers,
             "--variant", "layered", "--out", tmp / "bad")


def test_cli_build_quick(setup, capsys):
    tmp, _, _ = setup
    assert _cli("scene", "build", tmp / "t.ply", "--cameras", tmp / "cams.json", "--layers", "10,30",
                "--variant", "sort", "--out", tmp / "cli", "--quick", "--no-progress") == 0
    assert read_bundle(tmp / "cli").manifest["build"]["schedule"]["max_width"] == 128
    assert "wrote" in capsys.readouterr().out


def test_pruned_base_layer_is_the_separate_first_version(setup):
    """layered_base='pruned': the layered bundle's base layer is the separate variant's first version
    (the paper: at the first version layered equals separate), and the upper layers still stack."""
    import dataclasses

    tmp, scene, cams = setup
    sched = dataclasses.replace(TINY, layered_base="pruned")
    build_bundle(tmp / "t.ply", cams, SIZES, "separate", tmp / "sep-p", schedule=sched, show_progress=False)
    build_bundle(tmp / "t.ply", cams, SIZES, "layered", tmp / "lay-p", schedule=sched, show_progress=False)
    sep, lay = read_bundle(tmp / "sep-p"), read_bundle(tmp / "lay-p")
    a, b = sep.level_scene(0), lay.level_scene(0)
    ia, ib = np.lexsort(a.means.T), np.lexsort(b.means.T)   # chunks store rows by object: same rows, other order
    for field in ("means", "log_scales", "quats", "opacity_logits", "sh"):
        assert np.array_equal(getattr(a, field)[ia], getattr(b, field)[ib]), field
    assert [lv["cumulative_splats"] for lv in lay.manifest["levels"]] == SIZES
    with pytest.raises(BuildError, match="layered_base = 'x'"):
        BuildSchedule(layered_base="x")


def test_cli_build_without_cameras_segments_and_samples(setup, capsys):
    """A teacher given alone, as users have one: ids from segmentation, cameras sampled around it,
    in a compressed format."""
    tmp, scene, _ = setup
    from l3gs_opt.scene.scene_files import write_scene

    import dataclasses

    write_scene(dataclasses.replace(scene, object_ids=None), tmp / "t.spz")
    assert _cli("scene", "build", tmp / "t.spz", "--layers", "10,30", "--objects", "3", "--views", "4",
                "--size", "32x24", "--out", tmp / "alone", "--max-width", "24", "--no-progress") == 0
    out = capsys.readouterr().out
    assert "segmented the teacher into 3 objects" in out and "4 cameras sampled outside" in out
    m = read_bundle(tmp / "alone").manifest
    assert m["segmented"] and sorted(m["objects"]) == [0, 1, 2] and m["build"]["cameras"] == 4
    assert m["build"]["train_resolution"] == [24, 18]


def test_cli_convert_round_trip(setup, capsys):
    tmp, scene, _ = setup
    from l3gs_opt.scene.scene_files import read_scene

    assert _cli("scene", "convert", tmp / "t.ply", tmp / "c.compressed.ply") == 0
    assert "object ids and layers are not kept" in capsys.readouterr().out
    assert _cli("scene", "convert", tmp / "c.compressed.ply", tmp / "back.ply") == 0
    back = read_scene(tmp / "back.ply")
    assert back.num_splats == scene.num_splats and back.object_ids is None


def test_resume_of_a_separate_build_ignores_the_base_layer_option(setup):
    """layered_base shapes only layered and distill stages: a separate build resumes across it."""
    import dataclasses

    tmp, _, cams = setup
    out = tmp / "sep-resume"
    build_bundle(tmp / "t.ply", cams, SIZES, "separate", out, schedule=TINY, show_progress=False)
    lines = []
    build_bundle(tmp / "t.ply", cams, SIZES, "separate", out, schedule=dataclasses.replace(TINY, layered_base="top"),
                 show_progress=False, resume=True, log=lines.append)
    assert sum("resumed" in s for s in lines) == len(SIZES)
    with pytest.raises(BuildError, match="different schedule"):
        build_bundle(tmp / "t.ply", cams, SIZES, "layered", tmp / "lay-base", schedule=TINY, show_progress=False)
        build_bundle(tmp / "t.ply", cams, SIZES, "layered", tmp / "lay-base",
                     schedule=dataclasses.replace(TINY, layered_base="top"), show_progress=False, resume=True)
