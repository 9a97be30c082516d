"""The experiments of issue 9 (``l3gs-opt experiments``): the paper's evaluation on procedural scenes.

A plan (:class:`ExperimentPlan`) says which scenes and bundle variants, which traces and windows,
which viewer paths and which methods; :meth:`ExperimentPlan.tasks` turns it into a fixed list of
records, each one simulation (or one exact ceiling) that :func:`run_experiments` appends to
``OUT/runs.jsonl`` as soon as it finishes. ``resume=True`` skips every record already there, so an
interrupted run loses nothing and redoes nothing that finished.

The experiments (the report, :mod:`l3gs_opt.experiments.report`, reads them back from the records):

1. SSIM over time per method and mean SSIM per method (role ``main``, condition ``none``);
2. ground-truth ablations: the same with the true bandwidth, the true viewport, both (role
   ``ablation``, conditions ``true_bandwidth``, ``true_viewport``, ``true_both``), and the four
   again with requests limited to each slot's picks (``nofill*``, see :data:`ABLATIONS`);
3. per bandwidth class of the trace (``low`` / ``mid`` / ``high`` in the Lumos5G file name):
   bandwidth prediction error and SSIM (the ``main`` records grouped);
4. per-slot latency breakdown (prediction, utility look-up, scheduling, rendering: every record
   carries the simulator's mean per-slot timings);
5. the distill and hierarchy bundles against layered (role ``variant``): the simulator's own
   ``distill`` / ``hierarchy`` methods when :data:`l3gs_opt.simulator.simulation.SIM_METHODS` has them, else
   ``l3gs`` on the distill bundle and ``separate`` on the hierarchy bundle;
6. the ceiling (kind ``ceiling``): per (variant, window, path) the exact optimum of Problem I
   (layered bundles) or II (separate bundles) with perfect knowledge -- the true per-slot utilities
   (Eq. 1 averaged over the viewer's true poses in each slot, exactly as the simulator's oracle
   viewport computes them) and the true bandwidth, ``cumulative`` budget -- solved exactly by
   ``link-dp`` (:mod:`l3gs_opt.solvers.link_dp`, a DP over the delivered sets; optionally
   cross-checked against ``ilp/highs``), or by ``ilp/highs`` within a time limit when the DP's
   state space is too large (a time-limited answer is labelled and carries its bound).

Why the cumulative budget: the simulated link carries a chunk cut off at a slot's end into the next
slot, so the chunks *completed* by slot t never exceed the trace's bytes up to t; every
scheduler's completed chunks are therefore a feasible schedule of that instance, and its summed
true utility (``utility_sum`` of each record: complete chunks only, from the slot they complete in)
is at most the ceiling. Splats of a chunk still streaming are shown by the simulator but not
counted there. Each record checks its schedule against the instance in exact bytes
(``schedule_violations``).

Scale: the paper delivers ~180k splats x 248 B (44.6 MB) at a mean of 11.8 Mbit/s, so the whole
scene takes ~30 s of a 60 s window. Our scenes are far smaller; each trace is scaled to a mean of
``11.8 x scene bytes / 44.64 MB`` Mbit/s, which keeps the ratio scene bytes / bytes in the window
(0.50) the paper's. ``scene bytes`` is the largest layered model (every splat at full SH).

Example
-------
>>> from l3gs_opt.experiments.run import make_plan, run_experiments            # doctest: +SKIP
>>> from l3gs_opt.experiments.report import write_report                    # doctest: +SKIP
>>> plan = make_plan(quick=True)                                            # doctest: +SKIP
>>> runs = run_experiments(plan, "exp-out")   # doctest: +SKIP
>>> write_report(runs, "exp-out")                                           # doctest: +SKIP
"""

from __future__ import annotations

import dataclasses
import json
import math
import os
import time
import zlib
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any, Callable, Mapping, Sequence

import numpy as np

from l3gs_opt.errors import L3gsError
from l3gs_opt.jsonout import dumps
from l3gs_opt.records import RecordLog, append_record

__all__ = ["ExperimentError", "SceneSpec", "PathSpec", "TraceSpec", "Task", "ExperimentPlan", "make_plan",
           "run_experiments", "default_traces", "trace_class", "scaled_mbps", "method_variant", "ABLATIONS",
           "PATHS", "BASELINES", "PAPER_SCENE_BYTES", "PAPER_MBPS", "RUNS_FILE"]

#: The paper's scene and link: ~180k splats x 248 bytes at a mean of 11.8 Mbit/s, 60 s windows.
PAPER_SPLATS = 180_000
PAPER_BYTES_PER_SPLAT = 248
PAPER_SCENE_BYTES = PAPER_SPLATS * PAPER_BYTES_PER_SPLAT
PAPER_MBPS = 11.8
PAPER_WINDOW_S = 60
RUNS_FILE = "runs.jsonl"
#: Ground-truth ablations: SimConfig overrides per condition (``none`` is the plain run). The
#: ``nofill`` conditions request only each slot's picks (``fill=False``): with the default kept-busy
#: link a bandwidth prediction only reorders requests, without it an over-estimate leaves requests
#: unsent and an under-estimate leaves the link idle, as in the paper's per-slot scheduling.
ABLATIONS: dict[str, dict[str, Any]] = {
    "none": {},
    "true_bandwidth": {"bandwidth_predictor": "oracle"},
    "true_viewport": {"viewport": "oracle"},
    "true_both": {"bandwidth_predictor": "oracle", "viewport": "oracle"},
    "nofill": {"fill": False},
    "nofill_true_bandwidth": {"fill": False, "bandwidth_predictor": "oracle"},
    "nofill_true_viewport": {"fill": False, "viewport": "oracle"},
    "nofill_true_both": {"fill": False, "bandwidth_predictor": "oracle", "viewport": "oracle"},
}
#: Bundle a method runs on when several would accept it (the paper's pairing).
_PREFERRED = {"l3gs": "layered", "l3gs-noseg": "layered", "preload": "layered", "separate": "separate",
              "sort": "sort", "distill": "distill", "hierarchy": "hierarchy"}
_VARIANT_ORDER = ("layered", "sort", "separate", "distill", "hierarchy")
#: Methods that never look at a prediction: their ablation runs would repeat the plain one.
_PREDICTION_FREE = ("sort", "preload")
#: Baselines of the headline (the paper's L3GS against the other delivery schemes).
BASELINES = ("sort", "separate", "l3gs-noseg")
_CLASSES = ("low", "mid", "high")


class ExperimentError(L3gsError, ValueError):
    """Bad experiment input (plan option, trace, method, existing output); names the field and index."""

    def __init__(self, field: str, message: str, index: int | None = None):
        self.field = field
        self.index = index
        super().__init__(f"{field}{'' if index is None else f'[{index}]'}: {message}")


# ---------------------------------------------------------------------------------------- plan parts
@dataclass(frozen=True)
class SceneSpec:
    """A procedural room (:func:`l3gs_opt.scene.procedural.make_scene`) and its level sizes (splats)."""

    name: str
    splats: int
    objects: int = 4
    sh_degree: int = 1
    seed: int = 0
    sizes: tuple[int, ...] = ()
    #: The room's six surfaces as objects of their own (:func:`~l3gs_opt.scene.procedural.make_scene`).
    room_parts: bool = False

    def __post_init__(self) -> None:
        sizes = tuple(int(s) for s in self.sizes) or _default_sizes(self.splats)
        object.__setattr__(self, "sizes", sizes)
        if any(b <= a for a, b in zip(sizes, sizes[1:])) or sizes[0] < 1 or sizes[-1] > self.splats:
            raise ExperimentError("scene.sizes", f"{list(sizes)}: must increase, from >= 1 to <= {self.splats} "
                                                 "splats")


def _default_sizes(splats: int) -> tuple[int, ...]:
    """Four levels doubling up to the whole teacher: 1/8, 1/4, 1/2, 1."""
    return tuple(max(1, splats // 8 * k) for k in (1, 2, 4)) + (int(splats),)


@dataclass(frozen=True)
class PathSpec:
    """A viewer path: :func:`l3gs_opt.traces.poses.synthetic_poses` ``kind``, given to the simulator in
    memory (``source="synthetic"``) or written as a headset log and read back (``"log"``)."""

    name: str
    kind: str
    source: str = "synthetic"
    seed: int = 0


#: Paths by name: the orbit circles the room looking at its centre; the turns stand in the middle
#: and turn the head quickly (60-120 degrees), the hard case for the viewport predictor. A
#: ``walk`` would leave the 8 x 8 m room within seconds, so it is not offered.
PATHS = {"orbit": PathSpec("orbit", "orbit", "synthetic", 0),
         "orbit-log": PathSpec("orbit-log", "orbit", "log", 0),
         "turns-log": PathSpec("turns-log", "fast_turns", "log", 1),
         "turns": PathSpec("turns", "fast_turns", "synthetic", 1)}


@dataclass(frozen=True)
class TraceSpec:
    """A bandwidth trace file and its class (``low`` / ``mid`` / ``high``, or ``other``)."""

    name: str
    path: str
    klass: str


def trace_class(name: str) -> str:
    """The Lumos5G class in a trace's name (``lumos-throughput-mid-11`` -> ``mid``), else ``other``."""
    parts = name.lower().replace("_", "-").split("-")
    for c in _CLASSES:
        if c in parts:
            return c
    return "other"


def default_traces() -> list[TraceSpec]:
    """Every trace of the project's shared data (``../shared/data/bandwidth/lumos5g``) when it is
    there, else the traces bundled with the package (the same nine Lumos5G files)."""
    from l3gs_opt.traces.bandwidth import bundled_traces

    shared = Path(__file__).resolve().parents[3] / "shared" / "data" / "bandwidth" / "lumos5g"
    files = sorted(shared.glob("*.txt")) if shared.is_dir() else []
    if not files:
        files = [p for _, p in sorted(bundled_traces().items())]
    return [TraceSpec(p.stem, str(p), trace_class(p.stem)) for p in files]


def _trace_specs(traces: Sequence[str] | str | None, quick: bool) -> list[TraceSpec]:
    from l3gs_opt.traces.bandwidth import bundled_traces

    if traces is None:
        every = default_traces()
        if not quick:
            return every
        # One trace per class: the first of each in name order (mid-11 is the demo's trace).
        wanted = {"low": "lumos-throughput-low-47", "mid": "lumos-throughput-mid-11",
                  "high": "lumos-throughput-high-31"}
        picked = [t for t in every if wanted.get(t.klass) == t.name]
        return picked or every[:3]
    if isinstance(traces, str):
        folder = Path(traces)
        if not folder.is_dir():
            raise ExperimentError("traces", f"{traces!r} is not a folder of trace files")
        files = sorted(folder.glob("*.txt")) + sorted(folder.glob("*.csv"))
        if not files:
            raise ExperimentError("traces", f"{traces}: no .txt or .csv trace in the folder")
        return [TraceSpec(p.stem, str(p), trace_class(p.stem)) for p in files]
    bundled = bundled_traces()
    shared = {t.name: t for t in default_traces()}
    out = []
    for i, name in enumerate(traces):
        if name in shared:
            out.append(shared[name])
        elif name in bundled:
            out.append(TraceSpec(name, str(bundled[name]), trace_class(name)))
        elif Path(name).is_file():
            out.append(TraceSpec(Path(name).stem, str(Path(name)), trace_class(Path(name).stem)))
        else:
            raise ExperimentError("traces", f"{name!r}: no such trace file or bundled trace "
                                            f"(bundled: {', '.join(sorted(bundled))})", i)
    if len({t.name for t in out}) != len(out):
        raise ExperimentError("traces", "a trace is listed twice")
    return out


def scaled_mbps(scene_bytes: int) -> float:
    """The trace mean (Mbit/s) that makes ``scene_bytes`` take the share of a 60 s window the
    paper's 44.64 MB scene takes at 11.8 Mbit/s (~30 s)."""
    return PAPER_MBPS * float(scene_bytes) / PAPER_SCENE_BYTES


def method_variant(method: str, variants: Sequence[str]) -> str | None:
    """The bundle variant ``method`` runs on among ``variants`` (None: none accepts it).

    The paper's pairing first (:data:`_PREFERRED`), else the first variant whose bundle the
    simulator accepts for the method.
    """
    from l3gs_opt.scene.bundle import REPRESENTATION
    from l3gs_opt.simulator.simulation import SimulationError, method_spec

    pref = _PREFERRED.get(method)
    order = ([pref] if pref in variants else []) + [v for v in _VARIANT_ORDER if v in variants and v != pref]
    for v in order:
        try:
            method_spec(method, representation=REPRESENTATION[v], variant=v)
        except SimulationError:
            continue
        return v
    return None


# ---------------------------------------------------------------------------------------- tasks
@dataclass(frozen=True)
class Task:
    """One record: a simulation (``kind="sim"``) or the ceiling of a (variant, window, path)."""

    kind: str
    scene: str
    variant: str
    trace: str
    start_s: int
    path: str
    method: str | None = None
    ablation: str = "none"
    role: str = "ceiling"

    @property
    def record_id(self) -> str:
        what = "ceiling" if self.kind == "ceiling" else f"{self.method}/{self.ablation}"
        return f"{self.scene}/{self.variant}/{self.trace}@{self.start_s}/{self.path}/{what}"

    @property
    def group(self) -> tuple:
        """Records sharing one :class:`~l3gs_opt.simulator.simulation.Simulation` (same bundle, link, viewer, config)."""
        return (self.scene, self.variant, self.trace, self.start_s, self.path, self.ablation)


@dataclass(frozen=True)
class ExperimentPlan:
    """Everything that decides the records (see the module docstring).

    Attributes
    ----------
    scenes : tuple of SceneSpec
    variants : tuple of str
        Bundle variants built per scene (:data:`l3gs_opt.scene.bundle.VARIANTS`).
    traces : tuple of TraceSpec
    starts : tuple of tuple of int
        Window start seconds per trace (random, seeded: :meth:`make_plan`).
    window_s : int
        Slots per window (1 s each).
    paths : tuple of PathSpec
    methods : tuple of (method, variant)
        Experiment 1 (and 3, 4, 6).
    ablations : tuple of str
        Conditions of experiment 2 besides ``none``.
    ablation_methods : tuple of (method, variant)
    variant_methods : tuple of (method, variant)
        Experiment 5 (compared with ``l3gs`` on ``layered``).
    width, height : int
        Rendered image size, pixels.
    samples_per_slot : int
        Viewpoints per slot (predictions, utilities, the ceiling's true utilities).
    ceiling_time_limit_s : float
        Seconds per ceiling solve when the exact DP is too large and ``ilp/highs`` solves it.
    ceiling_check_s : float
        Seconds of an ``ilp/highs`` cross-check of each DP ceiling (0: none).
    schedule : dict
        :class:`l3gs_opt.pipeline.build.BuildSchedule` fields of the bundle builds.
    seed : int
        Seed of the window start points.
    quick : bool
    notes : tuple of str
        Methods left out and why.
    """

    scenes: tuple
    variants: tuple
    traces: tuple
    starts: tuple
    window_s: int
    paths: tuple
    methods: tuple
    ablations: tuple
    ablation_methods: tuple
    variant_methods: tuple
    width: int = 160
    height: int = 120
    samples_per_slot: int = 2
    ceiling_time_limit_s: float = 30.0
    ceiling_check_s: float = 0.0
    schedule: Mapping[str, Any] = field(default_factory=dict)
    seed: int = 0
    quick: bool = False
    notes: tuple = ()

    def windows(self) -> list[tuple[TraceSpec, int]]:
        return [(tr, int(s)) for tr, starts in zip(self.traces, self.starts) for s in starts]

    def tasks(self) -> list[Task]:
        """Every record, in run order: per scene, window and path the ceilings, then the
        simulations grouped by (variant, condition) so one Simulation serves a group."""
        out: list[Task] = []
        for sc in self.scenes:
            for tr, start in self.windows():
                for p in self.paths:
                    sims: list[Task] = []
                    for m, v in self.methods:
                        sims.append(Task("sim", sc.name, v, tr.name, start, p.name, m, "none", "main"))
                    for cond in self.ablations:
                        for m, v in self.ablation_methods:
                            sims.append(Task("sim", sc.name, v, tr.name, start, p.name, m, cond, "ablation"))
                    for m, v in self.variant_methods:
                        sims.append(Task("sim", sc.name, v, tr.name, start, p.name, m, "none", "variant"))
                    variants = [v for v in _VARIANT_ORDER if any(t.variant == v for t in sims)]
                    out += [Task("ceiling", sc.name, v, tr.name, start, p.name) for v in variants]
                    order = {g: i for i, g in enumerate(dict.fromkeys(t.group for t in sims))}
                    out += sorted(sims, key=lambda t: order[t.group])
        ids = [t.record_id for t in out]
        if len(set(ids)) != len(ids):
            raise ExperimentError("methods", "the plan lists a record twice (a method given twice?)")
        return out

    def config(self, ablation: str = "none"):
        from l3gs_opt.simulator.simulation import SimConfig

        return SimConfig(width=self.width, height=self.height, samples_per_slot=self.samples_per_slot,
                         **ABLATIONS[ablation])

    def to_dict(self) -> dict:
        d = dataclasses.asdict(self)
        for scene in d["scenes"]:
            # Written only when set, so plans recorded before the option existed still resume.
            if not scene["room_parts"]:
                del scene["room_parts"]
        d["schema"] = "l3gs-opt/experiments-plan@1"
        return json.loads(json.dumps(d))


def _starts(trace: TraceSpec, count: int, window_s: int, seed: int) -> tuple[int, ...]:
    """``count`` distinct random window starts of ``trace`` (seeded by the plan seed and the name)."""
    from l3gs_opt.traces.bandwidth import read_bandwidth_trace

    n = len(read_bandwidth_trace(trace.path).mbps)
    room = n - window_s + 1
    if room < 1:
        raise ExperimentError("window_s", f"{window_s} s does not fit trace {trace.name} ({n} samples)")
    if count > room:
        raise ExperimentError("starts", f"{count} distinct {window_s} s windows do not fit trace {trace.name}")
    rng = np.random.default_rng([int(seed), zlib.crc32(trace.name.encode())])
    return tuple(sorted(int(s) for s in rng.choice(room, size=count, replace=False)))


def _positive_int(name: str, value: Any, minimum: int = 1) -> int:
    if isinstance(value, bool) or not isinstance(value, (int, np.integer)) or value < minimum:
        raise ExperimentError(name, f"{value!r}: must be an integer >= {minimum}")
    return int(value)


def make_plan(*, quick: bool = False, scenes: Sequence[SceneSpec] | None = None,
              variants: Sequence[str] | None = None, traces: Sequence[str] | str | None = None,
              starts: int | None = None, window_s: int = PAPER_WINDOW_S, paths: Sequence[str] | None = None,
              methods: Sequence[str] | None = None, ablations: Sequence[str] | None = None,
              ablation_methods: Sequence[str] | None = None, width: int | None = None, height: int | None = None,
              samples_per_slot: int = 2, ceiling_time_limit_s: float | None = None,
              ceiling_check_s: float | None = None, schedule=None,
              seed: int = 0) -> ExperimentPlan:
    """The plan of a run; the same arguments always give the same plan (seeded window starts).

    Defaults (``quick``: the README's demo, <= 15 min on 2 cores at low load): one 8k-splat room
    (``quick``) or two 20k-splat rooms; every variant; one trace per class (``quick``) or every
    trace; 1 (``quick``) or 3 random 60 s windows per trace; the orbit (``quick``) or the orbit and
    the logged head turns; the simulator's methods (:data:`~l3gs_opt.simulator.simulation.SIM_METHODS`, each
    on its bundle); ablations of ``l3gs`` (``quick``) or of every method that uses a prediction;
    160x120 (``quick``: 128x96) renders.

    Raises
    ------
    ExperimentError
        An unknown variant, path, method or condition, a method no built variant accepts, a
        trace that is missing or too short, a count out of range (naming the argument and index).
    """
    from l3gs_opt.scene.bundle import VARIANTS
    from l3gs_opt.pipeline.build import QUICK, BuildSchedule
    from l3gs_opt.simulator.simulation import SIM_METHODS

    window_s = _positive_int("window_s", window_s)
    samples_per_slot = _positive_int("samples_per_slot", samples_per_slot)
    seed = _positive_int("seed", seed, 0)
    if scenes is None:
        scenes = ([SceneSpec("room8k", 8000, objects=4, sh_degree=1, seed=0)] if quick else
                  [SceneSpec("room20k-a", 20_000, objects=4, sh_degree=1, seed=0),
                   SceneSpec("room20k-b", 20_000, objects=4, sh_degree=1, seed=1)])
    scenes = tuple(scenes)
    if not scenes or len({s.name for s in scenes}) != len(scenes):
        raise ExperimentError("scenes", "need at least one scene, with distinct names")
    variants = tuple(variants) if variants is not None else tuple(_VARIANT_ORDER)
    for i, v in enumerate(variants):
        if v not in VARIANTS:
            raise ExperimentError("variants", f"{v!r} is not one of {', '.join(VARIANTS)}", i)
    if len(set(variants)) != len(variants) or not variants:
        raise ExperimentError("variants", "need at least one variant, each once")
    trace_specs = tuple(_trace_specs(traces, quick))
    n_starts = _positive_int("starts", starts if starts is not None else (1 if quick else 3))
    start_points = tuple(_starts(t, n_starts, window_s, seed) for t in trace_specs)
    path_names = list(paths) if paths is not None else (["orbit"] if quick else ["orbit", "turns-log"])
    if not path_names:
        raise ExperimentError("paths", "need at least one path")
    path_specs = []
    for i, name in enumerate(path_names):
        if name not in PATHS:
            raise ExperimentError("paths", f"{name!r} is not one of {', '.join(PATHS)}", i)
        path_specs.append(PATHS[name])
    if len(set(path_names)) != len(path_names):
        raise ExperimentError("paths", "a path is listed twice")
    notes: list[str] = []

    def variant_of(m: str, what: str, i: int | None) -> str | None:
        v = method_variant(m, variants)
        if v is None and i is not None:
            raise ExperimentError(what, f"{m!r}: no bundle among {', '.join(variants)} accepts it "
                                        "(or it is not a method; see l3gs-opt simulate --help)", i)
        return v

    # Variant-specific simulator methods (distill, hierarchy, ...) belong to experiment 5.
    special = {v: [m for m in SIM_METHODS if v in m] for v in ("distill", "hierarchy")}
    if methods is None:
        chosen = []
        for m in SIM_METHODS:
            if any(m in ms for ms in special.values()):
                continue
            v = variant_of(m, "methods", None)
            if v is None:
                notes.append(f"method {m}: no bundle among {', '.join(variants)} accepts it; left out")
            else:
                chosen.append((m, v))
    else:
        chosen = [(m, variant_of(m, "methods", i)) for i, m in enumerate(methods)]
    if not chosen:
        raise ExperimentError("methods", "no method to run")
    conds = list(ablations) if ablations is not None else [a for a in ABLATIONS if a != "none"]
    for i, c in enumerate(conds):
        if c not in ABLATIONS or c == "none":
            raise ExperimentError("ablations", f"{c!r} is not one of {', '.join(a for a in ABLATIONS if a != 'none')}",
                                  i)
    if ablation_methods is None:
        if quick:
            abl = [(m, v) for m, v in chosen if m == "l3gs"]
        else:
            abl = [(m, v) for m, v in chosen if m not in _PREDICTION_FREE]
    else:
        abl = [(m, variant_of(m, "ablation_methods", i)) for i, m in enumerate(ablation_methods)]
    if not conds:
        abl = []
    var_methods = []
    for v in ("distill", "hierarchy"):
        if v not in variants:
            continue
        own = special[v]
        m = own[0] if own else ("l3gs" if v == "distill" else "separate")
        if method_variant(m, [v]) is None:
            notes.append(f"experiment 5: {m} does not accept the {v} bundle; left out")
            continue
        var_methods.append((m, v))
        if not own:
            how = ("one stream per layer, compact part and SH upgrade together" if v == "distill"
                   else "versions replace each other, parents not used")
            notes.append(f"experiment 5: the simulator has no {v} method yet; {m} runs on the {v} bundle ({how})")
    if ceiling_time_limit_s is None:
        ceiling_time_limit_s = 20.0 if quick else 60.0
    if not (isinstance(ceiling_time_limit_s, (int, float)) and ceiling_time_limit_s > 0):
        raise ExperimentError("ceiling_time_limit_s", f"{ceiling_time_limit_s!r}: must be a positive number of seconds")
    if ceiling_check_s is None:
        ceiling_check_s = 3.0 if quick else 10.0
    if not (isinstance(ceiling_check_s, (int, float)) and ceiling_check_s >= 0):
        raise ExperimentError("ceiling_check_s", f"{ceiling_check_s!r}: must be a number of seconds >= 0")
    if schedule is None:
        schedule = QUICK
    if isinstance(schedule, BuildSchedule):
        schedule = dataclasses.asdict(schedule)
    w = width if width is not None else (128 if quick else 160)
    h = height if height is not None else (96 if quick else 120)
    plan = ExperimentPlan(scenes=scenes, variants=variants, traces=trace_specs, starts=start_points,
                          window_s=window_s, paths=tuple(path_specs), methods=tuple(chosen),
                          ablations=tuple(conds), ablation_methods=tuple(abl), variant_methods=tuple(var_methods),
                          width=int(w), height=int(h), samples_per_slot=samples_per_slot,
                          ceiling_time_limit_s=float(ceiling_time_limit_s), ceiling_check_s=float(ceiling_check_s),
                          schedule=dict(schedule), seed=seed,
                          quick=bool(quick), notes=tuple(notes))
    plan.config()   # validates width, height
    plan.tasks()    # no duplicate records
    return plan


# ---------------------------------------------------------------------------------------- running
class _Scene:
    """A scene's teacher, bundles and viewer paths, built once and cached under ``cache``."""

    def __init__(self, spec: SceneSpec, plan: ExperimentPlan, cache: Path, log: Callable[[str], None]):
        self.spec, self.plan, self.dir, self.log = spec, plan, cache / spec.name, log
        self.dir.mkdir(parents=True, exist_ok=True)
        self.teacher = self.dir / "teacher.ply"
        self.build_s: dict[str, float] = {}
        self._poses: dict[str, Any] = {}
        self._bundles: dict[str, Any] = {}

    def prepare_teacher(self) -> None:
        from l3gs_opt.scene.splats import write_ply
        from l3gs_opt.scene.procedural import make_scene

        if not self.teacher.exists():
            s = self.spec
            tmp = self.teacher.with_suffix(".tmp.ply")
            write_ply(make_scene(s.splats, objects=s.objects, sh_degree=s.sh_degree, seed=s.seed,
                                 room_parts=s.room_parts), tmp)
            os.replace(tmp, self.teacher)

    def bundle(self, variant: str):
        """The bundle of ``variant`` (built on first use; an interrupted build resumes)."""
        if variant in self._bundles:
            return self._bundles[variant]
        from l3gs_opt.scene.bundle import read_bundle
        from l3gs_opt.scene.camera_paths import orbit_path
        from l3gs_opt.pipeline.build import BuildSchedule, build_bundle

        out = self.dir / variant
        if not (out / "manifest.json").exists():
            self.prepare_teacher()
            t0 = time.perf_counter()
            load = os.getloadavg()[0]
            cams = orbit_path(12, width=160, height=120)
            build_bundle(self.teacher, cams, list(self.spec.sizes), variant, out,
                         schedule=BuildSchedule(**self.plan.schedule), resume=True, show_progress=False)
            self.build_s[variant] = time.perf_counter() - t0
            self.log(f"built {self.spec.name}/{variant} in {self.build_s[variant]:.1f} s (load {load:.2f})")
        self._bundles[variant] = read_bundle(out)
        return self._bundles[variant]

    def scene_bytes(self) -> int:
        """Bytes of the largest layered model: every splat of the top level at full SH."""
        for v in ("layered", "sort", "distill"):
            if v in self.plan.variants:
                return int(sum(c["bytes"] for c in self.bundle(v).manifest["chunks"]))
        b = self.bundle(self.plan.variants[0])
        top = b.num_levels - 1
        return int(sum(c["bytes"] for c in b.manifest["chunks"] if c["level"] == top))

    def poses(self, spec: PathSpec, seconds: int):
        """The path's poses: in memory (synthetic) or through a headset log file (log)."""
        if spec.name not in self._poses:
            from l3gs_opt.traces.poses import read_pose_log, synthetic_poses, write_pose_log

            trace = synthetic_poses(spec.kind, seconds=seconds + 2, rate_hz=30, seed=spec.seed)
            if spec.source == "log":
                path = write_pose_log(trace, self.dir / f"{spec.name}.log")
                trace = read_pose_log(path)
            self._poses[spec.name] = trace
        return self._poses[spec.name]


def _truth(sim, T: int) -> np.ndarray:
    """``[T, J, L]`` true per-unit utilities (object view) of a Simulation run with the oracle viewport."""
    cat = sim.catalog("object")
    J, L = cat.shape
    out = np.zeros((T, J, L))
    for t in range(T):
        u = sim.prediction(t)["splat_utility"]
        out[t] = np.bincount(cat.unit_of_row, weights=u, minlength=J * L).reshape(J, L)
    return np.where(cat.empty[None], 0.0, out)


def _ceiling_instance(sim, truth: np.ndarray, bandwidth: Sequence[int], meta: dict):
    from l3gs_opt.problem.instance import Instance, Options

    cat = sim.catalog("object")
    empty = [[int(j), int(l)] for j, l in zip(*np.nonzero(cat.empty))]
    return Instance(cat.representation, bandwidth=[int(b) for b in bandwidth], cost=cat.cost, utility=truth,
                    options=Options(budget="cumulative"), meta={**meta, "empty_chunks": empty})


def _arrivals(summary: dict, records: list, inst) -> tuple[list[tuple[int, int, int]] | None, str | None]:
    """The method's completed chunks as Problem I/II arrivals ``(j, l, t)`` (object view).

    Views: ``object`` and ``hierarchy`` units are the chunks; a ``scene`` unit (whole-scene layer
    or version ``l``) completes every object's chunk ``l``; a ``distill`` layer counts once both its
    compact part and its SH upgrade completed (its compact splats shown before are not counted).
    Layered: a layer counts from when it and every layer below it are complete; an empty chunk
    (1 byte in the instance, no splats) below a counted layer rides along with the next one above.
    Returns ``(None, reason)`` for a unit kind this mapping does not know.
    """
    view = summary.get("view")
    J, L = inst.J, inst.L
    units = list(summary.get("units") or [])
    expected = {"object": [J, L], "hierarchy": [J, L], "scene": [1, L], "distill": [J, L, 2]}
    if expected.get(view) != units:
        return None, f"units {units} of view {view!r} do not map onto the {J} x {L} chunks"
    empty = np.zeros((J, L), bool)   # chunks without splats (1 byte in the instance)
    for j, l in inst.meta.get("empty_chunks", []):
        empty[j, l] = True
    parts: dict[tuple[int, int], dict] = {}
    for rec in records:
        for label in rec["completed"]:
            j, l = int(label[0]), int(label[1])
            form = int(label[2]) if view == "distill" else 0
            for jj in (range(J) if view == "scene" else (j,)):
                parts.setdefault((jj, l), {}).setdefault(form, int(rec["slot"]))
    need = 2 if view == "distill" else 1
    first = {c: max(f.values()) for c, f in parts.items() if len(f) == need and not empty[c]}
    if inst.layered:
        # A layer counts from when it and every layer below it are complete, and not at all when
        # one below never completes: a feasible Problem I schedule.
        counted = {}
        for j in range(J):
            t_prefix, times = 0, {}
            for l in range(L):
                if not empty[j, l]:
                    t = first.get((j, l))
                    if t is None:
                        break
                    t_prefix = times[l] = max(t_prefix, t)
            # An empty layer (1 byte in the instance) rides with the next counted layer above it.
            for l in range(max(times, default=-1), -1, -1):
                times.setdefault(l, times.get(l + 1))
            counted.update({(j, l): t for l, t in times.items()})
        first = counted
    return [(j, l, t) for (j, l), t in sorted(first.items())], None


def _preload_utility(inst) -> np.ndarray:
    """Per-slot utility of holding the largest model from the start: all layers, or each object's top version."""
    U = inst.utility
    if inst.layered:
        return U.sum(axis=(1, 2))
    return U[:, :, -1].sum(axis=1)


def _per_slot_utility(inst, arrivals) -> np.ndarray:
    """Per-slot utility shown by ``arrivals`` (layered: every held layer; separate: the best held version)."""
    T, J, L = inst.utility.shape
    held_from = np.full((J, L), T, np.int64)
    for j, l, t in arrivals:
        held_from[j, l] = min(held_from[j, l], t)
    held = np.arange(T)[:, None, None] >= held_from[None]
    if inst.layered:
        return (inst.utility * held).sum(axis=(1, 2))
    return np.where(held, inst.utility, 0.0).max(axis=2).sum(axis=1)


def _sim_record(task: Task, result, inst, base: dict, *, preload: bool = False) -> dict:
    from l3gs_opt.problem.evaluate import evaluate_objective, feasibility_violations

    s = result.summary
    recs = result.records
    rec = dict(base)
    rec.update({
        "kind": "sim", "method": task.method, "solver": s.get("solver"), "ablation": task.ablation,
        "role": task.role, "view": s.get("view"), "units": s.get("units"), "representation": s.get("representation"),
        "ssim_mean": s["ssim_mean"], "ssim_per_s": [float(v) for v in s["ssim_per_s"]], "psnr_mean": s.get("psnr_mean"),
        "bytes_delivered": s["bytes_delivered"], "bytes_wasted": s["bytes_wasted"], "bytes_idle": s["bytes_idle"],
        "bytes_trace": s["bytes_trace"], "bytes_model": s["bytes_model"], "splats_final": s["splats_final"],
        "predicted_bytes": [int(r["predicted_bytes"]) for r in recs],
        "trace_bytes": [int(r["bytes_trace"]) for r in recs],
        "timings_mean_s": s["timings_mean_s"], "run_s": s["run_s"],
        # Renders are cached by content (a hit costs ~0 s): the client's own cost is that of the
        # slots that did render, kept as [seconds summed, slots].
        "render_fresh_s": [float(sum(r["timings_s"]["rendering"] for r in recs if not r.get("render_reused"))),
                           int(sum(not r.get("render_reused") for r in recs))],
        "loadavg_start": s["loadavg_start"], "loadavg_end": s["loadavg_end"],
    })
    if preload:
        per = _preload_utility(inst)
        rec.update(utility_per_s=[float(v) for v in per], utility_sum=float(math.fsum(per)), schedule_violations=[],
                   utility_note="holds the largest model from the start (not bandwidth-limited)")
        return rec
    arrivals, why = _arrivals(s, recs, inst)
    if arrivals is None:
        rec.update(utility_per_s=None, utility_sum=None, schedule_violations=[], utility_note=why)
        return rec
    per = _per_slot_utility(inst, arrivals)
    total = evaluate_objective(inst, arrivals)
    note = ("a layer counts once its compact part and its SH upgrade both arrived; compact-only splats are shown "
            "but not counted" if s.get("view") == "distill" else None)
    rec.update(utility_per_s=[float(v) for v in per], utility_sum=float(total),
               schedule_violations=feasibility_violations(inst, arrivals), chunks_completed=len(arrivals),
               utility_note=note)
    return rec


def _ceiling_record(task: Task, inst, base: dict, time_limit_s: float, check_s: float) -> dict:
    """The exact ceiling: ``link-dp`` (proven optimal, :mod:`l3gs_opt.solvers.link_dp`) when its state
    space is small enough, else ``ilp/highs`` within ``time_limit_s`` (a time-limited answer keeps its
    bound). ``check_s > 0``: also run ``ilp/highs`` for that long and check its incumbent <= the DP
    optimum <= its bound."""
    from l3gs_opt.methods import solve
    from l3gs_opt.solvers.link_dp import MAX_STATES, link_dp_states, solve_link_dp

    if link_dp_states(inst) <= MAX_STATES:
        sol = solve_link_dp(inst)
    else:
        # HiGHS 1.14's root-reduced-cost heuristic ran a sub-MIP that ignored the time limit and the
        # interrupt callbacks for > 20 min on a 14-object ceiling (a one-link Problem I, 60 slots);
        # without it the same solve stopped at its 20 s limit.
        sol = solve(inst, "ilp", backend="highs", time_limit_s=time_limit_s,
                    options={"mip_heuristic_run_root_reduced_cost": False})
    rec = dict(base)
    rec.update({
        "kind": "ceiling", "problem": "I" if inst.layered else "II", "method": sol.method, "backend": sol.backend,
        "status": str(sol.status), "objective": float(sol.objective),
        "bound": None if sol.bound is None else float(sol.bound), "gap": sol.gap, "runtime_s": sol.runtime_s,
        "time_limit_s": time_limit_s if sol.method != "link-dp" else None, "budget": "cumulative",
        "shape": [inst.T, inst.J, inst.L], "utility_preload": float(_preload_utility(inst).sum()),
        "bandwidth_total": int(inst.bandwidth.sum()), "bytes_chunks": int(inst.cost.sum()),
        "chunk_bytes_max": int(inst.cost.max()), "slot_bytes_mean": float(inst.bandwidth.mean()),
        "object_bytes_share_max": float(inst.cost.sum(axis=1).max() / inst.cost.sum()),
        "loadavg": list(os.getloadavg()), "check": None,
    })
    if check_s > 0 and sol.method == "link-dp":
        ilp = solve(inst, "ilp", backend="highs", time_limit_s=check_s)
        tol = 1e-6 * max(1.0, abs(sol.objective))
        ok = ilp.objective <= sol.objective + tol and (ilp.bound is None or sol.objective <= ilp.bound + tol)
        rec["check"] = {"method": "ilp/highs", "status": str(ilp.status), "objective": float(ilp.objective),
                        "bound": None if ilp.bound is None else float(ilp.bound), "runtime_s": ilp.runtime_s,
                        "time_limit_s": check_s, "consistent": bool(ok)}
    return rec


def _read_records(records: RecordLog) -> list[dict]:
    try:
        return records.records()
    except L3gsError as exc:
        raise ExperimentError("runs", str(exc)) from None


def run_experiments(plan: ExperimentPlan, out_dir: str | os.PathLike[str], *, resume: bool = False,
                    cache_dir: str | os.PathLike[str] | None = None, progress: bool = True,
                    on_record: Callable[[dict], None] | None = None,
                    log: Callable[[str], None] | None = None) -> Path:
    """Run every record of ``plan`` not yet in ``OUT/runs.jsonl``, appending each as it finishes.

    Parameters
    ----------
    plan : ExperimentPlan
    out_dir : path
        ``runs.jsonl`` (records), ``plan.json`` (the plan), ``sessions.jsonl`` (one line per call:
        wall time, load, bundle build times).
    resume : bool
        Continue an existing ``runs.jsonl`` (it must come from the same plan).
    cache_dir : path, optional
        Teachers, bundles and pose logs (default ``OUT/cache``); reused by later runs.
    progress : bool
        A tqdm bar over the records (stderr).
    on_record : callable(dict), optional
        Called after each record is written (tests interrupt a run with it).
    log : callable(str), optional
        Receives one line per bundle build (default: print).

    Returns
    -------
    Path of ``runs.jsonl``.

    Raises
    ------
    ExperimentError
        ``runs.jsonl`` exists without ``resume``, or comes from a different plan.
    OutputLockedError
        Another run is writing to ``out_dir`` (each run holds ``runs.jsonl.lock`` to its end).
    RecordFileError
        ``out_dir`` is a file.
    """
    out = Path(out_dir)
    # One writer per folder, from reading what is done to the last record (and the session line).
    records = RecordLog(out / RUNS_FILE, what="experiments")
    try:
        return _run_locked(plan, out, records, resume=resume, cache_dir=cache_dir, progress=progress,
                           on_record=on_record, log=log)
    finally:
        records.close()


def _run_locked(plan: ExperimentPlan, out: Path, records: RecordLog, *, resume: bool,
                cache_dir: str | os.PathLike[str] | None, progress: bool,
                on_record: Callable[[dict], None] | None, log: Callable[[str], None] | None) -> Path:
    """:func:`run_experiments` once ``records`` (``OUT/runs.jsonl``, torn last line repaired) is locked."""
    from tqdm import tqdm

    from l3gs_opt.simulator.simulation import Simulation, method_spec, trace_bytes

    runs = records.path
    plan_path = out / "plan.json"
    existing = _read_records(records)
    plan_dict = plan.to_dict()
    if existing and not resume:
        raise ExperimentError("--resume", f"{runs} already holds {len(existing)} records: pass --resume to "
                                          "continue it, or choose another --out")
    for i, rec in enumerate(existing):
        if not isinstance(rec.get("record_id"), str):
            raise ExperimentError("runs", f"{runs}: record {i} has no record_id: not a record of l3gs-opt "
                                          "experiments; choose another --out", i)
    if resume and existing and plan_path.exists():
        try:
            old = json.loads(plan_path.read_text(encoding="utf-8"))
        except (UnicodeDecodeError, json.JSONDecodeError) as exc:
            raise ExperimentError("--resume", f"{plan_path} is not the JSON plan of a run ({exc}); use another "
                                              "--out") from None
        if not isinstance(old, dict):
            raise ExperimentError("--resume", f"{plan_path} is not the JSON plan of a run; use another --out")
        diff = sorted(k for k in set(old) | set(plan_dict) if old.get(k) != plan_dict.get(k))
        if diff:
            raise ExperimentError("--resume", f"{out} was run with a different plan ({', '.join(diff)} differ); "
                                              "use the same options, or another --out")
    plan_path.write_text(dumps(plan_dict, indent=1, where="plan") + "\n")
    done = {r["record_id"] for r in existing}
    tasks = plan.tasks()
    todo = [t for t in tasks if t.record_id not in done]
    say = log or print
    cache = Path(cache_dir) if cache_dir is not None else out / "cache"
    session = {"started": time.strftime("%Y-%m-%d %H:%M:%S"), "loadavg_start": list(os.getloadavg()),
               "records_before": len(existing), "records_planned": len(tasks), "quick": plan.quick}
    t_start = time.perf_counter()
    bar = tqdm(total=len(todo), desc="experiments", unit="record", disable=not progress)
    written = 0
    scenes = {s.name: s for s in plan.scenes}
    paths = {p.name: p for p in plan.paths}
    klass = {t.name: t for t in plan.traces}
    prepared: dict[str, _Scene] = {}
    truths: dict[tuple, tuple] = {}
    sims: dict[tuple, Any] = {}
    try:
        for task in todo:
            sc = prepared.get(task.scene)
            if sc is None:
                sims.clear()   # one scene's bundles and renders at a time
                truths.clear()
                sc = prepared[task.scene] = _Scene(scenes[task.scene], plan, cache, say)
            mbps = scaled_mbps(sc.scene_bytes())
            tr = klass[task.trace]
            bandwidth, info = trace_bytes(tr.path, mbps=mbps, start=task.start_s, slots=plan.window_s)
            poses = sc.poses(paths[task.path], plan.window_s)
            bundle = sc.bundle(task.variant)
            tkey = (task.scene, task.variant, task.path)
            if tkey not in truths:
                # The true utilities depend on the bundle and the viewer only (not on the window).
                oracle = Simulation(bundle, poses, bandwidth, config=plan.config("true_viewport"))
                truths[tkey] = (oracle, _truth(oracle, plan.window_s))
            oracle, truth = truths[tkey]
            base = {"record_id": task.record_id, "scene": task.scene, "variant": task.variant,
                    "trace": task.trace, "trace_class": tr.klass, "start_s": task.start_s,
                    "window_s": plan.window_s, "path": task.path, "path_source": paths[task.path].source,
                    "mbps": mbps, "scale_factor": info["scale_factor"],
                    "trace_mean_mbps_raw": info["trace_mean_mbps_raw"],
                    "window_mean_mbps": info["window_mean_mbps"], "scene_bytes": sc.scene_bytes(),
                    "bandwidth_cv": float(np.std(bandwidth) / max(float(np.mean(bandwidth)), 1e-12)),
                    "width": plan.width, "height": plan.height}
            meta = {"experiment": "ceiling", **{k: base[k] for k in ("scene", "variant", "trace", "start_s",
                                                                     "path", "mbps")}}
            inst = _ceiling_instance(oracle, truth, bandwidth, meta)
            if task.kind == "ceiling":
                record = _ceiling_record(task, inst, base, plan.ceiling_time_limit_s, plan.ceiling_check_s)
            else:
                sim = sims.get(task.group)
                if sim is None:
                    sims.clear()   # groups run one after another: keep one simulation's caches
                    # Reference renders are shared by content across simulations (sim_render's cache).
                    sim = sims[task.group] = Simulation(bundle, poses, bandwidth,
                                                        config=plan.config(task.ablation),
                                                        reference=str(sc.teacher), info=info)
                result = sim.run(task.method)
                spec = method_spec(task.method, representation=bundle.manifest["representation"],
                                   variant=task.variant)
                record = _sim_record(task, result, inst, base, preload=spec.preload)
            records.append(record, where=task.record_id)
            written += 1
            bar.update(1)
            bar.set_postfix_str(f"{task.variant} {task.method or 'ceiling'} {task.ablation}", refresh=False)
            if on_record is not None:
                on_record(record)
    finally:
        bar.close()
        builds = {f"{name}/{v}": s for name, sc in prepared.items() for v, s in sc.build_s.items()}
        session.update(wall_s=time.perf_counter() - t_start, loadavg_end=list(os.getloadavg()),
                       records_written=written, build_s=builds)
        append_record(out / "sessions.jsonl", session)   # covered by the lock on runs.jsonl
    return runs
