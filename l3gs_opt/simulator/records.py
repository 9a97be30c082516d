"""Per-slot records of a simulation on disk: appended as they finish, and read back to resume a run.

``OUT/slots.jsonl`` holds one JSON line per slot and ``OUT/summary.jsonl`` one per finished run,
each tagged with ``method``, ``solver``, ``utility`` (and ``client`` in shared-link runs) and the run's
``run_id``, a digest of everything that decides the run (bundle, poses, trace bytes, reference,
config, method). A re-run of the same method replaces that method's lines and keeps the others;
a resumed run keeps its slots ``0..t-1`` (the longest run of consecutive slots with its run id)
and continues from slot t.
"""

from __future__ import annotations

import hashlib
import json
import re
from dataclasses import dataclass, field, fields
from pathlib import Path
from typing import Any, Iterator, Mapping

import numpy as np

from l3gs_opt.records import OutputLock, RecordLog, prepare_path, read_records, repair_torn_tail, rewrite_records
from l3gs_opt.simulator.config import SimulationError

__all__ = ["run_id", "RecordWriter", "RunSummary", "SimulationResult"]

SLOTS_FILE, SUMMARY_FILE = "slots.jsonl", "summary.jsonl"


def run_id(parts: dict) -> str:
    """A 16-hex digest of ``parts`` (JSON-serialisable; keys sorted)."""
    text = json.dumps(parts, sort_keys=True, default=str, allow_nan=False)
    return hashlib.sha1(text.encode()).hexdigest()[:16]


def _key(record: dict) -> tuple:
    """``(method, solver, client, utility)`` of a record (records written before utilities had
    names were all ``eq1``)."""
    return record.get("method"), record.get("solver"), record.get("client"), record.get("utility", "eq1")


class RecordWriter:
    """Slot records and the summary of one run, appended as they finish (an interrupted run loses nothing).

    Both files are shared by the runs of every method in ``out_dir``; each run holds a lock of its
    own key (``OUT/slots.jsonl.KEY.lock``) from construction to :meth:`summary` (or :meth:`close`),
    so a second run of the same method into the same folder is refused while the first goes on.
    Every change of a file (the rewrite below, each append) happens under that file's lock
    (``OUT/slots.jsonl.lock``, held for the moment of the change), through
    :mod:`l3gs_opt.records`: a torn last line is repaired first, a bad line elsewhere is an error.

    Parameters
    ----------
    out_dir : path or None
        None: write nothing (and resume nothing).
    method, solver, client, utility : the run's key (``client``: None for a single-client run)
    run : str
        The run's :func:`run_id`.
    resume : bool
        Keep this key's recorded slots ``0..t-1`` (:attr:`resumed`) instead of dropping them.

    Raises
    ------
    SimulationError
        ``resume`` when this key's recorded slots come from a run with other inputs.
    OutputLockedError
        Another run of this key is writing to ``out_dir``.
    RecordFileError
        A line of a record file (other than a torn last one) is not a JSON record.
    """

    def __init__(self, out_dir, method: str, solver: str | None, *, client: int | None = None, run: str = "",
                 resume: bool = False, utility: str = "eq1"):
        self.dir = None if out_dir is None else Path(out_dir)
        self.resumed: list[dict] = []
        self._owner: OutputLock | None = None
        if self.dir is None:
            return
        self.key = (method, solver, client, utility)
        slots = self.dir / SLOTS_FILE
        prepare_path(slots)
        name = re.sub(r"[^A-Za-z0-9._-]+", "_", "-".join(str(k) for k in self.key))
        self._owner = OutputLock(self.dir / f"{SLOTS_FILE}.{name}.lock", field=str(slots),
                                 what=f"simulate of method {method!r}, solver {solver!r}"
                                      + ("" if client is None else f", client {client}")).acquire()
        try:
            self._start(slots, run, resume)
        except BaseException:
            self.close()
            raise

    def _start(self, slots: Path, run: str, resume: bool) -> None:
        method, solver, _, _ = self.key
        with self._file_lock(SLOTS_FILE):
            repair_torn_tail(slots)
            records = read_records(slots)
            mine = [r for r in records if _key(r) == self.key]
            if resume:
                foreign = sorted({r.get("run_id") for r in mine} - {run})
                if foreign:
                    raise SimulationError("resume", f"{slots} holds slots of method {method!r} (solver {solver!r}) "
                                                    f"from a run with other inputs (run id {foreign[0]}, this run "
                                                    f"{run}): run without resume to start over")
                by_slot = {r["slot"]: r for r in mine}
                while len(self.resumed) in by_slot:
                    self.resumed.append(by_slot[len(self.resumed)])
            # Rewrite: other keys' lines, then the slots kept, in order (drops gaps and later slots).
            rewrite_records(slots, [r for r in records if _key(r) != self.key] + self.resumed)
        summary = self.dir / SUMMARY_FILE
        with self._file_lock(SUMMARY_FILE):
            if summary.exists():   # a re-run (or a resumed one) writes its summary again when it finishes
                repair_torn_tail(summary)
                rewrite_records(summary, [r for r in read_records(summary) if _key(r) != self.key])

    def _file_lock(self, name: str) -> OutputLock:
        """The brief lock of one shared file (waits for another run's change to end)."""
        return OutputLock(self.dir / f"{name}.lock", field=str(self.dir / name)).acquire(wait=True)

    def _append(self, name: str, obj: dict) -> None:
        if self.dir is None:
            return
        with self._file_lock(name):
            with RecordLog(self.dir / name, lock=False) as log:
                log.append(obj, where=name)

    def slot(self, record: dict) -> None:
        self._append(SLOTS_FILE, record)

    def summary(self, summary: dict) -> None:
        """Append the run's summary: its last record; the run's lock is released."""
        self._append(SUMMARY_FILE, summary)
        self.close()

    def close(self) -> None:
        """Release the run's lock (also when the process ends)."""
        if self._owner is not None:
            self._owner.release()
            self._owner = None


@dataclass(frozen=True)
class RunSummary:
    """What one finished run delivered and cost: the run's line of ``summary.jsonl``.

    Bytes are integers (whole run); ``slot_s``, ``run_s`` and ``timings_mean_s`` (per slot, by
    stage) in seconds; ``ssim_per_s`` / ``psnr_per_s`` one value per slot (PSNR ``None`` where the
    picture equals the reference). ``bytes_wasted`` = delivered but not shown, split into
    ``bytes_replaced`` (units superseded by a higher one) and ``bytes_unshown`` (partial splats,
    units never shown). ``client`` / ``clients``: set in shared-link runs only. ``info``: the
    caller's extra keys (e.g. the trace's name), written beside the others.

    :meth:`to_dict` is the JSON record; reading by key (``summary["bytes_delivered"]``,
    :meth:`get`, :meth:`items`) reads that record, so code that reads records from disk and
    summaries in memory is the same.
    """

    method: str
    solver: str | None
    utility: str | None
    order_utility: str | None
    slots: int
    slot_s: float
    ssim_mean: float
    ssim_per_s: tuple[float, ...]
    psnr_per_s: tuple[float | None, ...]
    psnr_mean: float | None
    bytes_delivered: int
    bytes_wasted: int
    bytes_replaced: int
    bytes_unshown: int
    bytes_idle: int
    bytes_trace: int
    bytes_share: int
    bytes_model: int
    splats_final: int
    timings_mean_s: Mapping[str, float]
    run_s: float
    loadavg_start: tuple[float, ...]
    loadavg_end: tuple[float, ...]
    bundle: str
    variant: str
    representation: str
    view: str
    units: tuple[int, ...]
    reference: str
    config: Mapping[str, Any]
    render_backend: str
    renders: Mapping[str, int]
    resumed_slots: int
    run_id: str
    client: int | None = None
    clients: int | None = None
    info: Mapping[str, Any] = field(default_factory=dict)

    def to_dict(self) -> dict:
        """The JSON record (lists for sequences; ``info`` flattened; ``client``/``clients`` only
        when set)."""
        out: dict[str, Any] = {}
        for f in fields(self):
            value = getattr(self, f.name)
            if f.name == "info" or (f.name in ("client", "clients") and value is None):
                continue
            if isinstance(value, tuple):
                value = list(value)
            elif isinstance(value, Mapping):
                value = dict(value)
            out[f.name] = value
        return {**out, **self.info}

    def __getitem__(self, key: str) -> Any:
        return self.to_dict()[key]

    def get(self, key: str, default: Any = None) -> Any:
        return self.to_dict().get(key, default)

    def items(self) -> Iterator[tuple[str, Any]]:
        return iter(self.to_dict().items())

    def keys(self) -> Iterator[str]:
        return iter(self.to_dict())


@dataclass
class SimulationResult:
    """One run: a record per slot (dicts, as written to ``slots.jsonl``) and the :class:`RunSummary`."""

    method: str
    solver: str | None
    records: list = field(default_factory=list)
    summary: RunSummary | None = None
    #: Rows of :attr:`Simulation.scene` shown in the last slot.
    final_rows: np.ndarray = field(default_factory=lambda: np.zeros(0, np.int64))

    @property
    def ssim_per_s(self) -> list[float]:
        return [r["ssim"] for r in self.records]

    @property
    def ssim_mean(self) -> float:
        return float(np.mean(self.ssim_per_s)) if self.records else float("nan")

    def to_dict(self) -> dict:
        return {} if self.summary is None else self.summary.to_dict()
