"""Viewport and bandwidth predictors (the L3GS paper's section 5) and their error measures.

Viewport: per 6DoF feature (x, y, z and the three angles) a linear regression on the samples of
the history window (``hw_s``, 0.5 s) with each sample's order 0..n-1 as the regressor, extrapolated
to every sample of the prediction window (``pw_s``, 1 s). Angles are re-centred on the first
history sample and wrapped to [-180, 180) before fitting, and wrapped back after, so a turn across
359 -> 1 degrees is a 2 degree step, not a 358 degree jump. Baselines: ``last`` (the last history
sample held), ``oracle`` (the true future).

Bandwidth: the harmonic mean of the last ``window`` samples (one per second); a window holding a
zero sample predicts 0 (the harmonic mean's limit: outages are in the real traces, and a scheduler
should not count on bytes an outage does not deliver). ``robust``: divide by 1 + the largest
relative error of the last ``window`` predictions, as RobustMPC does. Baselines: ``last``, ``oracle``.

Errors are averaged over every sample time that has a full history window, across all predicted
samples of its prediction window that lie inside the log.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from l3gs_opt.errors import L3gsError
from l3gs_opt.traces.poses import PoseTrace

__all__ = ["PredictionError", "wrap_deg", "predict_viewport", "viewport_errors", "predict_bandwidth",
           "bandwidth_errors", "VIEWPORT_METHODS", "BANDWIDTH_METHODS"]

VIEWPORT_METHODS = ("lr", "last", "oracle")
BANDWIDTH_METHODS = ("harmonic", "last", "oracle")


class PredictionError(L3gsError, ValueError):
    """Bad predictor arguments (window lengths, method names) or too short an input."""


def wrap_deg(angle: np.ndarray | float) -> np.ndarray:
    """Angles to [-180, 180) degrees."""
    return (np.asarray(angle, dtype=np.float64) + 180.0) % 360.0 - 180.0


def _windows(rate_hz: float, hw_s: float, pw_s: float, samples: int) -> tuple[int, int]:
    """History and prediction windows in samples (at least 1). A window longer than the log is
    capped at the log's ``samples``: only predicted samples inside the log are scored, so any longer
    window gives the same errors."""
    for name, value in (("hw", hw_s), ("pw", pw_s)):
        if not (isinstance(value, (int, float, np.integer, np.floating)) and 0 < value < math.inf):
            raise PredictionError(f"{name} = {value!r}: must be a finite number of seconds > 0")
    if not rate_hz > 0:
        raise PredictionError("the pose log needs at least two samples to have a rate")
    return tuple(max(1, int(round(min(w * rate_hz, samples)))) for w in (hw_s, pw_s))


def predict_viewport(history: np.ndarray, horizon: int, *, method: str = "lr",
                     future: np.ndarray | None = None) -> np.ndarray:
    """Predict ``horizon`` samples after a ``[n, 6]`` history (x, y, z in m, three angles in deg).

    Returns ``[horizon, 6]``; angles wrapped to [-180, 180). ``future`` (the truth) is needed for
    ``oracle`` only.
    """
    history = np.asarray(history, dtype=np.float64)
    n = len(history)
    if method == "oracle":
        if future is None or len(future) < horizon:
            raise PredictionError("oracle needs the true future samples")
        out = np.array(future[:horizon], dtype=np.float64)
    elif method == "last":
        out = np.repeat(history[-1:], horizon, axis=0)
    elif method == "lr":
        x = np.arange(n, dtype=np.float64)
        xf = np.arange(n, n + horizon, dtype=np.float64)
        y = history.copy()
        base = y[0, 3:].copy()
        y[:, 3:] = wrap_deg(y[:, 3:] - base)  # re-centre angles on the first history sample
        if n == 1:
            out = np.repeat(y[-1:], horizon, axis=0)
        else:
            slope, intercept = np.polyfit(x, y, 1)
            out = intercept[None, :] + slope[None, :] * xf[:, None]
        out[:, 3:] += base
    else:
        raise PredictionError(f"viewport method {method!r} is not one of {', '.join(VIEWPORT_METHODS)}")
    out[:, 3:] = wrap_deg(out[:, 3:])
    return out


@dataclass(frozen=True)
class ViewportErrors:
    mae_position_m: float
    mae_rotation_deg: float
    samples: int
    rate_hz: float

    def to_dict(self) -> dict:
        return {"mae_position_m": self.mae_position_m, "mae_rotation_deg": self.mae_rotation_deg,
                "samples": self.samples, "rate_hz": self.rate_hz}


def viewport_errors(trace: PoseTrace, *, hw_s: float = 0.5, pw_s: float = 1.0, method: str = "lr") -> ViewportErrors:
    """Mean position error (Euclidean, m) and rotation error (wrapped absolute difference averaged
    over the three angles, deg) of a predictor over a pose trace."""
    rate = trace.rate_hz
    feats = trace.features
    n = len(feats)
    h, p = _windows(rate, hw_s, pw_s, n)
    pos_err: list[np.ndarray] = []
    rot_err: list[np.ndarray] = []
    for end in range(h, n):  # predict from samples end-h .. end-1
        m = min(p, n - end)
        if m <= 0:
            break
        truth = feats[end:end + m]
        pred = predict_viewport(feats[end - h:end], m, method=method, future=truth)
        pos_err.append(np.linalg.norm(pred[:, :3] - truth[:, :3], axis=1))
        rot_err.append(np.abs(wrap_deg(pred[:, 3:] - truth[:, 3:])).mean(axis=1))
    if not pos_err:
        raise PredictionError(f"the log has {n} samples: not one full history window of {h} samples and a sample "
                              "after it")
    pe, re_ = np.concatenate(pos_err), np.concatenate(rot_err)
    return ViewportErrors(float(pe.mean()), float(re_.mean()), int(pe.size), rate)


def predict_bandwidth(samples_mbps: np.ndarray, *, window: int = 5, robust: bool = False,
                      method: str = "harmonic") -> np.ndarray:
    """Prediction for every sample ``t`` from the samples before it: ``[N]`` Mbit/s, NaN where the
    history is shorter than ``window`` (``last`` needs one sample, ``oracle`` none)."""
    x = np.asarray(samples_mbps, dtype=np.float64)
    if window < 1:
        raise PredictionError(f"window = {window}: must be >= 1 sample")
    if method not in BANDWIDTH_METHODS:
        raise PredictionError(f"bandwidth method {method!r} is not one of {', '.join(BANDWIDTH_METHODS)}")
    n = len(x)
    pred = np.full(n, np.nan)
    if method == "oracle":
        return x.copy()
    if method == "last":
        pred[1:] = x[:-1]
        return pred
    for t in range(window, n):
        hist = x[t - window:t]
        pred[t] = 0.0 if (hist <= 0).any() else window / np.sum(1.0 / hist)
    if robust:
        raw = pred.copy()
        for t in range(window, n):
            past = [(raw[k], x[k]) for k in range(max(window, t - window), t) if x[k] > 0]
            if past:
                worst = max(abs(pk - xk) / xk for pk, xk in past)
                pred[t] = raw[t] / (1.0 + worst)
    return pred


def bandwidth_errors(samples_mbps: np.ndarray, *, window: int = 5, robust: bool = False,
                     method: str = "harmonic") -> dict:
    """Mean absolute error (Mbit/s) over the samples that have a full window."""
    x = np.asarray(samples_mbps, dtype=np.float64)
    pred = predict_bandwidth(x, window=window, robust=robust, method=method)
    start = window if method == "harmonic" else (1 if method == "last" else 0)
    ok = np.arange(len(x)) >= start
    if not ok.any():
        raise PredictionError(f"the trace has {len(x)} samples: none after a full window of {window}")
    return {"mae_mbps": float(np.mean(np.abs(pred[ok] - x[ok]))), "samples": int(ok.sum())}
