"""Bandwidth traces: read, scale to a target mean, cut a window, turn into bytes per slot.

Formats (``read_bandwidth_trace(path, format=...)``):

- ``"lumos"``: one throughput value in Mbit/s per line, one line per second (the Lumos5G files
  bundled in ``l3gs_opt/data/traces``), or CSV ``time_s,mbps``. Lines that are not numbers are
  skipped with one warning that counts them (given only when the file is read; a file that is
  refused gives its error alone); a file with no number at all is an error.
- ``"mahimahi"`` and ``"pensieve"``: packet-delivery traces and two-column ``time_s mbps`` traces
  (below); ``"auto"``, the default, tells the formats apart from the content (below).
  :func:`write_mahimahi` writes a trace for ``mm-link``.

The time column of a CSV sets the time base: each sample holds from its time until the next
sample's (the last one for the median spacing), and the trace is resampled to one sample per
whole second, the mean throughput over that second (a 10 Hz trace of N lines gives N / 10
samples; a 1 Hz trace is kept as it is). Times must be finite and increasing.

**Mahimahi** (``mm-link`` packet-delivery traces): one integer a line, a time in milliseconds
from the start; each line is one opportunity to deliver 1500 bytes, so a time repeated k times is
k packets in that millisecond. Times never decrease. ``mm-link`` loops the file with period T =
the last time (and refuses T = 0), so a line at T delivers at the same instant as a line at 0
of the next loop. Resampling: the trace is read in its steady-state loop, every time taken
modulo T; second k counts the opportunities in ``[1000 k, 1000 k + 1000)`` ms and its rate is
``count * 1500 * 8 / 1e6`` Mbit/s. A trace of T >= 1000 ms gives ``floor(T / 1000)`` seconds
(the last partial second, ``T mod 1000`` ms, is dropped, as for a CSV); a shorter one (the
classic one-line ``1`` file is 12 Mbit/s) is unrolled over ``lcm(T, 1000)`` ms, a whole number
of loops and of seconds.

**Pensieve** (``cooked_traces`` of Pensieve and the ABR work that reuses them: FCC broadband,
Norway HSDPA 3G, Belgium/Ghent 4G): two whitespace-separated columns per line, ``time_s mbps``,
time in seconds (float, increasing, usually from 0), throughput in **Mbit/s** (Pensieve's
simulator multiplies it by 1e6 / 8 to get bytes per second). The raw Ghent 4G logs have six
columns (ms since epoch, ms since start, latitude, longitude, bytes received, ms elapsed) and
are refused by name; their throughput is ``bytes * 8 / ms / 1000`` Mbit/s. Resampling: a value
holds from its time until the next one (the last for the median spacing) and each whole second
from the first time gets the time-weighted mean, as for the ``time_s,mbps`` CSV. (Pensieve's own
simulator applies value i to the interval ending at time i, one sample earlier; over a trace the
two differ by a shift of one sample.) Lines that are not numbers (a header) are skipped with the
same warning as Lumos files.

**auto** (:func:`detect_format`), from the data lines (blank lines and lines that are not numbers
set nothing):

1. a comma on any line: ``lumos`` (its ``time_s,mbps`` CSV; unchanged behaviour);
2. any line of exactly two numbers separated by blanks: ``pensieve``, unless one-number lines
   also occur (ambiguous);
3. one number a line: ``lumos``, unless every value is a non-negative integer written without a
   point or exponent, the values never decrease and at least two differ. Such a file is
   ``mahimahi`` when it has at least :data:`MIN_AUTO_MAHIMAHI_LINES` lines, ambiguous otherwise.
   (A throughput trace that never decreases over 100 seconds does not occur; a short one and a
   short packet trace cannot be told apart, so they must be named. A file of one repeated value
   stays ``lumos``, as it always was read.)

Ambiguous content raises :class:`AmbiguousTraceError`.

Limits (refused by name, before anything large is built): a throughput sample above
:data:`MAX_MBPS` Mbit/s, more than :data:`MAX_TRACE_SAMPLES` samples (after resampling), a file
above :data:`MAX_TRACE_FILE_BYTES`, and a slot's byte count above :data:`MAX_SLOT_BYTES` = 2^53
in :func:`mbps_to_bytes` (so every byte count is an exact integer in float64 as well).
"""

from __future__ import annotations

import math
import os
import re
import warnings
from dataclasses import dataclass
from importlib import resources
from pathlib import Path

import numpy as np

from l3gs_opt.checks import (check_count, check_number, check_path, check_seed, field_error, is_real, real_array,
                             shown)
from l3gs_opt.errors import L3gsError
from l3gs_opt.input_files import read_text

__all__ = ["TraceError", "AmbiguousTraceError", "BandwidthTrace", "bundled_traces", "read_bandwidth_trace",
           "mbps_to_bytes", "synthetic_bandwidth", "iter_lines", "TRACE_FORMATS", "detect_format", "write_mahimahi",
           "MAHIMAHI_PACKET_BYTES", "MIN_AUTO_MAHIMAHI_LINES", "MIN_MBPS", "MAX_MBPS", "MAX_TRACE_SAMPLES", "MAX_TRACE_FILE_BYTES",
           "MAX_SLOT_BYTES", "MAX_VARIABILITY"]

#: Largest throughput sample read (Mbit/s): 10 Tbit/s, ~5000 x the fastest 5G trace bundled. A
#: larger value is a unit mistake or corruption; refusing it (rather than clipping it) keeps the
#: link honest, and keeps one slot's bytes (1.25e12 per second) far below :data:`MAX_SLOT_BYTES`.
MAX_MBPS = 1e7
#: Smallest target mean a trace is scaled to (Mbit/s): one bit a second. A smaller target is a unit
#: mistake (bits for Mbit); far below it the scale factor leaves float64's normal range (a
#: subnormal target came back with a mean that missed it) and every slot carries 0 bytes.
MIN_MBPS = 1e-6
#: Most samples in a trace (after resampling to one per second): 11.6 days at 1 Hz.
MAX_TRACE_SAMPLES = 10**6
#: Largest trace file read (bytes): room for MAX_TRACE_SAMPLES CSV lines of ~30 characters.
MAX_TRACE_FILE_BYTES = 32 * 2**20
#: Largest byte count of one slot (2^53: every count is exact in float64 too, as instances require).
MAX_SLOT_BYTES = 2**53
#: Largest ``variability`` of :func:`synthetic_bandwidth` (standard deviation of the natural log of
#: the throughput): 3x the bundled Lumos5G traces' 1.0-1.7. Already at 5 one second of a 600 s
#: trace carries 25-60% of its bytes; and a trace of MAX_TRACE_SAMPLES samples reaches |log| ~ 27,
#: far from float64's overflow of exp at 709 (a 140-sigma draw), so the trace is always finite.
MAX_VARIABILITY = 5.0


#: The values of ``read_bandwidth_trace(..., format=)``.
TRACE_FORMATS = ("auto", "lumos", "mahimahi", "pensieve")


class TraceError(L3gsError, ValueError):
    """A trace file is missing, empty or malformed."""


class AmbiguousTraceError(TraceError):
    """``format="auto"`` cannot tell which format a trace file is in: pass ``format=`` explicitly."""


@dataclass(frozen=True, eq=False)
class BandwidthTrace:
    """Throughput samples of one trace.

    Attributes
    ----------
    name : str
    mbps : float array [N]
        Throughput in Mbit/s, one sample per ``sample_s`` seconds.
    sample_s : float
        1 for every trace read from a file (a CSV is resampled to one sample per second).
    skipped : int
        Lines that were not numbers.
    """

    name: str
    mbps: np.ndarray
    sample_s: float = 1.0
    skipped: int = 0

    def __post_init__(self) -> None:
        if not isinstance(self.name, str):
            raise TraceError(f"name = {shown(self.name)}: must be a string")
        # Float arrays are kept as given (the readers' float64); lists and integer arrays become float64.
        mbps = real_array("mbps", self.mbps, _trace_error)
        if mbps.ndim != 1 or len(mbps) < 1:
            raise TraceError(f"{self.name}: mbps: shape {mbps.shape} must be [N] with N >= 1")
        bad = ~(mbps >= 0) | ~np.isfinite(mbps)
        if bad.any():
            i = int(np.argmax(bad))
            raise TraceError(f"{self.name}: mbps[{i}] = {float(mbps[i])!r}: must be finite and >= 0 Mbit/s")
        object.__setattr__(self, "mbps", mbps)
        object.__setattr__(self, "sample_s", check_number("sample_s", self.sample_s, lambda x: x > 0,
                                                          "a positive number of seconds", _trace_error))
        # A skipped line takes at least one byte of a file no larger than MAX_TRACE_FILE_BYTES.
        object.__setattr__(self, "skipped", check_count("skipped", self.skipped, low=0, high=MAX_TRACE_FILE_BYTES,
                                                                error=_trace_error))

    def scaled(self, target_mean_mbps: float) -> tuple["BandwidthTrace", float]:
        """The trace scaled so its mean is ``target_mean_mbps`` (Mbit/s, in [MIN_MBPS, MAX_MBPS]);
        returns it and the factor."""
        mean = float(self.mbps.mean())
        if not (is_real(target_mean_mbps) and MIN_MBPS <= target_mean_mbps <= MAX_MBPS):
            raise TraceError(f"mbps = {shown(target_mean_mbps)} (the target mean, Mbit/s): must be a positive "
                             f"number in [{MIN_MBPS:g}, {MAX_MBPS:g}] (MIN_MBPS, MAX_MBPS)")
        if mean <= 0:
            raise TraceError(f"{self.name}: mean throughput is 0, cannot scale")
        factor = target_mean_mbps / mean
        return BandwidthTrace(self.name, self.mbps * factor, self.sample_s, self.skipped), factor

    def window(self, start: int, length: int) -> "BandwidthTrace":
        """Samples ``start .. start+length-1``; an error if the trace is shorter."""
        # Integers only: a float would be truncated by a slice, or refused by it with a raw TypeError.
        for field, value in (("start", start), ("length", length)):
            if isinstance(value, bool) or not isinstance(value, (int, np.integer)):
                raise TraceError(f"{self.name}: window {field} = {shown(value)}: must be an integer (samples)")
        if start < 0 or length < 1 or start + length > len(self.mbps):
            raise TraceError(f"{self.name}: window start={start} length={length} does not fit "
                             f"{len(self.mbps)} samples")
        return BandwidthTrace(self.name, self.mbps[start:start + length].copy(), self.sample_s, self.skipped)


def bundled_traces() -> dict[str, Path]:
    """Name -> path of the traces shipped with the package (e.g. ``lumos-throughput-mid-11``)."""
    folder = resources.files("l3gs_opt.data.traces")
    return {Path(str(p)).stem: Path(str(p)) for p in folder.iterdir() if str(p).endswith(".txt")}


_LINE_END = re.compile(r"\r\n|\r|\n")


def iter_lines(text: str, *, block_chars: int = 1 << 20):
    """``(number, line)`` of every line of ``text`` (1-based, split as :meth:`str.splitlines` does),
    a block at a time: a file of millions of short lines is never held as one list of strings."""
    number, start, n = 0, 0, len(text)
    while start < n:
        end = min(start + block_chars, n)
        if end < n:  # cut after the block's last line end (or the first one after the block)
            cut = max(text.rfind("\n", start, end), text.rfind("\r", start, end))
            match = _LINE_END.search(text, cut if cut >= start else end)
            end = match.end() if match else n
        for line in text[start:end].splitlines():
            number += 1
            yield number, line
        start = end


#: The ``error`` of the shared checks (:mod:`l3gs_opt.checks`) and of ``read_text``.
_trace_error = field_error(TraceError)


def read_bandwidth_trace(path: str | os.PathLike[str], *, format: str = "auto") -> BandwidthTrace:
    """Read a bandwidth trace file (a bundled trace's name also works) as Mbit/s per second.

    Parameters
    ----------
    path : path or str
        The trace file, or the name of a bundled trace (e.g. ``lumos-throughput-mid-11``).
    format : {"auto", "lumos", "mahimahi", "pensieve"}
        ``"lumos"``: one Mbit/s value a line, one line a second, or a ``time_s,mbps`` CSV (see the
        module docstring). ``"mahimahi"``: one integer millisecond a line, each line one
        1500-byte delivery opportunity. ``"pensieve"``: ``time_s mbps`` whitespace-separated
        lines (Pensieve's cooked FCC / Norway HSDPA / Belgium 4G traces). ``"auto"`` picks one
        from the content; see :func:`detect_format`.

    Returns
    -------
    BandwidthTrace
        Always one sample per second (``sample_s = 1``): time-stamped formats are resampled to
        whole seconds (the mean throughput over each second).

    Raises
    ------
    TraceError
        Missing or non-regular file, no numeric sample, a negative, non-finite or too large
        sample or time (naming the line and the column), times that do not increase, too many
        samples, an unknown ``format``.
    AmbiguousTraceError
        ``format="auto"`` and the content fits more than one format.
    """
    if not isinstance(format, str) or format not in TRACE_FORMATS:
        raise TraceError(f"format = {shown(format)}: must be one of {', '.join(TRACE_FORMATS)}")
    path = check_path(path, error=_trace_error)
    bundled = bundled_traces()
    if not path.exists() and str(path) in bundled:
        path = bundled[str(path)]
    if not path.exists() and not path.is_symlink():
        raise TraceError(f"{path}: no such trace file (bundled traces: {', '.join(sorted(bundled))})")
    text = read_text(path, _trace_error, field="trace", max_bytes=MAX_TRACE_FILE_BYTES, errors="replace")
    chosen = detect_format(text, path) if format == "auto" else format
    if chosen == "lumos":
        mbps, skipped = _parse_lumos(text, path)
    elif chosen == "mahimahi":
        mbps, skipped = _parse_mahimahi(text, path), 0
    else:
        mbps, skipped = _parse_pensieve(text, path)
    if skipped:
        warnings.warn(f"{path}: skipped {skipped} line(s) that are not numbers", stacklevel=2)
    return BandwidthTrace(path.stem, mbps, 1.0, skipped)


def _parse_lumos(text: str, path: Path) -> tuple[np.ndarray, int]:
    """Mbit/s per second of a Lumos-style file (one column, or ``time_s,mbps`` CSV) and the
    number of lines skipped as not numbers."""
    values: list[float] = []
    times: list[float] = []
    skipped = 0
    for number, line in iter_lines(text):
        text_ = line.strip()
        if not text_ or text_.count(",") > 1:
            skipped += bool(text_)
            continue
        parts = [p.strip() for p in text_.split(",")]
        try:
            if len(parts) == 2:
                t, v = float(parts[0]), float(parts[1])
            elif len(parts) == 1:
                t, v = None, float(parts[0])
            else:
                raise ValueError
        except ValueError:
            skipped += 1
            continue
        column = "mbps" if t is not None else "throughput"
        if not (0 <= v <= MAX_MBPS):
            raise TraceError(f"{path}: line {number}: {column} {v!r} Mbit/s must be finite, >= 0 and "
                             f"<= {MAX_MBPS:g} (MAX_MBPS)")
        if values and (t is None) != (not times):
            raise TraceError(f"{path}: line {number}: mixes one-column and time_s,mbps lines")
        if t is not None:
            if not math.isfinite(t):
                raise TraceError(f"{path}: line {number}: time_s {t!r} must be finite")
            if times and t <= times[-1]:
                raise TraceError(f"{path}: line {number}: time_s {t!r} must increase (previous {times[-1]!r})")
            times.append(t)
        values.append(v)
        if len(values) > MAX_TRACE_SAMPLES:
            raise TraceError(f"{path}: line {number}: more than {MAX_TRACE_SAMPLES:,} samples (MAX_TRACE_SAMPLES)")
    if not values:
        raise TraceError(f"{path}: no throughput sample found")
    mbps = np.asarray(values, dtype=np.float64)
    if times:
        mbps = _per_second(np.asarray(times, dtype=np.float64), mbps, path)
    return mbps, skipped


def _per_second(times: np.ndarray, mbps: np.ndarray, path: Path) -> np.ndarray:
    """Samples at increasing ``times`` (s), each holding until the next one (the last for the median
    spacing), averaged over every whole second from the first time: ``[floor(duration)]`` Mbit/s."""
    t = times - times[0]
    last = float(np.median(np.diff(t))) if len(t) > 1 else 1.0
    ends = np.append(t[1:], t[-1] + last)
    duration = float(ends[-1])
    if not math.isfinite(duration) or duration > MAX_TRACE_SAMPLES:
        raise TraceError(f"{path}: time_s spans {duration!r} s, more than {MAX_TRACE_SAMPLES:,} one-second "
                         f"samples (MAX_TRACE_SAMPLES)")
    seconds = int(math.floor(duration + 1e-9))
    if seconds < 1:
        raise TraceError(f"{path}: time_s spans {duration!r} s, less than one whole second")
    # Every (sample, second) overlap: sample i covers [t_i, ends_i), second k covers [k, k + 1).
    first = np.floor(t).astype(np.int64)
    count = np.maximum(np.ceil(ends).astype(np.int64) - first, 1)
    sample = np.repeat(np.arange(len(t)), count)
    second = first[sample] + np.arange(int(count.sum())) - np.repeat(np.cumsum(count) - count, count)
    overlap = np.minimum(ends[sample], second + 1.0) - np.maximum(t[sample], second)
    keep = (second < seconds) & (overlap > 0)
    return np.bincount(second[keep], weights=mbps[sample[keep]] * overlap[keep], minlength=seconds)[:seconds]


# ------------------------------------------------------------------------- Mahimahi and Pensieve
#: Bytes one Mahimahi delivery opportunity carries (``mm-link``: one MTU).
MAHIMAHI_PACKET_BYTES = 1500
#: Mbit/s of one opportunity per second: 1500 * 8 / 1e6.
_PACKET_MBIT = MAHIMAHI_PACKET_BYTES * 8 / 1e6
#: Fewest lines for ``format="auto"`` to call a never-decreasing integer column a Mahimahi trace
#: (100 s of never-decreasing throughput is not a measured trace; a 1 Mbit/s packet trace has
#: 100 lines in 1.2 s).
MIN_AUTO_MAHIMAHI_LINES = 100
_UINT = re.compile(r"\d+")
#: Integers above this are only ever refused as too large; capping them here keeps Python from
#: converting a thousands-digit line (it refuses past 4300 digits with a bare ValueError).
_UINT_CAP = 10**30


def _uint(token: str) -> int:
    """The value of a string of digits, at most :data:`_UINT_CAP`."""
    digits = token.lstrip("0")
    return _UINT_CAP if len(digits) > len(str(_UINT_CAP)) else min(int(digits or "0"), _UINT_CAP)
_FLOAT_TOKEN = re.compile(r"[-+]?(?:\d+\.?\d*|\.\d+)(?:[eE][-+]?\d+)?|[-+]?(?:inf|nan)", re.IGNORECASE)


def detect_format(text: str, path: str | os.PathLike[str] = "trace") -> str:
    """``"lumos"``, ``"mahimahi"`` or ``"pensieve"`` for a trace file's text (rules in the module
    docstring).

    Raises
    ------
    AmbiguousTraceError
        Mixed one- and two-number lines, or a short never-decreasing integer column.
    """
    one = two = 0
    first_one = first_two = None
    integers: list[int] = []
    all_uint = True
    for number, line in iter_lines(text):
        s = line.strip()
        if not s:
            continue
        if "," in s:
            return "lumos"
        tokens = s.split()
        if not all(_FLOAT_TOKEN.fullmatch(t) for t in tokens):
            continue
        if len(tokens) == 2:
            two += 1
            first_two = first_two or number
        elif len(tokens) == 1:
            one += 1
            first_one = first_one or number
            if all_uint:
                if _UINT.fullmatch(tokens[0]):
                    integers.append(_uint(tokens[0]))
                else:
                    all_uint = False
    if two:
        if one:
            raise AmbiguousTraceError(
                f"{path}: format='auto' cannot tell the format: line {first_one} has one number (a Lumos or "
                f"Mahimahi line) and line {first_two} two (a Pensieve 'time_s mbps' line); pass format=")
        return "pensieve"
    if not (all_uint and len(integers) >= 2):
        return "lumos"
    values = np.asarray(integers, dtype=object if max(integers) >= 2**62 else np.int64)
    steps = np.diff(values)
    if (steps < 0).any() or not (steps > 0).any():
        return "lumos"
    if len(integers) >= MIN_AUTO_MAHIMAHI_LINES:
        return "mahimahi"
    raise AmbiguousTraceError(
        f"{path}: format='auto' cannot tell the format: {len(integers)} never-decreasing integer lines fit both a "
        f"Lumos trace (Mbit/s per second) and a Mahimahi trace (ms per 1500-byte packet); pass "
        f"format='lumos' or format='mahimahi'")


def _parse_mahimahi(text: str, path: str | os.PathLike[str] = "trace") -> np.ndarray:
    """Per-second Mbit/s ``[S]`` of a Mahimahi packet-delivery trace (resampling in the module
    docstring).

    Raises
    ------
    TraceError
        A line that is not one non-negative integer, a time below the previous one (naming the
        line and column 1, ``timestamp_ms``), no line, a last time of 0, more seconds than
        ``MAX_TRACE_SAMPLES``.
    """
    times: list[int] = []
    previous = -1
    for number, line in iter_lines(text):
        s = line.strip()
        if not s:
            continue
        if not _UINT.fullmatch(s):
            what = "has more than one column" if len(s.split()) > 1 else "is not a non-negative integer"
            raise TraceError(f"{path}: line {number}: column 1 (timestamp_ms) {s[:40]!r} {what}: a Mahimahi "
                             f"trace has one integer millisecond a line")
        t = _uint(s)
        if t < previous:
            raise TraceError(f"{path}: line {number}: column 1 (timestamp_ms) {t} must not decrease "
                             f"(previous {previous})")
        if t > 1000 * MAX_TRACE_SAMPLES:
            raise TraceError(f"{path}: line {number}: column 1 (timestamp_ms) {t} ms is more than "
                             f"{MAX_TRACE_SAMPLES:,} one-second samples (MAX_TRACE_SAMPLES)")
        times.append(t)
        previous = t
    if not times:
        raise TraceError(f"{path}: no delivery opportunity found")
    period = times[-1]
    if period == 0:
        raise TraceError(f"{path}: every time is 0 ms: a Mahimahi trace must last a nonzero time "
                         f"(its loop period is its last time)")
    t = np.asarray(times, dtype=np.int64) % period
    if period >= 1000:
        seconds = period // 1000
        counts = np.bincount(t // 1000, minlength=seconds + 1)[:seconds]
    else:
        span = period * 1000 // math.gcd(period, 1000)  # lcm(period, 1000) ms: whole loops, whole seconds
        per_ms = np.bincount(t, minlength=period)
        counts = np.tile(per_ms, span // period).reshape(-1, 1000).sum(axis=1)
    mbps = counts * _PACKET_MBIT
    if mbps.max() > MAX_MBPS:
        k = int(np.argmax(mbps))
        raise TraceError(f"{path}: second {k}: {mbps[k]:.6g} Mbit/s is more than {MAX_MBPS:g} (MAX_MBPS)")
    return mbps.astype(np.float64)


def _parse_pensieve(text: str, path: str | os.PathLike[str] = "trace") -> tuple[np.ndarray, int]:
    """Per-second Mbit/s ``[S]`` of a ``time_s mbps`` trace and the number of lines skipped as not
    numbers (resampling in the module docstring).

    Raises
    ------
    TraceError
        A line of numbers with other than two columns (the raw six-column Ghent 4G log named), a
        non-finite time or a time that does not increase (column 1, ``time_s``), a negative,
        non-finite or too large throughput (column 2, ``mbps``), no sample, less than a second.
    """
    times: list[float] = []
    values: list[float] = []
    skipped = 0
    for number, line in iter_lines(text):
        tokens = line.split()
        if not tokens:
            continue
        if not all(_FLOAT_TOKEN.fullmatch(t) for t in tokens):
            skipped += 1
            continue
        if len(tokens) != 2:
            hint = (" (six columns: a raw Ghent 4G/LTE log, 'epoch_ms start_ms lat lon bytes ms'; Mbit/s = "
                    "bytes * 8 / ms / 1000)") if len(tokens) == 6 else ""
            raise TraceError(f"{path}: line {number}: {len(tokens)} columns, a Pensieve trace has two: "
                             f"time_s mbps{hint}")
        t, v = float(tokens[0]), float(tokens[1])
        if not math.isfinite(t):
            raise TraceError(f"{path}: line {number}: column 1 (time_s) {t!r} must be finite")
        if times and t <= times[-1]:
            raise TraceError(f"{path}: line {number}: column 1 (time_s) {t!r} must increase (previous {times[-1]!r})")
        if not (0 <= v <= MAX_MBPS):
            raise TraceError(f"{path}: line {number}: column 2 (mbps) {v!r} Mbit/s must be finite, >= 0 and "
                             f"<= {MAX_MBPS:g} (MAX_MBPS)")
        times.append(t)
        values.append(v)
        if len(values) > MAX_TRACE_SAMPLES:
            raise TraceError(f"{path}: line {number}: more than {MAX_TRACE_SAMPLES:,} samples (MAX_TRACE_SAMPLES)")
    if not values:
        raise TraceError(f"{path}: no 'time_s mbps' sample found")
    mbps = _per_second(np.asarray(times, dtype=np.float64), np.asarray(values, dtype=np.float64), Path(path))
    return mbps, skipped


def write_mahimahi(trace: BandwidthTrace, path: str | os.PathLike[str]) -> Path:
    """Write ``trace`` as a Mahimahi packet-delivery trace (for ``mm-link``, or to read back).

    Second k carries ``n_k`` 1500-byte opportunities at ms ``1000 k + floor(j * 1000 / n_k)``,
    ``j = 0 .. n_k - 1``; ``n_k`` is the whole packets of the running total, so the rounding
    never accumulates (every prefix of the written trace is within one packet, 0.012 Mbit/s x 1 s,
    of the original). Mahimahi's loop period is the last time, so second 0's first opportunity is
    written at ``1000 S`` ms (S = the trace's seconds), the same instant of the next loop; when
    second 0 has no packet, one is added there (0.012 Mbit/s) to mark the period. Reading the
    file back with ``format="mahimahi"`` gives ``n_k * 0.012`` Mbit/s for every second.

    Parameters
    ----------
    trace : BandwidthTrace
        One sample a second (``sample_s = 1``), Mbit/s.
    path : path

    Raises
    ------
    TraceError
        ``sample_s`` other than 1, or a sample that is negative or not finite (named).
    """
    if trace.sample_s != 1.0:
        raise TraceError(f"{trace.name}: sample_s = {trace.sample_s!r}: write_mahimahi needs one sample a second")
    mbps = np.asarray(trace.mbps, dtype=np.float64)
    bad = ~(mbps >= 0) | ~np.isfinite(mbps)
    if bad.any():
        i = int(np.argmax(bad))
        raise TraceError(f"{trace.name}: mbps[{i}] = {float(mbps[i])!r}: must be finite and >= 0 Mbit/s")
    # A tiny relative slack so that 0.012 * k Mbit/s (inexact in binary) rounds to k packets.
    total = np.floor(np.cumsum(mbps) / _PACKET_MBIT * (1 + 1e-12) + 1e-9).astype(np.int64)
    counts = np.diff(np.concatenate([[0], total]))
    if len(counts) and counts[0] == 0:
        counts[0] = 1
    second = np.repeat(np.arange(len(counts), dtype=np.int64), counts)
    j = np.arange(len(second), dtype=np.int64) - np.repeat(np.cumsum(counts) - counts, counts)
    ms = 1000 * second + (j * 1000) // np.repeat(counts, counts)
    if len(ms):
        ms[0] = 1000 * len(counts)  # second 0's first packet, at the period (see the docstring)
        ms = np.sort(ms)
    path = Path(path)
    path.write_text("".join(f"{t}\n" for t in ms.tolist()), encoding="ascii")
    return path


def mbps_to_bytes(mbps: np.ndarray, slot_s: float = 1.0) -> np.ndarray:
    """Bytes per slot from Mbit/s (1 Mbit = 10**6 bits), rounded down: int64 [N].

    Raises
    ------
    TraceError
        ``mbps`` that is not a one-dimensional sequence of numbers (bools and strings included), a
        sample that is negative or not finite, a slot length that is not a positive number, or a
        byte count above :data:`MAX_SLOT_BYTES` (naming the sample).
    """
    slot_s = check_number("slot_s", slot_s, lambda s: s > 0, "a positive number of seconds", _trace_error)
    x = real_array("mbps", mbps, _trace_error).astype(np.float64, copy=False)
    if x.ndim != 1:
        raise TraceError(f"mbps: shape {x.shape} must be [N] (one Mbit/s value per slot)")
    bad = ~(x >= 0) | ~np.isfinite(x)
    if bad.any():
        i = int(np.argmax(bad))
        raise TraceError(f"mbps[{i}] = {float(x.flat[i])!r}: must be finite and >= 0 Mbit/s")
    with np.errstate(over="ignore"):  # an overflow is inf, refused just below
        out = np.floor(x * 1e6 / 8.0 * slot_s)
    over = ~(out <= MAX_SLOT_BYTES)
    if over.any():
        i = int(np.argmax(over))
        raise TraceError(f"mbps[{i}] = {float(x.flat[i])!r} Mbit/s over a {slot_s!r} s slot: {out.flat[i]:.4g} bytes, more "
                         f"than 2^53 (MAX_SLOT_BYTES)")
    return out.astype(np.int64)


def synthetic_bandwidth(seconds: int = 60, mean_mbps: float = 11.8, *, variability: float = 0.5,
                        outage_rate: float = 0.02, outage_s: tuple[int, int] = (1, 4), correlation: float = 0.8,
                        seed: int = 0) -> BandwidthTrace:
    """A synthetic throughput trace (one sample per second) with fades and outages.

    The log-throughput is an AR(1) process ``g[k] = correlation * g[k-1] + e[k]`` with
    stationary standard deviation ``variability``, so throughput fades last a few seconds as in the
    Lumos5G traces; outages (runs of zero samples, lengths uniform in ``outage_s`` seconds) start
    in each second with probability ``outage_rate``. The trace is then scaled so that its mean,
    outages included, is ``mean_mbps``.

    Parameters
    ----------
    seconds : int
        Number of samples (s), 1 .. :data:`MAX_TRACE_SAMPLES` (the readers' limit).
    mean_mbps : float
        Target mean throughput (Mbit/s), in [:data:`MIN_MBPS`, :data:`MAX_MBPS`].
    variability : float
        Standard deviation of the natural log of the throughput, in [0, :data:`MAX_VARIABILITY`]
        (0 gives a constant trace between outages).
    outage_rate : float
        Probability that an outage starts in a given second, in [0, 1).
    outage_s : (int, int)
        Shortest and longest outage (s), integers with 1 <= lo <= hi <= :data:`MAX_TRACE_SAMPLES`.
    correlation : float
        Lag-one correlation of the log-throughput, in [0, 1).
    seed : int
        >= 0.

    Raises
    ------
    TraceError
        An argument of the wrong type or out of range (named), or a trace that is all outage.
    """
    # The cap bounds the per-second Python loop below (~2 s at the cap) and the arrays it fills.
    seconds = check_count("seconds", seconds, high=MAX_TRACE_SAMPLES, error=_trace_error)
    mean_mbps = check_number("mean_mbps", mean_mbps, lambda x: MIN_MBPS <= x <= MAX_MBPS,
                             f"a number in [{MIN_MBPS:g}, {MAX_MBPS:g}] Mbit/s (MIN_MBPS, MAX_MBPS)", _trace_error)
    # A documented cap rather than a finiteness check after exp: well below overflow (variability
    # ~100) one sample already carries nearly the whole trace, which no finite check would catch.
    variability = check_number("variability", variability, lambda x: 0 <= x <= MAX_VARIABILITY,
                               f"a number in [0, {MAX_VARIABILITY:g}] (MAX_VARIABILITY)", _trace_error)
    outage_rate = check_number("outage_rate", outage_rate, lambda x: 0 <= x < 1, "a number in [0, 1)", _trace_error)
    correlation = check_number("correlation", correlation, lambda x: 0 <= x < 1, "a number in [0, 1)", _trace_error)
    want = f"a pair (lo, hi) of integers with 1 <= lo <= hi <= {MAX_TRACE_SAMPLES} (MAX_TRACE_SAMPLES)"
    if not (isinstance(outage_s, (tuple, list)) and len(outage_s) == 2
            and all(isinstance(v, (int, np.integer)) and not isinstance(v, bool) for v in outage_s)
            and 1 <= outage_s[0] <= outage_s[1] <= MAX_TRACE_SAMPLES):
        raise TraceError(f"outage_s = {shown(outage_s)}: must be {want}")
    lo, hi = int(outage_s[0]), int(outage_s[1])
    seed = check_seed(seed, error=_trace_error)
    rng = np.random.default_rng(seed)
    innovation = variability * math.sqrt(1.0 - correlation ** 2)
    g = np.empty(seconds)
    g[0] = rng.normal(0.0, variability) if variability > 0 else 0.0
    for k in range(1, seconds):
        g[k] = correlation * g[k - 1] + rng.normal(0.0, innovation)
    mbps = np.exp(g)
    k = 0
    while k < seconds:
        if rng.random() < outage_rate:
            length = int(rng.integers(lo, hi + 1))
            mbps[k:k + length] = 0.0
            k += length
        else:
            k += 1
    if not mbps.any():
        raise TraceError(f"synthetic trace (seed {seed}) is all outage: lower outage_rate")
    trace = BandwidthTrace(f"synthetic-s{seed}", mbps)
    return trace.scaled(mean_mbps)[0]
