"""Bandwidth traces: read, scale to a target mean, cut a window, turn into bytes per slot.

Formats: one throughput value in Mbit/s per line, one line per second (the Lumos5G files
bundled in ``l3gs_opt/data/traces``), or CSV ``time_s,mbps``. Lines that are not numbers are
skipped with one warning that counts them; a file with no number at all is an error.
"""

from __future__ import annotations

import math
import os
import warnings
from dataclasses import dataclass
from importlib import resources
from pathlib import Path

import numpy as np

from .errors import L3gsError

__all__ = ["TraceError", "BandwidthTrace", "bundled_traces", "read_bandwidth_trace", "mbps_to_bytes",
           "synthetic_bandwidth"]


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
        if not (target_mean_mbps > 0 and math.isfinite(target_mean_mbps)):
            raise TraceError(f"target mean {target_mean_mbps!r} Mbit/s: must be a positive number")
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


def read_bandwidth_trace(path: str | os.PathLike[str]) -> BandwidthTrace:
    """Read a Mbit/s-per-line trace or a ``time_s,mbps`` CSV; a bundled trace's name also works.

    Raises
    ------
    TraceError
        Missing file, no numeric sample, a negative or non-finite sample (naming the line).
    """
    bundled = bundled_traces()
    if not Path(path).exists() and str(path) in bundled:
        path = bundled[str(path)]
    path = Path(path)
    try:
        lines = path.read_text(encoding="utf-8", errors="replace").splitlines()
    except FileNotFoundError:
        raise TraceError(f"{path}: no such trace file (bundled traces: {', '.join(sorted(bundled))})") from None
    except OSError as exc:
        raise TraceError(f"{path}: cannot be read ({exc})") from None
    values: list[float] = []
    times: list[float] = []
    skipped = 0
    for number, line in enumerate(lines, start=1):
        text = line.strip()
        if not text:
            continue
        parts = [p.strip() for p in text.split(",")]
        try:
            if len(parts) == 2:
                t, v = float(parts[0]), float(parts[1])
                times.append(t)
            elif len(parts) == 1:
                v = float(parts[0])
            else:
                raise ValueError
        except ValueError:
            skipped += 1
            continue
        if not math.isfinite(v) or v < 0:
            raise TraceError(f"{path}: line {number}: throughput {v!r} Mbit/s must be finite and >= 0")
        values.append(v)
    if not values:
        raise TraceError(f"{path}: no throughput sample found")
    if skipped:
        warnings.warn(f"{path}: skipped {skipped} line(s) that are not numbers", stacklevel=2)
    sample_s = 1.0
    if times:
        if len(times) != len(values):
            raise TraceError(f"{path}: mixes one-column and time_s,mbps lines")
        steps = np.diff(np.asarray(times))
        if len(steps) and (steps <= 0).any():
            bad = int(np.argmax(steps <= 0)) + 1
            raise TraceError(f"{path}: time_s must increase (sample {bad})")
        if len(steps):
            sample_s = float(np.median(steps))
    return BandwidthTrace(path.stem, np.asarray(values, dtype=np.float64), sample_s, skipped)


def mbps_to_bytes(mbps: np.ndarray, slot_s: float = 1.0) -> np.ndarray:
    """Bytes per slot from Mbit/s (1 Mbit = 10**6 bits), rounded down: int64 [N]."""
    return np.floor(np.asarray(mbps, dtype=np.float64) * 1e6 / 8.0 * slot_s).astype(np.int64)


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
