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
   cross-checked against ``ilp/highs``), or by ``exact`` within a time limit when the DP's state
   space is too large (a time-limited answer is labelled and carries its bound; before ``exact``
   took the cumulative budget this was ``ilp/highs``, 1-100% gaps at 14 objects in 20 s).

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

import functools
import json
import math
import os
import time
from pathlib import Path
from typing import Any, Callable, Sequence

import numpy as np

from l3gs_opt.errors import L3gsError
from l3gs_opt.executors import run_tasks
from l3gs_opt.solvers.exact.warm import warm_up
from l3gs_opt.jsonout import dumps
from l3gs_opt.records import RecordLog, append_record

__all__ = ["run_experiments"]
from l3gs_opt.experiments.plan import (RUNS_FILE, ExperimentError, ExperimentPlan, PathSpec, SceneSpec, Task, scaled_mbps,
                                       truth_utility)


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
                path = self.dir / f"{spec.name}.log"
                if not path.exists():   # written whole or not at all: parallel workers read it
                    tmp = write_pose_log(trace, path.with_suffix(f".{os.getpid()}.tmp"))
                    os.replace(tmp, path)
                trace = read_pose_log(path)
            self._poses[spec.name] = trace
        return self._poses[spec.name]


def _truth(sim, T: int, utility: str) -> np.ndarray:
    """``[T, J, L]`` true per-unit values of ``utility`` (object view) of a Simulation run with the
    oracle viewport."""
    cat = sim.catalog("object")
    J, L = cat.shape
    out = np.zeros((T, J, L))
    for t in range(T):
        u = sim.splat_values(t, utility)
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
        "kind": "sim", "method": task.label, "method_name": task.method, "utility": task.utility,
        "last_chunk": task.last_chunk,
        "solver": s.get("solver"), "ablation": task.ablation,
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


def _ceiling_solve(inst, time_limit_s: float, method: str = "exact"):
    from l3gs_opt.methods import solve

    if method == "exact":
        return solve(inst, "exact", time_limit_s=time_limit_s)
    # HiGHS 1.14's root-reduced-cost heuristic ran a sub-MIP that ignored the time limit and the
    # interrupt callbacks for > 20 min on a 14-object ceiling (a one-link Problem I, 60 slots);
    # without it the same solve stopped at its 20 s limit.
    return solve(inst, "ilp", backend="highs", time_limit_s=time_limit_s,
                 options={"mip_heuristic_run_root_reduced_cost": False})


#: A ceiling's solve is killed this long past its time limit (seconds): on a 180k-splat room of
#: 14 objects ``ilp/highs`` ran > 30 min past a 20 s limit (HiGHS 1.14, with the other heuristic
#: off). ``exact`` runs HiGHS too (on the model its fixing leaves), so it keeps the guard.
CEILING_KILL_AFTER_S = 60.0


def _guarded_ceiling(inst, time_limit_s: float, method: str = "exact"):
    """``exact`` (the ceiling) or ``ilp`` (the DP ceiling's cross-check, HiGHS) within
    ``time_limit_s``, in a child process killed :data:`CEILING_KILL_AFTER_S` past it. A killed
    run leaves no incumbent: the answer is then ``rolling-future:bb``'s schedule (feasible) with
    the LP relaxation's bound, status ``time_limit``, and says so in its message."""
    from l3gs_opt.executors import run_guarded
    from l3gs_opt.methods import solve
    from l3gs_opt.problem.solution import Status, finish_solution

    sol = run_guarded(functools.partial(_ceiling_solve, time_limit_s=time_limit_s, method=method), inst,
                      time_limit_s + CEILING_KILL_AFTER_S, lambda *_: None, start_method="spawn")
    if sol is not None:
        return sol
    started = time.perf_counter()
    lp = solve(inst, "lp", backend="highs", time_limit_s=time_limit_s)
    heur = solve(inst, "rolling-future:bb", options={"bound": False})
    return finish_solution(inst, heur.arrivals, problem=heur.problem, method=method, status=Status.TIME_LIMIT,
                           bound=lp.bound,   # the relaxation's bound (None if it did not finish)
                           runtime_s=time_limit_s + CEILING_KILL_AFTER_S + time.perf_counter() - started,
                           backend="highs" if method == "ilp" else None,
                           message=f"{method} killed {CEILING_KILL_AFTER_S:.0f} s past its {time_limit_s:.0f} s "
                                   "limit; schedule of rolling-future:bb, bound of the LP relaxation")


def _ceiling_record(task: Task, inst, base: dict, time_limit_s: float, check_s: float) -> dict:
    """The exact ceiling: ``link-dp`` (proven optimal, :mod:`l3gs_opt.solvers.link_dp`) when its state
    space is small enough, else ``exact`` within ``time_limit_s`` (a time-limited answer keeps its
    bound). ``check_s > 0``: also run ``ilp/highs`` for that long and check its incumbent <= the DP
    optimum <= its bound."""
    from l3gs_opt.solvers.link_dp import MAX_STATES, link_dp_states, solve_link_dp

    if link_dp_states(inst) <= MAX_STATES:
        sol = solve_link_dp(inst)
    else:
        sol = _guarded_ceiling(inst, time_limit_s)
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
        "loadavg": list(os.getloadavg()), "check": None, "message": sol.message,
    })
    if check_s > 0 and sol.method == "link-dp":
        ilp = _guarded_ceiling(inst, check_s, method="ilp")
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
                    log: Callable[[str], None] | None = None, jobs: int = 0, executor: str = "local",
                    address: str | None = None) -> Path:
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
    jobs, executor, address
        ``jobs=0`` (default): records one after another in this process, each written as it
        finishes. ``jobs >= 1``: the records of each (scene, window, path) form one task, run by
        :func:`l3gs_opt.executors.run_tasks` (``local``: ``jobs`` forked processes; ``dask``: a
        local Dask cluster of ``jobs`` threads, or the scheduler at ``address``); a group's records
        are written when it finishes. Bundles are built here first either way.

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
                           on_record=on_record, log=log, jobs=jobs, executor=executor, address=address)
    finally:
        records.close()


def _run_locked(plan: ExperimentPlan, out: Path, records: RecordLog, *, resume: bool,
                cache_dir: str | os.PathLike[str] | None, progress: bool,
                on_record: Callable[[dict], None] | None, log: Callable[[str], None] | None, jobs: int = 0,
                executor: str = "local", address: str | None = None) -> Path:
    """:func:`run_experiments` once ``records`` (``OUT/runs.jsonl``, torn last line repaired) is locked."""
    from tqdm import tqdm

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
    runner = _Runner(plan, cache, say)
    failures: list[str] = []

    def write(record: dict) -> None:
        nonlocal written
        records.append(record, where=record["record_id"])
        written += 1
        bar.update(1)
        bar.set_postfix_str(f"{record['variant']} {record.get('method') or 'ceiling'} {record.get('ablation', '')}",
                            refresh=False)
        if on_record is not None:
            on_record(record)

    try:
        if jobs == 0:
            for task in todo:
                write(runner.record(task))
        else:
            # Bundles, teachers and pose logs first, here: workers only read them.
            for task in todo:
                runner.scene(task.scene).bundle(task.variant)
                runner.scene(task.scene).poses(runner.paths[task.path], plan.window_s)
            groups: dict[tuple, list[Task]] = {}
            for task in todo:
                groups.setdefault((task.scene, task.trace, task.start_s, task.path), []).append(task)

            def write_group(group: list[Task], result: Any) -> None:
                if isinstance(result, str):
                    failures.append(f"{group[0].record_id}...: {result}")
                    return
                for record in result:
                    write(record)

            warm_up()   # exact's kernels (its ceiling) into numba's cache, off every record's clock
            run_tasks(list(groups.values()), functools.partial(_run_group, plan, str(cache)), write_group,
                      jobs=jobs, executor=executor, address=address, failed=_group_failed,
                      start_method="spawn")   # this process has rendered (numba and torch thread pools)
    finally:
        bar.close()
        builds = {f"{name}/{v}": s for name, sc in runner.prepared.items() for v, s in sc.build_s.items()}
        session.update(wall_s=time.perf_counter() - t_start, loadavg_end=list(os.getloadavg()),
                       records_written=written, build_s=builds, jobs=jobs, executor=executor)
        append_record(out / "sessions.jsonl", session)   # covered by the lock on runs.jsonl
    if failures:
        raise ExperimentError("runs", f"{len(failures)} group(s) of records failed (run again with --resume to "
                                      f"retry them): {'; '.join(failures[:3])}")
    return runs


def _run_group(plan: ExperimentPlan, cache: str, tasks: list[Task]) -> list[dict] | str:
    """A worker's share: the records of one (scene, window, path), in plan order (or the error)."""
    try:
        runner = _Runner(plan, Path(cache), lambda _line: None)
        return [runner.record(task) for task in tasks]
    except Exception as exc:   # reported by the parent, which writes what the other groups finished
        return f"{type(exc).__name__}: {exc}"


def _group_failed(tasks: list[Task], seconds: float, why: str) -> str:
    return f"worker {why} after {seconds:.0f} s"


class _Runner:
    """Runs records one at a time, keeping what consecutive records share: a scene's bundles, the
    true utilities of a (variant, path, utility), the Simulation of a group."""

    def __init__(self, plan: ExperimentPlan, cache: Path, say: Callable[[str], None]):
        self.plan, self.cache, self.say = plan, cache, say
        self.scenes = {s.name: s for s in plan.scenes}
        self.paths = {p.name: p for p in plan.paths}
        self.klass = {t.name: t for t in plan.traces}
        self.prepared: dict[str, _Scene] = {}
        self.truths: dict[tuple, tuple] = {}
        self.sims: dict[tuple, Any] = {}

    def scene(self, name: str) -> _Scene:
        sc = self.prepared.get(name)
        if sc is None:
            self.sims.clear()   # one scene's bundles and renders at a time
            self.truths.clear()
            sc = self.prepared[name] = _Scene(self.scenes[name], self.plan, self.cache, self.say)
        return sc

    def record(self, task: Task) -> dict:
        from l3gs_opt.simulator.simulation import Simulation, method_spec, trace_bytes

        plan, paths = self.plan, self.paths
        sc = self.scene(task.scene)
        mbps = scaled_mbps(sc.scene_bytes())
        tr = self.klass[task.trace]
        bandwidth, info = trace_bytes(tr.path, mbps=mbps, start=task.start_s, slots=plan.window_s)
        poses = sc.poses(paths[task.path], plan.window_s)
        bundle = sc.bundle(task.variant)
        truth_name = truth_utility(task.utility)
        tkey = (task.scene, task.variant, task.path, truth_name)
        if tkey not in self.truths:
            # The true utilities depend on the bundle and the viewer only (not on the window).
            oracle = Simulation(bundle, poses, bandwidth, config=plan.config("true_viewport"))
            self.truths[tkey] = (oracle, _truth(oracle, plan.window_s, truth_name))
        oracle, truth = self.truths[tkey]
        base = {"record_id": task.record_id, "scene": task.scene, "variant": task.variant,
                "trace": task.trace, "trace_class": tr.klass, "start_s": task.start_s,
                "window_s": plan.window_s, "path": task.path, "path_source": paths[task.path].source,
                "mbps": mbps, "scale_factor": info["scale_factor"],
                "trace_mean_mbps_raw": info["trace_mean_mbps_raw"],
                "window_mean_mbps": info["window_mean_mbps"], "scene_bytes": sc.scene_bytes(),
                "bandwidth_cv": float(np.std(bandwidth) / max(float(np.mean(bandwidth)), 1e-12)),
                "width": plan.width, "height": plan.height, "truth_utility": truth_name}
        meta = {"experiment": "ceiling", **{k: base[k] for k in ("scene", "variant", "trace", "start_s",
                                                                 "path", "mbps", "truth_utility")}}
        inst = _ceiling_instance(oracle, truth, bandwidth, meta)
        if task.kind == "ceiling":
            return _ceiling_record(task, inst, base, plan.ceiling_time_limit_s, plan.ceiling_check_s)
        sim = self.sims.get(task.group)
        if sim is None:
            self.sims.clear()   # groups run one after another: keep one simulation's caches
            # Reference renders are shared by content across simulations (sim_render's cache).
            sim = self.sims[task.group] = Simulation(bundle, poses, bandwidth, config=plan.config(task.ablation, task.last_chunk),
                                                     reference=str(sc.teacher), info=info)
        result = sim.run(task.method, utility=task.utility)
        spec = method_spec(task.method, representation=bundle.manifest["representation"], variant=task.variant)
        return _sim_record(task, result, inst, base, preload=spec.preload)


def plan_fidelity(plan: ExperimentPlan, out_dir: str | os.PathLike[str], *,
                  cache_dir: str | os.PathLike[str] | None = None, samples: int = 8) -> dict:
    """How well each of the plan's utilities (and ``eq1``) predicts the picture on each scene's
    layered bundle and the plan's first path (:func:`l3gs_opt.pipeline.fidelity.utility_fidelity`
    at the plan's render size), written to ``OUT/fidelity.json`` and returned: ``{scene: {utility:
    correlations and seconds per viewpoint}}``. Needs the bundles the run built."""
    from l3gs_opt.pipeline.fidelity import utility_fidelity

    out = Path(out_dir)
    cache = Path(cache_dir) if cache_dir is not None else out / "cache"
    if "layered" not in plan.variants:
        return {}
    names = list(dict.fromkeys(["eq1", *plan.utilities]))
    result: dict[str, Any] = {}
    for spec in plan.scenes:
        sc = _Scene(spec, plan, cache, lambda _line: None)
        bundle = sc.dir / "layered"
        if not (bundle / "manifest.json").exists():
            continue
        path_spec = plan.paths[0]
        log = sc.dir / f"{path_spec.name}.fidelity.log"
        if not log.exists():
            from l3gs_opt.traces.poses import write_pose_log

            tmp = write_pose_log(sc.poses(path_spec, plan.window_s), log.with_suffix(f".{os.getpid()}.tmp"))
            os.replace(tmp, log)
        rep = utility_fidelity(bundle, log, utilities=names, samples=samples, slots=plan.window_s,
                               width=plan.width, height=plan.height)
        result[spec.name] = {"path": path_spec.name, "samples": rep.setup["samples"],
                             "candidates": rep.setup["candidates"],
                             "spearman_ssim_chunk_size": rep.setup["spearman_ssim_chunk_size"],
                             "utilities": {n: {**rep.correlations[n], "ms_per_viewpoint":
                                               1e3 * rep.seconds_per_viewpoint[n]} for n in rep.utilities}}
    (out / "fidelity.json").write_text(dumps(result, indent=1, where="fidelity") + "\n")
    return result
