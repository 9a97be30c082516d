"""One writer and one reader for JSONL record files (``bench``, ``compare``, ``simulate``, ``experiments``).

A record file holds one JSON object per line, appended as each record finishes:

* **Durable appends.** :meth:`RecordLog.append` writes a whole line with one ``write`` call through
  the strict serialiser (:func:`l3gs_opt.jsonout.dumps`), then flushes and ``fsync``\\ s it: a record
  reported written survives a crash of the process or the machine.
* **Torn last line.** A process killed in the middle of a write leaves a last line without its
  newline. Readers ignore it (:func:`read_records`); before anything is appended it is repaired
  (:func:`repair_torn_tail`): a complete record missing only its newline gets the newline, a
  fragment is cut off, and either is reported in a note. A complete record is never lost, and the
  next record never lands on a fragment.
* **A bad line elsewhere** (edited by hand, another format) is :class:`RecordFileError` naming the
  file and the line (1-based), never skipped in silence.
* **One writer at a time.** A writer holds an exclusive ``fcntl.flock`` on ``FILE.lock`` (holding
  its pid) for as long as it writes; a second writer gets :class:`OutputLockedError`. The lock goes
  when the holder closes it or its process ends, even by ``SIGKILL``; the lock file stays behind.

Example
-------
>>> with RecordLog("out/results.jsonl") as log:                 # doctest: +SKIP
...     done = {r["record_id"] for r in log.records()}
...     log.append({"record_id": "a", "objective": 1.0})
"""

from __future__ import annotations

import errno
import fcntl
import gc
import json
import os
import sys
from pathlib import Path
from typing import Any, Callable, Iterable, Mapping

from l3gs_opt.jsonout import OutputError, dumps
from l3gs_opt.output_files import write_atomic

__all__ = ["LOCK_SUFFIX", "RecordFileError", "OutputLockedError", "read_records", "repair_torn_tail",
           "OutputLock", "RecordLog", "append_record", "rewrite_records", "prepare_path"]

#: Suffix of the lock file beside a record file (``results.jsonl`` -> ``results.jsonl.lock``).
LOCK_SUFFIX = ".lock"


class RecordFileError(OutputError):
    """A record file (or its folder) cannot be read or written: a line that is not a JSON record
    (``index`` is its 1-based line number), or a path that is a folder where a file belongs or the
    other way round."""


class OutputLockedError(OutputError):
    """Another writer (another process, or a live writer in this one) holds the record file's lock."""


def _note_to_stderr(text: str) -> None:
    print(f"note: {text}", file=sys.stderr)


def _check_file_path(path: Path, field: str) -> None:
    """Refuse a record path that is a folder or not a regular file, or whose folder is a file."""
    it = "" if field == str(path) else f"{path} "   # the field names the path already
    if path.is_dir():
        raise RecordFileError(field, f"{it}is a folder, expected a records file")
    if path.exists() and not path.is_file():
        raise RecordFileError(field, f"{it}is not a regular file (a FIFO, socket or device is refused)")
    for parent in path.parents:
        if parent.exists():
            if not parent.is_dir():
                raise RecordFileError(field, f"its folder {parent} is a file")
            break


def prepare_path(path: str | os.PathLike[str], *, field: str | None = None) -> Path:
    """``path`` as a :class:`Path`, its folder created, after refusing a folder or a non-regular
    file at ``path`` and a file where its folder belongs (:class:`RecordFileError`)."""
    path = Path(path)
    field = field or str(path)
    _check_file_path(path, field)
    try:
        path.parent.mkdir(parents=True, exist_ok=True)
    except OSError as exc:
        raise RecordFileError(field, f"cannot create the folder {path.parent} ({exc.strerror or exc})") from None
    return path


def _refuse_constant(name: str) -> Any:
    raise ValueError(f"{name} is not JSON (records hold null for a number without a finite value)")


def _parse(line: bytes) -> Any:
    """The JSON value of one line, or the exception that says why it is none (strict: no NaN)."""
    try:
        return json.loads(line.decode("utf-8"), parse_constant=_refuse_constant)
    except (UnicodeDecodeError, ValueError, RecursionError) as exc:
        return exc


def read_records(path: str | os.PathLike[str], *, field: str | None = None) -> list[dict[str, Any]]:
    """The records (JSON objects) of a JSONL file, in order; ``[]`` when the file does not exist.

    Blank lines are skipped; a torn last line (no newline and not a complete record) is ignored.

    Raises
    ------
    RecordFileError
        A line other than the torn last one is not a JSON object (``index``: its line number), or
        ``path`` is a folder or not a regular file.
    """
    path = Path(path)
    field = field or str(path)
    if not path.exists() and not path.is_symlink():
        return []
    _check_file_path(path, field)
    try:
        data = path.read_bytes()
    except OSError as exc:
        raise RecordFileError(field, f"cannot be read ({exc.strerror or exc})") from None
    lines = data.split(b"\n")
    torn = lines.pop()   # b"" when the file ends with a newline
    out = []
    for number, line in enumerate(lines, start=1):
        if not line.strip():
            continue
        obj = _parse(line)
        if not isinstance(obj, dict):
            why = f": {obj}" if isinstance(obj, Exception) else f" (a JSON {type(obj).__name__}, not an object)"
            raise RecordFileError(field, f"line {number} is not a JSON record{why}", number)
        out.append(obj)
    if torn.strip() and isinstance(_parse(torn), dict):   # complete, only its newline missing
        out.append(_parse(torn))
    return out


def repair_torn_tail(path: str | os.PathLike[str], *,
                     log: Callable[[str], None] | None = _note_to_stderr) -> str | None:
    """Make ``path`` end with a newline before anything is appended; returns a note (also sent to
    ``log``: by default ``note: ...`` on stderr), or None when there was nothing to repair (no
    file, empty, or ending with a newline).

    A last line that is a complete JSON object gets its newline; any other last line (a write cut
    off by a kill) is cut off. Not locked: call it while holding the file's lock.
    """
    path = Path(path)
    if not path.is_file():
        return None
    with open(path, "r+b") as fh:
        size = fh.seek(0, os.SEEK_END)
        if size == 0:
            return None
        fh.seek(size - 1)
        if fh.read(1) == b"\n":
            return None
        # Find the start of the last line without reading the whole file.
        start, block = size, 1 << 16
        while start > 0:
            lo = max(0, start - block)
            fh.seek(lo)
            chunk = fh.read(start - lo)
            cut = chunk.rfind(b"\n")
            if cut >= 0:
                start = lo + cut + 1
                break
            start = lo
        fh.seek(start)
        tail = fh.read()
        if tail.strip() and isinstance(_parse(tail), dict):
            fh.seek(size)
            fh.write(b"\n")
            note = f"{path}: the last record had no newline (a write cut off at its end): newline added"
        else:
            fh.truncate(start)
            note = f"{path}: dropped a torn last line of {len(tail)} bytes (a write cut off by a kill)"
        fh.flush()
        os.fsync(fh.fileno())
    if log is not None:
        log(note)
    return note


class OutputLock:
    """An exclusive ``fcntl.flock`` on a lock file that holds the holder's pid.

    Parameters
    ----------
    path : path
        The lock file (created if missing; never removed, so that no second file can appear).
    field : str
        Named in :class:`OutputLockedError`.
    what : str
        Who holds it, for the message (``"bench"``, ``"simulate of method l3gs"``).

    ``flock`` locks belong to an open file: a second :class:`OutputLock` on the same file is
    refused in this process too, and every lock is gone when its process ends (even by SIGKILL).
    Children forked while it is held close their copy (they never write records).
    """

    _held: set[int] = set()
    _fork_hook = False

    def __init__(self, path: str | os.PathLike[str], *, field: str, what: str = "a writer"):
        self.path = Path(path)
        self.field = field
        self.what = what
        self._fh = None

    @classmethod
    def _close_in_child(cls) -> None:
        # dup2 rather than close: the fd number stays valid for the file object that owns it, and
        # the child's reference to the locked open file (which would keep the lock) is gone.
        if not cls._held:
            return
        null = os.open(os.devnull, os.O_RDONLY | os.O_CLOEXEC)
        for fd in list(cls._held):
            try:
                os.dup2(null, fd, inheritable=False)
            except OSError:
                pass
        os.close(null)
        cls._held.clear()

    def acquire(self, *, wait: bool = False) -> "OutputLock":
        """Take the lock; ``wait``: block until it is free instead of refusing.

        Raises
        ------
        OutputLockedError
            ``wait`` is false and another holder has it.
        """
        if self._fh is not None:
            return self
        if not OutputLock._fork_hook:
            os.register_at_fork(after_in_child=OutputLock._close_in_child)
            OutputLock._fork_hook = True
        try:
            fh = open(self.path, "a+", encoding="utf-8")
        except OSError as exc:
            raise RecordFileError(self.field, f"cannot create the lock file {self.path} ({exc.strerror or exc})") \
                from None
        for attempt in (0, 1):
            try:
                fcntl.flock(fh.fileno(), fcntl.LOCK_EX | (0 if wait else fcntl.LOCK_NB))
                break
            except OSError as exc:
                if exc.errno not in (errno.EWOULDBLOCK, errno.EAGAIN, errno.EACCES):
                    fh.close()
                    raise RecordFileError(self.field, f"cannot lock {self.path} ({exc.strerror or exc})") from None
                holder = _read_pid(self.path)
                if attempt == 0 and holder == os.getpid():
                    gc.collect()   # a writer of this process that nothing uses any more closes on collection
                    continue
                fh.close()
                who = f"process {holder}" if holder else "another process"
                here = " (this process)" if holder == os.getpid() else ""
                raise OutputLockedError(self.field, f"{who}{here} is writing here ({self.what}; lock "
                                                    f"{self.path}): wait for it to finish, or choose another "
                                                    "--out") from None
        fh.seek(0)
        fh.truncate()
        fh.write(f"{os.getpid()}\n")
        fh.flush()
        self._fh = fh
        OutputLock._held.add(fh.fileno())
        return self

    def release(self) -> None:
        """Drop the lock (the lock file stays)."""
        if self._fh is None:
            return
        OutputLock._held.discard(self._fh.fileno())
        try:
            fcntl.flock(self._fh.fileno(), fcntl.LOCK_UN)
        finally:
            self._fh.close()
            self._fh = None

    @property
    def held(self) -> bool:
        return self._fh is not None

    def __enter__(self) -> "OutputLock":
        return self.acquire()

    def __exit__(self, *exc: object) -> None:
        self.release()

    def __del__(self) -> None:
        if self._fh is not None:
            OutputLock._held.discard(self._fh.fileno())


def _read_pid(path: Path) -> int | None:
    try:
        return int(path.read_text(encoding="utf-8").split()[0])
    except (OSError, ValueError, IndexError):
        return None


def _write_all(fd: int, data: bytes) -> None:
    view = memoryview(data)
    while view:
        view = view[os.write(fd, view):]


class RecordLog:
    """A JSONL record file opened for appending, by one writer at a time.

    Opening takes the lock (``lock=True``), then either empties the file (``fresh=True``) or
    repairs a torn last line (:func:`repair_torn_tail`, with a note to ``log``).

    Parameters
    ----------
    path : path
        The record file; its folder is created.
    lock : bool
        Hold ``path + LOCK_SUFFIX`` until :meth:`close` (see :class:`OutputLock`).
    fresh : bool
        Start an empty file (the records there are dropped, under the lock).
    what : str
        The writer, for a lock error's message.
    log : callable(str), optional
        Receives notes (a repaired last line); default: ``note: ...`` on stderr.

    Raises
    ------
    OutputLockedError
        Another writer holds the lock.
    RecordFileError
        ``path`` is a folder, or its folder a file.
    """

    def __init__(self, path: str | os.PathLike[str], *, lock: bool = True, fresh: bool = False,
                 what: str = "a writer", log: Callable[[str], None] | None = None, field: str | None = None):
        self.path = Path(path)
        self.field = field or str(self.path)
        self.notes: list[str] = []
        prepare_path(self.path, field=self.field)
        self._lock = OutputLock(self.path.with_name(self.path.name + LOCK_SUFFIX), field=self.field, what=what)
        if lock:
            self._lock.acquire()
        self._fd: int | None = None
        try:
            if fresh:
                self.path.write_bytes(b"")
            else:
                note = repair_torn_tail(self.path, log=log or _note_to_stderr)
                if note:
                    self.notes.append(note)
            self._fd = os.open(self.path, os.O_WRONLY | os.O_APPEND | os.O_CREAT | os.O_CLOEXEC, 0o644)
        except BaseException:
            self._lock.release()
            raise

    def records(self) -> list[dict[str, Any]]:
        """The records in the file now (see :func:`read_records`)."""
        return read_records(self.path, field=self.field)

    def append(self, record: Mapping[str, Any], *, where: str = "record") -> None:
        """Append one record as one line and ``fsync`` it.

        Raises
        ------
        JsonOutputError
            A value of ``record`` has no strict JSON form (nothing is written).
        """
        if self._fd is None:
            raise RecordFileError(self.field, "is closed for writing")
        _write_all(self._fd, (dumps(record, where=where) + "\n").encode("utf-8"))
        os.fsync(self._fd)

    def close(self) -> None:
        """Close the file and release the lock."""
        if self._fd is not None:
            os.close(self._fd)
            self._fd = None
        self._lock.release()

    def __enter__(self) -> "RecordLog":
        return self

    def __exit__(self, *exc: object) -> None:
        self.close()

    def __del__(self) -> None:
        if getattr(self, "_fd", None) is not None:
            os.close(self._fd)
            self._fd = None


def append_record(path: str | os.PathLike[str], record: Mapping[str, Any], *,
                  log: Callable[[str], None] | None = None) -> None:
    """Append one record to ``path`` without taking its lock (for a caller that already holds a
    lock covering it), repairing a torn last line first."""
    with RecordLog(path, lock=False, log=log) as out:
        out.append(record)


def rewrite_records(path: str | os.PathLike[str], records: Iterable[Mapping[str, Any]]) -> None:
    """Replace ``path`` by ``records`` atomically (a temporary file renamed over it, fsynced): a
    crash leaves the old file or the new one, never a mix. Not locked: hold the file's lock."""
    write_atomic(path, "".join(dumps(r, where="record") + "\n" for r in records), fsync=True)
