"""Camera paths through the procedural room of :mod:`l3gs_opt.scene.procedural`: orbit and walk.

Both return lists of :class:`l3gs_opt.scene.cameras.Camera` (OpenCV convention, world z up) that a
camera JSON file stores as a list (:func:`l3gs_opt.scene.cameras.save_cameras`).
"""

from __future__ import annotations

import math

import numpy as np

from l3gs_opt.checks import check_count
from l3gs_opt.scene.cameras import Camera, CameraError, look_at
from l3gs_opt.scene.procedural import ROOM_HALF, ROOM_HEIGHT

__all__ = ["intrinsics_from_fov", "orbit_path", "walk_path", "check_views", "MAX_PATH_VIEWS"]

#: Most cameras in one path. A path is saved as a camera JSON list (~580 bytes a camera), which
#: :func:`l3gs_opt.scene.cameras.load_cameras` reads back only up to ``MAX_CAMERA_FILE_BYTES``
#: (64 MiB, ~115,000 cameras); 10,000 (5.5 minutes at 30 frames/s, a few seconds to build) is far
#: more than any walk-through needs and keeps the file readable. ``--views 100000000`` would
#: otherwise build cameras for hours before failing.
MAX_PATH_VIEWS = 10_000


def check_views(n_views, field: str = "n_views") -> int:
    """``n_views`` as an int in ``[1, MAX_PATH_VIEWS]``, checked before any camera is built (camera
    paths here, sampled training cameras in :mod:`.camera_sampling`)."""
    return check_count(field, n_views, high=MAX_PATH_VIEWS,
                       error=lambda f, message: CameraError(f"{f}: {message} (MAX_PATH_VIEWS)"))


def intrinsics_from_fov(width: int, height: int, fov_x_deg: float) -> dict:
    """``fx = fy = width / (2 tan(fov_x / 2))``, principal point at the image centre; checked as a
    :class:`Camera` is (image size limits), so a bad size fails here, before any slot runs."""
    if not 1.0 <= fov_x_deg <= 170.0:
        raise CameraError(f"fov_x_deg: {fov_x_deg} must be in [1, 170]")
    for key, v in (("width", width), ("height", height)):
        if isinstance(v, bool) or not isinstance(v, (int, np.integer)) or v <= 0:
            raise CameraError(f"{key}: {v!r} must be a positive integer")
    f = width / (2.0 * math.tan(math.radians(fov_x_deg) / 2.0))
    out = {"width": width, "height": height, "fx": f, "fy": f, "cx": width / 2.0, "cy": height / 2.0}
    Camera(**out, world_to_camera=np.eye(4))
    return out


def orbit_path(n_views: int = 36, *, width: int = 800, height: int = 600, fov_x_deg: float = 70.0,
               radius: float = 3.4, eye_height: float = 1.6, target=(0.0, 0.0, 0.5),
               background=(0.0, 0.0, 0.0)) -> list[Camera]:
    """Cameras on a horizontal circle of ``radius`` around the room centre, looking at ``target``.

    Parameters
    ----------
    n_views : int
        Number of cameras, 1..:data:`MAX_PATH_VIEWS`, evenly spaced in angle (the first at +x).
    width, height : int, keyword-only
        Image size in pixels.
    fov_x_deg : float, keyword-only
        Horizontal field of view in degrees.
    radius, eye_height : float, keyword-only
        Circle radius and camera height (metres).
    target : array_like, shape [3], keyword-only
        Look-at point (metres).
    """
    n_views = check_views(n_views)
    k = intrinsics_from_fov(width, height, fov_x_deg)
    cams = []
    for i in range(n_views):
        a = 2 * math.pi * i / n_views
        eye = [radius * math.cos(a), radius * math.sin(a), eye_height]
        cams.append(Camera(**k, world_to_camera=look_at(eye, target), background=background,
                           name=f"orbit_{i:03d}"))
    return cams


def walk_path(n_views: int = 36, *, width: int = 800, height: int = 600, fov_x_deg: float = 70.0,
              eye_height: float = 1.6, background=(0.0, 0.0, 0.0)) -> list[Camera]:
    """A walk along the room's walls, in a rounded rectangle, looking ahead and slightly inwards.

    The walker moves counter-clockwise on an ellipse of half-axes ``0.85 ROOM_HALF`` and
    ``0.7 ROOM_HALF``; the gaze leads the position by 50 degrees and bends towards the centre, so
    objects enter, cross and leave the view (what a viewport predictor sees in a walk-through).
    ``n_views`` is 1..:data:`MAX_PATH_VIEWS`.
    """
    n_views = check_views(n_views)
    k = intrinsics_from_fov(width, height, fov_x_deg)
    ax, ay = 0.85 * ROOM_HALF, 0.7 * ROOM_HALF
    cams = []
    for i in range(n_views):
        a = 2 * math.pi * i / n_views
        eye = np.array([ax * math.cos(a), ay * math.sin(a), eye_height])
        b = a + math.radians(50.0)
        ahead = np.array([0.5 * ax * math.cos(b), 0.5 * ay * math.sin(b), 0.6])
        eye[2] = min(eye[2], ROOM_HEIGHT - 0.3)
        cams.append(Camera(**k, world_to_camera=look_at(eye, ahead), background=background,
                           name=f"walk_{i:03d}"))
    return cams
