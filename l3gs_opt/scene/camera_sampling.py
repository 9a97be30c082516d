"""Training cameras sampled around (or inside) a scene, for a teacher that comes without its own.

Distilling a layered model needs views of the teacher, not photographs: any camera the teacher can
be rendered from gives a target.  A user who has only the trained PLY gets cameras from
:func:`sample_cameras`:

- ``"outside"`` (object captures, e.g. a bicycle or a donut): cameras on a sphere around the
  scene's centre (coordinate-wise median of the splat centres) at ``distance`` times the radius that
  holds :data:`RADIUS_QUANTILE` of the splats, spread evenly by a Fibonacci lattice, each looking
  at the centre.  Splats farther than :data:`l3gs_opt.scene.segment.BACKGROUND_FACTOR` median
  distances (a captured scene's far shell) do not set the radius.
- ``"inside"`` (rooms): cameras at points drawn uniformly in the middle half of the box that holds the
  same splats, looking in Fibonacci-lattice directions, so every wall is seen.
- ``"orbit"`` (a viewer's path, not training views): consecutive cameras on a ring at the ``outside``
  distance, :data:`ORBIT_ELEVATION_DEG` above the plane normal to ``up``, looking at the centre.

Both are deterministic (the lattice; ``inside`` positions by ``seed``).  The world's up axis is
unknown for a real scene (COLMAP frames are arbitrary), so the cameras' roll is only fixed to keep
``look_at`` well defined: its up hint is world +z, or +y for a view along z.
"""

from __future__ import annotations

import math

import numpy as np

from l3gs_opt.scene.camera_paths import check_views, intrinsics_from_fov
from l3gs_opt.scene.cameras import Camera, CameraError, look_at
from l3gs_opt.scene.segment import BACKGROUND_FACTOR
from l3gs_opt.scene.splats import SplatScene

__all__ = ["CAMERA_MODES", "RADIUS_QUANTILE", "sample_cameras"]

CAMERA_MODES = ("outside", "inside", "orbit")
#: ``orbit``: the ring's elevation above the plane normal to ``up``, degrees.
ORBIT_ELEVATION_DEG = 20.0
#: The scene's radius holds this share of the (foreground) splats.
RADIUS_QUANTILE = 0.9


def _fibonacci(n: int) -> np.ndarray:
    """``n`` unit vectors spread evenly over the sphere (golden-angle spiral), [n, 3]."""
    i = np.arange(n) + 0.5
    z = 1.0 - 2.0 * i / n
    r = np.sqrt(np.maximum(0.0, 1.0 - z * z))
    phi = math.pi * (3.0 - math.sqrt(5.0)) * i
    return np.column_stack([r * np.cos(phi), r * np.sin(phi), z])


def _look(eye: np.ndarray, target: np.ndarray) -> np.ndarray:
    d = target - eye
    d = d / np.linalg.norm(d)
    up = (0.0, 0.0, 1.0) if abs(d[2]) < 0.95 else (0.0, 1.0, 0.0)
    return look_at(eye, target, up)


def sample_cameras(scene: SplatScene, count: int = 32, *, mode: str = "outside", width: int = 256,
                   height: int = 192, fov_x_deg: float = 60.0, distance: float = 1.5, seed: int = 0,
                   up=(0.0, 0.0, 1.0), background=(0.0, 0.0, 0.0)) -> list[Camera]:
    """Cameras to render a teacher from (see the module docstring).

    Parameters
    ----------
    scene : SplatScene
    count : int
        Number of cameras, 1..:data:`l3gs_opt.scene.camera_paths.MAX_PATH_VIEWS` (each is
        rendered and trained on; the limit also keeps ``--views 100000000`` from running for hours).
    mode : {"outside", "inside", "orbit"}, keyword-only
    width, height : int, keyword-only
        Image size in pixels.
    fov_x_deg : float, keyword-only
        Horizontal field of view, degrees.
    distance : float, keyword-only
        ``outside``, ``orbit``: camera distance from the centre in scene radii (> 0).
    up : array_like [3], keyword-only
        ``orbit``: the ring's axis.
    seed : int, keyword-only
        ``inside``: seed of the positions, >= 0.
    background : RGB triple, keyword-only

    Returns
    -------
    list of Camera
        Named ``sampled_{mode}_{i:03d}``.

    Raises
    ------
    CameraError
        On an empty scene or an argument out of range (naming it).
    """
    if mode not in CAMERA_MODES:
        raise CameraError(f"mode: {mode!r} must be one of {', '.join(CAMERA_MODES)}")
    count = check_views(count, "count")
    if isinstance(seed, bool) or not isinstance(seed, (int, np.integer)) or seed < 0:  # as splats.check_seed
        raise CameraError(f"seed = {seed!r}: must be an integer >= 0")
    if not (isinstance(distance, (int, float)) and math.isfinite(distance) and distance > 0):
        raise CameraError(f"distance: {distance!r} must be a positive number")
    if scene.num_splats == 0:
        raise CameraError("scene: has no splats to place cameras around")
    k = intrinsics_from_fov(width, height, fov_x_deg)
    pts = scene.means.astype(np.float64)
    centre = np.median(pts, axis=0)
    dist = np.linalg.norm(pts - centre, axis=1)
    fg = pts[dist <= BACKGROUND_FACTOR * max(float(np.median(dist)), 1e-12)]
    cams = []
    radius = max(float(np.quantile(np.linalg.norm(fg - centre, axis=1), RADIUS_QUANTILE)), 1e-6)
    if mode == "orbit":
        axis = np.asarray(up, np.float64)
        if axis.shape != (3,) or not np.isfinite(axis).all() or np.linalg.norm(axis) == 0:
            raise CameraError(f"up: {up!r} must be a non-zero 3-vector")
        axis = axis / np.linalg.norm(axis)
        e1 = np.cross(axis, [1.0, 0.0, 0.0] if abs(axis[0]) < 0.9 else [0.0, 1.0, 0.0])
        e1 /= np.linalg.norm(e1)
        e2 = np.cross(axis, e1)
        el = math.radians(ORBIT_ELEVATION_DEG)
        for i in range(count):
            a = 2 * math.pi * i / count
            d = math.cos(el) * (math.cos(a) * e1 + math.sin(a) * e2) + math.sin(el) * axis
            eye = centre + distance * radius * d
            cams.append(Camera(**k, world_to_camera=look_at(eye, centre, axis), background=background,
                               name=f"sampled_orbit_{i:03d}"))
    elif mode == "outside":
        for i, d in enumerate(_fibonacci(count)):
            eye = centre + distance * radius * d
            cams.append(Camera(**k, world_to_camera=_look(eye, centre), background=background,
                               name=f"sampled_outside_{i:03d}"))
    else:
        lo, hi = np.quantile(fg, 1 - RADIUS_QUANTILE, axis=0), np.quantile(fg, RADIUS_QUANTILE, axis=0)
        mid, half = (lo + hi) / 2, (hi - lo) / 4
        rng = np.random.default_rng(seed)
        for i, d in enumerate(_fibonacci(count)):
            eye = mid + rng.uniform(-1, 1, 3) * half
            cams.append(Camera(**k, world_to_camera=_look(eye, eye + d), background=background,
                               name=f"sampled_inside_{i:03d}"))
    return cams
