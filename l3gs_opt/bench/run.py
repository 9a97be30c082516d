"""Benchmark runs: one JSONL record per (instance, method), written as soon as it finishes.

* Resumable: ``resume=True`` skips every record already in the file; an interrupted run (Ctrl-C,
  a killed process) loses only the records in flight.
* Enforced time limits: each record runs in its own forked process; one that outlives
  ``time_limit_s * 1.5 + 10`` seconds is killed and recorded as ``time_limit`` (flag ``killed``).
* Checked: every record's schedule is re-checked for feasibility in exact bytes and its objective
  re-evaluated from the instance; exact methods must agree and bounds must not cut off the best
  known optimum. Disagreements are flagged in the record, never dropped. A record's
  ``best_known`` and ``rel_error`` are as of when it was written (from the records of its instance
  before it); ``l3gs-opt report`` recomputes both over the whole file.
* Executors: ``local`` (a pool of processes on this machine) or ``dask`` (a Dask cluster: a
  local one by default, or the scheduler at ``address``).
"""

from __future__ import annotations

import functools
import math
import os
import time
import traceback
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any, Callable, Iterable, Mapping

from tqdm import tqdm

from l3gs_opt.executors import EXECUTORS, run_tasks
from l3gs_opt.solvers.exact.warm import warm_up
from l3gs_opt.methods import solve
from l3gs_opt.errors import L3gsError, SolveError
from l3gs_opt.problem.evaluate import evaluate_objective, feasibility_violations
from l3gs_opt.problem.instance import Instance
from l3gs_opt.jsonout import to_jsonable
from l3gs_opt.records import RecordLog, read_records
from l3gs_opt.problem.solution import Solution, Status
from l3gs_opt.bench.suites import InstanceSpec, split_method

__all__ = ["RECORD_SCHEMA", "BenchError", "BenchTask", "run_bench", "read_records", "recheck", "run_task",
           "AGREE_TOL", "CROSS_FLAGS", "check_records"]

RECORD_SCHEMA = "l3gs-opt/bench-record@1"
#: A record's status when the method refuses the instance before solving (e.g. ``dp``'s table would
#: be too large): beside the :class:`~l3gs_opt.problem.solution.Status` values, never a failure.
DECLINED = "declined"


def is_declined(record: dict) -> bool:
    """Whether ``record`` is a refusal (also records written before the status existed: ``error``
    with a ``declined`` flag)."""
    return record.get("status") == DECLINED or "declined" in record.get("flags", ())
#: Relative tolerance for two proven optima to count as equal and for a bound to count as valid:
#: backends solve to zero gap; their round-off on objectives of 1e5-1e9 stays far below it.
AGREE_TOL = 1e-7


class BenchError(SolveError):
    """A benchmark request or results file is unusable (an empty plan, a bad option, records of
    another kind); names the field (an option such as ``--seeds``, or ``records``) and index."""

    def __init__(self, field: str, message: str, index: int | None = None):
        self.field = field
        self.index = index
        sep = " " if message.startswith("= ") else ": "   # "--seeds = -1: ...", as InstanceError
        super().__init__(f"{field}{'' if index is None else f'[{index}]'}{sep}{message}")


@dataclass(frozen=True)
class BenchTask:
    spec: InstanceSpec
    method: str

    @property
    def record_id(self) -> str:
        return f"{self.spec.suite}/{self.spec.instance_id}/{self.method}"


def _versions() -> dict[str, str | None]:
    from importlib.metadata import PackageNotFoundError, version

    out: dict[str, str | None] = {}
    for name in ("l3gs-opt", "numpy", "pulp", "highspy", "ortools"):
        try:
            out[name] = version(name)
        except PackageNotFoundError:
            out[name] = None
    return out


def _solve_label(instance: Instance, label: str, time_limit_s: float | None, single_slot: bool,
                 custom: Mapping[str, Callable[..., Solution]] | None) -> Solution:
    name, kwargs = split_method(label)
    slot = 0 if single_slot else None
    if custom and name in custom:
        return custom[name](instance, slot=slot, time_limit_s=time_limit_s, **kwargs)
    return solve(instance, name, slot=slot, time_limit_s=time_limit_s, **kwargs)


def run_task(task: BenchTask, time_limit_s: float | None,
             custom: Mapping[str, Callable[..., Solution]] | None = None) -> dict[str, Any]:
    """Build the instance, run the method, check its answer; a record without cross-method flags."""
    spec = task.spec
    instance = spec.build()
    slot = 0 if spec.single_slot else None
    record: dict[str, Any] = {
        "schema": RECORD_SCHEMA, "record_id": task.record_id, "suite": spec.suite, "instance_id": spec.instance_id,
        "spec": spec.to_dict(), "method": task.method, "T": instance.T, "J": instance.J, "L": instance.L,
        "problem": "MCKP" if spec.single_slot else instance.problem, "time_limit_s": time_limit_s,
        "versions": _versions(), "flags": [],
        # Run times on a shared machine mean little without the load they ran under.
        "loadavg_1m": os.getloadavg()[0] if hasattr(os, "getloadavg") else None,
        # A relaxation answers with a bound only (its schedule is empty): judged by its bound, not its error.
        "bound_only": split_method(task.method)[0] == "lp",
    }
    started = time.perf_counter()
    try:
        sol = _solve_label(instance, task.method, time_limit_s, spec.single_slot, custom)
    except L3gsError as exc:  # e.g. a DP table too large: a refusal, not a failure (its own status, no flag)
        record.update(status=DECLINED, objective=None, bound=None, runtime_s=time.perf_counter() - started,
                      message=f"{type(exc).__name__}: {exc}", feasible=None, objective_ok=None, model_size=None)
        return record
    except Exception as exc:  # a crash is a result too: record it, do not lose the run
        record.update(status="error", objective=None, bound=None, runtime_s=time.perf_counter() - started,
                      message=f"{type(exc).__name__}: {exc}\n{traceback.format_exc(limit=3)}", feasible=None,
                      objective_ok=None, model_size=None)
        record["flags"].append("crashed")
        return record
    violations = feasibility_violations(instance, sol.arrivals, slot=slot)
    recomputed = evaluate_objective(instance, sol.arrivals, slot=slot) if not violations else None
    objective_ok = recomputed is not None and math.isclose(recomputed, sol.objective, rel_tol=1e-9, abs_tol=1e-12)
    record.update(
        problem=sol.problem, status=sol.status.value, objective=sol.objective, bound=sol.bound, runtime_s=sol.runtime_s,
        backend=sol.backend, message=sol.message, feasible=not violations, objective_ok=objective_ok,
        recomputed_objective=recomputed,
        model_size=sol.to_dict()["model_size"] if sol.size_after else None, details=_jsonable(sol.details))
    if violations:
        record["flags"].append("infeasible")
        record["violations"] = violations[:5]
    if not objective_ok and not violations:
        record["flags"].append("objective_mismatch")
    return record


def _jsonable(value: Any) -> Any:
    """A method's free-form ``details`` as strict JSON data (:func:`l3gs_opt.jsonout.to_jsonable`:
    non-finite floats become None); an object of another type becomes its ``str`` rather than
    costing the record."""
    return to_jsonable(value, other=str, where="details")


def hard_limit(time_limit_s: float | None) -> float | None:
    """Wall-clock seconds after which a record's process is killed."""
    return None if time_limit_s is None else time_limit_s * 1.5 + 10.0


def _killed_record(time_limit_s: float | None, task: BenchTask, elapsed: float, why: str) -> dict[str, Any]:
    instance = task.spec.build()
    slot = 0 if task.spec.single_slot else None
    return {"schema": RECORD_SCHEMA, "record_id": task.record_id, "suite": task.spec.suite,
            "instance_id": task.spec.instance_id, "spec": task.spec.to_dict(), "method": task.method,
            "T": instance.T, "J": instance.J, "L": instance.L,
            "problem": "MCKP" if task.spec.single_slot else instance.problem, "time_limit_s": time_limit_s,
            "versions": _versions(), "status": Status.TIME_LIMIT.value if why == "killed" else Status.ERROR.value,
            # The empty schedule is what a killed method leaves: feasible, worth the held chunks.
            "objective": evaluate_objective(instance, [], slot=slot), "bound": None, "runtime_s": elapsed,
            "message": f"process {why} after {elapsed:.1f} s", "feasible": True, "objective_ok": True,
            "model_size": None, "flags": [why]}


@dataclass
class _InstanceState:
    """What is known about one instance so far, to flag disagreements as records arrive."""

    optima: list[tuple[str, float]] = field(default_factory=list)   # (method, proven optimum)
    bounds: list[tuple[str, float]] = field(default_factory=list)   # (method, bound)
    best_feasible: float = -math.inf


#: Flags that depend on the other records of the instance (the rest describe the record's own run).
CROSS_FLAGS = ("mismatch", "cuts_bound_of_others", "bound_invalid")


def recheck(records: list[dict[str, Any]]) -> list[dict[str, Any]]:
    """Copies of ``records`` with the cross-record flags recomputed over the whole list, in order.

    A record written during a run is checked against the records before it; after a method is
    re-run (records removed and the run resumed), this replays the checks so that no flag refers to
    an answer that is no longer in the file.
    """
    states: dict[tuple[str, str], _InstanceState] = {}
    out = []
    for rec in records:
        rec = {k: v for k, v in rec.items() if k not in ("mismatch_with", "invalid_bounds_of")}
        rec["flags"] = [f for f in rec.get("flags", []) if f not in CROSS_FLAGS]
        _cross_check(rec, states.setdefault(_instance_key(rec), _InstanceState()))
        out.append(rec)
    return out


def _instance_key(record: Mapping[str, Any]) -> tuple[str, str]:
    return record["suite"], record["instance_id"]


def _cross_check(record: dict[str, Any], state: _InstanceState) -> None:
    """Flag disagreement between exact methods and bounds that cut off a known solution."""
    obj, bound, status = record.get("objective"), record.get("bound"), record.get("status")
    usable = obj is not None and record.get("feasible") and record.get("objective_ok")

    def differs(a: float, b: float) -> bool:
        return abs(a - b) > AGREE_TOL * max(abs(a), abs(b), 1e-12)

    if usable and status == "optimal":
        others = [m for m, v in state.optima if differs(v, obj)]
        if others:
            record["flags"].append("mismatch")
            record["mismatch_with"] = others
        cut = [m for m, b in state.bounds if b < obj and differs(b, obj)]
        if cut:
            record["flags"].append("cuts_bound_of_others")
            record["invalid_bounds_of"] = cut
    if bound is not None and state.best_feasible > bound and differs(state.best_feasible, bound):
        record["flags"].append("bound_invalid")
    if usable:
        if status == "optimal":
            state.optima.append((record["method"], obj))
        state.best_feasible = max(state.best_feasible, obj)
    if bound is not None:
        state.bounds.append((record["method"], bound))
    known = [v for _, v in state.optima]
    record["best_known"] = max(known) if known else (state.best_feasible if state.best_feasible > -math.inf
                                                     else None)
    record["best_known_proven"] = bool(known)
    best = record["best_known"]
    if usable and best is not None:
        record["rel_error"] = 0.0 if best == obj else max(0.0, (best - obj) / abs(best)) if best else math.inf
    else:
        record["rel_error"] = None


#: Keys every bench record has and their types (what ``report`` and the cross-checks read without a default).
RECORD_KEYS = {"record_id": str, "suite": str, "instance_id": str, "method": str, "status": str, "J": int, "T": int,
               "L": int}
#: Keys a record may lack or hold as null; finite numbers when present (a record writes null for a
#: number without a finite value, and JSON's ``1e400`` reads as infinity).
RECORD_NUMBERS = ("objective", "bound", "runtime_s", "loadavg_1m", "time_limit_s", "recomputed_objective")
#: Of those, the ones that cannot be negative (seconds, load), like the sizes J, T and L.
RECORD_NON_NEGATIVE = ("runtime_s", "loadavg_1m", "time_limit_s", "J", "T", "L")
#: Keys a record may lack or hold as null; true or false when present.
RECORD_FLAGS = ("feasible", "objective_ok", "bound_only")
#: Keys a record may lack or hold as null, and their type when present.
RECORD_OPTIONAL = {"problem": str, "message": str, "spec": dict, "versions": dict}


def _shown(value: Any) -> str:
    """``repr(value)``, cut to 40 characters (a record's field may hold a whole file's worth)."""
    text = repr(value)
    return text if len(text) <= 40 else text[:37] + "..."


def _record_fault(rec: Mapping[str, Any]) -> str | None:
    """What makes ``rec`` no bench record, or None."""
    schema = rec.get("schema")
    if schema is not None and schema != RECORD_SCHEMA:
        return f"schema {_shown(schema)}"
    missing = [k for k, kind in RECORD_KEYS.items() if not isinstance(rec.get(k), kind) or isinstance(rec[k], bool)]
    if missing:
        return f"no {', '.join(f'{k} ({RECORD_KEYS[k].__name__})' for k in missing)}"
    for k in RECORD_NUMBERS:
        v = rec.get(k)
        if v is not None and (isinstance(v, bool) or not isinstance(v, (int, float)) or not math.isfinite(v)):
            return f"{k} = {_shown(v)} is not a finite number or null"
    for k in RECORD_NON_NEGATIVE:
        v = rec.get(k)
        if v is not None and v < 0:
            return f"{k} = {_shown(v)} is negative"
    for k in RECORD_FLAGS:
        if rec.get(k) not in (None, True, False):
            return f"{k} = {_shown(rec[k])} is not true, false or null"
    for k, kind in RECORD_OPTIONAL.items():
        v = rec.get(k)
        if v is not None and not isinstance(v, kind):
            return f"{k} = {_shown(v)} is not {'text' if kind is str else 'an object'} or null"
    params = (rec.get("spec") or {}).get("params")
    if params is not None and not isinstance(params, dict):
        return f"spec.params = {_shown(params)} is not an object or null"
    flags = rec.get("flags", [])
    if not isinstance(flags, list) or not all(isinstance(f, str) for f in flags):
        return f"flags = {_shown(flags)} is not a list of text"
    return None


def check_records(records: list[dict[str, Any]], *, field: str = "records") -> list[dict[str, Any]]:
    """``records`` if each is a bench record (:data:`RECORD_SCHEMA`: the keys and types ``report``
    reads).

    Raises
    ------
    BenchError
        A record of another kind (e.g. ``simulate``'s or ``experiments``' records) or with a value
        of the wrong type: ``index`` is its position (0-based).
    """
    for i, rec in enumerate(records):
        fault = _record_fault(rec)
        if fault:
            raise BenchError(field, f"not a bench record ({fault}; expected {RECORD_SCHEMA} records from "
                                    "l3gs-opt bench or compare)", i)
    return records


def _order(tasks: list[BenchTask]) -> list[BenchTask]:
    """Per instance, exact references first so later records can be checked against them."""
    rank = {"brute": 0, "bb": 1, "dp": 2}

    def key(t: BenchTask) -> tuple:
        name = t.method.split("/")[0]
        return (rank.get(name, 3 if name == "ilp" else 4),)

    by_instance: dict[str, list[BenchTask]] = {}
    for t in tasks:
        by_instance.setdefault(t.spec.instance_id, []).append(t)
    return [t for group in by_instance.values() for t in sorted(group, key=key)]


def run_bench(tasks: Iterable[BenchTask], out_path: str | os.PathLike[str], *, time_limit_s: float | None = 60.0,
              jobs: int = 1, executor: str = "local", address: str | None = None, resume: bool = False,
              progress: bool = True, custom: Mapping[str, Callable[..., Solution]] | None = None,
              fresh: bool = False) -> Path:
    """Run every task and append its record to ``out_path`` (JSONL).

    ``jobs=0`` runs in this process (no kill enforcement; for debugging and custom methods).

    The file is written through one :class:`l3gs_opt.records.RecordLog`: locked against a second
    writer for the whole run, each record fsynced, a torn last line repaired before ``resume``
    appends.

    Parameters
    ----------
    fresh : bool
        Drop the records already in ``out_path`` (under the lock) instead of refusing them.

    Raises
    ------
    BenchError
        No tasks; the output holds records without ``resume`` (or records of another kind); an
        unknown executor; bad ``jobs`` or time limit.
    OutputLockedError
        Another writer holds ``out_path``'s lock.
    RecordFileError
        ``out_path`` is a folder or its folder a file; a line other than the last is not a record.
    """
    out_path = Path(out_path)
    tasks = list(tasks)
    if not tasks:
        raise BenchError("tasks", "nothing to run (an empty plan)")
    if executor not in EXECUTORS:
        raise BenchError("executor", f"{executor!r} is not one of {', '.join(EXECUTORS)}")
    if jobs < 0:
        raise BenchError("jobs", f"= {jobs}: must be >= 0")
    if time_limit_s is not None and not time_limit_s > 0:
        raise BenchError("time_limit_s", f"= {time_limit_s!r}: must be > 0 seconds")
    with RecordLog(out_path, fresh=fresh, what="bench") as log:
        existing = check_records(log.records(), field=str(out_path))
        if existing and not resume:
            raise BenchError("--resume", f"{out_path} already holds {len(existing)} records: pass --resume to "
                                         "continue it, or choose another --out")
        _run_logged(tasks, log, existing, time_limit_s=time_limit_s, jobs=jobs, executor=executor,
                    address=address, progress=progress, custom=custom)
    return out_path


def _run_logged(tasks: list[BenchTask], log: RecordLog, existing: list[dict[str, Any]], *,
                time_limit_s: float | None, jobs: int, executor: str, address: str | None, progress: bool,
                custom: Mapping[str, Callable[..., Solution]] | None) -> None:
    states: dict[tuple[str, str], _InstanceState] = {}
    done = set()
    for rec in existing:
        done.add(rec["record_id"])
        _cross_check(dict(rec, flags=list(rec.get("flags", []))), states.setdefault(_instance_key(rec),
                                                                                    _InstanceState()))
    todo = _order([t for t in tasks if t.record_id not in done])
    bar = tqdm(total=len(todo), desc="bench", unit="record", disable=not progress)
    try:
        def write(rec: dict[str, Any]) -> None:
            _cross_check(rec, states.setdefault(_instance_key(rec), _InstanceState()))
            log.append(rec, where=rec.get("record_id", "record"))
            bar.update(1)
            bar.set_postfix_str(f"{rec['method']} {rec['status']}", refresh=False)

        # Compiled once here, off every record's clock: a forked worker's compile dies with it.
        if todo:
            warm_up()
        work = functools.partial(run_task, time_limit_s=time_limit_s, custom=custom)
        run_tasks(todo, work, lambda _task, rec: write(rec), jobs=jobs, executor=executor, address=address,
                  hard_limit_s=hard_limit(time_limit_s), failed=functools.partial(_killed_record, time_limit_s))
    finally:
        bar.close()
