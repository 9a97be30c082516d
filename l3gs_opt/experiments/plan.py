"""The plan of the experiments (``l3gs-opt experiments``): scenes and bundle variants, traces and
windows, viewer paths, methods and ablations, and the fixed list of records they make.

:func:`make_plan` checks every choice and returns an :class:`ExperimentPlan`; its
:meth:`~ExperimentPlan.tasks` are what :func:`l3gs_opt.experiments.run.run_experiments` runs, one
record each. The constants here are the paper's set-up (scene bytes, mean bandwidth, window) and
the ablation conditions; :mod:`l3gs_opt.experiments.run` says what each experiment measures.
"""

from __future__ import annotations

import dataclasses
import json
import math
import zlib
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any, Mapping, Sequence

import numpy as np

from l3gs_opt.errors import L3gsError
from l3gs_opt.pipeline.utilities import DEFAULT_UTILITY
from l3gs_opt.pipeline.counts import check_count
from l3gs_opt.scene.cameras import MAX_IMAGE_PIXELS, MAX_IMAGE_SIDE

__all__ = ["ExperimentError", "SceneSpec", "PathSpec", "TraceSpec", "Task", "ExperimentPlan", "make_plan",
           "default_traces", "trace_class", "scaled_mbps", "method_variant", "ABLATIONS",
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
def truth_utility(utility: str) -> str:
    """The utility a ceiling of ``utility``'s runs is the optimum of: itself when held-free; else
    ``visibility`` (a fixed per-chunk value is what Problem I needs)."""
    from l3gs_opt.pipeline.utilities import get_utility

    return "visibility" if get_utility(utility).held_aware else utility


#: Methods that never look at a prediction: their ablation runs would repeat the plain one.
_PREDICTION_FREE = ("sort", "preload")
#: Methods the plan runs with the slot's last chunk counted by its first splats. ``l3gs-noseg``
#: can too (``simulate --last-chunk``), but its one object's layers go in order whatever the
#: MCKP counts: its prefix records equalled its whole-chunk ones in every quick run (6 of 6,
#: 2026-12-03), so the plan does not spend renders on them.
PREFIX_METHODS = ("l3gs",)
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
    #: The splat utility the method schedules by (a ceiling's: the utility it is the optimum of).
    utility: str = DEFAULT_UTILITY
    #: What the per-slot MCKP of ``l3gs`` / ``l3gs-noseg`` counts of the slot's last chunk
    #: (``SimConfig.last_chunk``); ``whole`` for every other method and for ceilings.
    last_chunk: str = "whole"

    @property
    def record_id(self) -> str:
        what = "ceiling" if self.kind == "ceiling" else f"{self.method}/{self.ablation}"
        # eq1 records keep the ids they had before utilities were named (their runs still resume)
        tag = ("" if self.utility == DEFAULT_UTILITY else f"[{self.utility}]") + self._chunk_tag
        return f"{self.scene}/{self.variant}/{self.trace}@{self.start_s}/{self.path}/{what}{tag}"

    @property
    def label(self) -> str:
        """The method as reports show it: ``l3gs``, ``l3gs[visibility]`` for another utility,
        ``l3gs[visibility]+prefix`` when the slot's last chunk counts by its first splats."""
        return (self.method if self.utility == DEFAULT_UTILITY else f"{self.method}[{self.utility}]") + self._chunk_tag

    @property
    def _chunk_tag(self) -> str:
        # (whole-chunk records keep the ids they had before the option existed)
        return "" if self.last_chunk == "whole" else f"+{self.last_chunk}"

    @property
    def group(self) -> tuple:
        """Records sharing one :class:`~l3gs_opt.simulator.simulation.Simulation` (same bundle, link, viewer, config)."""
        return (self.scene, self.variant, self.trace, self.start_s, self.path, self.ablation, self.last_chunk)


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
        Seconds per ceiling solve when the exact DP is too large and ``exact`` solves it.
    ceiling_check_s : float
        Seconds of an ``ilp/highs`` cross-check of each DP ceiling (0: none).
    schedule : dict
        :class:`l3gs_opt.pipeline.build.BuildSchedule` fields of the bundle builds.
    seed : int
        Seed of the window start points.
    quick : bool
    notes : tuple of str
        Methods left out and why.
    utilities : tuple of str
        Splat utilities (:mod:`l3gs_opt.pipeline.utilities`): every method that schedules by a
        utility runs once per utility; the others (``sort``, ``preload``) once. Each utility's
        records are compared with the ceiling of its own values (a held-aware utility's: those of
        ``visibility``, its held-free base), so utilities are never summed together.
    last_chunks : tuple of str
        What ``l3gs`` counts of each slot's last chunk
        (:data:`~l3gs_opt.simulator.last_chunk.LAST_CHUNKS`): it runs once per value in
        experiment 1 (``prefix`` only with a utility that values splats, not whole chunks, and not
        on ``distill``); every other method, the ablations and the ceilings count whole chunks.
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
    utilities: tuple = (DEFAULT_UTILITY,)
    last_chunks: tuple = ("whole",)

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
                    for role, pairs, conds in (("main", self.methods, ("none",)),
                                               ("ablation", self.ablation_methods, self.ablations),
                                               ("variant", self.variant_methods, ("none",))):
                        for cond in conds:
                            for m, v in pairs:
                                for u in self.method_utilities(m, v):
                                    # (the ablations are about predictions: whole chunks only)
                                    chunks = self.method_last_chunks(m, v, u) if role == "main" else ("whole",)
                                    for lc in chunks:
                                        sims.append(Task("sim", sc.name, v, tr.name, start, p.name, m, cond, role,
                                                         u, lc))
                    variants = [v for v in _VARIANT_ORDER if any(t.variant == v for t in sims)]
                    truths = list(dict.fromkeys(truth_utility(t.utility) for t in sims))
                    out += [Task("ceiling", sc.name, v, tr.name, start, p.name, utility=u)
                            for v in variants for u in truths]
                    order = {g: i for i, g in enumerate(dict.fromkeys(t.group for t in sims))}
                    out += sorted(sims, key=lambda t: order[t.group])
        ids = [t.record_id for t in out]
        if len(set(ids)) != len(ids):
            raise ExperimentError("methods", "the plan lists a record twice (a method given twice?)")
        return out

    def method_utilities(self, method: str, variant: str) -> tuple:
        """The utilities ``method`` runs with on ``variant``: all of the plan's when it schedules by a
        utility, else the default only."""
        from l3gs_opt.scene.bundle import REPRESENTATION
        from l3gs_opt.simulator.simulation import method_spec

        spec = method_spec(method, representation=REPRESENTATION[variant], variant=variant)
        return self.utilities if spec.order == "utility" else (DEFAULT_UTILITY,)

    def method_last_chunks(self, method: str, variant: str, utility: str) -> tuple:
        """What ``method`` counts of the slot's last chunk on ``variant`` with ``utility``: the plan's
        values for :data:`PREFIX_METHODS` (``prefix`` where it can run: per-splat values, no
        ``distill`` forms), else ``whole``."""
        if method not in PREFIX_METHODS:
            return ("whole",)
        return tuple(lc for lc in self.last_chunks if lc == "whole" or _splat_valued(utility, variant)) or ("whole",)

    def config(self, ablation: str = "none", last_chunk: str = "whole"):
        from l3gs_opt.simulator.simulation import SimConfig

        return SimConfig(width=self.width, height=self.height, samples_per_slot=self.samples_per_slot,
                         last_chunk=last_chunk, **ABLATIONS[ablation])

    def to_dict(self) -> dict:
        d = dataclasses.asdict(self)
        if tuple(d["utilities"]) == (DEFAULT_UTILITY,):
            del d["utilities"]   # plans recorded before utilities had names still resume
        if tuple(d["last_chunks"]) == ("whole",):
            del d["last_chunks"]   # (likewise)
        for scene in d["scenes"]:
            # Written only when set, so plans recorded before the option existed still resume.
            if not scene["room_parts"]:
                del scene["room_parts"]
        d["schema"] = "l3gs-opt/experiments-plan@1"
        return json.loads(json.dumps(d))


def _splat_valued(utility: str, variant: str) -> bool:
    """Whether ``prefix`` can count a chunk's first splats: ``utility`` values splats (not whole
    chunks) and the bundle's units have one form (``distill`` splits each splat in two)."""
    from l3gs_opt.pipeline.utilities import SplatUtility, get_utility

    return variant != "distill" and type(get_utility(utility)).chunk_values is SplatUtility.chunk_values


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
              seed: int = 0, utilities: Sequence[str] | None = None,
              last_chunks: Sequence[str] | None = None) -> ExperimentPlan:
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
    # Finite: the help documents no "inf = no limit", and one unbounded check could run for hours.
    if not (isinstance(ceiling_check_s, (int, float)) and math.isfinite(ceiling_check_s) and ceiling_check_s >= 0):
        raise ExperimentError("ceiling_check_s", f"{ceiling_check_s!r}: must be a finite number of seconds >= 0")
    if schedule is None:
        schedule = QUICK
    if isinstance(schedule, BuildSchedule):
        schedule = dataclasses.asdict(schedule)
    w = width if width is not None else (128 if quick else 160)
    h = height if height is not None else (96 if quick else 120)
    # The cameras' limits, checked here: the cameras are made only after the bundles are built.
    # >= 11: SSIM's window, as SimConfig and the fidelity check require.
    w = check_count("width", w, low=11, high=MAX_IMAGE_SIDE, error=ExperimentError)
    h = check_count("height", h, low=11, high=MAX_IMAGE_SIDE, error=ExperimentError)
    if w * h > MAX_IMAGE_PIXELS:
        raise ExperimentError("width", f"{w} x {h} = {w * h:,} pixels, more than {MAX_IMAGE_PIXELS:,} "
                                       "(MAX_IMAGE_PIXELS)")
    chosen_utilities = tuple(utilities) if utilities is not None else (DEFAULT_UTILITY,)
    if not chosen_utilities or len(set(chosen_utilities)) != len(chosen_utilities):
        raise ExperimentError("utilities", "need at least one utility, each once")
    from l3gs_opt.pipeline.utilities import UtilityNameError, get_utility

    for i, u in enumerate(chosen_utilities):
        try:
            get_utility(u)
        except UtilityNameError as exc:
            raise ExperimentError("utilities", str(exc), i) from None
    from l3gs_opt.simulator.last_chunk import LAST_CHUNKS

    chosen_chunks = tuple(last_chunks) if last_chunks is not None else ("whole",)
    if not chosen_chunks or len(set(chosen_chunks)) != len(chosen_chunks):
        raise ExperimentError("last_chunks", "need at least one value, each once")
    for i, lc in enumerate(chosen_chunks):
        if lc not in LAST_CHUNKS:
            raise ExperimentError("last_chunks", f"{lc!r} is not one of {', '.join(LAST_CHUNKS)}", i)
    if any(lc != "whole" for lc in chosen_chunks):
        runs = [(m, v) for m, v in chosen if m in PREFIX_METHODS]
        if not runs:
            raise ExperimentError("last_chunks", f"{', '.join(c for c in chosen_chunks if c != 'whole')} applies "
                                                 f"to {' and '.join(PREFIX_METHODS)} only, which does not run")
        for u in chosen_utilities:
            if not _splat_valued(u, "layered"):
                notes.append(f"last chunk: utility {u} values whole chunks; its runs count whole chunks only")
    plan = ExperimentPlan(scenes=scenes, variants=variants, traces=trace_specs, starts=start_points,
                          window_s=window_s, paths=tuple(path_specs), methods=tuple(chosen),
                          ablations=tuple(conds), ablation_methods=tuple(abl), variant_methods=tuple(var_methods),
                          width=int(w), height=int(h), samples_per_slot=samples_per_slot,
                          ceiling_time_limit_s=float(ceiling_time_limit_s), ceiling_check_s=float(ceiling_check_s),
                          schedule=dict(schedule), seed=seed,
                          quick=bool(quick), notes=tuple(notes), utilities=chosen_utilities,
                          last_chunks=chosen_chunks)
    plan.config()   # validates width, height
    plan.tasks()    # no duplicate records
    return plan
