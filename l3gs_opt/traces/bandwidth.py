"""Bandwidth traces: read, scale to a target mean, cut a window, turn into bytes per slot.

Formats: one throughput value in Mbit/s per line, one line per second (the Lumos5G files
bundled in ``l3gs_opt/data/traces``), or CSV ``time_s,mbps``. Lines that are not numbers are
skipped with one warning that counts them (given only when the file is read; a file that is
refused gives its error alone); a file with no number at all is an error.

The time column of a CSV sets the time base: each sample holds from its time until the next
sample's (the last one for the median spacing), and the trace is resampled to one sample per
whole second, the mean throughput over that second (a 10 Hz trace of N lines gives N / 10
samples; a 1 Hz trace is kept as it is). Times must be finite and increasing.

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

from l3gs_opt.errors import L3gsError
from l3gs_opt.input_files import read_text

__all__ = ["TraceError", "BandwidthTrace", "bundled_traces", "read_bandwidth_trace", "mbps_to_bytes",
           "synthetic_bandwidth", "iter_lines", "MAX_MBPS", "MAX_TRACE_SAMPLES", "MAX_TRACE_FILE_BYTES", "MAX_SLOT_BYTES"]

#: Largest throughput sample read (Mbit/s): 10 Tbit/s, ~5000 x the fastest 5G trace bundled. A
#: larger value is a unit mistake or corruption; refusing it (rather than clipping it) keeps the
#: link honest, and keeps one slot's bytes (1.25e12 per second) far below :data:`MAX_SLOT_BYTES`.
MAX_MBPS = 1e7
#: Most samples in a trace (after resampling to one per second): 11.6 days at 1 Hz.
MAX_TRACE_SAMPLES = 10**6
#: Largest trace file read (bytes): room for MAX_TRACE_SAMPLES CSV lines of ~30 characters.
MAX_TRACE_FILE_BYTES = 32 * 2**20
#: Largest byte count of one slot (2^53: every count is exact in float64 too, as instances require).
MAX_SLOT_BYTES = 2**53


class TraceError(L3gsError, ValueError):
    """A trace file is missing, empty or malformed."""


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

    def scaled(self, target_mean_mbps: float) -> tuple["BandwidthTrace", float]:
        """The trace scaled so its mean is ``target_mean_mbps``; returns it and the factor."""
        mean = float(self.mbps.mean())
        if not (0 < target_mean_mbps <= MAX_MBPS):
            raise TraceError(f"target mean {target_mean_mbps!r} Mbit/s: must be a positive number <= {MAX_MBPS:g}")
        if mean <= 0:
            raise TraceError(f"{self.name}: mean throughput is 0, cannot scale")
        factor = target_mean_mbps / mean
        return BandwidthTrace(self.name, self.mbps * factor, self.sample_s, self.skipped), factor

    def window(self, start: int, length: int) -> "BandwidthTrace":
        """Samples ``start .. start+length-1``; an error if the trace is shorter."""
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


def _trace_error(field: str, message: str) -> TraceError:
    return TraceError(f"{field}: {message}")


def read_bandwidth_trace(path: str | os.PathLike[str]) -> BandwidthTrace:
    """Read a Mbit/s-per-line trace or a ``time_s,mbps`` CSV; a bundled trace's name also works.

    A CSV is resampled to one sample per whole second by its time column (see the module
    docstring); the result always has ``sample_s = 1``.

    Raises
    ------
    TraceError
        Missing or non-regular file, no numeric sample, a negative, non-finite or too large
        sample or time (naming the line and the column), times that do not increase, too many
        samples.
    """
    bundled = bundled_traces()
    if not Path(path).exists() and str(path) in bundled:
        path = bundled[str(path)]
    path = Path(path)
    if not path.exists() and not path.is_symlink():
        raise TraceError(f"{path}: no such trace file (bundled traces: {', '.join(sorted(bundled))})")
    text = read_text(path, _trace_error, field="trace", max_bytes=MAX_TRACE_FILE_BYTES, errors="replace")
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
    if skipped:
        warnings.warn(f"{path}: skipped {skipped} line(s) that are not numbers", stacklevel=2)
    return BandwidthTrace(path.stem, mbps, 1.0, skipped)


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


def mbps_to_bytes(mbps: np.ndarray, slot_s: float = 1.0) -> np.ndarray:
    """Bytes per slot from Mbit/s (1 Mbit = 10**6 bits), rounded down: int64 [N].

    Raises
    ------
    TraceError
        A sample that is negative or not finite, a slot length that is not a positive number, or
        a byte count above :data:`MAX_SLOT_BYTES` (naming the sample).
    """
    if not (isinstance(slot_s, (int, float, np.floating, np.integer)) and 0 < slot_s < math.inf):
        raise TraceError(f"slot_s = {slot_s!r}: must be a positive number of seconds")
    x = np.asarray(mbps, dtype=np.float64)
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
        Number of samples (s), >= 1.
    mean_mbps : float
        Target mean throughput (Mbit/s), > 0.
    variability : float
        Standard deviation of the log-throughput (>= 0; 0 gives a constant trace between outages).
    outage_rate : float
        Probability that an outage starts in a given second, in [0, 1).
    outage_s : (int, int)
        Shortest and longest outage (s), 1 <= lo <= hi.
    correlation : float
        Lag-one correlation of the log-throughput, in [0, 1).
    seed : int

    Raises
    ------
    TraceError
        An argument out of range (named), or a trace that is all outage.
    """
    if not (isinstance(seconds, (int, np.integer)) and seconds >= 1):
        raise TraceError(f"seconds = {seconds!r}: must be an integer >= 1")
    checks = [("mean_mbps", mean_mbps, mean_mbps > 0), ("variability", variability, variability >= 0),
              ("outage_rate", outage_rate, 0 <= outage_rate < 1), ("correlation", correlation, 0 <= correlation < 1)]
    for name, value, ok in checks:
        if not (math.isfinite(value) and ok):
            raise TraceError(f"{name} = {value!r}: out of range (see the docstring)")
    lo, hi = outage_s
    if not (1 <= lo <= hi):
        raise TraceError(f"outage_s = {outage_s!r}: must be (lo, hi) with 1 <= lo <= hi")
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
