"""Benchmark suites: named, seeded instance specifications and the methods each suite compares.

A spec is data (suite, id, generator parameters) so that a worker process, or a Dask worker on
another machine, rebuilds the very same instance from it. Suites:

* ``l3gs``: the paper's scale on the bundled 5G traces (scaled to 11.8 Mbit/s): single slot
  (J up to 10,000 objects, L=4) and T=60 slots;
* ``pisinger``: MCKP classes after Pisinger (uncorrelated, weakly, strongly and inverse strongly
  correlated), as single-slot separate-version instances (choose at most one item per class);
* ``stiff``: utilities over 18 orders of magnitude, costs over 7, ties, zero and huge bandwidth,
  one object, one layer, all held, chunks that never fit, near-equal efficiencies, utilities near
  the 1e300 total limit and subnormal ones, 1-byte chunks beside 10^12- and 2^53-byte budgets;
* ``problems``: Problems I-IV and the GAP form over T slots, exact ILP against the schedulers;
* ``knapsack-sets``: the public 0-1 knapsack files with known optima (Pisinger's large-scale classes,
  Jooken et al.'s hard set) from :data:`KNAPSACK_DIR_ENV` or ``../shared/data/reference/knapsack``
  beside the repository; each spec carries the published optimum (``params["optimum"]``) into its
  records. Without the folder the suite is empty and says so in one line on stderr.
"""

from __future__ import annotations

import functools
import math
import os
import sys
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any, Callable

import numpy as np

from l3gs_opt.errors import SolveError
from l3gs_opt.problem.arguments import check_slot
from l3gs_opt.problem.instance import MAX_UTILITY_TOTAL, Instance
from l3gs_opt.pipeline.synth import synth_instance
from l3gs_opt.traces.bandwidth import bundled_traces, mbps_to_bytes, read_bandwidth_trace

__all__ = ["InstanceSpec", "SUITES", "ALL_SUITES", "suite_specs", "paper_spec", "default_methods", "split_method",
           "knapsack_dir", "KNAPSACK_DIR_ENV", "MAX_SEEDS"]

#: The whole L3GS-like slot budget: one second at the paper's 11.8 Mbit/s.
SLOT_BYTES = int(mbps_to_bytes(np.array([11.8]))[0])


@dataclass(frozen=True)
class InstanceSpec:
    """A reproducible instance: ``build()`` always returns the same one.

    ``kind`` names the generator, ``params`` its keyword arguments (JSON-serialisable);
    ``single_slot`` says the methods compared are the single-slot ones.
    """

    suite: str
    instance_id: str
    kind: str
    params: dict[str, Any] = field(default_factory=dict)
    single_slot: bool = False

    def build(self) -> Instance:
        return _GENERATORS[self.kind](**self.params)

    def to_dict(self) -> dict[str, Any]:
        return {"suite": self.suite, "instance_id": self.instance_id, "kind": self.kind, "params": self.params,
                "single_slot": self.single_slot}

    @classmethod
    def from_dict(cls, data: dict[str, Any]) -> "InstanceSpec":
        return cls(**data)


# -- generators -------------------------------------------------------------------------------------

def _l3gs_slot(*, objects: int, layers: int = 4, seed: int = 0, trace: str = "lumos-throughput-mid-11",
               slot_index: int = 0) -> Instance:
    """One slot of an L3GS-like scene: the budget is one second at 11.8 Mbit/s (1,475,000 bytes)."""
    inst = synth_instance(objects=objects, layers=layers, slots=slot_index + 1, seed=seed, trace=trace)
    return inst.replace(bandwidth=[SLOT_BYTES], utility=inst.utility[slot_index:slot_index + 1],
                        meta={**dict(inst.meta), "budget_bytes": SLOT_BYTES, "slot_index": slot_index})


def _pisinger(*, kind: str, objects: int, items: int, seed: int = 0, R: int = 1000) -> Instance:
    """Pisinger-style MCKP class: J classes of ``items`` items (weight w, profit p), budget half the
    sum over classes of (min + max weight) / 2; at most one item per class (separate versions)."""
    rng = np.random.default_rng(seed)
    w = rng.integers(1, R + 1, size=(objects, items))
    if kind == "uncorrelated":
        p = rng.integers(1, R + 1, size=(objects, items)).astype(float)
    elif kind == "weakly":
        p = np.maximum(1, w + rng.integers(-10, 11, size=w.shape)).astype(float)
    elif kind == "strongly":
        p = (w + 10).astype(float)
    elif kind == "inverse_strongly":
        p = rng.integers(1, R + 1, size=(objects, items)).astype(float)
        w = (p + 10).astype(np.int64)
    else:
        raise SolveError(f"pisinger class {kind!r} is not one of uncorrelated, weakly, strongly, inverse_strongly")
    budget = int(0.5 * float((w.min(axis=1) + w.max(axis=1)).sum()) / 2)
    return Instance("separate", bandwidth=[budget], cost=w, utility=p[None], meta={"pisinger": kind, "R": R,
                                                                                  "seed": seed})


def _stiff(*, case: str, seed: int = 0, slots: int = 1) -> Instance:
    """Named extreme instances (single slot when ``slots == 1``)."""
    rng = np.random.default_rng(seed)
    T, J, L = slots, 8, 3

    def log_uniform(lo: float, hi: float, size: Any) -> np.ndarray:
        return np.exp(rng.uniform(math.log(lo), math.log(hi), size=size))

    cost = rng.integers(10_000, 400_000, size=(J, L))
    utility = rng.random((T, J, L))
    bandwidth = np.full(T, int(cost.sum() / max(T, 1) * 0.35))
    held = None
    if case == "utility_18_orders":
        utility = log_uniform(1e-9, 1e9, (T, J, L))
    elif case == "cost_7_orders":
        cost = np.round(log_uniform(1e2, 1e9, (J, L))).astype(np.int64)
        bandwidth = np.full(T, int(np.median(cost) * 3))
    elif case == "ties":
        cost = np.full((J, L), 100_000)
        utility = np.ones((T, J, L))
        bandwidth = np.full(T, 350_000)
    elif case == "zero_bandwidth":
        bandwidth = np.zeros(T, dtype=np.int64)
    elif case == "huge_bandwidth":
        bandwidth = np.full(T, int(cost.sum()) * 1000)
    elif case == "one_object":
        cost, utility = cost[:1], utility[:, :1]
        bandwidth = np.full(T, int(cost.sum() * 0.5))
    elif case == "one_layer":
        cost, utility = cost[:, :1], utility[:, :, :1]
        bandwidth = np.full(T, int(cost.sum() * 0.4))
    elif case == "all_held":
        held = np.ones((J, L), dtype=bool)
    elif case == "never_fit":
        cost[:, 1] = int(bandwidth.max()) + 1
    elif case == "utility_near_limit":
        # All utilities together 0.9 x MAX_UTILITY_TOTAL: objectives near 1e300 must not overflow.
        utility = utility / utility.sum() * 0.9 * MAX_UTILITY_TOTAL
    elif case == "utility_subnormal":
        # Subnormal utilities (multiples of 5e-324 up to ~1e-308): scaling them up must be exact.
        utility = np.where(utility < 0.5, rng.integers(1, 1000, size=utility.shape) * 5e-324, utility * 1e-308)
    elif case in ("bytes_1e12", "bytes_2_53"):
        # One-byte chunks beside chunks a few bytes short of the budget: float tolerances of
        # 1e-9 relative would let the one-byte chunks ride along for free.
        big = 10**12 if case == "bytes_1e12" else 2**53
        cost = np.where(rng.random((J, L)) < 0.5, rng.integers(1, 4, size=(J, L)), big - rng.integers(0, 5, size=(J, L)))
        bandwidth = np.full(T, big)
    elif case == "near_equal_efficiency":
        utility = np.broadcast_to(cost * (1 + 1e-12 * rng.random((J, L))), (T, J, L)).copy()
    else:
        raise SolveError(f"stiff case {case!r} is unknown (known: {', '.join(STIFF_CASES)})")
    return Instance("layered", bandwidth=bandwidth, cost=cost, utility=utility, held=held,
                    meta={"stiff_case": case, "seed": seed})


def _problem(*, representation: str, objects: int, slots: int, layers: int = 4, seed: int = 0,
             trace: str = "lumos-throughput-mid-11", start: int = 0) -> Instance:
    return synth_instance(objects=objects, layers=layers, slots=slots, seed=seed, trace=trace, start=start,
                          representation=representation)


def _file(*, path: str, slot: int | None = None) -> Instance:
    """An instance file; with ``slot``, just that slot (its bandwidth and utilities, same ``held``)."""
    from l3gs_opt.problem.instance_io import load_instance

    inst = load_instance(path)
    if slot is None:
        return inst
    slot = check_slot(slot, inst.T)
    return inst.replace(bandwidth=inst.bandwidth[slot:slot + 1], utility=inst.utility[slot:slot + 1])


def _knapsack(*, path: str, set: str | None = None, optimum: int | None = None) -> Instance:
    """A Pisinger or Jooken 0-1 knapsack file as a single-slot instance (``set`` and ``optimum``
    ride along in the spec for the report; the file is the instance)."""
    from l3gs_opt.problem.knapsack_sets import load_knapsack

    return load_knapsack(path).instance


_GENERATORS: dict[str, Callable[..., Instance]] = {"l3gs_slot": _l3gs_slot, "pisinger": _pisinger,
                                                   "stiff": _stiff, "problem": _problem, "file": _file,
                                                   "knapsack": _knapsack}
STIFF_CASES = ("utility_18_orders", "cost_7_orders", "ties", "zero_bandwidth", "huge_bandwidth", "one_object",
               "one_layer", "all_held", "never_fit", "near_equal_efficiency", "utility_near_limit",
               "utility_subnormal", "bytes_1e12", "bytes_2_53")
PISINGER_CLASSES = ("uncorrelated", "weakly", "strongly", "inverse_strongly")


# -- suites -------------------------------------------------------------------------------------------

#: Environment variable naming the folder of the ``knapsack-sets`` suite (subfolders ``pisinger/``
#: with ``*.txt`` + ``*.opt`` and ``jooken/`` with ``*.in`` + ``optima.csv``).
KNAPSACK_DIR_ENV = "L3GS_KNAPSACK_DIR"

#: The sets of the ``knapsack-sets`` suite: subfolder and file pattern.
KNAPSACK_SETS = (("pisinger", "*.txt"), ("jooken", "*.in"))

#: ``--quick``: this many files per set, the smallest first (the full suite is 141 files).
_KNAPSACK_QUICK = 3


def knapsack_dir() -> Path:
    """The ``knapsack-sets`` folder: ``$L3GS_KNAPSACK_DIR``, else ``../shared/data/reference/knapsack``
    beside the repository."""
    env = os.environ.get(KNAPSACK_DIR_ENV)
    if env:
        return Path(env)
    return Path(__file__).resolve().parents[3] / "shared" / "data" / "reference" / "knapsack"


def _knapsack_specs(suite: str, quick: bool) -> list[InstanceSpec]:
    from l3gs_opt.problem.knapsack_sets import load_knapsack

    root = knapsack_dir()
    if not root.is_dir():
        # CI has no ../shared: an empty suite with one line, never a traceback.
        print(f"suite {suite}: folder {root} is absent (set {KNAPSACK_DIR_ENV}): no instances", file=sys.stderr)
        return []
    specs: list[InstanceSpec] = []
    for name, pattern in KNAPSACK_SETS:
        files = sorted((root / name).glob(pattern))
        if quick:
            # Smallest first: the item count leads both formats' files.
            files = sorted(files, key=lambda f: (f.stat().st_size, f.name))[:_KNAPSACK_QUICK]
        for f in files:
            optimum = load_knapsack(f).optimum
            specs.append(InstanceSpec(suite, f"{name}/{f.stem}", "knapsack",
                                      {"path": str(f.resolve()), "set": name, "optimum": optimum}, True))
    return specs


def _traces() -> list[str]:
    return sorted(bundled_traces())


@functools.lru_cache(maxsize=None)
def _trace_samples(trace: str) -> int:
    return len(read_bandwidth_trace(trace).mbps)


def _window_start(trace: str, offset: int, slots: int) -> int:
    """``offset`` (seconds into ``trace``) wrapped so that the window of ``slots`` samples fits:
    every seed gets an instance, and a seed whose window fits as it is keeps it."""
    return offset % max(_trace_samples(trace) - slots + 1, 1)


#: Seeds per size a bench run may ask for: a paper-scale record takes up to its time limit (60 s) per
#: method, so 1000 seeds of one size and method are most of a day already.
MAX_SEEDS = 1000


def suite_specs(suite: str, *, sizes: list[int] | None = None, seeds: int = 3, quick: bool = False) -> list[InstanceSpec]:
    """The instance specs of a suite. ``sizes`` are object counts J; ``quick`` keeps a small subset."""
    traces = _traces()
    specs: list[InstanceSpec] = []
    if suite == "l3gs":
        single = sizes or ([100, 1000] if quick else [100, 1000, 10_000])
        multi = [j for j in (sizes or ([10, 20] if quick else [20, 200])) if j <= 1000]
        for J in single:
            for s in range(seeds):
                specs.append(InstanceSpec(suite, f"slot-J{J}-s{s}", "l3gs_slot",
                                          {"objects": J, "seed": s, "trace": traces[s % len(traces)]}, True))
        T = 20 if quick else 60
        for J in multi:
            for s in range(seeds):
                trace = traces[s % len(traces)]
                specs.append(InstanceSpec(suite, f"T60-J{J}-s{s}", "problem",
                                          {"representation": "layered", "objects": J, "slots": T, "seed": s,
                                           "trace": trace, "start": _window_start(trace, 60 * s, T)}))
    elif suite == "pisinger":
        Js = sizes or ([100, 1000] if quick else [100, 1000, 10_000])
        Ls = [5] if quick else [5, 10]
        for kind in PISINGER_CLASSES:
            for J in Js:
                for L in Ls:
                    for s in range(seeds):
                        specs.append(InstanceSpec(suite, f"{kind}-J{J}-L{L}-s{s}", "pisinger",
                                                  {"kind": kind, "objects": J, "items": L, "seed": s}, True))
    elif suite == "stiff":
        for case in STIFF_CASES:
            for slots in (1, 5):
                specs.append(InstanceSpec(suite, f"{case}-T{slots}", "stiff", {"case": case, "slots": slots},
                                          slots == 1))
    elif suite == "problems":
        Js = sizes or ([6, 12] if quick else [10, 20])
        T = 12 if quick else 30
        for rep in ("layered", "separate"):
            for J in [1, *Js]:
                for s in range(1 if quick else seeds):
                    trace = traces[s % len(traces)]
                    specs.append(InstanceSpec(suite, f"{rep}-J{J}-T{T}-s{s}", "problem",
                                              {"representation": rep, "objects": J, "slots": T, "seed": s,
                                               "trace": trace, "start": _window_start(trace, 120 * s, T)}))
    elif suite == "knapsack-sets":
        specs = _knapsack_specs(suite, quick)
    else:
        raise SolveError(f"suite {suite!r} is not one of {', '.join(SUITES)}")
    return specs


SUITES = ("l3gs", "pisinger", "stiff", "problems", "knapsack-sets")
#: What ``--suite all`` and the demo run: the built-in suites. ``knapsack-sets`` reads files from
#: outside the project (141 of them, minutes to hours with the ILPs) and runs only when named.
ALL_SUITES = ("l3gs", "pisinger", "stiff", "problems")

_SINGLE_SLOT_METHODS = ["ilp/highs", "ilp/cbc", "ilp/cpsat", "ilp/scip", "lp/highs", "bb", "dp", "greedy",
                        "fptas:0.1", "fptas:0.01", "brute"]
#: The knapsack-sets suite: the exact single-slot solver against three generic MILPs.
_KNAPSACK_METHODS = ["bb", "ilp/highs", "ilp/cbc", "ilp/cpsat"]
_MULTI_SLOT_METHODS = ["ilp/highs", "ilp/highs/gap", "ilp/cpsat", "lp/highs", "rolling:bb", "rolling-future:bb",
                       "mpc:3", "mpc:6", "progressive", "slope", "static", "brute"]


def paper_spec(J: int, seed: int) -> InstanceSpec:
    """The ``l3gs`` suite's multi-slot spec ``T60-J{J}-s{seed}`` (the benchmarks' paper-scale instance,
    per-slot budget; the same whatever ``seeds`` the suite is asked for)."""
    return next(s for s in suite_specs("l3gs", sizes=[J], seeds=seed + 1)
                if not s.single_slot and s.params.get("seed") == seed)


def split_method(label: str) -> tuple[str, dict[str, Any]]:
    """``"ilp/cpsat/gap"`` -> (``"ilp"``, ``{"backend": "cpsat", "form": "gap"}``)."""
    parts = label.split("/")
    kwargs: dict[str, Any] = {}
    for part in parts[1:]:
        if part in ("standard", "gap"):
            kwargs["form"] = part
        else:
            kwargs["backend"] = part
    return parts[0], kwargs


def check_label(label: str) -> None:
    """Refuse a method label ``NAME[/BACKEND][/FORM]`` a user gave, saying why.

    Raises
    ------
    SolveError
        An empty part, an unknown or malformed method (with the method's own reason, e.g.
        ``EPS = 0.0 ...``), an unknown backend, two backends or two forms, or a backend or form given
        to a method that does not use it (it would be dropped in silence).
    """
    from l3gs_opt.methods import resolve_method
    from l3gs_opt.models.backends import Backend
    from l3gs_opt.solvers.registry import entry

    parts = label.split("/")
    if "" in parts:
        raise SolveError(f"method {label!r}: an empty part (expected NAME[/BACKEND][/FORM], e.g. ilp/highs/gap)")
    name, kwargs = split_method(label)
    resolve_method(name)
    if len(kwargs) != len(parts) - 1:
        raise SolveError(f"method {label!r}: gives a backend or a form twice")
    if "backend" in kwargs:
        Backend.parse(kwargs["backend"])
    uses = entry(name).uses
    for option, value in kwargs.items():
        if option not in uses:
            raise SolveError(f"method {label!r}: {name} does not use a {option} ({value!r})")


def available(label: str) -> bool:
    """Whether ``solve`` knows the method of a label (solvers may not provide every method)."""
    from l3gs_opt.methods import resolve_method

    name, _ = split_method(label)
    try:
        resolve_method(name)
    except SolveError:
        return False
    return True


def default_methods(spec: InstanceSpec, *, quick: bool = False) -> list[str]:
    """The methods a suite compares on a spec, limited to what is installed and sensible at its size."""
    params = spec.params
    if spec.kind == "knapsack":
        return [m for m in _KNAPSACK_METHODS if available(m)]
    J = params.get("objects", 8)
    T = params.get("slots", 1)
    chunks = J * params.get("items", params.get("layers", 4))
    if spec.single_slot:
        methods = list(_SINGLE_SLOT_METHODS)
        if chunks > 12:
            methods.remove("brute")
        if quick and J > 200:
            methods = [m for m in methods if m not in ("ilp/cbc", "ilp/scip", "fptas:0.01")]
        if chunks > 20_000:
            # One generic MILP is reference enough at this size (the solvers benchmark races all four).
            methods = [m for m in methods if m not in ("ilp/cbc", "ilp/scip", "ilp/cpsat")]
    else:
        # "exact": branch-and-price on the GAP form (layered, per-slot budgets only).
        methods = [*_MULTI_SLOT_METHODS[:4], "exact", *_MULTI_SLOT_METHODS[4:]]
        if chunks * T > 10:
            methods.remove("brute")
        if params.get("representation") == "separate":
            methods = [m for m in methods if not m.endswith("/gap") and m != "exact"]
        if quick:
            methods = [m for m in methods if m not in ("ilp/cpsat", "mpc:6")]
    return [m for m in methods if available(m)]
