"""EyeNavGS 6-DoF viewer traces (Ding et al., arXiv 2506.02380): read, resample, turn into cameras.

The dataset: people in Meta Quest Pro headsets walking (3 m x 3 m play area) through standard 3DGS
scenes in the authors' SIBR/OpenXR viewer. One CSV per user and scene, one row per eye per
rendered frame (left, right, left, ...), columns (names as in the header, any order)::

    ViewIndex                          0 = left eye, 1 = right eye
    FOV1..FOV4                         OpenXR angleLeft, angleRight, angleDown, angleUp (radians;
                                       the dataset README says "left, right, top, bottom", but
                                       the viewer writes XrFovf in this order and FOV3 < 0)
    PositionX..Z                       the eye's position (head +- IPD/2), viewer world units
    QuaternionX..W                     head orientation, (x, y, z, w), body-to-world
    GazePosX..Z, GazeQX..W (optional)  eye gaze origin and orientation; the viewer writes
                                       (0, 0, 0) and (0, 0, 0, 1) when eye tracking is off
    Timestamp                          ms from the start of the recording

**Frames.** The viewer world is OpenXR's: right-handed, +x right, +y up, +z backward; a
head looks along its -z with +y up (checked on the sample: right eye minus left eye is
always along the quaternion's +x). The scene's 3DGS/COLMAP world is reached by the viewer's
fixed flip ``F = diag(1, -1, -1)`` (its "Y-Invert scene" option, on by default): camera
centre ``F p`` and camera-to-world rotation ``F R(q)`` for the viewer's OpenGL-style camera,
i.e. ``F R(q) F`` for the OpenCV camera (x right, y down, z forward) that the toolkit's
``world_to_camera`` matrices use (see ``OpenXRRdrMode.cpp`` of the EyeNavGS software: the
replay renders each CSV row exactly this way). The OpenXR frame is right-handed, not Unity's
left-handed one, so :class:`~l3gs_opt.traces.poses.PoseMapping`'s Unity-log path does not
apply directly; :meth:`EyeNavTrace.to_pose_trace` mirrors z to give an equivalent Unity-style
:class:`~l3gs_opt.traces.poses.PoseTrace` for the default ``PoseMapping``.

**Scene alignment** (``scene_setting.csv``: quaternion, scale, initial position per scene) is
already applied in the recorded positions: it is how the viewer put the physical play area
(OpenXR STAGE space, metres, floor at y = 0) into the scene, so the recorded poses need no
alignment to be rendered (the inter-eye distance in the files is ``scale x 62 mm``). The
alignment maps the recording back to the room (the inverse of the EyeNavGS
``WorldCoordConvert`` tool): with ``R`` = the alignment rotation, ``s`` the scale and ``t``
the initial position,

    stage = R ((p - t) / s + t) + t,        stage orientation = q_align * q.

Checked on the shared sample (3 scenes x 4 users): every head lies within the 3 m x 3 m area at
standing height, and the mean head-up vector is within 8 degrees of vertical in the stage
frame (10-17 degrees off in the recorded frame).

**Eyes.** ``eye="centre"`` (the default) merges each frame's left and right rows: the midpoint
of the two eye positions (the head, what a single-view renderer and a viewport predictor want;
a per-eye trace is offset by IPD/2 sideways), their mean time (the two rows are ~4 ms apart),
the head orientation (the same quaternion on both rows), the union of the two eye frusta, and
the mean gaze (valid when both eyes' gaze is). A row without its partner (e.g. a last left row)
is dropped and counted in ``unpaired``. ``eye="left"`` / ``"right"`` keep one eye's rows.
"""

from __future__ import annotations

import csv
import math
import os
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from l3gs_opt.errors import L3gsError
from l3gs_opt.input_files import read_text
from l3gs_opt.traces.poses import MAX_POSITION_M, PoseTrace, matrix_to_euler_zxy

__all__ = ["EyeNavError", "EyeNavTrace", "SceneAlignment", "read_eyenavgs", "read_scene_settings",
           "quaternion_to_matrix", "EYES", "MAX_EYENAV_FILE_BYTES", "QUATERNION_NORM_TOL"]

#: Largest trace CSV read (bytes): ~60 hours of 72 Hz stereo rows of ~120 characters.
MAX_EYENAV_FILE_BYTES = 64 * 2**20
#: Largest deviation of a written quaternion's norm from 1. The files hold 3 decimals, so the
#: norm is off by up to ~1e-3 (8e-4 seen); 10x that still refuses a non-rotation.
QUATERNION_NORM_TOL = 1e-2
#: The ``eye`` choices of :func:`read_eyenavgs`.
EYES = ("centre", "left", "right")

_HEAD = ("ViewIndex", "FOV1", "FOV2", "FOV3", "FOV4", "PositionX", "PositionY", "PositionZ",
         "QuaternionX", "QuaternionY", "QuaternionZ", "QuaternionW", "Timestamp")
_GAZE = ("GazePosX", "GazePosY", "GazePosZ", "GazeQX", "GazeQY", "GazeQZ", "GazeQW")
#: OpenXR (+y up, +z back) -> 3DGS/COLMAP (+y down, +z forward): the viewer's "Y-Invert scene".
_FLIP = np.diag([1.0, -1.0, -1.0])
#: Viewer's OpenGL camera (looks along -z, y up) <-> OpenCV camera (looks along +z, y down).
_GL_TO_CV = np.diag([1.0, -1.0, -1.0])
#: Right-handed OpenXR <-> left-handed Unity-style log frame (z mirrored).
_MIRROR_Z = np.diag([1.0, 1.0, -1.0])


class EyeNavError(L3gsError, ValueError):
    """An EyeNavGS trace or scene-setting file is missing or malformed, or an argument is out of range."""


def quaternion_to_matrix(q: np.ndarray) -> np.ndarray:
    """``[..., 4]`` unit quaternions ``(x, y, z, w)`` -> ``[..., 3, 3]`` rotation matrices (the
    rotation that takes body coordinates to world coordinates)."""
    q = np.asarray(q, dtype=np.float64)
    x, y, z, w = np.moveaxis(q, -1, 0)
    rows = [[1 - 2 * (y * y + z * z), 2 * (x * y - z * w), 2 * (x * z + y * w)],
            [2 * (x * y + z * w), 1 - 2 * (x * x + z * z), 2 * (y * z - x * w)],
            [2 * (x * z - y * w), 2 * (y * z + x * w), 1 - 2 * (x * x + y * y)]]
    return np.moveaxis(np.array(rows), [0, 1], [-2, -1])


def _quat_multiply(a: np.ndarray, b: np.ndarray) -> np.ndarray:
    """Hamilton product ``a * b`` of ``(x, y, z, w)`` quaternions (apply b, then a)."""
    ax, ay, az, aw = np.moveaxis(np.asarray(a, dtype=np.float64), -1, 0)
    bx, by, bz, bw = np.moveaxis(np.asarray(b, dtype=np.float64), -1, 0)
    return np.stack([aw * bx + ax * bw + ay * bz - az * by,
                     aw * by - ax * bz + ay * bw + az * bx,
                     aw * bz + ax * by - ay * bx + az * bw,
                     aw * bw - ax * bx - ay * by - az * bz], axis=-1)


def _slerp(q0: np.ndarray, q1: np.ndarray, u: np.ndarray) -> np.ndarray:
    """Spherical interpolation ``[N, 4]`` between unit quaternions at fractions ``u`` [N]."""
    dot = np.sum(q0 * q1, axis=-1)
    q1 = np.where((dot < 0)[:, None], -q1, q1)  # the short way round
    dot = np.abs(dot)
    theta = np.arccos(np.clip(dot, -1.0, 1.0))
    near = theta < 1e-6  # nearly equal: linear interpolation is exact to rounding
    s = np.where(near, 1.0, np.sin(theta))
    w0 = np.where(near, 1.0 - u, np.sin((1.0 - u) * theta) / s)
    w1 = np.where(near, u, np.sin(u * theta) / s)
    out = w0[:, None] * q0 + w1[:, None] * q1
    return out / np.linalg.norm(out, axis=-1, keepdims=True)


def _mean_quaternion(q0: np.ndarray, q1: np.ndarray) -> np.ndarray:
    return _slerp(q0, q1, np.full(len(q0), 0.5))


def _check_unit(q: np.ndarray, where, name: str) -> np.ndarray:
    """``q`` normalised; a quaternion whose norm is off by more than the tolerance is refused."""
    norm = np.linalg.norm(q, axis=-1)
    bad = ~(np.abs(norm - 1.0) <= QUATERNION_NORM_TOL)
    if bad.any():
        i = int(np.argmax(bad))
        raise EyeNavError(f"{where(i)}: {name} = {q[i].tolist()}: norm {norm[i]:.6g} is not 1 "
                          f"(within QUATERNION_NORM_TOL = {QUATERNION_NORM_TOL:g})")
    return q / norm[..., None]


@dataclass(frozen=True, eq=False)
class EyeNavTrace:
    """One EyeNavGS recording: head (or one eye) poses over time, in the viewer's OpenXR world.

    Attributes
    ----------
    name : str
        The file's stem (``user101_truck``).
    eye : str
        ``"centre"`` (both eyes merged), ``"left"`` or ``"right"``.
    timestamps_s : float array [N]
        Seconds from the start of the recording, increasing.
    positions : float array [N, 3]
        Viewer world units (scene scale x metres), OpenXR axes (+y up, +z backward).
    orientations : float array [N, 4]
        Unit quaternions ``(x, y, z, w)``, head to world.
    fov_rad : float array [N, 4]
        angleLeft, angleRight, angleDown, angleUp (radians, OpenXR signs: left and down < 0).
    gaze_positions, gaze_orientations : float arrays [N, 3], [N, 4], or None
        Eye gaze origin and orientation; ``None`` when the file has no gaze column or no valid
        gaze sample (eye tracking off). Invalid samples are kept as written.
    gaze_valid : bool array [N] or None
        Which gaze samples are real (``None`` with the gaze).
    unpaired : int
        Rows dropped because their other eye's row was missing (``eye="centre"`` only).
    """

    name: str
    eye: str
    timestamps_s: np.ndarray
    positions: np.ndarray
    orientations: np.ndarray
    fov_rad: np.ndarray
    gaze_positions: np.ndarray | None = None
    gaze_orientations: np.ndarray | None = None
    gaze_valid: np.ndarray | None = None
    unpaired: int = 0

    def __post_init__(self) -> None:
        if self.eye not in EYES:
            raise EyeNavError(f"eye = {self.eye!r}: must be one of {', '.join(EYES)}")
        t = np.array(self.timestamps_s, dtype=np.float64)
        n = len(t)
        shapes = {"positions": (n, 3), "orientations": (n, 4), "fov_rad": (n, 4)}
        gaze = (self.gaze_positions, self.gaze_orientations, self.gaze_valid)
        if any(g is not None for g in gaze):
            if any(g is None for g in gaze):
                raise EyeNavError("gaze_positions, gaze_orientations and gaze_valid: give all three or none")
            shapes.update(gaze_positions=(n, 3), gaze_orientations=(n, 4), gaze_valid=(n,))
        if n < 1 or t.ndim != 1:
            raise EyeNavError(f"timestamps_s: shape {t.shape} must be [N] with N >= 1")
        for field, shape in shapes.items():
            value = np.asarray(getattr(self, field))
            if value.shape != shape:
                raise EyeNavError(f"{field}: shape {value.shape} must be {list(shape)}")
        if not np.isfinite(t).all():
            i = int(np.argmax(~np.isfinite(t)))
            raise EyeNavError(f"timestamps_s[{i}] = {float(t[i])!r}: must be finite")
        if n > 1 and not (np.diff(t) > 0).all():
            i = int(np.argmax(~(np.diff(t) > 0))) + 1
            raise EyeNavError(f"timestamps_s[{i}] = {float(t[i])!r}: must increase (previous {float(t[i - 1])!r})")
        frozen = {"timestamps_s": t}
        for field in shapes:
            if field == "gaze_valid":
                frozen[field] = np.array(self.gaze_valid, dtype=bool)
                continue
            value = np.array(getattr(self, field), dtype=np.float64)
            bad = ~np.isfinite(value)
            if field in ("positions", "gaze_positions"):
                bad |= ~(np.abs(value) <= MAX_POSITION_M)
            if bad.any():
                i, c = (int(k) for k in np.argwhere(bad)[0])
                raise EyeNavError(f"{field}[{i}][{c}] = {float(value[i, c])!r}: must be finite (and within "
                                  f"+-{MAX_POSITION_M:g} for a position)")
            if field == "orientations" or (field == "gaze_orientations" and self.gaze_valid is not None):
                rows = np.ones(n, dtype=bool) if field == "orientations" else np.array(self.gaze_valid, dtype=bool)
                checked = value.copy()
                checked[rows] = _check_unit(value[rows], lambda i: f"{field}[{int(np.flatnonzero(rows)[i])}]", field)
                value = checked
            frozen[field] = value
        for field, value in frozen.items():
            value.setflags(write=False)
            object.__setattr__(self, field, value)

    def __len__(self) -> int:
        return len(self.timestamps_s)

    @property
    def rate_hz(self) -> float:
        """Samples per second (median spacing); 0 for a single sample."""
        return float(1.0 / np.median(np.diff(self.timestamps_s))) if len(self) > 1 else 0.0

    def resampled(self, rate_hz: float) -> "EyeNavTrace":
        """The trace at ``rate_hz`` samples per second from its first timestamp to its last.

        Positions, fields of view and gaze origins are interpolated linearly, orientations by
        spherical linear interpolation (slerp) between the two neighbouring samples; a
        resampled gaze sample is valid when both neighbours are.

        Raises
        ------
        EyeNavError
            ``rate_hz`` not a positive finite number, or more than 10^7 resulting samples.
        """
        if not (isinstance(rate_hz, (int, float, np.integer, np.floating)) and 0 < rate_hz < math.inf):
            raise EyeNavError(f"rate_hz = {rate_hz!r}: must be a positive number of samples per second")
        t = self.timestamps_s
        count = int(math.floor((t[-1] - t[0]) * rate_hz + 1e-9)) + 1
        if count > 10**7:
            raise EyeNavError(f"rate_hz = {rate_hz!r}: {count:,} samples, more than 10^7")
        new_t = t[0] + np.arange(count) / float(rate_hz)
        hi = np.clip(np.searchsorted(t, new_t, side="right"), 1, max(len(t) - 1, 1))
        lo = hi - 1 if len(t) > 1 else np.zeros_like(hi)
        hi = hi if len(t) > 1 else np.zeros_like(hi)
        span = t[hi] - t[lo]
        u = np.clip(np.where(span > 0, (new_t - t[lo]) / np.where(span > 0, span, 1.0), 0.0), 0.0, 1.0)

        def lerp(a: np.ndarray) -> np.ndarray:
            return a[lo] + (a[hi] - a[lo]) * u[:, None]

        gaze = {}
        if self.gaze_positions is not None:
            gaze = dict(gaze_positions=lerp(self.gaze_positions),
                        gaze_orientations=np.where(
                            (self.gaze_valid[lo] & self.gaze_valid[hi])[:, None],
                            _slerp(self.gaze_orientations[lo], self.gaze_orientations[hi], u),
                            self.gaze_orientations[lo]),
                        gaze_valid=self.gaze_valid[lo] & self.gaze_valid[hi])
        return EyeNavTrace(self.name, self.eye, new_t, lerp(self.positions),
                           _slerp(self.orientations[lo], self.orientations[hi], u), lerp(self.fov_rad),
                           unpaired=self.unpaired, **gaze)

    def world_to_camera(self, *, flip_y: bool = True) -> np.ndarray:
        """``[N, 4, 4]`` world-to-camera matrices in the scene's 3DGS/COLMAP world, OpenCV camera
        (x right, y down, z forward), as the EyeNavGS viewer rendered each sample.

        With ``F = diag(1, -1, -1)`` when ``flip_y`` (the viewer's default "Y-Invert scene", right
        for 3DGS/COLMAP scenes) and ``I`` otherwise, the camera centre is ``F p`` and the
        camera-to-world rotation ``F R(q) diag(1, -1, -1)``.
        """
        flip = _FLIP if flip_y else np.eye(3)
        r_cw = flip @ quaternion_to_matrix(self.orientations) @ _GL_TO_CV
        centre = self.positions @ flip.T
        r_wc = np.swapaxes(r_cw, -1, -2)
        out = np.zeros((len(self), 4, 4))
        out[:, :3, :3] = r_wc
        out[:, :3, 3] = -(r_wc @ centre[..., None])[..., 0]
        out[:, 3, 3] = 1.0
        return out

    def to_pose_trace(self) -> PoseTrace:
        """The same poses as a Unity-style :class:`PoseTrace` (left-handed: z mirrored; Euler
        degrees, order ZXY; times from 0) for the simulator: with the default
        :class:`~l3gs_opt.traces.poses.PoseMapping` its cameras equal :meth:`world_to_camera`.
        """
        R = _MIRROR_Z @ quaternion_to_matrix(self.orientations) @ _MIRROR_Z
        return PoseTrace(time_s=self.timestamps_s - self.timestamps_s[0], position=self.positions @ _MIRROR_Z,
                         rotation_deg=matrix_to_euler_zxy(R))


@dataclass(frozen=True)
class SceneAlignment:
    """How the EyeNavGS viewer placed the physical play area in one scene (``scene_setting.csv``).

    Attributes
    ----------
    name : str
    quaternion : (x, y, z, w)
        Unit quaternion (normalised on reading): the tilt correction.
    scale : float
        Viewer world units per metre (> 0).
    initial_position : (x, y, z)
        Viewer world units.

    The recorded poses already include this alignment (module docstring); it maps them back to
    the room's STAGE frame (metres, +y up, floor at 0) and forth.
    """

    name: str
    quaternion: tuple[float, float, float, float]
    scale: float
    initial_position: tuple[float, float, float]

    def __post_init__(self) -> None:
        q = np.asarray(self.quaternion, dtype=np.float64)
        t = np.asarray(self.initial_position, dtype=np.float64)
        if q.shape != (4,) or not np.isfinite(q).all():
            raise EyeNavError(f"{self.name}: quaternion {self.quaternion!r}: must be 4 finite numbers (x, y, z, w)")
        if t.shape != (3,) or not np.isfinite(t).all():
            raise EyeNavError(f"{self.name}: initial_position {self.initial_position!r}: must be 3 finite numbers")
        if not (isinstance(self.scale, (int, float)) and 0 < self.scale < math.inf):
            raise EyeNavError(f"{self.name}: scale {self.scale!r}: must be a positive number")
        q = _check_unit(q[None], lambda i: self.name, "quaternion")[0]
        object.__setattr__(self, "quaternion", tuple(float(v) for v in q))
        object.__setattr__(self, "initial_position", tuple(float(v) for v in t))
        object.__setattr__(self, "scale", float(self.scale))

    def stage_from_recorded(self, points: np.ndarray) -> np.ndarray:
        """``[..., 3]`` recorded positions -> STAGE positions (metres): ``R ((p - t) / s + t) + t``."""
        t = np.asarray(self.initial_position)
        R = quaternion_to_matrix(np.asarray(self.quaternion))
        return ((np.asarray(points, dtype=np.float64) - t) / self.scale + t) @ R.T + t

    def recorded_from_stage(self, points: np.ndarray) -> np.ndarray:
        """The inverse of :meth:`stage_from_recorded`: ``s (R^T (p - t) - t) + t``."""
        t = np.asarray(self.initial_position)
        R = quaternion_to_matrix(np.asarray(self.quaternion))
        return self.scale * ((np.asarray(points, dtype=np.float64) - t) @ R - t) + t

    def stage_orientation(self, quaternions: np.ndarray) -> np.ndarray:
        """``[..., 4]`` recorded orientations -> STAGE orientations: ``q_align * q``."""
        return _quat_multiply(np.asarray(self.quaternion), quaternions)


# ------------------------------------------------------------------------------------------ reading
def _eyenav_error(field: str, message: str) -> EyeNavError:
    return EyeNavError(f"{field}: {message}")


def _rows(path: Path, field: str) -> tuple[list[str], list[tuple[int, list[str]]]]:
    """Header and ``(line number, fields)`` of each non-blank row of a CSV file."""
    text = read_text(path, _eyenav_error, field=field, max_bytes=MAX_EYENAV_FILE_BYTES)
    lines = text.lstrip("\ufeff").splitlines()  # the dataset's files start with a UTF-8 BOM
    numbered = [(k + 1, line) for k, line in enumerate(lines) if line.strip()]
    if not numbered:
        raise EyeNavError(f"{path}: empty file, expected a header line")
    parsed = list(zip((n for n, _ in numbered), csv.reader(line for _, line in numbered)))
    return [h.strip() for h in parsed[0][1]], parsed[1:]


def read_eyenavgs(path: str | os.PathLike[str], *, eye: str = "centre") -> EyeNavTrace:
    """Read one EyeNavGS ``{user}_{scene}.csv`` trace (format and conventions in the module docstring).

    Parameters
    ----------
    path : path
    eye : {"centre", "left", "right"}
        Merge each frame's two eye rows (head pose), or keep one eye's rows.

    Raises
    ------
    EyeNavError
        Missing or non-regular file; a missing, repeated or unknown column (all gaze columns or
        none); a field that is not a finite number, a ViewIndex other than 0 or 1, a quaternion
        that is not unit, a position beyond ``MAX_POSITION_M``, a time that does not increase
        (each naming the CSV line and column); no row for the chosen eye.
    """
    if eye not in EYES:
        raise EyeNavError(f"eye = {eye!r}: must be one of {', '.join(EYES)}")
    path = Path(path)
    header, rows = _rows(path, "EyeNavGS trace")
    repeated = sorted({h for h in header if header.count(h) > 1})
    missing = [h for h in _HEAD if h not in header]
    unknown = [h for h in header if h not in _HEAD + _GAZE]
    gaze_present = [h for h in _GAZE if h in header]
    if repeated or missing or unknown or len(gaze_present) not in (0, len(_GAZE)):
        problems = ([f"repeated {', '.join(repeated)}"] if repeated else []) + \
                   ([f"missing {', '.join(missing)}"] if missing else []) + \
                   ([f"unknown {', '.join(unknown)}"] if unknown else []) + \
                   ([f"gaze columns incomplete: missing {', '.join(h for h in _GAZE if h not in header)}"]
                    if 0 < len(gaze_present) < len(_GAZE) else [])
        raise EyeNavError(f"{path}: line 1 (header): {'; '.join(problems)}")
    columns = list(_HEAD) + (list(_GAZE) if gaze_present else [])
    index = [header.index(c) for c in columns]
    values = np.empty((len(rows), len(columns)))
    lines = np.empty(len(rows), dtype=np.int64)
    for r, (number, fields) in enumerate(rows):
        if len(fields) != len(header):
            raise EyeNavError(f"{path}: line {number}: {len(fields)} fields, the header has {len(header)}")
        for c, k in enumerate(index):
            try:
                v = float(fields[k])
            except ValueError:
                raise EyeNavError(f"{path}: line {number}: column {columns[c]} = {fields[k][:40]!r}: "
                                  f"not a number") from None
            if not math.isfinite(v):
                raise EyeNavError(f"{path}: line {number}: column {columns[c]} = {v!r}: must be finite")
            values[r, c] = v
        lines[r] = number
    if not len(rows):
        raise EyeNavError(f"{path}: no data row after the header")
    col = {c: i for i, c in enumerate(columns)}
    view = values[:, col["ViewIndex"]]
    bad = (view != 0) & (view != 1)
    if bad.any():
        i = int(np.argmax(bad))
        raise EyeNavError(f"{path}: line {lines[i]}: column ViewIndex = {float(view[i])!r}: must be 0 (left) "
                          f"or 1 (right)")

    def where(rows_of: np.ndarray):
        return lambda i: f"{path}: line {lines[rows_of[i]]}"

    every = np.arange(len(rows))
    pos = values[:, [col[c] for c in ("PositionX", "PositionY", "PositionZ")]]
    far = ~(np.abs(pos) <= MAX_POSITION_M)
    if far.any():
        i, c = (int(k) for k in np.argwhere(far)[0])
        column = ("PositionX", "PositionY", "PositionZ")[c]
        raise EyeNavError(f"{where(every)(i)}: column {column} = {float(pos[i, c])!r}: "
                          f"must be within +-{MAX_POSITION_M:g} (MAX_POSITION_M)")
    quat = _check_unit(values[:, [col[c] for c in ("QuaternionX", "QuaternionY", "QuaternionZ", "QuaternionW")]],
                       lambda i: f"{where(every)(i)}: columns QuaternionX..W", "quaternion")
    fov = values[:, [col[c] for c in ("FOV1", "FOV2", "FOV3", "FOV4")]]
    time_s = values[:, col["Timestamp"]] / 1000.0
    gaze = None
    if gaze_present:
        gpos = values[:, [col[c] for c in _GAZE[:3]]]
        gq = values[:, [col[c] for c in _GAZE[3:]]]
        valid = ~((gq == [0.0, 0.0, 0.0, 1.0]).all(axis=1) & (gpos == 0.0).all(axis=1))
        if valid.any():
            rows_v = np.flatnonzero(valid)
            gq = gq.copy()
            gq[valid] = _check_unit(gq[valid], lambda i: f"{where(rows_v)(i)}: columns GazeQX..W", "gaze quaternion")
            gaze = (gpos, gq, valid)

    if eye == "centre":
        left = np.flatnonzero((view[:-1] == 0) & (view[1:] == 1))
        right = left + 1
        unpaired = len(rows) - 2 * len(left)
        take_time = (time_s[left] + time_s[right]) / 2
        take_pos = (pos[left] + pos[right]) / 2
        take_quat = _mean_quaternion(quat[left], quat[right])
        take_fov = np.stack([np.minimum(fov[left, 0], fov[right, 0]), np.maximum(fov[left, 1], fov[right, 1]),
                             np.minimum(fov[left, 2], fov[right, 2]), np.maximum(fov[left, 3], fov[right, 3])], axis=1)
        if gaze is not None:
            gpos, gq, valid = gaze
            both = valid[left] & valid[right]
            gaze = ((gpos[left] + gpos[right]) / 2,
                    np.where(both[:, None], _mean_quaternion(gq[left], gq[right]), gq[left]), both)
        source = left  # the line a merged sample is reported by
    else:
        source = np.flatnonzero(view == (0 if eye == "left" else 1))
        unpaired = 0
        take_time, take_pos, take_quat, take_fov = time_s[source], pos[source], quat[source], fov[source]
        if gaze is not None:
            gaze = tuple(g[source] for g in gaze)
    if not len(source):
        raise EyeNavError(f"{path}: no {'left/right row pair' if eye == 'centre' else eye + '-eye row'} found")
    steps = np.diff(take_time)
    if (steps <= 0).any():
        i = int(np.argmax(steps <= 0)) + 1
        stamp = float(values[source[i], col["Timestamp"]])
        raise EyeNavError(f"{path}: line {lines[source[i]]}: column Timestamp = {stamp!r} ms: must increase "
                          f"(previous sample's line {lines[source[i - 1]]})")
    if gaze is not None and not gaze[2].any():
        gaze = None  # eye tracking was off for the whole recording
    g_pos, g_q, g_valid = gaze if gaze is not None else (None, None, None)
    return EyeNavTrace(path.stem, eye, take_time, take_pos, take_quat, take_fov, g_pos, g_q, g_valid, unpaired)


def read_scene_settings(path: str | os.PathLike[str]) -> dict[str, SceneAlignment]:
    """Read ``scene_setting.csv``: scene name -> :class:`SceneAlignment`.

    Columns ``Scene_Name`` (or ``Dataset_Name``), ``Quaternion`` (``"x, y, z, w"``), ``Scale``,
    ``Initial_Position`` (``"x,y,z"``).

    Raises
    ------
    EyeNavError
        Missing or non-regular file, a missing column, a field that is not the right count of
        finite numbers, a non-unit quaternion, a scale that is not positive, a repeated scene
        (each naming the CSV line and column).
    """
    path = Path(path)
    header, rows = _rows(path, "scene settings")
    name_col = "Scene_Name" if "Scene_Name" in header else "Dataset_Name"
    need = (name_col, "Quaternion", "Scale", "Initial_Position")
    missing = [c for c in need if c not in header]
    if missing:
        raise EyeNavError(f"{path}: line 1 (header): missing {', '.join(missing)}")
    k = {c: header.index(c) for c in need}
    out: dict[str, SceneAlignment] = {}
    for number, fields in rows:
        if len(fields) != len(header):
            raise EyeNavError(f"{path}: line {number}: {len(fields)} fields, the header has {len(header)}")

        def numbers(column: str, count: int) -> list[float]:
            parts = fields[k[column]].split(",")
            try:
                vals = [float(p) for p in parts]
            except ValueError:
                vals = []
            if len(vals) != count or not all(math.isfinite(v) for v in vals):
                raise EyeNavError(f"{path}: line {number}: column {column} = {fields[k[column]][:60]!r}: must be "
                                  f"{count} finite number{'s' if count > 1 else ''} separated by commas")
            return vals

        name = fields[k[name_col]].strip()
        if not name:
            raise EyeNavError(f"{path}: line {number}: column {name_col} is empty")
        if name in out:
            raise EyeNavError(f"{path}: line {number}: column {name_col} = {name!r}: repeated scene")
        quaternion, (scale,), position = numbers("Quaternion", 4), numbers("Scale", 1), numbers("Initial_Position", 3)
        if not scale > 0:
            raise EyeNavError(f"{path}: line {number}: column Scale = {scale!r}: must be > 0")
        try:
            out[name] = SceneAlignment(name, tuple(quaternion), scale, tuple(position))
        except EyeNavError as exc:
            raise EyeNavError(f"{path}: line {number}: column Quaternion: {exc}") from None
    if not out:
        raise EyeNavError(f"{path}: no scene row after the header")
    return out
