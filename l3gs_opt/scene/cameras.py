"""Pinhole cameras (OpenCV convention) and their file formats.

Length (~650 lines): the camera type and the four file formats it is read from and written to
(camera JSON, NeRF ``transforms.json``, COLMAP text and binary), each validated field by field.

Convention (the standard 3DGS one): camera axes x right, y down, z forward; a world point
``p`` maps to camera coordinates ``R p + t`` with ``world_to_camera = [[R, t], [0, 0, 0, 1]]``
and to the pixel position ``(fx x / z + cx, fy y / z + cy)``, where pixel ``(i, j)`` (column,
row) covers ``[i, i + 1) x [j, j + 1)`` and is sampled at its centre ``(i + 0.5, j + 0.5)``.
COLMAP uses the same pixel convention, so its principal point is taken as is.

Formats read and written here:

* **camera JSON** (``l3gs-opt`` native): an object with ``width``, ``height``, ``fx``, ``fy``,
  ``cx``, ``cy``, ``world_to_camera`` (4x4 nested list) and optional ``background`` ``[r, g, b]``
  and ``name``; or a list of such objects (a camera path).  Unknown keys are an error.
* **COLMAP sparse model** (``cameras.txt``/``images.txt`` or ``cameras.bin``/``images.bin``):
  PINHOLE and SIMPLE_PINHOLE cameras (undistorted, as 3DGS requires).
* **NeRF / Blender ``transforms.json``**: OpenGL camera-to-world matrices (x right, y up,
  z backward), converted to OpenCV world-to-camera.

Every file is read through :mod:`l3gs_opt.input_files` (regular files only, sizes limited, strict
JSON). A camera is refused by name before any image is allocated when its size exceeds
:data:`MAX_IMAGE_SIDE` pixels a side or :data:`MAX_IMAGE_PIXELS` in all, its focal length
:data:`MAX_FOCAL_PX`, or a background channel leaves [0, 1].
"""

from __future__ import annotations

import dataclasses
import io
import json
import math
import numbers
import struct
from pathlib import Path
from typing import Any, Optional, Sequence

import numpy as np

from l3gs_opt.errors import L3gsError
from l3gs_opt.input_files import check_regular_file, read_json, read_text
from l3gs_opt.traces.bandwidth import iter_lines

__all__ = ["CameraError", "Camera", "load_cameras", "load_camera", "load_any_cameras", "save_cameras",
           "camera_to_dict", "camera_from_dict", "read_colmap", "write_colmap",
           "read_blender", "write_blender", "look_at", "MAX_IMAGE_SIDE", "MAX_IMAGE_PIXELS", "MAX_FOCAL_PX"]

#: Longest image side (pixels). Renders are allocated per pixel; 16k covers every real sensor.
MAX_IMAGE_SIDE = 16384
#: Most pixels of one image (2^25, about 8K UHD): a float32 RGB render of it takes 400 MB already.
MAX_IMAGE_PIXELS = 2**25
#: Largest focal length (pixels): a 0.0001 degree field of view at 16k pixels. Larger ones overflow
#: the renderer's float32 screen-space covariances (fx^2 Sigma / z^2) and training turns them into NaN.
MAX_FOCAL_PX = 1e9

#: Tolerance on ``R R^T = I`` for the rotation block of ``world_to_camera`` (file formats store
#: rotations in float32 or as rounded decimals; a true scale or shear is far larger).
ROTATION_TOL = 1e-4

_JSON_KEYS = {"width", "height", "fx", "fy", "cx", "cy", "world_to_camera", "background", "name"}


class CameraError(L3gsError, ValueError):
    """A camera or camera file is malformed; the message names the field (and camera index)."""


def _camera_error(field: str, message: str) -> CameraError:
    return CameraError(f"{field}: {message}")


def _whole_number(v: Any) -> Optional[int]:
    """``v`` as an int if it is an integer or an integral finite float (not a bool), else None."""
    if isinstance(v, bool):
        return None
    if isinstance(v, numbers.Integral):
        return int(v)
    if isinstance(v, numbers.Real) and math.isfinite(v) and float(v).is_integer():
        return int(v)
    return None


@dataclasses.dataclass(frozen=True, eq=False)
class Camera:
    """An immutable, validated pinhole camera in the OpenCV convention.

    Parameters
    ----------
    width, height : int
        Image size in pixels (> 0).
    fx, fy : float
        Focal lengths in pixels (> 0).
    cx, cy : float
        Principal point in pixels (pixel ``(i, j)`` is sampled at ``(i + 0.5, j + 0.5)``).
    world_to_camera : ndarray, shape [4, 4], float64
        Rigid transform ``[[R, t], [0, 0, 0, 1]]``; ``R`` must be a rotation (tolerance
        :data:`ROTATION_TOL`).
    background : ndarray, shape [3], float64
        Background colour in [0, 1] (default black).
    name : str
        Optional label (image name for COLMAP/Blender cameras).

    Raises
    ------
    CameraError
        On a non-positive or too large size (:data:`MAX_IMAGE_SIDE`, :data:`MAX_IMAGE_PIXELS`), a
        non-positive or too large focal length (:data:`MAX_FOCAL_PX`), a non-finite value, a
        matrix that is not rigid, or a background channel outside [0, 1].
    """

    width: int
    height: int
    fx: float
    fy: float
    cx: float
    cy: float
    world_to_camera: np.ndarray
    background: np.ndarray = dataclasses.field(default_factory=lambda: np.zeros(3))
    name: str = ""

    def __post_init__(self) -> None:
        set_ = lambda k, v: object.__setattr__(self, k, v)  # noqa: E731
        for key in ("width", "height"):
            v = _whole_number(getattr(self, key))
            if v is None:
                raise CameraError(f"{key}: {getattr(self, key)!r} must be a positive integer")
            if not 0 < v <= MAX_IMAGE_SIDE:
                raise CameraError(f"{key}: {v} must be a positive integer <= {MAX_IMAGE_SIDE} (MAX_IMAGE_SIDE)")
            set_(key, v)
        if self.width * self.height > MAX_IMAGE_PIXELS:
            raise CameraError(f"width: {self.width} x {self.height} = {self.width * self.height:,} pixels, more than "
                              f"{MAX_IMAGE_PIXELS:,} (MAX_IMAGE_PIXELS)")
        for key in ("fx", "fy", "cx", "cy"):
            try:
                v = float(getattr(self, key))
            except (TypeError, ValueError, OverflowError):
                raise CameraError(f"{key}: {getattr(self, key)!r} is not a number") from None
            if not math.isfinite(v):
                raise CameraError(f"{key}: {v} is not finite")
            if key in ("fx", "fy") and not 0 < v <= MAX_FOCAL_PX:
                raise CameraError(f"{key}: {v} must be > 0 and <= {MAX_FOCAL_PX:g} pixels (MAX_FOCAL_PX)")
            set_(key, v)
        try:
            m = np.array(self.world_to_camera, dtype=np.float64)
        except (TypeError, ValueError, OverflowError):
            raise CameraError("world_to_camera: must be a 4x4 matrix of numbers") from None
        if m.shape != (4, 4):
            raise CameraError(f"world_to_camera: shape {m.shape} must be [4, 4]")
        if not np.all(np.isfinite(m)):
            i, j = np.argwhere(~np.isfinite(m))[0]
            raise CameraError(f"world_to_camera[{i}][{j}]: {m[i, j]} is not finite")
        if not np.array_equal(m[3], [0.0, 0.0, 0.0, 1.0]):
            raise CameraError(f"world_to_camera[3]: {m[3].tolist()} must be [0, 0, 0, 1]")
        r = m[:3, :3]
        err = np.abs(r @ r.T - np.eye(3)).max()
        if err > ROTATION_TOL or np.linalg.det(r) < 0:
            raise CameraError(f"world_to_camera: rotation block is not a rotation "
                              f"(|R R^T - I| = {err:.2e}, det = {np.linalg.det(r):.4f})")
        m.setflags(write=False)
        set_("world_to_camera", m)
        try:
            bg = np.array(self.background, dtype=np.float64)
        except (TypeError, ValueError):
            raise CameraError(f"background: {self.background!r} must be 3 numbers in [0, 1]") from None
        if bg.shape != (3,):
            raise CameraError(f"background: {bg.tolist()} must be 3 numbers in [0, 1]")
        bad = ~((bg >= 0) & (bg <= 1))
        if bad.any():
            c = int(np.argmax(bad))
            raise CameraError(f"background[{c}]: {bg[c]} must be in [0, 1] (r, g, b)")
        bg.setflags(write=False)
        set_("background", bg)
        set_("name", str(self.name))

    @property
    def camera_to_world(self) -> np.ndarray:
        """Inverse of ``world_to_camera``, shape [4, 4]."""
        r, t = self.world_to_camera[:3, :3], self.world_to_camera[:3, 3]
        out = np.eye(4)
        out[:3, :3] = r.T
        out[:3, 3] = -r.T @ t
        return out

    @property
    def center(self) -> np.ndarray:
        """Camera centre in world coordinates, shape [3]."""
        return self.camera_to_world[:3, 3]

    @property
    def tan_half_fov(self) -> tuple[float, float]:
        """``(width / (2 fx), height / (2 fy))``: tangents of the half fields of view."""
        return self.width / (2.0 * self.fx), self.height / (2.0 * self.fy)

    def replace(self, **changes) -> "Camera":
        """Return a copy with some fields changed (validated again)."""
        return dataclasses.replace(self, **changes)

    def __repr__(self) -> str:
        return (f"Camera({self.width}x{self.height}, fx={self.fx:.2f}, fy={self.fy:.2f}, "
                f"cx={self.cx:.2f}, cy={self.cy:.2f}, center={np.round(self.center, 3).tolist()})")


def look_at(eye, target, up=(0.0, 0.0, 1.0)) -> np.ndarray:
    """World-to-camera matrix of a camera at ``eye`` looking at ``target`` (OpenCV axes).

    Parameters
    ----------
    eye, target : array_like, shape [3]
        World positions.
    up : array_like, shape [3]
        World up direction; image rows grow opposite to it.

    Returns
    -------
    ndarray, shape [4, 4]
    """
    eye, target, up = (np.asarray(v, np.float64) for v in (eye, target, up))
    z = target - eye
    if np.linalg.norm(z) == 0:
        raise CameraError("look_at: eye and target coincide")
    z = z / np.linalg.norm(z)
    x = np.cross(z, up)
    if np.linalg.norm(x) < 1e-9:
        x = np.cross(z, np.array([1.0, 0.0, 0.0]) if abs(z[0]) < 0.9 else np.array([0.0, 1.0, 0.0]))
    x = x / np.linalg.norm(x)
    y = np.cross(z, x)
    r = np.stack([x, y, z])
    out = np.eye(4)
    out[:3, :3] = r
    out[:3, 3] = -r @ eye
    return out


# ---------------------------------------------------------------------- camera JSON
def camera_to_dict(cam: Camera) -> dict:
    """The camera-JSON object of ``cam`` (floats written exactly, ``repr`` round trip)."""
    d = {"width": cam.width, "height": cam.height, "fx": cam.fx, "fy": cam.fy, "cx": cam.cx,
         "cy": cam.cy, "world_to_camera": cam.world_to_camera.tolist(),
         "background": cam.background.tolist()}
    if cam.name:
        d["name"] = cam.name
    return d


def camera_from_dict(d: dict, *, where: str = "camera") -> Camera:
    """Build a :class:`Camera` from a camera-JSON object; ``where`` prefixes error messages."""
    if not isinstance(d, dict):
        raise CameraError(f"{where}: expected an object, got {type(d).__name__}")
    unknown = sorted(set(d) - _JSON_KEYS)
    if unknown:
        raise CameraError(f"{where}.{unknown[0]}: unknown key (allowed: {', '.join(sorted(_JSON_KEYS))})")
    missing = [k for k in ("width", "height", "fx", "fy", "cx", "cy", "world_to_camera") if k not in d]
    if missing:
        raise CameraError(f"{where}.{missing[0]}: missing")
    try:
        return Camera(**{k: d[k] for k in d})
    except CameraError as exc:
        raise CameraError(f"{where}.{exc}") from None
    except (TypeError, ValueError, OverflowError) as exc:
        raise CameraError(f"{where}: {exc}") from None


#: Largest camera JSON or ``transforms.json`` read (bytes): ~100,000 cameras.
MAX_CAMERA_FILE_BYTES = 64 * 2**20


def _read_camera_json(path: Path) -> Any:
    return read_json(path, _camera_error, field="cameras", max_bytes=MAX_CAMERA_FILE_BYTES)


def _cameras_from_json(obj: Any, path: Path) -> list[Camera]:
    if isinstance(obj, dict):
        return [camera_from_dict(obj, where=f"{path.name}")]
    if isinstance(obj, list) and obj:
        return [camera_from_dict(o, where=f"{path.name}[{i}]") for i, o in enumerate(obj)]
    raise CameraError(f"{path}: expected a camera object or a non-empty list of them")


def load_cameras(path) -> list[Camera]:
    """Read a camera JSON file (one object or a list of objects) as a list of cameras.

    Raises
    ------
    CameraError
        If the file is missing, not a regular file, too large, not strict JSON, or any camera is
        malformed (the message gives its index).
    """
    path = Path(path)
    return _cameras_from_json(_read_camera_json(path), path)


def load_any_cameras(path) -> list[Camera]:
    """Cameras from a camera JSON, a ``transforms.json`` (an object with ``frames``) or a COLMAP
    model folder; the file is read once."""
    path = Path(path)
    if path.is_dir():
        return read_colmap(path)
    obj = _read_camera_json(path)
    if isinstance(obj, dict) and "frames" in obj:
        return _blender_from_json(obj, path)
    return _cameras_from_json(obj, path)


def load_camera(path, index: int = 0) -> Camera:
    """Read camera ``index`` of a camera JSON file (see :func:`load_cameras`)."""
    cams = load_cameras(path)
    if not -len(cams) <= index < len(cams):
        raise CameraError(f"{path}: camera index {index} out of range (file holds {len(cams)})")
    return cams[index]


def save_cameras(cameras: Camera | Sequence[Camera], path) -> Path:
    """Write one camera (an object) or a sequence (a list) as camera JSON; returns the path."""
    path = Path(path)
    path.parent.mkdir(parents=True, exist_ok=True)
    obj = camera_to_dict(cameras) if isinstance(cameras, Camera) else [camera_to_dict(c) for c in cameras]
    path.write_text(json.dumps(obj, indent=1))
    return path


# ---------------------------------------------------------------------- COLMAP
# model id -> (name, number of parameters), from COLMAP's src/colmap/sensor/models.h
_COLMAP_MODELS = {0: ("SIMPLE_PINHOLE", 3), 1: ("PINHOLE", 4), 2: ("SIMPLE_RADIAL", 4),
                  3: ("RADIAL", 5), 4: ("OPENCV", 8), 5: ("OPENCV_FISHEYE", 8),
                  6: ("FULL_OPENCV", 12), 7: ("FOV", 5), 8: ("SIMPLE_RADIAL_FISHEYE", 4),
                  9: ("RADIAL_FISHEYE", 5), 10: ("THIN_PRISM_FISHEYE", 12)}
_COLMAP_IDS = {name: (mid, n) for mid, (name, n) in _COLMAP_MODELS.items()}


def _qvec_to_rotmat(q) -> np.ndarray:
    q = np.asarray(q, np.float64)
    q = q / np.abs(q).max()  # first to [-1, 1]: the norm of a huge quaternion must not overflow
    w, x, y, z = q / np.linalg.norm(q)
    return np.array([[1 - 2 * (y * y + z * z), 2 * (x * y - w * z), 2 * (x * z + w * y)],
                     [2 * (x * y + w * z), 1 - 2 * (x * x + z * z), 2 * (y * z - w * x)],
                     [2 * (x * z - w * y), 2 * (y * z + w * x), 1 - 2 * (x * x + y * y)]])


def _rotmat_to_qvec(r: np.ndarray) -> np.ndarray:
    # Shepperd's method; returns w >= 0.
    m = np.asarray(r, np.float64)
    tr = np.trace(m)
    if tr > 0:
        s = 2.0 * math.sqrt(tr + 1.0)
        q = [0.25 * s, (m[2, 1] - m[1, 2]) / s, (m[0, 2] - m[2, 0]) / s, (m[1, 0] - m[0, 1]) / s]
    elif m[0, 0] > m[1, 1] and m[0, 0] > m[2, 2]:
        s = 2.0 * math.sqrt(1.0 + m[0, 0] - m[1, 1] - m[2, 2])
        q = [(m[2, 1] - m[1, 2]) / s, 0.25 * s, (m[0, 1] + m[1, 0]) / s, (m[0, 2] + m[2, 0]) / s]
    elif m[1, 1] > m[2, 2]:
        s = 2.0 * math.sqrt(1.0 + m[1, 1] - m[0, 0] - m[2, 2])
        q = [(m[0, 2] - m[2, 0]) / s, (m[0, 1] + m[1, 0]) / s, 0.25 * s, (m[1, 2] + m[2, 1]) / s]
    else:
        s = 2.0 * math.sqrt(1.0 + m[2, 2] - m[0, 0] - m[1, 1])
        q = [(m[1, 0] - m[0, 1]) / s, (m[0, 2] + m[2, 0]) / s, (m[1, 2] + m[2, 1]) / s, 0.25 * s]
    q = np.array(q)
    return q if q[0] >= 0 else -q


def _intrinsics(model: str, params, where: str) -> tuple[float, float, float, float]:
    if model == "SIMPLE_PINHOLE":
        f, cx, cy = params
        return f, f, cx, cy
    if model == "PINHOLE":
        return tuple(params)  # fx, fy, cx, cy
    raise CameraError(f"{where}: camera model {model} is not supported (undistort the images "
                      f"to PINHOLE first, as 3DGS requires)")


def _read_colmap_text(folder: Path):
    cams = {}
    for ln, line in iter_lines(read_text(folder / "cameras.txt", _camera_error, field="cameras.txt")):
        line = line.strip()
        if not line or line.startswith("#"):
            continue
        tok = line.split()
        where = f"cameras.txt line {ln}"
        try:
            cid, model, w, h = int(tok[0]), tok[1], int(tok[2]), int(tok[3])
            params = [float(v) for v in tok[4:]]
        except (IndexError, ValueError):
            raise CameraError(f"{where}: cannot parse {line!r}") from None
        if model not in _COLMAP_IDS:
            raise CameraError(f"{where}: unknown camera model {model!r}")
        if len(params) != _COLMAP_IDS[model][1]:
            raise CameraError(f"{where}: {model} takes {_COLMAP_IDS[model][1]} parameters, got {len(params)}")
        cams[cid] = (model, w, h, params, where)
    images = []
    points_line = False  # every image line is followed by its POINTS2D line
    for ln, line in iter_lines(read_text(folder / "images.txt", _camera_error, field="images.txt")):
        line = line.strip()
        if points_line:
            points_line = False
            continue
        if not line or line.startswith("#"):
            continue
        tok = line.split()
        where = f"images.txt line {ln}"
        try:
            q = [float(v) for v in tok[1:5]]
            t = [float(v) for v in tok[5:8]]
            cid, name = int(tok[8]), " ".join(tok[9:])
        except (IndexError, ValueError):
            raise CameraError(f"{where}: cannot parse {line!r}") from None
        images.append((name, q, t, cid, where))
        points_line = True
    return cams, images


def _read_colmap_binary(folder: Path):
    def unpack(f, fmt, where):
        size = struct.calcsize(fmt)
        buf = f.read(size)
        if len(buf) != size:
            raise CameraError(f"{where}: file truncated")
        return struct.unpack(fmt, buf)

    def opened(name: str):
        path = check_regular_file(folder / name, _camera_error, field=name)
        return open(path, "rb"), path.stat().st_size

    cams = {}
    f, _ = opened("cameras.bin")
    with f:
        (num,) = unpack(f, "<Q", "cameras.bin")
        for k in range(num):
            where = f"cameras.bin camera {k}"
            cid, mid, w, h = unpack(f, "<iiQQ", where)
            if mid not in _COLMAP_MODELS:
                raise CameraError(f"{where}: unknown camera model id {mid}")
            model, npar = _COLMAP_MODELS[mid]
            params = unpack(f, "<" + "d" * npar, where)
            cams[cid] = (model, w, h, list(params), where)
        if f.read(1):
            raise CameraError("cameras.bin: trailing bytes after the last camera")
    images = []
    f, size = opened("images.bin")
    with f:
        (num,) = unpack(f, "<Q", "images.bin")
        for k in range(num):
            where = f"images.bin image {k}"
            vals = unpack(f, "<idddddddi", where)
            name = b""
            while True:
                c = f.read(1)
                if not c:
                    raise CameraError(f"{where}: file truncated in the image name")
                if c == b"\x00":
                    break
                name += c
            (npts,) = unpack(f, "<Q", where)
            if 24 * npts > size - f.tell():  # skipped, never read: the count may be absurd
                raise CameraError(f"{where}: file truncated in the 2D points ({npts:,} claimed)")
            f.seek(24 * npts, io.SEEK_CUR)
            images.append((name.decode("utf-8", "replace"), list(vals[1:5]), list(vals[5:8]), vals[8], where))
        if f.read(1):
            raise CameraError("images.bin: trailing bytes after the last image")
    return cams, images


def read_colmap(folder, *, background=(0.0, 0.0, 0.0)) -> list[Camera]:
    """Read the cameras of a COLMAP sparse model (text or binary), sorted by image name.

    Parameters
    ----------
    folder : str or Path
        Folder holding ``cameras.txt`` + ``images.txt`` or ``cameras.bin`` + ``images.bin``
        (e.g. ``sparse/0``); text is used when both exist.
    background : array_like, shape [3]
        Background colour given to every camera.

    Returns
    -------
    list of Camera
        One camera per registered image, ``name`` = image name; ``world_to_camera`` from the
        image's ``QW QX QY QZ TX TY TZ`` (COLMAP already uses world-to-camera, OpenCV axes).

    Raises
    ------
    CameraError
        Missing or malformed files, an unknown camera id, a distorted camera model.
    """
    folder = Path(folder)
    if (folder / "cameras.txt").exists() and (folder / "images.txt").exists():
        cams, images = _read_colmap_text(folder)
    elif (folder / "cameras.bin").exists() and (folder / "images.bin").exists():
        cams, images = _read_colmap_binary(folder)
    else:
        raise CameraError(f"{folder}: no COLMAP model (cameras.txt + images.txt or cameras.bin + images.bin)")
    out = []
    for name, q, t, cid, where in sorted(images, key=lambda im: im[0]):
        if cid not in cams:
            raise CameraError(f"{where}: camera id {cid} is not in the cameras file")
        model, w, h, params, cwhere = cams[cid]
        fx, fy, cx, cy = _intrinsics(model, params, cwhere)
        if not np.all(np.isfinite(q)) or not np.any(q):
            raise CameraError(f"{where}: quaternion {q} must be finite and non-zero")
        m = np.eye(4)
        m[:3, :3] = _qvec_to_rotmat(q)
        m[:3, 3] = t
        try:
            out.append(Camera(width=w, height=h, fx=fx, fy=fy, cx=cx, cy=cy, world_to_camera=m,
                              background=background, name=name))
        except CameraError as exc:
            raise CameraError(f"{where}: {exc}") from None
    return out


def write_colmap(cameras: Sequence[Camera], folder, *, binary: bool = False) -> Path:
    """Write cameras as a COLMAP sparse model (PINHOLE, one camera per image, no points).

    Image names are the cameras' ``name`` (or ``{index:05d}.png``).  Returns the folder.
    """
    folder = Path(folder)
    folder.mkdir(parents=True, exist_ok=True)
    rows = []
    for i, cam in enumerate(cameras):
        q = _rotmat_to_qvec(cam.world_to_camera[:3, :3])
        rows.append((i + 1, cam, q, cam.world_to_camera[:3, 3], cam.name or f"{i:05d}.png"))
    if binary:
        with open(folder / "cameras.bin", "wb") as f:
            f.write(struct.pack("<Q", len(rows)))
            for cid, cam, _, _, _ in rows:
                f.write(struct.pack("<iiQQdddd", cid, 1, cam.width, cam.height, cam.fx, cam.fy, cam.cx, cam.cy))
        with open(folder / "images.bin", "wb") as f:
            f.write(struct.pack("<Q", len(rows)))
            for cid, cam, q, t, name in rows:
                f.write(struct.pack("<idddddddi", cid, *q, *t, cid))
                f.write(name.encode() + b"\x00")
                f.write(struct.pack("<Q", 0))
    else:
        lines = ["# Camera list with one line of data per camera:",
                 "#   CAMERA_ID, MODEL, WIDTH, HEIGHT, PARAMS[]"]
        lines += [f"{cid} PINHOLE {cam.width} {cam.height} {cam.fx!r} {cam.fy!r} {cam.cx!r} {cam.cy!r}"
                  for cid, cam, _, _, _ in rows]
        (folder / "cameras.txt").write_text("\n".join(lines) + "\n")
        lines = ["# Image list with two lines of data per image:",
                 "#   IMAGE_ID, QW, QX, QY, QZ, TX, TY, TZ, CAMERA_ID, NAME",
                 "#   POINTS2D[] as (X, Y, POINT3D_ID)"]
        for cid, cam, q, t, name in rows:
            lines.append(" ".join([str(cid)] + [repr(float(v)) for v in (*q, *t)] + [str(cid), name]))
            lines.append("")
        (folder / "images.txt").write_text("\n".join(lines) + "\n")
    return folder


# ---------------------------------------------------------------------- NeRF / Blender
def read_blender(path, *, width: Optional[int] = None, height: Optional[int] = None,
                 background=(0.0, 0.0, 0.0)) -> list[Camera]:
    """Read a NeRF / Blender ``transforms.json`` (OpenGL camera-to-world) as OpenCV cameras.

    Intrinsics: ``fl_x``/``fl_y``/``cx``/``cy`` when present (instant-ngp style), otherwise
    ``fx = fy = width / (2 tan(camera_angle_x / 2))`` (``fy`` from ``camera_angle_y`` if
    given) and the principal point at the image centre.  ``w``/``h`` in the file give the
    size; otherwise pass ``width`` and ``height`` (the Blender synthetic set is 800 x 800).
    Each ``transform_matrix`` ``C`` (x right, y up, z backward) becomes
    ``world_to_camera = inverse(C @ diag(1, -1, -1, 1))``.

    Raises
    ------
    CameraError
        Missing file or keys, unknown size, a matrix that is not 4x4 and rigid.
    """
    path = Path(path)
    return _blender_from_json(_read_camera_json(path), path, width=width, height=height, background=background)


def _blender_number(obj: dict, key: str, where: str, default: Optional[float] = None) -> float:
    v = obj.get(key, default)
    if isinstance(v, bool) or not isinstance(v, (int, float)):
        raise CameraError(f"{where}.{key}: {v!r} must be a number")
    try:
        v = float(v)
    except OverflowError:
        v = math.inf
    if not math.isfinite(v):
        raise CameraError(f"{where}.{key}: {v!r} must be finite")
    return v


def _blender_from_json(obj: Any, path: Path, *, width: Optional[int] = None, height: Optional[int] = None,
                       background=(0.0, 0.0, 0.0)) -> list[Camera]:
    if not isinstance(obj, dict) or not isinstance(obj.get("frames"), list):
        raise CameraError(f"{path}: expected an object with a 'frames' list")
    where = path.name
    w, h = obj.get("w", width), obj.get("h", height)
    if w is None or h is None:
        raise CameraError(f"{path}: image size unknown (no 'w'/'h' in the file; pass width= and height=)")
    for key, v in (("w", w), ("h", h)):
        if _whole_number(v) is None or not 0 < _whole_number(v) <= MAX_IMAGE_SIDE:
            raise CameraError(f"{where}.{key}: {v!r} must be a positive integer <= {MAX_IMAGE_SIDE} (MAX_IMAGE_SIDE)")
    w, h = _whole_number(w), _whole_number(h)
    if "fl_x" in obj:
        fx = _blender_number(obj, "fl_x", where)
        fy = _blender_number(obj, "fl_y", where, fx)
    elif "camera_angle_x" in obj:
        angles = {}
        for key in ("camera_angle_x", "camera_angle_y"):
            if key in obj:
                angles[key] = _blender_number(obj, key, where)
                if not 0 < angles[key] < math.pi:
                    raise CameraError(f"{where}.{key}: {angles[key]!r} must be in (0, pi) radians")
        fx = 0.5 * w / math.tan(0.5 * angles["camera_angle_x"])
        fy = 0.5 * h / math.tan(0.5 * angles["camera_angle_y"]) if "camera_angle_y" in angles else fx
    else:
        raise CameraError(f"{path}: neither 'fl_x' nor 'camera_angle_x' given")
    cx = _blender_number(obj, "cx", where, w / 2.0)
    cy = _blender_number(obj, "cy", where, h / 2.0)
    flip = np.diag([1.0, -1.0, -1.0, 1.0])
    out = []
    for i, fr in enumerate(obj["frames"]):
        where = f"{path.name}: frames[{i}]"
        if not isinstance(fr, dict) or "transform_matrix" not in fr:
            raise CameraError(f"{where}: missing 'transform_matrix'")
        try:
            c2w = np.array(fr["transform_matrix"], dtype=np.float64)
        except (TypeError, ValueError, OverflowError):
            c2w = np.zeros(0)
        if c2w.shape != (4, 4) or not np.all(np.isfinite(c2w)):
            raise CameraError(f"{where}.transform_matrix: must be a finite 4x4 matrix")
        c2w = c2w @ flip
        r, t = c2w[:3, :3], c2w[:3, 3]
        w2c = np.eye(4)
        w2c[:3, :3] = r.T
        with np.errstate(over="ignore", invalid="ignore"):  # an overflow is refused by Camera, by name
            w2c[:3, 3] = -r.T @ t
        try:
            out.append(Camera(width=w, height=h, fx=fx, fy=fy, cx=cx, cy=cy, world_to_camera=w2c,
                              background=background, name=str(fr.get("file_path", f"{i:05d}"))))
        except CameraError as exc:
            raise CameraError(f"{where}: {exc}") from None
    return out


def write_blender(cameras: Sequence[Camera], path) -> Path:
    """Write cameras as an instant-ngp style ``transforms.json`` (``w``, ``h``, ``fl_x``, ...).

    All cameras must share the intrinsics.  Returns the path.
    """
    cams = list(cameras)
    c0 = cams[0]
    for i, c in enumerate(cams):
        if (c.width, c.height, c.fx, c.fy, c.cx, c.cy) != (c0.width, c0.height, c0.fx, c0.fy, c0.cx, c0.cy):
            raise CameraError(f"cameras[{i}]: intrinsics differ from cameras[0]; transforms.json holds one set")
    flip = np.diag([1.0, -1.0, -1.0, 1.0])
    frames = [{"file_path": c.name or f"{i:05d}", "transform_matrix": (c.camera_to_world @ flip).tolist()}
              for i, c in enumerate(cams)]
    obj = {"w": c0.width, "h": c0.height, "fl_x": c0.fx, "fl_y": c0.fy, "cx": c0.cx, "cy": c0.cy,
           "camera_angle_x": 2.0 * math.atan(c0.width / (2.0 * c0.fx)), "frames": frames}
    path = Path(path)
    path.parent.mkdir(parents=True, exist_ok=True)
    path.write_text(json.dumps(obj, indent=1))
    return path
