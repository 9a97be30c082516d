"""Build a deliverable bundle from a teacher scene: the five variants, in checkpointed stages.

=============  ==========================================================================
variant        how the levels are made (sizes ``d_1 < ... < d_L``)
=============  ==========================================================================
``layered``    Prune2TargetSize(teacher, d_L), then ProgressiveTraining (lower layers frozen)
``distill``    ``layered``, plus a compact-SH form of every layer fitted to its full SH
               (:func:`l3gs_opt.renderer.distill.distill_sh`), so a layer can be sent compact
               and upgraded later by its SH bytes alone
``separate``   one independently fine-tuned model per size: version L = Prune2TargetSize
               (teacher, d_L), version l = Prune2TargetSize(version l+1, d_l) (chained from the
               next larger version rather than from the teacher: the loop passes through
               that size anyway, and it saves one pruning pass per version); every splat of
               every version is trained, nothing is frozen or shared
``hierarchy``  ``separate``, with each version-l splat linked to its parent: the version-(l-1)
               splat of the same object with the nearest mean (world units; -1 if that object
               has no splat there)
``sort``       the teacher sorted by global significance; versions are prefixes, no training
=============  ==========================================================================

Training views are the teacher's renders from the given cameras, downscaled so that the width
is at most ``schedule.max_width`` pixels.

Before any stage runs, the teacher is checked against what float32 training survives, naming the
PLY property and row of the first value outside it: ``scale_*`` (log standard deviations) at
most :data:`MAX_TRAIN_LOG_SCALE` (e^44 already overflows the squared scales to inf and the first
training step to NaN) and SH coefficients within :data:`MAX_TRAIN_SH` (the SSIM loss squares
colours; 1e20 overflows). Cameras are limited by :class:`~l3gs_opt.scene.cameras.Camera` itself (a
focal length of 1e20 pixels also turns training to NaN) and quaternions by
:data:`~l3gs_opt.scene.splats.MIN_QUAT_NORM`. Should training still produce a non-finite value, the
error names the stage, not an internal array.  Each stage writes a checkpoint (a PLY under
``OUT/.build/``) and records itself in ``OUT/.build/state.json``; with ``resume=True`` a build
skips the stages already done (if the teacher, cameras, sizes, variant and schedule match).
"""

from __future__ import annotations

import dataclasses
import hashlib
import json
import os
import time
from pathlib import Path
from typing import Callable, NamedTuple, Optional, Sequence

import numpy as np

from l3gs_opt.output_files import write_atomic
from l3gs_opt.scene.bundle import REPRESENTATION, VARIANTS, split_layers, write_bundle
from l3gs_opt.errors import L3gsError
from l3gs_opt.input_files import read_json
from l3gs_opt.scene.scene_files import read_scene
from l3gs_opt.scene.splats import SceneError, SplatScene, ply_property, read_ply, write_ply

__all__ = ["BuildError", "IN_MEMORY_TEACHER", "BuildSchedule", "QUICK", "DEFAULT", "BuildResult", "build_bundle",
           "scale_camera", "hierarchy_parents", "check_trainable", "MAX_TRAIN_LOG_SCALE", "MAX_TRAIN_SH"]

#: ``build.teacher`` of a bundle built from a scene in memory: no file to score against later.
IN_MEMORY_TEACHER = "<in memory>"
#: Largest ``scale_*`` (natural log of a standard deviation, world units) a teacher may hold: a
#: standard deviation of 4.9e8 units. Training overflows (NaN) from about 44.
MAX_TRAIN_LOG_SCALE = 20.0
#: Largest |SH coefficient| a teacher may hold (colours are ~0.28 x the DC term, displayed in [0, 1]).
#: Training overflows (NaN) from about 1e20.
MAX_TRAIN_SH = 1e6

_STATE_VERSION = 1


class BuildError(L3gsError, ValueError):
    """A build request is invalid (variant, sizes, checkpoint that does not match)."""


@dataclasses.dataclass(frozen=True)
class BuildSchedule:
    """How hard a build trains.

    Attributes
    ----------
    max_width : int
        Training views are downscaled to at most this width in pixels (aspect kept).
    prune_ratio : float
        ``r`` of Prune2TargetSize.
    recovery_iterations, finetune_iterations, layer_iterations : int
        Iterations of each Recovery run, of the final Finetune of Prune2TargetSize, and of each
        ProgressiveTraining layer.  Densification runs 5 times per Recovery (every
        ``recovery_iterations // 5`` iterations, the last at 80 %).  The opacity reset keeps the
        reference period (3000 iterations), so it does not fire in runs this short: after a
        reset the reference needs thousands of iterations to recover the opacities.
    compact_sh_degree : int
        SH degree of the compact form (``distill``).
    seed : int
    layered_base : {"pruned", "top"}
        Where a layered (or distill) bundle's base layer comes from. ``pruned`` (default): the
        paper's base layer, the teacher pruned by Prune2TargetSize down the chain
        ``d_L -> ... -> d_1`` -- the ``separate`` variant's first version, bit for bit (same
        schedule and cameras) -- kept as it is. ``top``: the first ``d_1`` splats of the teacher
        pruned to the top size ``d_L`` (sorted by significance), fine-tuned alone: about 2.3x faster
        to build, and 8.6 dB behind at the first version (``benchmarks/results/trainer_paper360k.md``:
        360k teacher, 4 x 45k). The upper layers come from the top model either way.
    """

    max_width: int = 320
    prune_ratio: float = 0.3
    recovery_iterations: int = 300
    finetune_iterations: int = 400
    layer_iterations: int = 400
    compact_sh_degree: int = 0
    seed: int = 0
    layered_base: str = "pruned"

    def __post_init__(self) -> None:
        if self.layered_base not in ("pruned", "top"):
            raise BuildError(f"layered_base = {self.layered_base!r}: must be 'pruned' or 'top'")

    def train_config(self, kind: str):
        """The :class:`TrainConfig` of a ``"recovery"``, ``"finetune"`` or ``"layer"`` run."""
        from l3gs_opt.renderer.train import TrainConfig

        if kind == "recovery":
            it = self.recovery_iterations
            step = max(1, it // 5)
            return TrainConfig(iterations=it, densify_from=0, densify_every=step, densify_until=int(0.8 * it) + 1,
                               seed=self.seed)
        it = self.finetune_iterations if kind == "finetune" else self.layer_iterations
        return TrainConfig(iterations=it, seed=self.seed)


#: ``--quick``: small views and short runs (the demo and CI; a 10k-splat teacher builds in minutes).
QUICK = BuildSchedule(max_width=128, prune_ratio=0.3, recovery_iterations=60, finetune_iterations=100,
                      layer_iterations=100)
#: The default schedule (still far shorter than the reference 30k iterations: CPU budget).
DEFAULT = BuildSchedule()


class BuildResult(NamedTuple):
    """What :func:`build_bundle` returns: the manifest path and per-stage wall-clock seconds."""

    manifest: Path
    stage_seconds: dict
    total_seconds: float


def scale_camera(cam, max_width: int):
    """``cam`` downscaled so that its width is at most ``max_width`` pixels (unchanged if smaller)."""
    if cam.width <= max_width:
        return cam
    s = max_width / cam.width
    h = max(1, int(round(cam.height * s)))
    return cam.replace(width=max_width, height=h, fx=cam.fx * s, fy=cam.fy * h / cam.height,
                       cx=cam.cx * s, cy=cam.cy * h / cam.height)


def hierarchy_parents(lower: SplatScene, upper: SplatScene) -> np.ndarray:
    """Per splat of ``upper``, the row of the nearest-mean splat of ``lower`` with the same object id
    (-1 when the object has no splat in ``lower``); shape [N_upper], int64."""
    from scipy.spatial import cKDTree

    lo_ids = np.zeros(lower.num_splats, np.int64) if lower.object_ids is None else lower.object_ids
    up_ids = np.zeros(upper.num_splats, np.int64) if upper.object_ids is None else upper.object_ids
    out = np.full(upper.num_splats, -1, np.int64)
    for j in np.unique(up_ids):
        lo_rows = np.flatnonzero(lo_ids == j)
        if lo_rows.size == 0:
            continue
        up_rows = np.flatnonzero(up_ids == j)
        _, k = cKDTree(lower.means[lo_rows].astype(np.float64)).query(upper.means[up_rows].astype(np.float64))
        out[up_rows] = lo_rows[k]
    return out


def check_trainable(scene: SplatScene) -> None:
    """Refuse a teacher that float32 training would turn into NaN (see the module docstring).

    Raises
    ------
    BuildError
        Naming the PLY property and row, e.g. ``teacher: scale_0[17] = 50.0: ...``.
    """
    for field, values, bad, rule in (
            ("log_scales", scene.log_scales, scene.log_scales > MAX_TRAIN_LOG_SCALE,
             f"must be <= {MAX_TRAIN_LOG_SCALE:g} (MAX_TRAIN_LOG_SCALE; a larger log-scale overflows training)"),
            ("sh", scene.sh, np.abs(scene.sh) > MAX_TRAIN_SH,
             f"must be within +-{MAX_TRAIN_SH:g} (MAX_TRAIN_SH; larger colours overflow the SSIM loss)")):
        if bad.any():
            index = tuple(int(i) for i in np.argwhere(bad)[0])
            prop, row = ply_property(field, index, scene.sh.shape[1])
            raise BuildError(f"teacher: {prop}[{row[0]}] = {float(values[index])!r}: {rule}")


def _digest(path: Path) -> str:
    h = hashlib.sha256()
    with open(path, "rb") as fh:
        for block in iter(lambda: fh.read(1 << 20), b""):
            h.update(block)
    return h.hexdigest()


class _Stages:
    """Checkpoint bookkeeping under ``OUT/.build``."""

    def __init__(self, out: Path, key: dict, resume: bool):
        self.dir = out / ".build"
        self.state_path = self.dir / "state.json"
        self.key = key
        self.done: dict = {}
        #: Stages checkpointed between rounds (Prune2TargetSize), by name.
        self.partial: dict = {}
        if resume and self.state_path.is_file():
            state = read_json(self.state_path, lambda f, m: BuildError(f"--resume: {m}"))
            if not isinstance(state, dict) or not isinstance(state.get("done"), dict):
                raise BuildError(f"--resume: {self.state_path} is not a build checkpoint; drop --resume to start over")
            if state.get("key") != key:
                old = state["key"] if isinstance(state.get("key"), dict) else {}
                diff = sorted(k for k in key if old.get(k) != key[k])
                raise BuildError(f"--resume: the checkpoint in {self.dir} was made with a different "
                                 f"{', '.join(diff) or 'state version'}; drop --resume to start over")
            self.done = state["done"]
            partial = state.get("partial", {})
            self.partial = partial if isinstance(partial, dict) else {}
        elif self.dir.is_dir():
            for f in self.dir.iterdir():  # a fresh build must not pick up stale checkpoints
                f.unlink()
        self.dir.mkdir(parents=True, exist_ok=True)

    def load(self, name: str) -> Optional[SplatScene]:
        if name not in self.done:
            return None
        return read_ply(self.dir / self.done[name]["file"])

    def save(self, name: str, scene: SplatScene, seconds: float) -> None:
        write_ply(scene, self.dir / f"{name}.ply")
        self.done[name] = {"file": f"{name}.ply", "seconds": seconds}
        self.partial.pop(name, None)
        self._write_state()
        (self.dir / f"{name}.partial.ply").unlink(missing_ok=True)

    def load_partial(self, name: str) -> Optional[tuple[SplatScene, list, float]]:
        """A stage's last round (scene, rounds' records, seconds spent), or None."""
        got = self.partial.get(name)
        if got is None:
            return None
        return read_ply(self.dir / got["file"]), got["rounds"], got["seconds"]

    def save_partial(self, name: str, scene: SplatScene, rounds: list, seconds: float) -> None:
        """Checkpoint a stage between rounds (written first, then named in the state, atomically)."""
        tmp = self.dir / f"{name}.partial.tmp.ply"
        write_ply(scene, tmp)
        os.replace(tmp, self.dir / f"{name}.partial.ply")
        self.partial[name] = {"file": f"{name}.partial.ply", "rounds": rounds, "seconds": seconds}
        self._write_state()

    def _write_state(self) -> None:
        # atomic: an interrupted write never leaves a broken state
        state = {"key": self.key, "done": self.done, "partial": self.partial}
        write_atomic(self.state_path, json.dumps(state, indent=1))


def _schedule_key(schedule: BuildSchedule, variant: str) -> dict:
    """The schedule's fields that shape ``variant``'s stages (what a checkpoint must match):
    ``layered_base`` only matters to the variants with a base layer."""
    key = dataclasses.asdict(schedule)
    if variant not in ("layered", "distill"):
        key.pop("layered_base")
    return key


def build_bundle(teacher, cameras: Sequence, sizes: Sequence[int], variant: str, out, *,
                 schedule: BuildSchedule = DEFAULT, resume: bool = False, show_progress: bool = True,
                 log: Optional[Callable[[str], None]] = None) -> BuildResult:
    """Build the ``variant`` bundle of ``teacher`` at ``sizes`` into the directory ``out``.

    Parameters
    ----------
    teacher : str, Path or SplatScene
        Teacher scene (a PLY path is hashed for the resume check).
    cameras : sequence of Camera
        Training cameras.
    sizes : sequence of int
        Cumulative sizes ``0 < d_1 < ... < d_L <= N_teacher`` (splats).
    variant : str
        One of :data:`l3gs_opt.scene.bundle.VARIANTS`.
    out : str or Path
        Bundle directory.
    schedule : BuildSchedule, keyword-only
    resume : bool, keyword-only
        Skip the stages checkpointed by an earlier, interrupted build with the same inputs.
    show_progress : bool, keyword-only
        A tqdm bar per stage (on stderr).
    log : callable(str), optional, keyword-only
        Receives one line per finished stage.

    Returns
    -------
    BuildResult

    Raises
    ------
    BuildError, SizeError
        On an unknown variant, bad sizes (naming ``--layers`` and the index), no cameras, or a
        checkpoint that does not match.
    """
    from l3gs_opt.renderer.progressive import check_sizes, prune_to_target_size, train_layer
    from l3gs_opt.renderer.significance import global_significance, significance_order
    from l3gs_opt.renderer.train import teacher_views

    t_start = time.perf_counter()
    if variant not in VARIANTS:
        raise BuildError(f"--variant: {variant!r} must be one of {', '.join(VARIANTS)}")
    if len(cameras) == 0:
        raise BuildError("--cameras: no cameras")
    if isinstance(teacher, (str, Path)):
        teacher_path = Path(teacher)
        scene = read_scene(teacher_path)
        ident = {"teacher": str(teacher_path), "teacher_sha256": _digest(teacher_path)}
    else:
        scene = teacher
        ids = scene.object_ids.tobytes() if scene.object_ids is not None else b""
        ident = {"teacher": IN_MEMORY_TEACHER, "teacher_sha256": hashlib.sha256(scene.means.tobytes() + scene.sh.tobytes()
                                                                            + ids).hexdigest()}
    check_trainable(scene)
    sizes = check_sizes(sizes, scene.num_splats, field="--layers")
    out = Path(out)
    cams = [scale_camera(c, schedule.max_width) for c in cameras]
    cam_key = hashlib.sha256(json.dumps([[c.width, c.height, c.fx, c.fy, c.cx, c.cy,
                                          c.world_to_camera.tolist()] for c in cams]).encode()).hexdigest()
    key = {"state_version": _STATE_VERSION, "variant": variant, "sizes": sizes, "cameras": cam_key,
           "schedule": _schedule_key(schedule, variant), **ident}
    stages = _Stages(out, key, resume)
    say = log or (lambda s: None)
    views = None
    seconds: dict = {}

    def get_views():
        nonlocal views
        if views is None:
            t0 = time.perf_counter()
            views = teacher_views(scene, cams)
            seconds["teacher_renders"] = time.perf_counter() - t0
        return views

    def run(name: str, fn, total: Optional[int] = None, *, rounds: bool = False) -> SplatScene:
        """Stage ``name``: ``fn(views, tick)`` (``rounds``: ``fn(views, tick, start, on_round)``, a
        stage checkpointed between its rounds), or its checkpoint."""
        got = stages.load(name)
        if got is not None:
            seconds[name] = stages.done[name]["seconds"]
            say(f"{name}: resumed from checkpoint")
            return got
        vws = get_views()
        t0 = time.perf_counter()
        before = 0.0
        if rounds:
            part = stages.load_partial(name)
            start = None
            if part is not None:
                start, before = (part[0], part[1]), part[2]
                say(f"{name}: resumed after round {len(part[1])} ({part[0].num_splats} splats)")

            def on_round(scene, recs):
                stages.save_partial(name, scene, recs, before + time.perf_counter() - t0)

            inner = fn
            fn = lambda v, tk: inner(v, tk, start, on_round)  # noqa: E731
        bar = None
        if show_progress:
            from tqdm import tqdm

            bar = tqdm(total=total, desc=name, unit="it", leave=False)

        def tick(it, loss):
            if bar is not None:
                bar.update(1)
                if it % 10 == 0:
                    bar.set_postfix(loss=f"{loss:.4f}")

        try:
            result = fn(vws, tick)
        except SceneError as exc:  # the inputs passed check_trainable: say where training failed
            raise BuildError(f"stage {name}: training produced an invalid scene ({exc}); the teacher and "
                             f"cameras are within the checked limits: please report this input") from None
        finally:
            if bar is not None:
                bar.close()
        dt = before + time.perf_counter() - t0
        seconds[name] = dt
        stages.save(name, result, dt)
        say(f"{name}: {result.num_splats} splats, {dt:.1f} s")
        return result

    rc, fc, lc = (schedule.train_config(k) for k in ("recovery", "finetune", "layer"))

    def prune(src, d):
        return lambda vws, tick, start, on_round: prune_to_target_size(
            src, d, vws, r=schedule.prune_ratio, recovery_config=rc, finetune_config=fc, progress=tick,
            start=start, on_round=on_round).scene

    compact = parents = None
    if variant in ("layered", "distill"):
        srt = run(f"prune_{sizes[-1]}", prune(scene, sizes[-1]), rounds=True)
        cur, prev = None, 0
        if schedule.layered_base == "pruned" and len(sizes) > 1:
            # The separate variant's chain (its stage names: the same stages, the same scenes).
            src = srt
            for i in range(len(sizes) - 2, -1, -1):
                src = run(f"version_{i}", prune(src, sizes[i]), rounds=True)
            cur = dataclasses.replace(src, layers=np.zeros(src.num_splats, np.int32))
            prev = sizes[0]
        for i, d in enumerate(sizes):
            if d <= prev and cur is not None:
                continue   # the base layer, already trained
            lower, new = cur, srt.subset(np.arange(prev, d))
            cur = run(f"layer_{i}", lambda vws, tick, lower=lower, new=new:
                      train_layer(lower, new, vws, config=lc, progress=tick), total=lc.iterations)
            prev = d
        levels = split_layers(cur)
        if variant == "distill":
            from l3gs_opt.renderer.distill import distill_sh

            if levels[0].sh_degree <= schedule.compact_sh_degree:
                raise BuildError(f"--variant distill: the teacher's SH degree {scene.sh_degree} has nothing to "
                                 f"distil below compact degree {schedule.compact_sh_degree}")
            t0 = time.perf_counter()
            compact = [distill_sh(lv.means, lv.sh, cams, schedule.compact_sh_degree) for lv in levels]
            seconds["distill_sh"] = time.perf_counter() - t0
    elif variant in ("separate", "hierarchy"):
        versions: list = [None] * len(sizes)
        src = scene
        for i in range(len(sizes) - 1, -1, -1):
            versions[i] = src = run(f"version_{i}", prune(src, sizes[i]), rounds=True)
        levels = versions
        if variant == "hierarchy":
            parents = [None] + [hierarchy_parents(levels[i - 1], levels[i]) for i in range(1, len(levels))]
    else:  # sort
        def sort_stage(vws, tick):
            return scene.subset(significance_order(global_significance(scene, [v.camera for v in vws]))[:sizes[-1]])

        srt = run("significance", sort_stage)
        bounds = [0] + sizes
        levels = [srt.subset(np.arange(bounds[i], bounds[i + 1])) for i in range(len(sizes))]
    total = time.perf_counter() - t_start
    build = {"teacher": ident["teacher"], "teacher_sha256": ident["teacher_sha256"],
             "teacher_splats": scene.num_splats, "teacher_sh_degree": scene.sh_degree, "sizes": sizes,
             "representation": REPRESENTATION[variant], "cameras": len(cams),
             "train_resolution": [cams[0].width, cams[0].height], "schedule": dataclasses.asdict(schedule),
             "stage_seconds": {k: round(v, 3) for k, v in seconds.items()}, "total_seconds": round(total, 3),
             "resumed_stages": sorted(k for k in stages.done if k in seconds and resume),
             "loadavg_at_end": list(os.getloadavg())}
    manifest = write_bundle(out, levels, variant=variant, compact_sh=compact, parents=parents, build=build)
    say(f"wrote {manifest}: {len(levels)} levels, {total:.1f} s")
    return BuildResult(manifest=manifest, stage_seconds=seconds, total_seconds=total)
