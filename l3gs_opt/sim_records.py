"""Per-slot records of a simulation on disk: appended as they finish, and read back to resume a run.

``OUT/slots.jsonl`` holds one JSON line per slot and ``OUT/summary.jsonl`` one per finished run,
each tagged with ``method``, ``solver`` (and ``client`` in shared-link runs) and the run's
``run_id``, a digest of everything that decides the run (bundle, poses, trace bytes, reference,
config, method). A re-run of the same method replaces that method's lines and keeps the others;
a resumed run keeps its slots ``0..t-1`` (the longest run of consecutive slots with its run id)
and continues from slot t.
"""

from __future__ import annotations

import hashlib
import json
from pathlib import Path

from .sim_config import SimulationError

__all__ = ["run_id", "RecordWriter"]


def run_id(parts: dict) -> str:
    """A 16-hex digest of ``parts`` (JSON-serialisable; keys sorted)."""
    text = json.dumps(parts, sort_keys=True, default=str, allow_nan=False)
    return hashlib.sha1(text.encode()).hexdigest()[:16]


def _key(line: str) -> tuple | None:
    """``(method, solver, client)`` of a record line; None for a blank or cut-off line (an interrupted write)."""
    try:
        obj = json.loads(line)
    except json.JSONDecodeError:
        return None
    return (obj.get("method"), obj.get("solver"), obj.get("client")) if isinstance(obj, dict) else None


class RecordWriter:
    """Slot records and the summary of one run, appended as they finish (an interrupted run loses nothing).

    Parameters
    ----------
    out_dir : path or None
        None: write nothing (and resume nothing).
    method, solver, client : the run's key (``client``: None for a single-client run)
    run : str
        The run's :func:`run_id`.
    resume : bool
        Keep this key's recorded slots ``0..t-1`` (:attr:`resumed`) instead of dropping them.

    Raises
    ------
    SimulationError
        ``resume`` when this key's recorded slots come from a run with other inputs.
    """

    def __init__(self, out_dir, method: str, solver: str | None, *, client: int | None = None, run: str = "",
                 resume: bool = False):
        self.dir = None if out_dir is None else Path(out_dir)
        self.resumed: list[dict] = []
        if self.dir is None:
            return
        self.dir.mkdir(parents=True, exist_ok=True)
        self.key = (method, solver, client)
        slots = self.dir / "slots.jsonl"
        mine = []
        if slots.exists():
            lines = slots.read_text().splitlines()
            mine = [json.loads(line) for line in lines if _key(line) == self.key]
            keep = [line for line in lines if _key(line) not in (self.key, None)]
        else:
            keep = []
        if resume:
            foreign = sorted({r.get("run_id") for r in mine} - {run})
            if foreign:
                raise SimulationError("resume", f"{slots} holds slots of method {method!r} (solver {solver!r}) from "
                                                f"a run with other inputs (run id {foreign[0]}, this run {run}): run "
                                                "without resume to start over")
            by_slot = {r["slot"]: r for r in mine}
            while len(self.resumed) in by_slot:
                self.resumed.append(by_slot[len(self.resumed)])
        # Rewrite: other keys' lines, then the slots kept, in order (drops cut-off lines and gaps).
        slots.write_text("".join(line + "\n" for line in keep)
                         + "".join(json.dumps(r, allow_nan=False) + "\n" for r in self.resumed))
        summary = self.dir / "summary.jsonl"
        if summary.exists():   # a re-run (or a resumed one) writes its summary again when it finishes
            keep = [line for line in summary.read_text().splitlines() if _key(line) not in (self.key, None)]
            summary.write_text("".join(line + "\n" for line in keep))

    def _append(self, name: str, obj: dict) -> None:
        if self.dir is None:
            return
        with open(self.dir / name, "a", encoding="utf-8") as fh:
            fh.write(json.dumps(obj, allow_nan=False) + "\n")
            fh.flush()

    def slot(self, record: dict) -> None:
        self._append("slots.jsonl", record)

    def summary(self, summary: dict) -> None:
        self._append("summary.jsonl", summary)
