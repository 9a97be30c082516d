"""Viewer poses: headset logs, camera-path files, synthetic paths, and the pose -> camera mapping.

Headset logs have one line per sample::

    2024-06-20 17:48:42, Head Position: (0.00, 1.49, 0.52), Head Rotation: (3.92, 351.06, 359.03), ...

positions in metres (y up), rotations as Euler angles in degrees; timestamps have one-second
resolution with many lines per second, so sub-second times are inferred by spreading each second's
lines evenly over it (line k of n in second s is at ``s + k / n``). Leading lines whose head
position and rotation are all zero (the headset not yet tracking) are dropped. Lines that do not
parse are skipped with one warning that counts them.
"""

from __future__ import annotations

import math
import os
import re
import warnings
from dataclasses import dataclass
from datetime import datetime
from pathlib import Path

import numpy as np

from .errors import L3gsError

__all__ = ["PoseError", "PoseTrace", "PoseMapping", "read_pose_log", "write_pose_log", "read_camera_path",
           "write_camera_path", "synthetic_poses", "euler_to_matrix"]


class PoseError(L3gsError, ValueError):
    """A pose log or camera path is missing, empty or malformed."""


@dataclass(frozen=True, eq=False)
class PoseTrace:
    """Head poses over time.

    Attributes
    ----------
    time_s : float array [N]
        Seconds from the first kept sample.
    position : float array [N, 3]
        Metres, in the log's frame (y up).
    rotation_deg : float array [N, 3]
        Euler angles in degrees (x, y, z as logged).
    skipped : int
        Lines that did not parse.
    """

    time_s: np.ndarray
    position: np.ndarray
    rotation_deg: np.ndarray
    skipped: int = 0

    def __post_init__(self) -> None:
        n = len(self.time_s)
        if self.position.shape != (n, 3) or self.rotation_deg.shape != (n, 3):
            raise PoseError(f"pose arrays disagree: time {n}, position {self.position.shape}, "
                            f"rotation {self.rotation_deg.shape}")

    @property
    def rate_hz(self) -> float:
        """Samples per second (median spacing)."""
        if len(self.time_s) < 2:
            return 0.0
        return float(1.0 / np.median(np.diff(self.time_s)))

    @property
    def features(self) -> np.ndarray:
        """``[N, 6]``: x, y, z (m) and the three angles (deg)."""
        return np.concatenate([self.position, self.rotation_deg], axis=1)


_NUM = r"(-?\d+(?:\.\d*)?(?:[eE][-+]?\d+)?)"
_TRIPLE = rf"\(\s*{_NUM}\s*,\s*{_NUM}\s*,\s*{_NUM}\s*\)"
_LINE = re.compile(rf"^\s*(\d{{4}}-\d\d-\d\d \d\d:\d\d:\d\d(?:\.\d+)?)\s*,\s*Head Position:\s*{_TRIPLE}\s*,"
                   rf"\s*Head Rotation:\s*{_TRIPLE}")


def read_pose_log(path: str | os.PathLike[str]) -> PoseTrace:
    """Parse a headset log (see the module docstring).

    Raises
    ------
    PoseError
        Missing file, or no parsable line after the leading not-tracking lines.
    """
    path = Path(path)
    try:
        lines = path.read_text(encoding="utf-8", errors="replace").splitlines()
    except FileNotFoundError:
        raise PoseError(f"{path}: no such pose log") from None
    except OSError as exc:
        raise PoseError(f"{path}: cannot be read ({exc})") from None
    stamps: list[float] = []
    values: list[list[float]] = []
    skipped = 0
    for line in lines:
        if not line.strip():
            continue
        m = _LINE.match(line)
        if not m:
            skipped += 1
            continue
        stamp = m.group(1)
        try:
            when = datetime.fromisoformat(stamp).timestamp()
        except ValueError:
            skipped += 1
            continue
        nums = [float(g) for g in m.groups()[1:]]
        if not all(math.isfinite(v) for v in nums):
            skipped += 1
            continue
        stamps.append(when)
        values.append(nums)
    if skipped:
        warnings.warn(f"{path}: skipped {skipped} line(s) that are not pose samples", stacklevel=2)
    first = next((i for i, v in enumerate(values) if any(x != 0.0 for x in v)), None)
    if first is None:
        raise PoseError(f"{path}: no tracked pose sample found")
    stamps, values = stamps[first:], values[first:]
    raw = np.asarray(stamps)
    if (np.diff(raw) < 0).any():
        bad = int(np.argmax(np.diff(raw) < 0)) + 1
        raise PoseError(f"{path}: timestamps go backwards at sample {bad + first}")
    # Spread each second's lines evenly over it.
    times = np.empty(len(raw))
    start = 0
    while start < len(raw):
        end = start
        while end < len(raw) and raw[end] == raw[start]:
            end += 1
        count = end - start
        times[start:end] = raw[start] + np.arange(count) / count
        start = end
    arr = np.asarray(values)
    return PoseTrace(time_s=times - times[0], position=arr[:, :3], rotation_deg=arr[:, 3:], skipped=skipped)


def write_pose_log(trace: PoseTrace, path: str | os.PathLike[str], *, start: float = 1_718_900_000.0) -> Path:
    """Write a headset log (controllers logged as zeros); times are rounded down to whole seconds."""
    path = Path(path)
    out = []
    for t, p, r in zip(trace.time_s, trace.position, trace.rotation_deg):
        stamp = datetime.fromtimestamp(int(start + t)).strftime("%Y-%m-%d %H:%M:%S")
        zero = "(0.00, 0.00, 0.00)"
        out.append(f"{stamp}, Head Position: ({p[0]:.4f}, {p[1]:.4f}, {p[2]:.4f}), "
                   f"Head Rotation: ({r[0] % 360:.4f}, {r[1] % 360:.4f}, {r[2] % 360:.4f}), "
                   f"Left Controller Position: {zero}, Left Controller Rotation: {zero}, "
                   f"Right Controller Position: {zero}, Right Controller Rotation: {zero}")
    path.write_text("\n".join(out) + "\n", encoding="utf-8")
    return path


def _axis_rotation(axis: str, deg: np.ndarray) -> np.ndarray:
    a = np.radians(deg)
    c, s = np.cos(a), np.sin(a)
    one, zero = np.ones_like(a), np.zeros_like(a)
    if axis == "x":
        rows = [[one, zero, zero], [zero, c, -s], [zero, s, c]]
    elif axis == "y":
        rows = [[c, zero, s], [zero, one, zero], [-s, zero, c]]
    else:
        rows = [[c, -s, zero], [s, c, zero], [zero, zero, one]]
    return np.moveaxis(np.array(rows), [0, 1], [-2, -1])


def euler_to_matrix(angles_deg: np.ndarray, order: str = "ZXY") -> np.ndarray:
    """``[..., 3]`` angles (about x, y, z, degrees) -> ``[..., 3, 3]`` rotation matrices.

    ``order`` lists the axes in the order the rotations are applied to a vector (extrinsic):
    ``"ZXY"`` (Unity's convention) is ``R = Ry @ Rx @ Rz``.
    """
    angles_deg = np.asarray(angles_deg, dtype=np.float64)
    index = {"x": 0, "y": 1, "z": 2}
    R = np.broadcast_to(np.eye(3), angles_deg.shape[:-1] + (3, 3)).copy()
    for axis in order.lower():
        R = _axis_rotation(axis, angles_deg[..., index[axis]]) @ R
    return R


@dataclass(frozen=True)
class PoseMapping:
    """How a logged head pose becomes the renderer's OpenCV ``world_to_camera``.

    The log's frame is Unity-like: x right, y up, z forward, left-handed; a camera looks along its
    +z with y up. The renderer's camera looks along +z with y *down* (OpenCV). With ``W`` =
    ``world_from_log`` (3x3) and ``R`` the logged rotation (``euler_order``), the camera-to-world
    rotation is ``W @ R @ diag(1, -1, 1)`` and the camera centre ``scale * W @ p + offset``.
    ``W`` must flip handedness (determinant -1). The default ``W = diag(1, -1, 1)`` makes the
    world right-handed with y down, like OpenCV; pass another ``W`` (e.g. one that maps the log's
    y-up to a z-up scene's z) to match a scene's frame.
    """

    world_from_log: tuple[tuple[float, ...], ...] = ((1.0, 0.0, 0.0), (0.0, -1.0, 0.0), (0.0, 0.0, 1.0))
    euler_order: str = "ZXY"
    scale: float = 1.0
    offset: tuple[float, float, float] = (0.0, 0.0, 0.0)

    def __post_init__(self) -> None:
        W = np.asarray(self.world_from_log, dtype=np.float64)
        if W.shape != (3, 3) or not np.allclose(W @ W.T, np.eye(3), atol=1e-9):
            raise PoseError("world_from_log: must be a 3x3 orthogonal matrix")
        if np.linalg.det(W) > 0:
            raise PoseError("world_from_log: must have determinant -1: the log's frame is left-handed and the "
                            "renderer's world is right-handed, so the map must flip handedness")
        if sorted(self.euler_order.lower()) != ["x", "y", "z"]:
            raise PoseError(f"euler_order {self.euler_order!r}: must be a permutation of XYZ")
        if not (self.scale > 0 and math.isfinite(self.scale)):
            raise PoseError(f"scale {self.scale!r}: must be a positive number")

    def world_to_camera(self, position: np.ndarray, rotation_deg: np.ndarray) -> np.ndarray:
        """``[N, 3]`` positions and ``[N, 3]`` angles -> ``[N, 4, 4]`` world-to-camera matrices."""
        W = np.asarray(self.world_from_log, dtype=np.float64)
        flip = np.diag([1.0, -1.0, 1.0])
        R_cw = W @ euler_to_matrix(rotation_deg, self.euler_order) @ flip  # det(W) = det(flip) = -1: proper
        centre = self.scale * np.asarray(position, dtype=np.float64) @ W.T + np.asarray(self.offset)
        out = np.zeros(np.shape(position)[:-1] + (4, 4))
        R_wc = np.swapaxes(R_cw, -1, -2)
        out[..., :3, :3] = R_wc
        out[..., :3, 3] = -(R_wc @ centre[..., None])[..., 0]
        out[..., 3, 3] = 1.0
        return out


def read_camera_path(path: str | os.PathLike[str]) -> np.ndarray:
    """Camera path file: 4x4 world-to-camera matrices, 4 rows each, blank line between -> ``[N, 4, 4]``."""
    path = Path(path)
    try:
        text = path.read_text(encoding="utf-8")
    except FileNotFoundError:
        raise PoseError(f"{path}: no such camera path") from None
    blocks = [b for b in re.split(r"\n\s*\n", text.strip()) if b.strip()]
    if not blocks:
        raise PoseError(f"{path}: no matrix found")
    mats = []
    for k, block in enumerate(blocks):
        rows = [r.split() for r in block.strip().splitlines()]
        try:
            m = np.array([[float(v) for v in row] for row in rows])
        except ValueError:
            raise PoseError(f"{path}: matrix {k}: entries must be numbers") from None
        if m.shape != (4, 4) or not np.isfinite(m).all():
            raise PoseError(f"{path}: matrix {k}: expected 4 rows of 4 finite numbers, got shape {m.shape}")
        mats.append(m)
    return np.stack(mats)


def write_camera_path(matrices: np.ndarray, path: str | os.PathLike[str]) -> Path:
    path = Path(path)
    path.write_text("\n\n".join("\n".join(" ".join(f"{v:.9g}" for v in row) for row in m) for m in matrices) + "\n",
                    encoding="utf-8")
    return path


def synthetic_poses(kind: str = "walk", *, seconds: float = 60.0, rate_hz: float = 30.0, seed: int = 0) -> PoseTrace:
    """Synthetic head motion: ``walk`` (slow walk, gentle head turns), ``orbit`` (circling a
    point while looking at it), ``fast_turns`` (standing, quick 60-120 degree head turns)."""
    rng = np.random.default_rng(seed)
    n = int(round(seconds * rate_hz))
    t = np.arange(n) / rate_hz
    if kind == "walk":
        heading = np.cumsum(rng.normal(0, 0.6, n)) / rate_hz * 10
        speed = 0.6
        x = np.cumsum(speed * np.sin(np.radians(heading))) / rate_hz
        z = np.cumsum(speed * np.cos(np.radians(heading))) / rate_hz
        pos = np.stack([x, 1.6 + 0.02 * np.sin(2 * np.pi * 1.8 * t), z], axis=1)
        rot = np.stack([5 * np.sin(0.3 * t), heading + 15 * np.sin(0.5 * t), 2 * np.sin(0.7 * t)], axis=1)
    elif kind == "orbit":
        ang = 360.0 * t / max(seconds, 1e-9)
        pos = np.stack([3 * np.sin(np.radians(ang)), np.full(n, 1.6), -3 * np.cos(np.radians(ang))], axis=1)
        rot = np.stack([np.full(n, 10.0), -ang, np.zeros(n)], axis=1)
    elif kind == "fast_turns":
        targets = np.cumsum(rng.choice([-1, 1], size=int(seconds) + 2) * rng.uniform(60, 120, int(seconds) + 2))
        yaw = np.interp(t, np.arange(len(targets)) * 2.0, targets)
        pos = np.stack([np.zeros(n), np.full(n, 1.6), np.zeros(n)], axis=1) + rng.normal(0, 0.005, (n, 3))
        rot = np.stack([rng.normal(0, 2, n), yaw, np.zeros(n)], axis=1)
    else:
        raise PoseError(f"synthetic pose kind {kind!r} is not one of walk, orbit, fast_turns")
    return PoseTrace(time_s=t, position=pos, rotation_deg=(rot + 180.0) % 360.0 - 180.0)
