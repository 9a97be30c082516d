"""Viewer poses: headset logs, camera-path files, synthetic paths, and the pose -> camera mapping.

Headset logs have one line per sample::

    2024-06-20 17:48:42, Head Position: (0.00, 1.49, 0.52), Head Rotation: (3.92, 351.06, 359.03), ...

positions in metres (y up), rotations as Euler angles in degrees; timestamps have one-second
resolution with many lines per second, so sub-second times are inferred by spreading each second's
lines evenly over it (line k of n in second s is at ``s + k / n``). Leading lines whose head
position and rotation are all zero (the headset not yet tracking) are dropped. Lines that do not
parse are skipped with one warning that counts them (given only when the log is read; a log that
is refused gives its error alone).

Non-physical poses are refused by name (line and field), never rendered: a head position
coordinate beyond :data:`MAX_POSITION_M` metres or an angle beyond :data:`MAX_ANGLE_DEG` degrees
(a camera 10^308 m away sees nothing, and its empty picture would score like a perfect one).
"""

from __future__ import annotations

import math
import os
import re
import warnings
from dataclasses import dataclass
from datetime import datetime
from pathlib import Path
from typing import Callable, Optional

import numpy as np

from l3gs_opt.checks import check_count, check_number, check_path, check_seed, field_error, real_array
from l3gs_opt.errors import L3gsError
from l3gs_opt.input_files import read_text
from l3gs_opt.traces.bandwidth import MAX_TRACE_SAMPLES, iter_lines

__all__ = ["PoseError", "PoseTrace", "PoseMapping", "read_pose_log", "write_pose_log", "read_camera_path",
           "write_camera_path", "synthetic_poses", "euler_to_matrix", "MAX_POSITION_M", "MAX_ANGLE_DEG",
           "MAX_POSE_FILE_BYTES", "MAX_POSE_SAMPLES", "MAX_POSE_SECONDS"]

#: Largest |coordinate| of a head position (m): 1000 km, far beyond any tracked space.
MAX_POSITION_M = 1e6
#: Largest |angle| of a head rotation (degrees): logs hold [0, 360); unwrapped ones may add turns.
MAX_ANGLE_DEG = 1e6
#: Largest pose log or camera path file read (bytes): ~250,000 poses of ~250 characters, a day at 30 Hz.
MAX_POSE_FILE_BYTES = 64 * 2**20
#: Most samples :func:`synthetic_poses` makes: the bandwidth traces' MAX_TRACE_SAMPLES (9 hours at
#: 30 Hz; ~60 MB of arrays), so that a mistyped duration is refused before anything is allocated.
MAX_POSE_SAMPLES = MAX_TRACE_SAMPLES
#: Longest :func:`synthetic_poses` path (s): the longest bandwidth trace, MAX_TRACE_SAMPLES one-second
#: samples (11.6 days); a path beyond every trace drives nothing. It also bounds ``fast_turns``,
#: which draws a head turn for every second.
MAX_POSE_SECONDS = float(MAX_TRACE_SAMPLES)
#: Tolerance on ``R R^T = I`` for a camera path's rotation block: ``scene.cameras.ROTATION_TOL``,
#: which traces cannot import (scene imports traces). Rounded decimals pass; a scale or shear does not.
_ROTATION_TOL = 1e-4


class PoseError(L3gsError, ValueError):
    """A pose log or camera path is missing, empty or malformed."""


#: The ``error`` of the shared checks (:mod:`l3gs_opt.checks`).
_pose_error = field_error(PoseError)


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
        # Lists (and integer arrays) become float64 arrays; float arrays are kept as given.
        for field in ("time_s", "position", "rotation_deg"):
            object.__setattr__(self, field, real_array(field, getattr(self, field), _pose_error))
        if self.time_s.ndim != 1 or len(self.time_s) < 1:
            raise PoseError(f"time_s: shape {self.time_s.shape} must be [N] with N >= 1")
        n = len(self.time_s)
        if self.position.shape != (n, 3) or self.rotation_deg.shape != (n, 3):
            raise PoseError(f"pose arrays disagree: time {n}, position {self.position.shape}, "
                            f"rotation {self.rotation_deg.shape}")
        if not np.all(np.isfinite(self.time_s)):
            i = int(np.argmax(~np.isfinite(self.time_s)))
            raise PoseError(f"time_s[{i}] = {float(self.time_s[i])!r}: must be finite")
        # Strictly increasing, as every reader makes it: a step back or a repeat would make
        # rate_hz (1 / the median step) negative or infinite and the pose at a time ambiguous.
        steps = np.diff(self.time_s)
        if (steps <= 0).any():
            i = int(np.argmax(steps <= 0)) + 1
            raise PoseError(f"time_s[{i}] = {float(self.time_s[i])!r}: must increase "
                            f"(previous {float(self.time_s[i - 1])!r})")
        # A skipped line takes at least one byte of a log no larger than MAX_POSE_FILE_BYTES.
        object.__setattr__(self, "skipped", check_count("skipped", self.skipped, low=0, high=MAX_POSE_FILE_BYTES,
                                                                error=_pose_error))
        _check_pose_values(self.position, self.rotation_deg, lambda i: f"sample {i}",
                           ("position", "rotation_deg"))

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


# nan and inf are matched so that such a line is refused by name (below), not skipped as no pose.
_NUM = r"(-?(?:\d+(?:\.\d*)?(?:[eE][-+]?\d+)?|(?i:nan|inf(?:inity)?)))"
_TRIPLE = rf"\(\s*{_NUM}\s*,\s*{_NUM}\s*,\s*{_NUM}\s*\)"
_LINE = re.compile(rf"^\s*(\d{{4}}-\d\d-\d\d \d\d:\d\d:\d\d(?:\.\d+)?)\s*,\s*Head Position:\s*{_TRIPLE}\s*,"
                   rf"\s*Head Rotation:\s*{_TRIPLE}")
_EPOCH = datetime(1970, 1, 1)


def _check_pose_values(position: np.ndarray, rotation_deg: np.ndarray, where: Callable[[int], str],
                       names: tuple[str, str]) -> None:
    """Refuse a non-finite or non-physical pose: ``where(row)`` and ``names`` (position, rotation)
    label the message, e.g. ``line 7: Head Position[0] = 1e+308: ...``."""
    for values, name, limit, unit, constant in ((position, names[0], MAX_POSITION_M, "m", "MAX_POSITION_M"),
                                                (rotation_deg, names[1], MAX_ANGLE_DEG, "degrees", "MAX_ANGLE_DEG")):
        bad = ~(np.abs(values) <= limit)
        if bad.any():
            i, c = (int(k) for k in np.argwhere(bad)[0])
            raise PoseError(f"{where(i)}: {name}[{c}] = {float(values[i, c])!r}: must be finite and within "
                            f"+-{limit:g} {unit} ({constant})")


def read_pose_log(path: str | os.PathLike[str]) -> PoseTrace:
    """Parse a headset log (see the module docstring).

    Raises
    ------
    PoseError
        Missing or non-regular file, no parsable line after the leading not-tracking lines, a
        non-finite or non-physical pose (naming the line and the field), timestamps going backwards,
        a ``path`` that is not a str or path.
    """
    path = check_path(path, error=_pose_error)
    if not path.exists() and not path.is_symlink():
        raise PoseError(f"{path}: no such pose log")
    text = read_text(path, _pose_error, field="pose log", max_bytes=MAX_POSE_FILE_BYTES, errors="replace")
    stamps: list[float] = []
    values: list[list[float]] = []
    numbers: list[int] = []
    skipped = 0
    for number, line in iter_lines(text):
        if not line.strip():
            continue
        m = _LINE.match(line)
        if not m:
            skipped += 1
            continue
        try:  # naive stamps, read as written (no time zone, no daylight-saving jumps)
            when = (datetime.fromisoformat(m.group(1)) - _EPOCH).total_seconds()
        except ValueError:
            skipped += 1
            continue
        stamps.append(when)
        values.append([float(g) for g in m.groups()[1:]])
        numbers.append(number)
    arr = np.asarray(values, dtype=np.float64).reshape(-1, 6)
    _check_pose_values(arr[:, :3], arr[:, 3:], lambda i: f"{path}: line {numbers[i]}",
                       ("Head Position", "Head Rotation"))
    first = next((i for i, v in enumerate(values) if any(x != 0.0 for x in v)), None)
    if first is None:
        raise PoseError(f"{path}: no tracked pose sample found"
                        + (f" ({skipped} line(s) are not pose samples)" if skipped else ""))
    raw, arr, numbers = np.asarray(stamps[first:]), arr[first:], numbers[first:]
    if (np.diff(raw) < 0).any():
        bad = int(np.argmax(np.diff(raw) < 0)) + 1
        raise PoseError(f"{path}: line {numbers[bad]}: timestamp goes backwards (sample {bad + first})")
    if skipped:
        warnings.warn(f"{path}: skipped {skipped} line(s) that are not pose samples", stacklevel=2)
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


def matrix_to_euler_zxy(R: np.ndarray) -> np.ndarray:
    """``[N, 3, 3]`` -> ``[N, 3]`` degrees (about x, y, z) with ``R = Ry @ Rx @ Rz``: the inverse of
    ``euler_to_matrix(angles, "ZXY")``; at +-90 degrees of pitch (gimbal lock) z is set to 0."""
    sx = np.clip(-R[:, 1, 2], -1.0, 1.0)
    x = np.arcsin(sx)
    lock = np.abs(sx) > 1 - 1e-12
    y = np.where(lock, np.arctan2(-R[:, 2, 0], R[:, 0, 0]), np.arctan2(R[:, 0, 2], R[:, 2, 2]))
    z = np.where(lock, 0.0, np.arctan2(R[:, 1, 0], R[:, 1, 1]))
    return np.degrees(np.stack([x, y, z], axis=1))


def poses_from_cameras(world_to_camera: np.ndarray, time_s: np.ndarray,
                       mapping: Optional["PoseMapping"] = None) -> PoseTrace:
    """The :class:`PoseTrace` whose cameras under ``mapping`` are ``world_to_camera`` ``[N, 4, 4]``
    (the inverse of :meth:`PoseMapping.world_to_camera`; ``mapping`` default: ``PoseMapping()``),
    so that camera paths and other viewers' traces drive the simulator unchanged. Only ZXY mappings
    are inverted (every mapping the toolkit makes)."""
    mapping = mapping or PoseMapping()
    if mapping.euler_order.upper() != "ZXY":
        raise PoseError(f"euler_order {mapping.euler_order!r}: only ZXY mappings can be inverted")
    w2c = np.asarray(world_to_camera, dtype=np.float64)
    if w2c.ndim != 3 or w2c.shape[1:] != (4, 4):
        raise PoseError(f"world_to_camera: shape {w2c.shape} must be [N, 4, 4]")
    W = np.asarray(mapping.world_from_log, dtype=np.float64)
    R_wc = w2c[:, :3, :3]
    R_cw = np.swapaxes(R_wc, -1, -2)
    centre = -(R_cw @ w2c[:, :3, 3:])[..., 0]
    flip = np.diag([1.0, -1.0, 1.0])
    R_log = W.T @ R_cw @ flip
    position = (centre - np.asarray(mapping.offset)) @ W / mapping.scale
    return PoseTrace(time_s=np.asarray(time_s, dtype=np.float64), position=position,
                     rotation_deg=matrix_to_euler_zxy(R_log))


def read_camera_path(path: str | os.PathLike[str]) -> np.ndarray:
    """Camera path file: 4x4 world-to-camera matrices, 4 rows each, blank line between -> ``[N, 4, 4]``.

    Raises
    ------
    PoseError
        Missing file, no matrix, a block that is not 4 rows of 4 finite numbers (naming the row),
        a last row other than ``0 0 0 1`` or a rotation block that is not a rotation (naming the
        matrix), a ``path`` that is not a str or path.
    """
    path = check_path(path, error=_pose_error)
    if not path.exists() and not path.is_symlink():
        raise PoseError(f"{path}: no such camera path")
    text = read_text(path, _pose_error, field="camera path", max_bytes=MAX_POSE_FILE_BYTES)
    blocks = [b for b in re.split(r"\n\s*\n", text.strip()) if b.strip()]
    if not blocks:
        raise PoseError(f"{path}: no matrix found")
    mats = []
    for k, block in enumerate(blocks):
        rows = [r.split() for r in block.strip().splitlines()]
        # Row by row, so that a short row is named as such, not as an entry that is not a number.
        for r, row in enumerate(rows):
            try:
                values = [float(v) for v in row]
            except ValueError:
                raise PoseError(f"{path}: matrix {k}: row {r}: entries must be numbers") from None
            if len(values) != 4:
                raise PoseError(f"{path}: matrix {k}: row {r} has {len(values)} entries: expected 4 rows of 4 "
                                f"finite numbers")
            for c, v in enumerate(values):
                if not math.isfinite(v):
                    raise PoseError(f"{path}: matrix {k}: row {r}, entry {c} = {v!r}: must be finite")
        if len(rows) != 4:
            raise PoseError(f"{path}: matrix {k}: expected 4 rows of 4 finite numbers, got {len(rows)} rows")
        m = np.array([[float(v) for v in row] for row in rows])
        # A world-to-camera matrix is rigid, [[R, t], [0, 0, 0, 1]], as Camera requires: anything
        # else would be turned into a pose (poses_from_cameras) that is silently wrong.
        if not np.array_equal(m[3], [0.0, 0.0, 0.0, 1.0]):
            raise PoseError(f"{path}: matrix {k}: last row {m[3].tolist()} must be [0, 0, 0, 1]")
        rot = m[:3, :3]
        err = float(np.abs(rot @ rot.T - np.eye(3)).max())
        if err > _ROTATION_TOL or np.linalg.det(rot) < 0:
            raise PoseError(f"{path}: matrix {k}: rotation block is not a rotation "
                            f"(|R R^T - I| = {err:.2e}, det = {np.linalg.det(rot):.4f})")
        mats.append(m)
    return np.stack(mats)


def write_camera_path(matrices: np.ndarray, path: str | os.PathLike[str]) -> Path:
    path = Path(path)
    path.write_text("\n\n".join("\n".join(" ".join(f"{v:.9g}" for v in row) for row in m) for m in matrices) + "\n",
                    encoding="utf-8")
    return path


def synthetic_poses(kind: str = "walk", *, seconds: float = 60.0, rate_hz: float = 30.0, seed: int = 0) -> PoseTrace:
    """Synthetic head motion: ``walk`` (slow walk, gentle head turns), ``orbit`` (circling a
    point while looking at it), ``fast_turns`` (standing, quick 60-120 degree head turns).

    ``seconds`` (s) is in (0, :data:`MAX_POSE_SECONDS`] and ``rate_hz`` (Hz) finite and > 0; the path
    has ``round(seconds * rate_hz)`` samples, 1 .. :data:`MAX_POSE_SAMPLES`. ``seed`` is an integer >= 0.

    Raises
    ------
    PoseError
        An unknown ``kind``, or an argument of the wrong type or out of range (named).
    """
    if not isinstance(kind, str) or kind not in ("walk", "orbit", "fast_turns"):
        raise PoseError(f"synthetic pose kind {kind!r} is not one of walk, orbit, fast_turns")
    seconds = check_number("seconds", seconds, lambda x: 0 < x <= MAX_POSE_SECONDS,
                           f"a number of seconds in (0, {MAX_POSE_SECONDS:g}] (MAX_POSE_SECONDS)", _pose_error)
    rate_hz = check_number("rate_hz", rate_hz, lambda x: x > 0, "a finite number of samples per second > 0", _pose_error)
    # Checked before anything is allocated (a mistyped rate is terabytes). The product of two
    # finite numbers may still be inf, which the first test refuses before round() sees it.
    samples = seconds * rate_hz
    if not (samples <= MAX_POSE_SAMPLES + 1 and 1 <= round(samples) <= MAX_POSE_SAMPLES):
        raise PoseError(f"seconds * rate_hz = {seconds!r} * {rate_hz!r} = {samples:.6g} samples: must round to "
                        f"an integer in [1, {MAX_POSE_SAMPLES}] (MAX_POSE_SAMPLES)")
    rng = np.random.default_rng(check_seed(seed, error=_pose_error))
    n = int(round(samples))
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
