"""Pinhole cameras (OpenCV convention) and their file formats.

Length (~1000 lines): the camera type, the four file formats it is read from and written to
(camera JSON, NeRF ``transforms.json``, COLMAP text and binary), each validated field by field, and
the one lens-distortion rule both real formats share (so it lives beside them).

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
  PINHOLE and SIMPLE_PINHOLE cameras, and SIMPLE_RADIAL, RADIAL, OPENCV and FULL_OPENCV ones under
  the distortion rule below; fisheye and FOV models are refused.
* **NeRF / Blender ``transforms.json``**: OpenGL camera-to-world matrices (x right, y up,
  z backward), converted to OpenCV world-to-camera; intrinsics, size and distortion
  (``k1``-``k4``, ``p1``, ``p2``) from the file or, nerfstudio style, from each frame.

**Lens distortion** (one rule for COLMAP and ``transforms.json``): the renderer is a pinhole, so
distortion is dropped, and what that costs is measured by :func:`max_distortion_px`, the largest
displacement (pixels) the distortion model applies over the camera's image.  Zero distortion is
accepted silently; up to :data:`MAX_DROPPED_DISTORTION_PX` it is accepted with a
:class:`DistortionWarning` that states the error; above it the camera is refused with a
:class:`CameraError` naming the file, the camera or frame and the coefficients, and asking for
undistorted images (COLMAP's ``image_undistorter``).

**Image size**: every loader takes ``width=``/``height=`` (the command line's ``--size WxH``,
parsed by :func:`parse_image_size`).  A file without a size (the NeRF synthetic
``transforms_*.json``, 800 x 800 images) takes it as its size; a file with one is rescaled to it by
:meth:`Camera.resized` (``fx``, ``cx`` scale by the width ratio, ``fy``, ``cy`` by the height
ratio; the aspect ratio must stay, up to rounding).

Every file is read through :mod:`l3gs_opt.input_files` (regular files only, sizes limited, strict
JSON). A camera is refused by name before any image is allocated when its size exceeds
:data:`MAX_IMAGE_SIDE` pixels a side or :data:`MAX_IMAGE_PIXELS` in all, its focal length
:data:`MAX_FOCAL_PX`, its field of view :data:`MAX_FOV_DEG`, its principal point lies more than :data:`MAX_PRINCIPAL_POINT_OUTSIDE` image
sizes outside the image, a background channel leaves [0, 1], or its name is not text.
"""

from __future__ import annotations

import dataclasses
import io
import json
import math
import numbers
import re
import struct
import warnings
from pathlib import Path
from typing import Any, Optional, Sequence

import numpy as np

from l3gs_opt.errors import L3gsError
from l3gs_opt.input_files import check_regular_file, read_json, read_text
from l3gs_opt.scene.splats import MAX_ABS_MEAN
from l3gs_opt.traces.bandwidth import iter_lines

__all__ = ["CameraError", "DistortionWarning", "Camera", "load_cameras", "load_camera", "load_any_cameras",
           "save_cameras", "camera_to_dict", "camera_from_dict", "read_colmap", "write_colmap",
           "read_blender", "write_blender", "look_at", "parse_image_size", "max_distortion_px",
           "check_background", "MAX_IMAGE_SIDE", "MAX_IMAGE_PIXELS", "MAX_FOCAL_PX", "MAX_FOV_DEG",
           "MAX_PRINCIPAL_POINT_OUTSIDE", "MAX_DROPPED_DISTORTION_PX"]

#: Longest image side (pixels). Renders are allocated per pixel; 16k covers every real sensor.
MAX_IMAGE_SIDE = 16384
#: Most pixels of one image (2^25, about 8K UHD): a float32 RGB render of it takes 400 MB already.
MAX_IMAGE_PIXELS = 2**25
#: Largest focal length (pixels): a 0.0001 degree field of view at 16k pixels. Larger ones overflow
#: the renderer's float32 screen-space covariances (fx^2 Sigma / z^2) and training turns them into NaN.
MAX_FOCAL_PX = 1e9
#: Widest field of view (degrees) across either image axis, the smallest focal length's limit
#: (``fx >= width / (2 tan(MAX_FOV_DEG / 2))``, about ``width / 229``): a pinhole's image plane is
#: infinitely wide at 180 degrees, and near it ``tan(fov / 2)``, which the renderer's clamps and
#: screen-space covariances scale by, explodes (``fx = 1e-300`` is a 3e302 tangent). Real lenses,
#: undistorted, stay well below 150 degrees.
MAX_FOV_DEG = 179.0
#: How far outside the image the principal point may lie, in image sizes: ``cx`` in
#: ``[-W, 2 W]``, ``cy`` in ``[-H, 2 H]``. Real calibrations put it within a few per cent of the
#: centre, and a crop moves it at most about an image away; the renderer clamps x/z and y/z to
#: 1.3 tan(fov / 2) about the optical axis (the 3DGS Jacobian clamp), so already at this distance
#: every pixel lies beyond the clamp. Further out is a unit or typing mistake (``cx = 1e20``
#: renders an empty image without complaint).
MAX_PRINCIPAL_POINT_OUTSIDE = 1.0

#: Tolerance on ``R R^T = I`` for the rotation block of ``world_to_camera`` (file formats store
#: rotations in float32 or as rounded decimals; a true scale or shear is far larger).
ROTATION_TOL = 1e-4

#: Largest lens distortion (pixels, over the whole image) dropped with a warning rather than refused.
#: Half a pixel is as far as rounding to the pixel grid already moves a point, so below it a
#: pinhole render is as faithful as the grid allows; more visibly misregisters renders against
#: the photographs (and training fits splats to the distorted geometry).
MAX_DROPPED_DISTORTION_PX = 0.5
#: Samples per image side at which :func:`max_distortion_px` evaluates the distortion (edges and
#: corners included): the displacement is a smooth low-order function of the position, so 65 x 65
#: points bound it to far below :data:`MAX_DROPPED_DISTORTION_PX`'s precision.
DISTORTION_SAMPLES = 65

_JSON_KEYS = {"width", "height", "fx", "fy", "cx", "cy", "world_to_camera", "background", "name"}


class CameraError(L3gsError, ValueError):
    """A camera or camera file is malformed; the message names the field (and camera index)."""


class DistortionWarning(UserWarning):
    """A camera's lens distortion was dropped (the renderer is a pinhole); the message states the
    largest pixel error it causes, below :data:`MAX_DROPPED_DISTORTION_PX`."""


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


def _check_size(width: Any, height: Any, field: str) -> tuple[int, int]:
    """``(width, height)`` as ints after the limits every camera obeys; ``field`` names them."""
    out = []
    for key, v in (("width", width), ("height", height)):
        n = _whole_number(v)
        if n is None or not 0 < n <= MAX_IMAGE_SIDE:
            raise CameraError(f"{field}: {key} {v!r} must be a positive integer <= {MAX_IMAGE_SIDE} (MAX_IMAGE_SIDE)")
        out.append(n)
    if out[0] * out[1] > MAX_IMAGE_PIXELS:
        raise CameraError(f"{field}: {out[0]} x {out[1]} = {out[0] * out[1]:,} pixels, more than "
                          f"{MAX_IMAGE_PIXELS:,} (MAX_IMAGE_PIXELS)")
    return out[0], out[1]


def check_background(value: Any, field: str = "background") -> np.ndarray:
    """``value`` as an RGB triple, float64 ``[3]``, each channel in [0, 1]; the one check of every
    background (a camera's, ``render --background``, ``scene make --background``).

    Raises
    ------
    CameraError
        ``background[0]: 2.0 must be in [0, 1] (r, g, b)``, or naming ``field`` for a value that is
        not 3 numbers.
    """
    try:
        bg = np.array(value, dtype=np.float64)
    except (TypeError, ValueError):
        raise CameraError(f"{field}: {value!r} must be 3 numbers in [0, 1]") from None
    if bg.shape != (3,):
        raise CameraError(f"{field}: {bg.tolist()} must be 3 numbers in [0, 1]")
    bad = ~((bg >= 0) & (bg <= 1))
    if bad.any():
        c = int(np.argmax(bad))
        raise CameraError(f"{field}[{c}]: {bg[c]} must be in [0, 1] (r, g, b)")
    return bg


def _optional_size(width: Any, height: Any) -> Optional[tuple[int, int]]:
    """The ``width=``/``height=`` options of the loaders: both or neither."""
    if width is None and height is None:
        return None
    if width is None or height is None:
        raise CameraError(f"size: width={width!r}, height={height!r}: give both or neither")
    return _check_size(width, height, "size")


# ASCII digits only (\d would take other scripts' digits), no sign, no leading zero
_SIZE_RE = re.compile(r"([1-9][0-9]{0,15})[xX]([1-9][0-9]{0,15})")


def parse_image_size(text: str, *, field: str = "--size") -> tuple[int, int]:
    """Parse ``WxH`` (e.g. ``800x800``) into ``(width, height)`` in pixels.

    Strict: two positive whole numbers without sign, spaces or leading zeros, joined by ``x``
    (or ``X``); each at most :data:`MAX_IMAGE_SIDE`, their product at most
    :data:`MAX_IMAGE_PIXELS`.

    Raises
    ------
    CameraError
        Naming ``field`` and the text, e.g. ``--size: '0x5' must be WxH ...``.
    """
    m = _SIZE_RE.fullmatch(text) if isinstance(text, str) else None
    if m is None:
        raise CameraError(f"{field}: {text!r} must be WxH, two positive whole numbers of pixels such as 800x800")
    return _check_size(int(m.group(1)), int(m.group(2)), f"{field} {text}")


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
        Principal point in pixels (pixel ``(i, j)`` is sampled at ``(i + 0.5, j + 0.5)``), within
        ``[-W, 2 W]`` x ``[-H, 2 H]`` (:data:`MAX_PRINCIPAL_POINT_OUTSIDE`).
    world_to_camera : ndarray, shape [4, 4], float64
        Rigid transform ``[[R, t], [0, 0, 0, 1]]``; ``R`` must be a rotation (tolerance
        :data:`ROTATION_TOL`).
    background : ndarray, shape [3], float64
        Background colour in [0, 1] (default black).
    name : str
        Optional label (image name for COLMAP/Blender cameras); must be text.

    Raises
    ------
    CameraError
        On a non-positive or too large size (:data:`MAX_IMAGE_SIDE`, :data:`MAX_IMAGE_PIXELS`), a
        focal length that is not a number (a string or bool), non-positive, too large
        (:data:`MAX_FOCAL_PX`) or so small that the field of view passes :data:`MAX_FOV_DEG`, a principal point more
        than :data:`MAX_PRINCIPAL_POINT_OUTSIDE` image sizes outside the image, a non-finite
        value, a matrix that is not rigid, a translation beyond the splats'
        :data:`~l3gs_opt.scene.splats.MAX_ABS_MEAN`, a background channel outside [0, 1], or a
        name that is not text.
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
            raw = getattr(self, key)
            # float("500") and float(True) would take a string or a flag as a number (as width does not)
            if isinstance(raw, (bool, np.bool_)) or not isinstance(raw, numbers.Real):
                raise CameraError(f"{key}: {raw!r} is not a number")
            try:
                v = float(raw)
            except (TypeError, ValueError, OverflowError):
                raise CameraError(f"{key}: {raw!r} is not a number") from None
            if not math.isfinite(v):
                raise CameraError(f"{key}: {v} is not finite")
            if key in ("fx", "fy") and not 0 < v <= MAX_FOCAL_PX:
                raise CameraError(f"{key}: {v} must be > 0 and <= {MAX_FOCAL_PX:g} pixels (MAX_FOCAL_PX)")
            if key in ("fx", "fy"):
                side = self.width if key == "fx" else self.height
                if side / (2.0 * v) > math.tan(math.radians(MAX_FOV_DEG / 2)):
                    fov = math.degrees(2 * math.atan(side / (2.0 * v)))
                    raise CameraError(f"{key}: {v:g} pixels gives a {fov:.6g} degree field of view across the {side} "
                                      f"pixel {'width' if key == 'fx' else 'height'}; it must be at most "
                                      f"{MAX_FOV_DEG:g} (MAX_FOV_DEG)")
            if key in ("cx", "cy"):
                side = self.width if key == "cx" else self.height
                out = MAX_PRINCIPAL_POINT_OUTSIDE * side
                if not -out <= v <= side + out:
                    raise CameraError(f"{key}: {v:g} must be in [{-out:g}, {side + out:g}] pixels, at most "
                                      f"{MAX_PRINCIPAL_POINT_OUTSIDE:g} image size outside the "
                                      f"{self.width}x{self.height} image (MAX_PRINCIPAL_POINT_OUTSIDE)")
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
        # |t| is the camera centre's distance from the origin: beyond the splats' own limit the
        # renderer's float32 distances overflow and the picture comes out empty, without an error.
        far = np.nonzero(np.abs(m[:3, 3]) > MAX_ABS_MEAN)[0]
        if len(far):
            i = int(far[0])
            raise CameraError(f"world_to_camera[{i}][3]: {m[i, 3]:g} must be within +-{MAX_ABS_MEAN:g} world units "
                              "(MAX_ABS_MEAN): float32 arithmetic on it overflows")
        r = m[:3, :3]
        err = np.abs(r @ r.T - np.eye(3)).max()
        if err > ROTATION_TOL or np.linalg.det(r) < 0:
            raise CameraError(f"world_to_camera: rotation block is not a rotation "
                              f"(|R R^T - I| = {err:.2e}, det = {np.linalg.det(r):.4f})")
        m.setflags(write=False)
        set_("world_to_camera", m)
        bg = check_background(self.background)
        bg.setflags(write=False)
        set_("background", bg)
        # str(5) would hide a misplaced number (``"name": 5`` in a camera JSON)
        if not isinstance(self.name, str):
            raise CameraError(f"name: {self.name!r} must be text")
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

    def resized(self, width: int, height: int) -> "Camera":
        """The same view for an image of ``width`` x ``height`` pixels.

        ``fx`` and ``cx`` scale by ``width / self.width``, ``fy`` and ``cy`` by
        ``height / self.height``: pixel edges 0 and ``self.width`` map to 0 and ``width``, which
        in this convention (pixel ``i`` covers ``[i, i + 1)``) is exact, without half-pixel terms.
        The aspect ratio must stay up to rounding: some scale ``s`` has
        ``|s self.width - width| <= 0.5`` and ``|s self.height - height| <= 0.5``; a stretched
        view is refused as a likely mistake (build the camera by hand for that).

        Raises
        ------
        CameraError
            On a size outside the camera limits or one that changes the aspect ratio.
        """
        width, height = _check_size(width, height, "size")
        if (width, height) == (self.width, self.height):
            return self
        lo = max((width - 0.5) / self.width, (height - 0.5) / self.height)
        hi = min((width + 0.5) / self.width, (height + 0.5) / self.height)
        if lo > hi:
            keep = max(1, round(self.height * width / self.width))
            raise CameraError(f"size: {width}x{height} changes the aspect ratio of the camera's "
                              f"{self.width}x{self.height} image; give a size of the same shape, "
                              f"e.g. {width}x{keep}")
        sx, sy = width / self.width, height / self.height
        return self.replace(width=width, height=height, fx=self.fx * sx, fy=self.fy * sy,
                            cx=self.cx * sx, cy=self.cy * sy)

    def __repr__(self) -> str:
        return (f"Camera({self.width}x{self.height}, fx={self.fx:.2f}, fy={self.fy:.2f}, "
                f"cx={self.cx:.2f}, cy={self.cy:.2f}, center={np.round(self.center, 3).tolist()})")


def _look_at_vector(name: str, value: Any) -> np.ndarray:
    """An argument of :func:`look_at` as float64 [3] after checking it is 3 finite numbers."""
    try:
        v = np.asarray(value)
    except (TypeError, ValueError):   # ragged rows
        v = np.asarray(None)
    # strings ("abc", ["1", "2", "3"]) and flags are refused, not parsed or taken as 0 and 1
    if v.dtype.kind not in "iuf":
        raise CameraError(f"look_at: {name}: {value!r} must be 3 numbers")
    v = v.astype(np.float64)
    if v.shape != (3,):
        raise CameraError(f"look_at: {name}: shape {v.shape} must be [3] (x, y, z)")
    if not np.isfinite(v).all():
        i = int(np.argmax(~np.isfinite(v)))
        raise CameraError(f"look_at: {name}[{i}]: {v[i]} is not finite")
    return v


def look_at(eye, target, up=(0.0, 0.0, 1.0)) -> np.ndarray:
    """World-to-camera matrix of a camera at ``eye`` looking at ``target`` (OpenCV axes).

    Parameters
    ----------
    eye, target : array_like, shape [3]
        World positions.
    up : array_like, shape [3]
        World up direction (any length > 0); image rows grow opposite to it. It must not be
        parallel to the view direction ``target - eye``, which leaves the image's roll undefined
        (looking straight down with ``up`` = +z: pass the direction the image top should face).

    Returns
    -------
    ndarray, shape [4, 4]

    Raises
    ------
    CameraError
        On a position or direction that is not 3 finite numbers, a position beyond
        :data:`~l3gs_opt.scene.splats.MAX_ABS_MEAN`, ``eye == target``, a zero ``up`` or one
        parallel to the view direction.
    """
    eye, target, up = (_look_at_vector(name, v) for name, v in (("eye", eye), ("target", target), ("up", up)))
    for name, v in (("eye", eye), ("target", target)):
        # the Camera's own translation limit: beyond it target - eye and |t| leave float range
        if np.abs(v).max() > MAX_ABS_MEAN:
            raise CameraError(f"look_at: {name}: {v.tolist()} must be within +-{MAX_ABS_MEAN:g} world units "
                              "(MAX_ABS_MEAN)")
    z = target - eye
    if np.linalg.norm(z) == 0:
        raise CameraError("look_at: eye and target coincide")
    z = z / np.linalg.norm(z)
    if not np.any(up):
        raise CameraError(f"look_at: up: {up.tolist()} must be a non-zero direction")
    given = up.tolist()
    # scaled by its largest entry first, so that neither 1e-300 nor 1e300 under/overflows the norm
    up = up / np.abs(up).max()
    up = up / np.linalg.norm(up)
    x = np.cross(z, up)
    if np.linalg.norm(x) < 1e-9:   # |sin| of the angle between up and the view: the roll is undefined
        raise CameraError(f"look_at: up: {given} is parallel to the view direction {z.tolist()} "
                          "(target - eye): the image's roll is undefined; give an up direction across the view")
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


def load_any_cameras(path, *, width: Optional[int] = None, height: Optional[int] = None) -> list[Camera]:
    """Cameras from a camera JSON, a ``transforms.json`` (an object with ``frames``) or a COLMAP
    model folder; the file is read once.

    Parameters
    ----------
    path : str or Path
        The file or COLMAP folder.
    width, height : int, optional
        Image size in pixels, both or neither: the size of a ``transforms.json`` without
        ``w``/``h``; every other camera is rescaled to it (:meth:`Camera.resized`).

    Raises
    ------
    CameraError
        As the format's reader; a size that changes a camera's aspect ratio.
    """
    path = Path(path)
    if path.is_dir():
        return read_colmap(path, width=width, height=height)
    size = _optional_size(width, height)
    obj = _read_camera_json(path)
    if isinstance(obj, dict) and "frames" in obj:
        return _blender_from_json(obj, path, width=width, height=height)
    cams = _cameras_from_json(obj, path)
    if size is None:
        return cams
    out = []
    for i, cam in enumerate(cams):
        try:
            out.append(cam.resized(*size))
        except CameraError as exc:
            raise CameraError(f"{path.name}[{i}]: {exc}") from None
    return out


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


# ---------------------------------------------------------------------- lens distortion
def max_distortion_px(width: int, height: int, fx: float, fy: float, cx: float, cy: float, *,
                      radial: Sequence[float] = (), tangential: Sequence[float] = (0.0, 0.0),
                      rational: Sequence[float] = ()) -> float:
    """Largest displacement (pixels) an OpenCV-style lens distortion applies over an image.

    A pinhole pixel position ``(u, v)`` has normalised coordinates ``x = (u - cx) / fx``,
    ``y = (v - cy) / fy``, ``r^2 = x^2 + y^2``; the distortion moves it to

    .. math::

        x_d = x \\rho + 2 p_1 x y + p_2 (r^2 + 2 x^2), \\quad
        y_d = y \\rho + p_1 (r^2 + 2 y^2) + 2 p_2 x y, \\quad
        \\rho = \\frac{1 + \\sum_i a_i r^{2i}}{1 + \\sum_i b_i r^{2i}}

    (``a`` = ``radial``, ``b`` = ``rational``; COLMAP's and OpenCV's convention).  The result is
    ``max sqrt((fx (x_d - x))^2 + (fy (y_d - y))^2)`` over a :data:`DISTORTION_SAMPLES` square grid
    of ``[0, width] x [0, height]`` (edges and corners included): the pixel error of rendering
    the camera as a pinhole.  It is the forward displacement at the pinhole positions; the
    displacement at the photograph's own pixels differs from it by second-order terms only.

    Parameters
    ----------
    width, height : int
        Image size in pixels.
    fx, fy, cx, cy : float
        Focal lengths and principal point in pixels.
    radial : sequence of float
        ``a_1, a_2, ...``: coefficients of ``r^2, r^4, ...`` in the numerator (COLMAP's ``k1, k2``,
        FULL_OPENCV's ``k1, k2, k3``; nerfstudio's ``k1`` .. ``k4``).
    tangential : sequence of float, length 2
        ``p1, p2``.
    rational : sequence of float
        ``b_1, b_2, ...``: denominator coefficients (FULL_OPENCV's ``k4, k5, k6``).

    Returns
    -------
    float
        Pixels; ``inf`` when the model overflows or divides by zero on the image.

    Examples
    --------
    A SIMPLE_RADIAL camera ``f = 100`` on a 200 x 200 image (``cx = cy = 100``) with
    ``k1 = 0.001``: the corner ``x = y = 1`` moves by ``f k1 r^2 sqrt(2) = 100 * 0.002 * sqrt(2)``:

    >>> round(max_distortion_px(200, 200, 100.0, 100.0, 100.0, 100.0, radial=[0.001]), 6)
    0.282843
    """
    p1, p2 = (float(v) for v in tangential)
    u = np.linspace(0.0, float(width), DISTORTION_SAMPLES)
    v = np.linspace(0.0, float(height), DISTORTION_SAMPLES)
    x, y = np.meshgrid((u - cx) / fx, (v - cy) / fy)
    with np.errstate(over="ignore", invalid="ignore", divide="ignore"):
        r2 = x * x + y * y
        num, den, rk = np.ones_like(r2), np.ones_like(r2), np.ones_like(r2)
        for a in radial:
            rk = rk * r2
            num = num + float(a) * rk
        rk = np.ones_like(r2)
        for b in rational:
            rk = rk * r2
            den = den + float(b) * rk
        rho = num / den
        dx = x * (rho - 1.0) + 2.0 * p1 * x * y + p2 * (r2 + 2.0 * x * x)
        dy = y * (rho - 1.0) + p1 * (r2 + 2.0 * y * y) + 2.0 * p2 * x * y
        err = np.hypot(fx * dx, fy * dy)
    if not np.all(np.isfinite(err)):
        return math.inf
    return float(err.max())


def _describe(names: Sequence[str], values: Sequence[float]) -> str:
    return ", ".join(f"{n}={v:g}" for n, v in zip(names, values))


def _check_distortion(cam: Camera, coeffs: dict, where: str, *, radial=(), tangential=(0.0, 0.0),
                      rational=()) -> Optional[tuple[float, str]]:
    """Apply the distortion rule to ``cam``: None when undistorted, ``(pixels, description)``
    when the distortion is small enough to drop, else raise.  ``coeffs`` maps the file's
    coefficient names to values, for the messages."""
    bad = [k for k, v in coeffs.items() if not math.isfinite(v)]
    if bad:
        raise CameraError(f"{where}: distortion {bad[0]}={coeffs[bad[0]]!r} must be finite")
    if not any(coeffs.values()):
        return None
    err = max_distortion_px(cam.width, cam.height, cam.fx, cam.fy, cam.cx, cam.cy,
                            radial=radial, tangential=tangential, rational=rational)
    what = f"{where}: lens distortion {_describe(list(coeffs), list(coeffs.values()))}"
    if not err <= MAX_DROPPED_DISTORTION_PX:
        raise CameraError(f"{what} moves pixels by up to {err:.3g} px over the {cam.width}x{cam.height} "
                          f"image, more than the {MAX_DROPPED_DISTORTION_PX} px a pinhole render may drop "
                          f"(MAX_DROPPED_DISTORTION_PX); undistort the images first, e.g. COLMAP's "
                          f"'colmap image_undistorter', which writes PINHOLE cameras")
    return err, what


def _warn_distortion(found: list[tuple[float, str]], source: str) -> None:
    """One warning for all the small distortions of a file, naming the worst."""
    if not found:
        return
    err, what = max(found, key=lambda f: f[0])
    many = f" (the worst of {len(found)} distorted cameras)" if len(found) > 1 else ""
    warnings.warn(f"{what}{many} is dropped: rendered as a pinhole camera, pixels off by up to {err:.3g} px "
                  f"(<= MAX_DROPPED_DISTORTION_PX = {MAX_DROPPED_DISTORTION_PX} px)", DistortionWarning,
                  stacklevel=3)


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


def _intrinsics(model: str, params, where: str) -> tuple[tuple[float, float, float, float], dict, dict]:
    """``((fx, fy, cx, cy), coefficients by name, keyword arguments of max_distortion_px)`` of a
    COLMAP camera (parameter order from COLMAP's ``src/colmap/sensor/models.h``)."""
    p = [float(v) for v in params]
    if model == "SIMPLE_PINHOLE":
        return (p[0], p[0], p[1], p[2]), {}, {}
    if model == "PINHOLE":
        return tuple(p), {}, {}
    if model == "SIMPLE_RADIAL":
        return (p[0], p[0], p[1], p[2]), {"k": p[3]}, {"radial": p[3:4]}
    if model == "RADIAL":
        return (p[0], p[0], p[1], p[2]), {"k1": p[3], "k2": p[4]}, {"radial": p[3:5]}
    if model == "OPENCV":
        return (tuple(p[:4]), dict(zip(("k1", "k2", "p1", "p2"), p[4:8])),
                {"radial": p[4:6], "tangential": p[6:8]})
    if model == "FULL_OPENCV":
        return (tuple(p[:4]), dict(zip(("k1", "k2", "p1", "p2", "k3", "k4", "k5", "k6"), p[4:12])),
                {"radial": [p[4], p[5], p[8]], "tangential": p[6:8], "rational": p[9:12]})
    raise CameraError(f"{where}: camera model {model} is not supported: not a pinhole projection, even "
                      f"without distortion (undistort the images to PINHOLE first, e.g. COLMAP's "
                      f"'colmap image_undistorter', as 3DGS requires)")


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


def read_colmap(folder, *, width: Optional[int] = None, height: Optional[int] = None,
                background=(0.0, 0.0, 0.0)) -> list[Camera]:
    """Read the cameras of a COLMAP sparse model (text or binary), sorted by image name.

    Camera models: PINHOLE and SIMPLE_PINHOLE; SIMPLE_RADIAL, RADIAL, OPENCV and FULL_OPENCV
    under the module's distortion rule (checked once per camera id, at the model's own image size:
    zero distortion silently, up to :data:`MAX_DROPPED_DISTORTION_PX` with one
    :class:`DistortionWarning`, more refused); fisheye and FOV models are refused.

    Parameters
    ----------
    folder : str or Path
        Folder holding ``cameras.txt`` + ``images.txt`` or ``cameras.bin`` + ``images.bin``
        (e.g. ``sparse/0``); text is used when both exist.
    width, height : int, optional
        Rescale every camera to this image size (pixels; :meth:`Camera.resized`); both or neither.
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
        Missing or malformed files, an unknown camera id, a fisheye model, a distortion above
        :data:`MAX_DROPPED_DISTORTION_PX`, a size that changes the aspect ratio.
    """
    folder = Path(folder)
    size = _optional_size(width, height)
    if (folder / "cameras.txt").exists() and (folder / "images.txt").exists():
        cams, images = _read_colmap_text(folder)
    elif (folder / "cameras.bin").exists() and (folder / "images.bin").exists():
        cams, images = _read_colmap_binary(folder)
    else:
        raise CameraError(f"{folder}: no COLMAP model (cameras.txt + images.txt or cameras.bin + images.bin)")
    out, checked, found = [], set(), []
    for name, q, t, cid, where in sorted(images, key=lambda im: im[0]):
        if cid not in cams:
            raise CameraError(f"{where}: camera id {cid} is not in the cameras file")
        model, w, h, params, cwhere = cams[cid]
        (fx, fy, cx, cy), coeffs, model_kw = _intrinsics(model, params, f"{folder}: {cwhere}")
        if not np.all(np.isfinite(q)) or not np.any(q):
            raise CameraError(f"{where}: quaternion {q} must be finite and non-zero")
        m = np.eye(4)
        m[:3, :3] = _qvec_to_rotmat(q)
        m[:3, 3] = t
        try:
            cam = Camera(width=w, height=h, fx=fx, fy=fy, cx=cx, cy=cy, world_to_camera=m,
                         background=background, name=name)
        except CameraError as exc:
            raise CameraError(f"{where}: {exc}") from None
        if cid not in checked:  # a camera id is shared by many images: one check, one warning
            checked.add(cid)
            small = _check_distortion(cam, coeffs, f"{folder}: {cwhere} (camera id {cid}, {model})", **model_kw)
            if small:
                found.append(small)
        if size is not None:
            try:
                cam = cam.resized(*size)
            except CameraError as exc:
                raise CameraError(f"{where}: {exc}") from None
        out.append(cam)
    _warn_distortion(found, str(folder))
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
    ``fx = fy = w / (2 tan(camera_angle_x / 2))`` (``fy`` from ``camera_angle_y`` if
    given) and the principal point at the image centre.  Each of these keys, ``w``/``h``,
    ``camera_model`` and the distortion ``k1``-``k4``, ``p1``, ``p2`` may also be given per frame
    (nerfstudio style), where it overrides the file's.  Distortion follows nerfstudio's OpenCV
    model (``k1`` .. ``k4`` multiply ``r^2`` .. ``r^8``) under the module's distortion rule,
    checked at the file's own size; a ``camera_model`` other than OPENCV, PINHOLE or
    SIMPLE_PINHOLE (a fisheye, an equirectangular) is refused.
    Each ``transform_matrix`` ``C`` (x right, y up, z backward) becomes
    ``world_to_camera = inverse(C @ diag(1, -1, -1, 1))``.

    Parameters
    ----------
    path : str or Path
        The ``transforms.json``.
    width, height : int, optional
        Image size in pixels, both or neither.  Without ``w``/``h`` in the file (the NeRF
        synthetic set: 800 x 800) this is the size; with them, the cameras are rescaled to it
        (:meth:`Camera.resized`: same aspect ratio, up to rounding).
    background : array_like, shape [3]
        Background colour given to every camera.

    Raises
    ------
    CameraError
        Missing file or keys, unknown size, a matrix that is not 4x4 and rigid, a non-pinhole
        ``camera_model``, a distortion above :data:`MAX_DROPPED_DISTORTION_PX`.
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


#: Keys of a ``transforms.json`` that describe the camera's lens, at file level or per frame.
_BLENDER_LENS_KEYS = ("camera_model", "w", "h", "fl_x", "fl_y", "cx", "cy", "camera_angle_x", "camera_angle_y",
                      "k1", "k2", "k3", "k4", "p1", "p2")
#: nerfstudio's perspective models: a pinhole, with or without the polynomial distortion.
_BLENDER_PINHOLE_MODELS = ("OPENCV", "PINHOLE", "SIMPLE_PINHOLE")


def _blender_lens(src: dict, where: str, path: Path, size: Optional[tuple[int, int]]):
    """``(Camera kwargs, own_size, distortion coefficients, max_distortion_px kwargs)`` of the lens
    keys in ``src``; ``own_size`` tells whether the size came from the file."""
    model = src.get("camera_model")
    if model is not None and model not in _BLENDER_PINHOLE_MODELS:
        raise CameraError(f"{where}.camera_model: {model!r} is not a pinhole model (accepted: "
                          f"{', '.join(_BLENDER_PINHOLE_MODELS)}); undistort the images first, e.g. "
                          f"COLMAP's 'colmap image_undistorter'")
    if "w" not in src and "h" not in src:
        if size is None:
            raise CameraError(f"{path}: image size unknown (no 'w'/'h' in the file or its frames): give it "
                              f"with --size WxH on the command line, width= and height= in Python (the "
                              f"NeRF synthetic images are 800x800)")
        w, h = size
        own = False
    else:
        for key in ("w", "h"):
            v = src.get(key)
            if _whole_number(v) is None or not 0 < _whole_number(v) <= MAX_IMAGE_SIDE:
                raise CameraError(f"{where}.{key}: {v!r} must be a positive integer <= {MAX_IMAGE_SIDE} "
                                  f"(MAX_IMAGE_SIDE)")
        w, h = _whole_number(src["w"]), _whole_number(src["h"])
        own = True
    if "fl_x" in src:
        fx = _blender_number(src, "fl_x", where)
        fy = _blender_number(src, "fl_y", where, fx)
    elif "camera_angle_x" in src:
        angles = {}
        for key in ("camera_angle_x", "camera_angle_y"):
            if key in src:
                angles[key] = _blender_number(src, key, where)
                if not 0 < angles[key] < math.pi:
                    raise CameraError(f"{where}.{key}: {angles[key]!r} must be in (0, pi) radians")
        fx = 0.5 * w / math.tan(0.5 * angles["camera_angle_x"])
        fy = 0.5 * h / math.tan(0.5 * angles["camera_angle_y"]) if "camera_angle_y" in angles else fx
    else:
        raise CameraError(f"{where}: neither 'fl_x' nor 'camera_angle_x' given")
    cx = _blender_number(src, "cx", where, w / 2.0)
    cy = _blender_number(src, "cy", where, h / 2.0)
    coeffs = {k: _blender_number(src, k, where) for k in ("k1", "k2", "k3", "k4", "p1", "p2") if k in src}
    model_kw = {"radial": [coeffs.get(k, 0.0) for k in ("k1", "k2", "k3", "k4")],
                "tangential": [coeffs.get("p1", 0.0), coeffs.get("p2", 0.0)]}
    return dict(width=w, height=h, fx=fx, fy=fy, cx=cx, cy=cy), own, coeffs, model_kw


def _blender_from_json(obj: Any, path: Path, *, width: Optional[int] = None, height: Optional[int] = None,
                       background=(0.0, 0.0, 0.0)) -> list[Camera]:
    if not isinstance(obj, dict) or not isinstance(obj.get("frames"), list):
        raise CameraError(f"{path}: expected an object with a 'frames' list")
    if not obj["frames"]:
        raise CameraError(f"{path}: 'frames' is empty")
    size = _optional_size(width, height)
    base = {k: obj[k] for k in _BLENDER_LENS_KEYS if k in obj}
    flip = np.diag([1.0, -1.0, -1.0, 1.0])
    lenses: dict[str, tuple] = {}  # one lens (and one distortion check) per distinct set of overrides
    found = []
    out = []
    for i, fr in enumerate(obj["frames"]):
        where = f"{path.name}: frames[{i}]"
        if not isinstance(fr, dict) or "transform_matrix" not in fr:
            raise CameraError(f"{where}: missing 'transform_matrix'")
        over = {k: fr[k] for k in _BLENDER_LENS_KEYS if k in fr}
        key = json.dumps(over, sort_keys=True)
        if key not in lenses:
            lens_where = f"{path}: frames[{i}]" if over else str(path)
            kw, own, coeffs, model_kw = _blender_lens({**base, **over}, lens_where, path, size)
            try:
                probe = Camera(world_to_camera=np.eye(4), **kw)
            except CameraError as exc:
                raise CameraError(f"{lens_where}: {exc}") from None
            small = _check_distortion(probe, coeffs, lens_where, **model_kw)
            if small:
                found.append(small)
            lenses[key] = (kw, own)
        kw, own = lenses[key]
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
            cam = Camera(world_to_camera=w2c, background=background, name=str(fr.get("file_path", f"{i:05d}")),
                         **kw)
            if own and size is not None:
                cam = cam.resized(*size)
        except CameraError as exc:
            raise CameraError(f"{where}: {exc}") from None
        out.append(cam)
    _warn_distortion(found, str(path))
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
