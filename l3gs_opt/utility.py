"""The L3GS splat utility (the paper's Eq. 1), per object and layer, and precomputed tables.

For splat i seen from a camera::

    U_i = closeness_i * overlap_i * opacity_i

* closeness = 1 / max(distance from the splat centre to the camera centre, ``distance_floor``)
  (world units);
* overlap = area in pixels of the splat's screen-space 3-sigma extent clipped to the viewport,
  0 when the rasteriser culls the splat (behind the near plane, degenerate, or its square touches
  no 16 x 16 tile: a splat the renderer never draws is worth nothing, even if its square reaches
  a fraction of a pixel into the image). The
  extent is the square ``mean +- radius`` of the rasteriser (``radius = ceil(3 sigma_max)``), or
  with ``area="ellipse"`` the 3-sigma ellipse (area ``9 pi sqrt(det Sigma_2D)``) times the share
  of its bounding square inside the viewport (exact when the ellipse is fully in or fully out;
  an approximation at the image border);
* opacity = the activated opacity, ``sigmoid(opacity_logit)``. The paper's public code multiplies
  the raw stored value (the logit) instead, which can be negative; we follow the paper's text.

The projection is the renderer's (:func:`l3gs_opt.renderer.projection.project_gaussians`): one
projection, not two. Object utilities sum their splats: ``U[j, l]`` over the splats of object j
in layer l, i.e. the per-layer ``dU`` of a layered scene.
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from functools import cached_property

import numpy as np
import scipy.sparse as sp
import torch

from .cameras import Camera
from .errors import L3gsError
from .scene_io import SplatScene

__all__ = ["UtilityError", "UtilityScene", "splat_utility", "object_layer_utility", "UtilityTable",
           "build_utility_table"]

#: Default distance floor (world units): the renderer's near plane.
DISTANCE_FLOOR = 0.01


class UtilityError(L3gsError, ValueError):
    """Bad utility options or table parameters."""


@dataclass(frozen=True, eq=False)
class UtilityScene:
    """The camera-independent part of Eq. 1, computed once per scene.

    World covariances take about as long as the projection itself (~20 ms each for 180k splats
    on this machine); a scheduler evaluates one scene from a new camera every slot, so it prepares
    the scene once and pays only the projection per viewpoint.
    """

    means: torch.Tensor       # [N, 3] world
    covars: torch.Tensor      # [N, 3, 3] world units squared
    opacity: torch.Tensor     # [N] activated
    object_ids: np.ndarray    # [N] int64
    layers: np.ndarray        # [N] int64
    shape_jl: tuple[int, int]

    @classmethod
    def from_scene(cls, scene: SplatScene, dtype: torch.dtype = torch.float32) -> "UtilityScene":
        """Prepare ``scene`` in ``dtype`` (float32 for speed, float64 for reference checks)."""
        from .renderer.projection import covariances_from_params

        obj, lay, J, L = _labels(scene)
        with torch.no_grad():
            covars = covariances_from_params(torch.tensor(scene.log_scales, dtype=dtype),
                                             torch.tensor(scene.quats, dtype=dtype))
            opacity = torch.sigmoid(torch.tensor(scene.opacity_logits, dtype=dtype))
        return cls(torch.tensor(scene.means, dtype=dtype), covars, opacity, obj, lay, (J, L))

    @property
    def num_splats(self) -> int:
        return int(self.means.shape[0])


def _prepared(scene: "SplatScene | UtilityScene", dtype: torch.dtype | None) -> UtilityScene:
    if isinstance(scene, UtilityScene):
        if dtype is not None and dtype != scene.means.dtype:
            raise UtilityError(f"dtype {dtype}: the scene was prepared in {scene.means.dtype}")
        return scene
    return UtilityScene.from_scene(scene, dtype or torch.float32)


def splat_utility(scene: "SplatScene | UtilityScene", camera: Camera, *, area: str = "square",
                  distance_floor: float = DISTANCE_FLOOR, dtype: torch.dtype | None = None) -> np.ndarray:
    """Eq. 1 for every splat: ``[N]`` float64 (pixels per world unit).

    Parameters
    ----------
    scene : SplatScene or UtilityScene
        A :class:`UtilityScene` skips the per-scene preparation (pass one when evaluating many
        viewpoints).
    camera : Camera
    area : {"square", "ellipse"}
        The 3-sigma extent whose clipped area is the overlap (see the module docstring).
    distance_floor : float
        Distances below it count as it (world units), so a splat at the camera has a finite utility.
    dtype : torch dtype, optional
        Projection precision: float32 (default) for speed, float64 for reference checks; a
        prepared scene keeps the dtype it was prepared in.
    """
    from .renderer.projection import project_gaussians

    if area not in ("square", "ellipse"):
        raise UtilityError(f"area {area!r} is not one of square, ellipse")
    if not (distance_floor > 0 and math.isfinite(distance_floor)):
        raise UtilityError(f"distance_floor = {distance_floor!r}: must be a positive number")
    prep = _prepared(scene, dtype)
    if prep.num_splats == 0:
        return np.zeros(0)
    dtype = prep.means.dtype
    with torch.no_grad():
        proj = project_gaussians(prep.means, prep.covars, camera)
        mx, my = proj.means2d[:, 0], proj.means2d[:, 1]
        r = proj.radii.to(dtype)
        w = (torch.clamp(mx + r, 0, camera.width) - torch.clamp(mx - r, 0, camera.width)).clamp(min=0)
        h = (torch.clamp(my + r, 0, camera.height) - torch.clamp(my - r, 0, camera.height)).clamp(min=0)
        overlap = w * h
        if area == "ellipse":
            cov = proj.covars2d
            det = (cov[:, 0, 0] * cov[:, 1, 1] - cov[:, 0, 1] * cov[:, 1, 0]).clamp(min=0)
            full = (2 * r) ** 2
            share = torch.where(full > 0, overlap / torch.where(full > 0, full, torch.ones_like(full)),
                                torch.zeros_like(full))
            overlap = 9 * math.pi * torch.sqrt(det) * share
        overlap = torch.where(proj.visible, overlap, torch.zeros_like(overlap))
        centre = torch.as_tensor(camera.center, dtype=dtype)
        dist = torch.linalg.norm(prep.means - centre, dim=1).clamp(min=distance_floor)
        return (overlap / dist * prep.opacity).to(torch.float64).numpy()


def _labels(scene: SplatScene) -> tuple[np.ndarray, np.ndarray, int, int]:
    obj = np.zeros(scene.num_splats, np.int64) if scene.object_ids is None else scene.object_ids.astype(np.int64)
    lay = np.zeros(scene.num_splats, np.int64) if scene.layers is None else scene.layers.astype(np.int64)
    J = int(obj.max()) + 1 if obj.size else 0
    L = int(lay.max()) + 1 if lay.size else 0
    return obj, lay, J, L


def object_layer_utility(scene: "SplatScene | UtilityScene", camera: Camera, **options) -> np.ndarray:
    """``[J, L]``: summed splat utility of each (object id, layer) (``dU`` for a layered scene).

    Object ids index rows directly (an id with no splats has a zero row).
    """
    prep = _prepared(scene, options.pop("dtype", None))
    u = splat_utility(prep, camera, **options)
    J, L = prep.shape_jl
    return np.bincount(prep.object_ids * L + prep.layers, weights=u, minlength=J * L).reshape(J, L)


def _look_rotation(yaw_deg: float, pitch_deg: float, up_axis: int) -> np.ndarray:
    """World-to-camera rotation (OpenCV) of a camera with this yaw/pitch around the up axis."""
    yaw, pitch = math.radians(yaw_deg), math.radians(pitch_deg)
    up = np.zeros(3)
    up[up_axis] = 1.0
    # A horizontal basis orthogonal to up.
    a = np.zeros(3)
    a[(up_axis + 1) % 3] = 1.0
    b = np.cross(up, a)
    forward = math.cos(pitch) * (math.cos(yaw) * a + math.sin(yaw) * b) + math.sin(pitch) * up
    right = np.cross(forward, up)
    right /= np.linalg.norm(right)
    down = np.cross(forward, right)
    return np.stack([right, down, forward])


@dataclass(frozen=True, eq=False)
class UtilityTable:
    """Per-(object, layer) utilities precomputed on a grid of viewpoints, stored sparse.

    ``values`` is a CSR matrix ``[positions * orientations, J * L]`` (most objects are out of
    view from most viewpoints). ``lookup`` returns the table's entry for the grid viewpoint
    nearest in position and in viewing direction.
    """

    positions: np.ndarray        # [P, 3] world
    orientations: np.ndarray     # [O, 2] yaw, pitch in degrees
    values: sp.csr_matrix        # [P * O, J * L]
    shape_jl: tuple[int, int]
    up_axis: int
    intrinsics: tuple[int, int, float, float, float, float]

    def camera(self, p: int, o: int) -> Camera:
        w, h, fx, fy, cx, cy = self.intrinsics
        rot = _look_rotation(*self.orientations[o], self.up_axis)
        m = np.eye(4)
        m[:3, :3] = rot
        m[:3, 3] = -rot @ self.positions[p]
        return Camera(width=w, height=h, fx=fx, fy=fy, cx=cx, cy=cy, world_to_camera=m)

    @cached_property
    def directions(self) -> np.ndarray:
        """``[O, 3]`` unit viewing direction (camera +z in world) of each grid orientation."""
        return np.stack([_look_rotation(y, p, self.up_axis)[2] for y, p in self.orientations])

    def nearest(self, camera: Camera) -> tuple[int, int]:
        """Indices (position, orientation) of the grid viewpoint nearest to ``camera``."""
        p = int(np.argmin(np.linalg.norm(self.positions - camera.center, axis=1)))
        return p, self._orientation(camera)

    def _orientation(self, camera: Camera) -> int:
        return int(np.argmax(self.directions @ camera.world_to_camera[2, :3]))

    def lookup(self, camera: Camera, *, neighbours: int = 1) -> np.ndarray:
        """``[J, L]`` utilities seen from ``camera``, from the grid.

        ``neighbours=1``: the entry of the nearest grid viewpoint (nearest position, nearest
        viewing direction). ``neighbours=k``: the inverse-distance weighted mean over the k nearest
        grid positions, each at the viewing direction nearest to the camera's (exact at a grid
        position).
        """
        if not 1 <= neighbours <= len(self.positions):
            raise UtilityError(f"neighbours = {neighbours}: must be in [1, {len(self.positions)}]")
        o = self._orientation(camera)
        dist = np.linalg.norm(self.positions - camera.center, axis=1)
        near = np.argsort(dist, kind="stable")[:neighbours]
        if dist[near[0]] == 0.0 or neighbours == 1:
            weights = np.zeros(len(near))
            weights[0] = 1.0
        else:
            weights = 1.0 / dist[near]
            weights /= weights.sum()
        rows = self.values[near * len(self.orientations) + o].toarray()
        return (weights @ rows).reshape(self.shape_jl)

    @property
    def nbytes(self) -> int:
        v = self.values
        return int(v.data.nbytes + v.indices.nbytes + v.indptr.nbytes)


def build_utility_table(scene: "SplatScene | UtilityScene", positions: np.ndarray, *, yaw_steps: int = 12,
                        pitches_deg: tuple[float, ...] = (-20.0, 0.0, 20.0), up_axis: int = 2,
                        width: int = 320, height: int = 240, fov_deg: float = 70.0, progress: bool = False,
                        **options) -> UtilityTable:
    """Utilities of every (object, layer) from every grid position and orientation.

    The paper samples 1,000 positions x 1,728 orientations; pass as many as the time allows
    (each viewpoint costs one projection of the scene).
    """
    from tqdm import tqdm

    positions = np.asarray(positions, dtype=np.float64)
    if positions.ndim != 2 or positions.shape[1] != 3 or len(positions) == 0:
        raise UtilityError(f"positions: shape {positions.shape} must be [P, 3] with P >= 1")
    if yaw_steps < 1 or not pitches_deg:
        raise UtilityError("need at least one yaw step and one pitch")
    fx = width / (2 * math.tan(math.radians(fov_deg) / 2))
    orientations = np.array([(360.0 * k / yaw_steps, p) for k in range(yaw_steps) for p in pitches_deg])
    prep = _prepared(scene, options.pop("dtype", None))
    J, L = prep.shape_jl
    table = UtilityTable(positions, orientations, sp.csr_matrix((0, 0)), (J, L), up_axis,
                         (width, height, fx, fx, width / 2, height / 2))
    rows = []
    for p in tqdm(range(len(positions)), desc="utility table", disable=not progress):
        for o in range(len(orientations)):
            rows.append(sp.csr_matrix(object_layer_utility(prep, table.camera(p, o), **options).reshape(1, -1)))
    values = sp.vstack(rows, format="csr") if rows else sp.csr_matrix((0, J * L))
    return UtilityTable(positions, orientations, values, (J, L), up_axis, table.intrinsics)
