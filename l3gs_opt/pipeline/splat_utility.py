"""The L3GS splat utility (the paper's Eq. 1), per object and layer, and precomputed tables.

Length (~800 lines, one module on purpose): the per-viewpoint pass and the table builder share the
compiled kernels and their argument packing (``_kernel_args``, ``_eq1_views``, ``_prepared``);
split, the table module would import those privates.

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

Object utilities sum their splats: ``U[j, l]`` over the splats of object j in layer l, i.e. the
per-layer ``dU`` of a layered scene.

The projection is the renderer's (:mod:`l3gs_opt.renderer.projection`, the 3DGS ``computeCov2D``
and ``getRect`` rules and constants). It runs on one of two backends with the same arithmetic:

* ``"torch"``: :func:`l3gs_opt.renderer.projection.project_gaussians` itself, then the clipping
  as tensor operations. The reference: about 100 passes over N-element tensors per viewpoint.
* ``"numba"`` (the default when numba is installed): one compiled loop over the splats that does
  the same projection, cull, clipping and per-(object, layer) sum per splat, in float64. Before
  projecting a covariance it tests the splat, and first its chunk of 64 spatial neighbours,
  against the near plane and four planes that bound the image widened by an upper bound on the
  radius: what they drop the rasteriser would cull too. The tests hold it to the torch backend
  (equal to round-off in float64, same visible set) and to a plain per-splat loop, and the early
  cull to the loop without it (identical).

A scheduler evaluates one scene from a new camera every slot: prepare the scene once
(:class:`UtilityScene`, the world covariances) and pay only the projection per viewpoint. For
many viewpoints known in advance, :func:`build_utility_table` evaluates a grid of them on both
cores and :meth:`UtilityTable.lookup` interpolates between them at run time.
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from functools import cached_property

import numpy as np
import scipy.sparse as sp
import torch

from l3gs_opt.scene.cameras import Camera
from l3gs_opt.errors import L3gsError
from l3gs_opt.pipeline.counts import MAX_GRID_POSITIONS, MAX_YAW_STEPS, check_count
from l3gs_opt.renderer import HAVE_NUMBA
from l3gs_opt.renderer.projection import JACOBIAN_CLAMP, NEAR_PLANE, TILE_SIZE
from l3gs_opt.scene.splats import SplatScene

if HAVE_NUMBA:
    import numba

    from l3gs_opt.renderer._kernels import _screen_cov, _screen_radius

__all__ = ["UtilityError", "UtilityScene", "splat_utility", "object_layer_utility", "UtilityTable",
           "build_utility_table", "grid_positions", "DISTANCE_FLOOR"]

#: Default distance floor (world units): the renderer's near plane.
DISTANCE_FLOOR = 0.01

_AREAS = ("square", "ellipse")
#: A camera closer than this to a grid point (as a fraction of the grid step) snaps to it, so a
#: lookup from a grid camera returns the grid entry exactly (its centre and atan2/asin carry
#: round-off of ~1e-14).
_SNAP = 1e-9
_BACKENDS = ("auto", "numba", "torch")
#: Splats per chunk of the early cull (one bounding sphere per chunk).
CHUNK = 64


class UtilityError(L3gsError, ValueError):
    """Bad utility options or table parameters."""


# --------------------------------------------------------------------------------------------
# Prepared scenes
# --------------------------------------------------------------------------------------------

@dataclass(frozen=True, eq=False)
class UtilityScene:
    """The camera-independent part of Eq. 1, computed once per scene.

    Splats are stored in a spatial (Morton) order, in chunks of :data:`CHUNK` neighbours with a
    bounding sphere each, so that the compiled backend can skip a chunk behind the camera or
    beside the view with one test; ``order`` maps back to the scene's order.

    Attributes
    ----------
    order : ndarray, shape [N], int64
        Scene index of each prepared splat.
    means : ndarray, shape [N, 3]
        Splat centres (world units), in the preparation dtype.
    cov6 : ndarray, shape [N, 6]
        World covariances ``(xx, xy, xz, yy, yz, zz)`` (world units squared), from the renderer's
        :func:`~l3gs_opt.renderer.projection.covariances_from_params` in the preparation dtype.
    opacity : ndarray, shape [N]
        Activated opacity ``sigmoid(logit)``.
    sigma_max : ndarray, shape [N], float64
        An upper bound on the largest standard deviation of each splat (world units), for the
        early cull.
    bins : ndarray, shape [N], int64
        ``object_id * L + layer``: the flat (object, layer) cell of each splat.
    chunk_centre, chunk_radius, chunk_sigma : ndarray, shape [ceil(N / CHUNK), 3], [.], [.]
        Bounding sphere of each chunk of splat centres and its largest ``sigma_max`` (world units).
    shape_jl : tuple of int
        ``(J, L)``: object ids index rows directly, layers columns.
    """

    order: np.ndarray
    means: np.ndarray
    cov6: np.ndarray
    opacity: np.ndarray
    sigma_max: np.ndarray
    bins: np.ndarray
    chunk_centre: np.ndarray
    chunk_radius: np.ndarray
    chunk_sigma: np.ndarray
    shape_jl: tuple[int, int]

    @classmethod
    def from_scene(cls, scene: SplatScene, dtype: torch.dtype = torch.float64) -> "UtilityScene":
        """Prepare ``scene``: covariances, activated opacity and labels in ``dtype``.

        ``dtype`` is the precision of the prepared arrays (float64 by default; float32 halves the
        memory). The compiled backend computes in float64 either way; the torch backend computes in
        ``dtype``.
        """
        from l3gs_opt.renderer.projection import covariances_from_params

        if dtype not in (torch.float32, torch.float64):
            raise UtilityError(f"dtype {dtype}: must be torch.float32 or torch.float64")
        obj, lay, J, L = _labels(scene)
        order = _morton_order(scene.means)
        with torch.no_grad():
            covars = covariances_from_params(torch.tensor(scene.log_scales[order], dtype=dtype),
                                             torch.tensor(scene.quats[order], dtype=dtype))
            opacity = torch.sigmoid(torch.tensor(scene.opacity_logits[order], dtype=dtype))
        cov6 = covars.reshape(-1, 9)[:, [0, 1, 2, 4, 5, 8]].contiguous().numpy()
        means = np.array(scene.means[order], dtype=cov6.dtype, order="C")
        # Sigma = R diag(s^2) R^T has largest standard deviation max(s); the factor covers
        # round-off of the stored covariance (float32 entries carry a relative error of ~1e-7).
        sigma = np.exp(np.max(scene.log_scales[order].astype(np.float64), axis=1, initial=-np.inf)) * (1.0 + 1e-5)
        centre, radius, chunk_sigma = _chunk_spheres(means.astype(np.float64), sigma)
        return cls(order, means, cov6, opacity.numpy(), sigma, (obj * max(L, 1) + lay)[order], centre, radius,
                   chunk_sigma, (J, L))

    @property
    def num_splats(self) -> int:
        return int(self.means.shape[0])

    @property
    def dtype(self) -> torch.dtype:
        """Precision the scene was prepared in."""
        return torch.float64 if self.means.dtype == np.float64 else torch.float32

    @property
    def _kernel_args(self) -> tuple:
        return (self.means, self.cov6, self.opacity, self.sigma_max, self.bins, self.chunk_centre, self.chunk_radius,
                self.chunk_sigma, CHUNK)

    @cached_property
    def _tensors(self) -> tuple[torch.Tensor, torch.Tensor, torch.Tensor]:
        """``(means [N, 3], covars [N, 3, 3], opacity [N])`` as tensors, for the torch backend."""
        c = torch.from_numpy(self.cov6)
        covars = torch.stack([c[:, 0], c[:, 1], c[:, 2], c[:, 1], c[:, 3], c[:, 4], c[:, 2], c[:, 4], c[:, 5]],
                             dim=-1).reshape(-1, 3, 3)
        return torch.from_numpy(self.means), covars, torch.from_numpy(self.opacity)


def _morton_order(means: np.ndarray) -> np.ndarray:
    """Splat indices sorted along a Z-order curve (10 bits per axis over the bounding box)."""
    if len(means) == 0:
        return np.zeros(0, np.int64)
    m = means.astype(np.float64)
    lo, hi = m.min(axis=0), m.max(axis=0)
    q = np.floor((m - lo) / np.maximum(hi - lo, 1e-12) * 1023.0).clip(0, 1023).astype(np.uint64)
    code = np.zeros(len(m), np.uint64)
    for bit in range(10):
        for axis in range(3):
            code |= ((q[:, axis] >> np.uint64(bit)) & np.uint64(1)) << np.uint64(3 * bit + axis)
    return np.argsort(code, kind="stable").astype(np.int64)


def _chunk_spheres(means: np.ndarray, sigma: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Bounding sphere (centre [C, 3], radius [C]) and largest sigma [C] of each CHUNK of splats."""
    if len(means) == 0:
        return np.zeros((0, 3)), np.zeros(0), np.zeros(0)
    starts = np.arange(0, len(means), CHUNK)
    centre = 0.5 * (np.minimum.reduceat(means, starts, axis=0) + np.maximum.reduceat(means, starts, axis=0))
    dist = np.linalg.norm(means - np.repeat(centre, np.diff(np.append(starts, len(means))), axis=0), axis=1)
    # Inflated so that round-off in the kernel's sphere tests cannot drop a splat its own tests keep.
    radius = np.maximum.reduceat(dist, starts) * (1.0 + 1e-9) + 1e-9
    return centre, radius, np.maximum.reduceat(sigma, starts)


def _labels(scene: SplatScene) -> tuple[np.ndarray, np.ndarray, int, int]:
    obj = np.zeros(scene.num_splats, np.int64) if scene.object_ids is None else scene.object_ids.astype(np.int64)
    lay = np.zeros(scene.num_splats, np.int64) if scene.layers is None else scene.layers.astype(np.int64)
    J = int(obj.max()) + 1 if obj.size else 0
    L = int(lay.max()) + 1 if lay.size else 0
    return obj, lay, J, L


def _prepared(scene: "SplatScene | UtilityScene", dtype: torch.dtype | None) -> UtilityScene:
    if isinstance(scene, UtilityScene):
        if dtype is not None and dtype != scene.dtype:
            raise UtilityError(f"dtype {dtype}: the scene was prepared in {scene.dtype}")
        return scene
    if not isinstance(scene, SplatScene):
        raise UtilityError(f"scene: {type(scene).__name__} is neither a SplatScene nor a UtilityScene")
    return UtilityScene.from_scene(scene, torch.float64 if dtype is None else dtype)


def _check_options(area: str, distance_floor: float, backend: str) -> bool:
    """Validate the options; return whether the compiled backend runs."""
    if area not in _AREAS:
        raise UtilityError(f"area {area!r} is not one of {', '.join(_AREAS)}")
    if not (isinstance(distance_floor, (int, float, np.integer, np.floating)) and distance_floor > 0
            and math.isfinite(distance_floor)):
        raise UtilityError(f"distance_floor = {distance_floor!r}: must be a positive number")
    if backend not in _BACKENDS:
        raise UtilityError(f"backend {backend!r} is not one of {', '.join(_BACKENDS)}")
    if backend == "numba" and not HAVE_NUMBA:
        raise UtilityError("backend 'numba' needs the numba package (pip install numba)")
    return backend == "numba" or (backend == "auto" and HAVE_NUMBA)


# --------------------------------------------------------------------------------------------
# The compiled backend: one pass over the splats per viewpoint
# --------------------------------------------------------------------------------------------

if HAVE_NUMBA:
    @numba.njit(cache=True)
    def _eq1_pass(means, cov6, opacity, sigma_max, bins, cl_centre, cl_radius, cl_sigma, chunk, rot, trans, centre,
                  fx, fy, cx, cy, width, height, lim_x, lim_y, floor, ellipse, cull, out_u, out_sum):
        """One viewpoint: Eq. 1 per splat into ``out_u`` (unless empty; zeroed by the caller) and
        its sums per bin into ``out_sum`` (unless empty), splats in the prepared order.

        The operations and their order mirror ``project_gaussians`` and ``_splat_utility_torch``
        (float64 round-off apart). Sums run in the prepared order, as ``np.bincount`` over it does,
        so both give the same float64 sums.
        """
        keep = out_u.shape[0] > 0
        add = out_sum.shape[0] > 0
        gx = (width + TILE_SIZE - 1) // TILE_SIZE
        gy = (height + TILE_SIZE - 1) // TILE_SIZE
        edge_x = float(gx * TILE_SIZE)
        edge_y = float(gy * TILE_SIZE)
        # Early cull without a division or a root. The radius is r = ceil(3 sqrt(lam1)) with
        # lam1 <= |J|_F^2 lambda_max(Sigma) + 0.3 (dilation) + sqrt(0.1), |J|_F^2 <= jb / z^2
        # (the Jacobian's x/z, y/z are clamped to lim_x, lim_y), so r z <= k sigma_max + 3.36 z
        # with k = 3 sqrt(jb). getRect misses every tile when p + r < 1 or p - r >= edge (p the
        # pixel-centre coordinate); multiplied by z > 0 these become four planes in world space.
        # Margin 5.51 >= 3.36 + 2 pixels: a splat the planes drop is one the rasteriser culls.
        k = 3.0 * math.sqrt(fx * fx * (1.0 + lim_x * lim_x) + fy * fy * (1.0 + lim_y * lim_y))
        margin = 3.0 * math.sqrt(0.7) + 3.0
        ax_lo = cx - 1.5 + margin          # fx x + ax_lo z + k sigma < 0: left of the image
        ax_hi = cx - 0.5 - edge_x - margin  # fx x + ax_hi z - k sigma >= 0: right of it
        ay_lo = cy - 1.5 + margin
        ay_hi = cy - 0.5 - edge_y - margin
        pl = np.empty((4, 4))
        for q in range(3):
            pl[0, q] = fx * rot[0, q] + ax_lo * rot[2, q]
            pl[1, q] = fx * rot[0, q] + ax_hi * rot[2, q]
            pl[2, q] = fy * rot[1, q] + ay_lo * rot[2, q]
            pl[3, q] = fy * rot[1, q] + ay_hi * rot[2, q]
        pl[0, 3] = fx * trans[0] + ax_lo * trans[2]
        pl[1, 3] = fx * trans[0] + ax_hi * trans[2]
        pl[2, 3] = fy * trans[1] + ay_lo * trans[2]
        pl[3, 3] = fy * trans[1] + ay_hi * trans[2]
        norms = np.empty(4)
        for q in range(4):
            norms[q] = math.sqrt(pl[q, 0] ** 2 + pl[q, 1] ** 2 + pl[q, 2] ** 2)
        n = means.shape[0]
        for cl in range(cl_radius.shape[0]):
            if cull:
                # The same tests for a whole chunk of neighbouring splats, bounded by a sphere
                # (n . m <= n . centre + |n| radius) and its largest sigma: most chunks of a room
                # are behind the camera or beside the view, and skipping them is most of the gain.
                ox = cl_centre[cl, 0]
                oy = cl_centre[cl, 1]
                oz = cl_centre[cl, 2]
                rad = cl_radius[cl]
                ks = k * cl_sigma[cl]
                if rot[2, 0] * ox + rot[2, 1] * oy + rot[2, 2] * oz + trans[2] + rad < NEAR_PLANE \
                        or pl[0, 0] * ox + pl[0, 1] * oy + pl[0, 2] * oz + pl[0, 3] + norms[0] * rad + ks < 0.0 \
                        or pl[1, 0] * ox + pl[1, 1] * oy + pl[1, 2] * oz + pl[1, 3] - norms[1] * rad - ks >= 0.0 \
                        or pl[2, 0] * ox + pl[2, 1] * oy + pl[2, 2] * oz + pl[2, 3] + norms[2] * rad + ks < 0.0 \
                        or pl[3, 0] * ox + pl[3, 1] * oy + pl[3, 2] * oz + pl[3, 3] - norms[3] * rad - ks >= 0.0:
                    continue
            for i in range(cl * chunk, min(cl * chunk + chunk, n)):
                mx = means[i, 0]
                my = means[i, 1]
                mz = means[i, 2]
                z = rot[2, 0] * mx + rot[2, 1] * my + rot[2, 2] * mz + trans[2]
                if not z >= NEAR_PLANE:
                    continue
                if cull:
                    ks = k * sigma_max[i]
                    if pl[0, 0] * mx + pl[0, 1] * my + pl[0, 2] * mz + pl[0, 3] + ks < 0.0 \
                            or pl[1, 0] * mx + pl[1, 1] * my + pl[1, 2] * mz + pl[1, 3] - ks >= 0.0 \
                            or pl[2, 0] * mx + pl[2, 1] * my + pl[2, 2] * mz + pl[2, 3] + ks < 0.0 \
                            or pl[3, 0] * mx + pl[3, 1] * my + pl[3, 2] * mz + pl[3, 3] - ks >= 0.0:
                        continue
                x = rot[0, 0] * mx + rot[0, 1] * my + rot[0, 2] * mz + trans[0]
                y = rot[1, 0] * mx + rot[1, 1] * my + rot[1, 2] * mz + trans[1]
                px = fx * x / z + cx
                py = fy * y / z + cy
                a, b, b10, c = _screen_cov(rot, cov6, i, x, y, z, fx, fy, lim_x, lim_y)
                det = a * c - b * b
                if not det > 0.0:
                    continue
                r = _screen_radius(a, c, det)
                if not (r > 0.0 and r < math.inf):
                    continue
                # getRect (pixel-centre coordinates) touches a tile iff floor((p + r + 15) / 16) >= 1
                # and floor((p - r) / 16) < g (tiles g): with r >= 1 the two floors differ, so the
                # clamped range is not empty. Dividing by 16 is exact: compare before dividing.
                p0 = px - 0.5
                p1 = py - 0.5
                if not (p0 + r + TILE_SIZE - 1 >= TILE_SIZE and p0 - r < edge_x
                        and p1 + r + TILE_SIZE - 1 >= TILE_SIZE and p1 - r < edge_y):
                    continue
                w = min(max(px + r, 0.0), width) - min(max(px - r, 0.0), width)
                h = min(max(py + r, 0.0), height) - min(max(py - r, 0.0), height)
                overlap = max(w, 0.0) * max(h, 0.0)
                if ellipse:
                    overlap = 9.0 * math.pi * math.sqrt(max(a * c - b * b10, 0.0)) * (overlap / (2.0 * r) ** 2)
                dx = mx - centre[0]
                dy = my - centre[1]
                dz = mz - centre[2]
                dist = max(math.sqrt(dx * dx + dy * dy + dz * dz), floor)
                u = overlap / dist * opacity[i]
                if keep:
                    out_u[i] = u
                if add and u != 0.0:
                    out_sum[bins[i]] += u

    @numba.njit(cache=True, parallel=True)
    def _eq1_views(means, cov6, opacity, sigma_max, bins, cl_centre, cl_radius, cl_sigma, chunk, rots, transs,
                   centres, fx, fy, cx, cy, width, height, lim_x, lim_y, floor, ellipse, out_sum):
        """Many viewpoints (``rots [V, 3, 3]``, ``transs``/``centres [V, 3]``), one per thread at a time."""
        none = np.zeros(0)
        for v in numba.prange(rots.shape[0]):
            _eq1_pass(means, cov6, opacity, sigma_max, bins, cl_centre, cl_radius, cl_sigma, chunk, rots[v], transs[v],
                      centres[v], fx, fy, cx, cy, width, height, lim_x, lim_y, floor, ellipse, True, none, out_sum[v])


def _intrinsics(camera: Camera) -> tuple:
    tan_x, tan_y = camera.tan_half_fov
    return (float(camera.fx), float(camera.fy), float(camera.cx), float(camera.cy), int(camera.width),
            int(camera.height), JACOBIAN_CLAMP * tan_x, JACOBIAN_CLAMP * tan_y)


def _numba_pass(prep: UtilityScene, camera: Camera, area: str, floor: float, *, per_splat: bool,
                sums: bool, cull: bool = True) -> tuple[np.ndarray, np.ndarray]:
    w2c = camera.world_to_camera
    out_u = np.zeros(prep.num_splats if per_splat else 0)
    out_sum = np.zeros(prep.shape_jl[0] * prep.shape_jl[1] if sums else 0)
    _eq1_pass(*prep._kernel_args, np.ascontiguousarray(w2c[:3, :3]),
              np.ascontiguousarray(w2c[:3, 3]), np.ascontiguousarray(camera.center), *_intrinsics(camera),
              float(floor), area == "ellipse", cull, out_u, out_sum)
    return out_u, out_sum


# --------------------------------------------------------------------------------------------
# The torch backend (the reference): the renderer's projection, then tensor operations
# --------------------------------------------------------------------------------------------

def _splat_utility_torch(prep: UtilityScene, camera: Camera, area: str, distance_floor: float) -> np.ndarray:
    """Eq. 1 per splat in the prepared order, through ``project_gaussians``."""
    from l3gs_opt.renderer.projection import project_gaussians

    means, covars, opacity = prep._tensors
    dtype = means.dtype
    with torch.no_grad():
        proj = project_gaussians(means, covars, camera)
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
        dist = torch.linalg.norm(means - centre, dim=1).clamp(min=distance_floor)
        return (overlap / dist * opacity).to(torch.float64).numpy()


# --------------------------------------------------------------------------------------------
# Public functions
# --------------------------------------------------------------------------------------------

def splat_utility(scene: "SplatScene | UtilityScene", camera: Camera, *, area: str = "square",
                  distance_floor: float = DISTANCE_FLOOR, dtype: torch.dtype | None = None,
                  backend: str = "auto") -> np.ndarray:
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
        Precision of the preparation (default float64); a prepared scene keeps the dtype it was
        prepared in, and asking for another is an error.
    backend : {"auto", "numba", "torch"}
        ``"auto"``: the compiled loop when numba is installed, else the torch reference.

    Raises
    ------
    UtilityError
        On an unknown ``area`` or ``backend``, a non-positive ``distance_floor``, or a ``dtype``
        other than the prepared scene's.
    """
    compiled = _check_options(area, distance_floor, backend)
    prep = _prepared(scene, dtype)
    if prep.num_splats == 0:
        return np.zeros(0)
    if compiled:
        u = _numba_pass(prep, camera, area, distance_floor, per_splat=True, sums=False)[0]
    else:
        u = _splat_utility_torch(prep, camera, area, distance_floor)
    out = np.empty_like(u)
    out[prep.order] = u
    return out


def object_layer_utility(scene: "SplatScene | UtilityScene", camera: Camera, *, area: str = "square",
                         distance_floor: float = DISTANCE_FLOOR, dtype: torch.dtype | None = None,
                         backend: str = "auto") -> np.ndarray:
    """``[J, L]``: summed splat utility of each (object id, layer) (``dU`` for a layered scene).

    Object ids index rows directly (an id with no splats has a zero row). Options as in
    :func:`splat_utility`; the sums are ``np.bincount`` of its output in the prepared order.
    """
    compiled = _check_options(area, distance_floor, backend)
    prep = _prepared(scene, dtype)
    J, L = prep.shape_jl
    if prep.num_splats == 0:
        return np.zeros((J, L))
    if compiled:
        return _numba_pass(prep, camera, area, distance_floor, per_splat=False, sums=True)[1].reshape(J, L)
    u = _splat_utility_torch(prep, camera, area, distance_floor)
    return np.bincount(prep.bins, weights=u, minlength=J * L).reshape(J, L)


# --------------------------------------------------------------------------------------------
# Tables
# --------------------------------------------------------------------------------------------

def _horizontal_basis(up_axis: int) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """``(a, b, up)``: yaw 0 looks along ``a``, yaw 90 along ``b = up x a``."""
    up = np.zeros(3)
    up[up_axis] = 1.0
    a = np.zeros(3)
    a[(up_axis + 1) % 3] = 1.0
    return a, np.cross(up, a), up


def _look_rotation(yaw_deg: float, pitch_deg: float, up_axis: int) -> np.ndarray:
    """World-to-camera rotation (OpenCV, no roll) of a camera with this yaw/pitch around the up axis."""
    yaw, pitch = math.radians(yaw_deg), math.radians(pitch_deg)
    a, b, up = _horizontal_basis(up_axis)
    forward = math.cos(pitch) * (math.cos(yaw) * a + math.sin(yaw) * b) + math.sin(pitch) * up
    right = np.cross(forward, up)
    right /= np.linalg.norm(right)
    down = np.cross(forward, right)
    return np.stack([right, down, forward])


def grid_positions(lo, hi, counts) -> np.ndarray:
    """``[nx * ny * nz, 3]`` lattice of positions from ``lo`` to ``hi`` (inclusive), x slowest.

    A table built on such a lattice interpolates trilinearly over position.

    Parameters
    ----------
    lo, hi : array_like, shape [3]
        Corners of the box (world units), ``hi > lo``; an axis with one count sits at
        ``(lo + hi) / 2``.
    counts : sequence of 3 int
        Positions per axis (>= 1).
    """
    lo, hi = np.asarray(lo, np.float64), np.asarray(hi, np.float64)
    if lo.shape != (3,) or hi.shape != (3,) or not (np.all(np.isfinite(lo)) and np.all(np.isfinite(hi))):
        raise UtilityError("lo, hi: must be 3 finite numbers each")
    if len(counts) != 3 or any(int(n) != n or n < 1 for n in counts):
        raise UtilityError(f"counts = {list(counts)}: must be 3 integers >= 1")
    # Before allocating: 100000^3 positions would ask numpy for petabytes.
    total = math.prod(int(n) for n in counts)
    if total > MAX_GRID_POSITIONS:
        raise UtilityError(f"counts = {list(counts)}: {total} positions; must be at most "
                           f"MAX_GRID_POSITIONS = {MAX_GRID_POSITIONS}")
    for k in range(3):
        if hi[k] < lo[k] or (hi[k] == lo[k] and counts[k] > 1):
            raise UtilityError(f"hi[{k}] = {hi[k]} must be > lo[{k}] = {lo[k]} (or equal with counts[{k}] = 1)")
    axes = [np.linspace(lo[k], hi[k], int(n)) if n > 1 else np.array([(lo[k] + hi[k]) / 2]) for k, n in
            enumerate(counts)]
    return np.stack(np.meshgrid(*axes, indexing="ij"), axis=-1).reshape(-1, 3)


def _lattice_axes(positions: np.ndarray) -> tuple[np.ndarray, ...] | None:
    """The per-axis coordinates when ``positions`` is a full lattice in ``grid_positions`` order."""
    axes = tuple(np.unique(positions[:, k]) for k in range(3))
    if math.prod(len(a) for a in axes) != len(positions):
        return None
    full = np.stack(np.meshgrid(*axes, indexing="ij"), axis=-1).reshape(-1, 3)
    return axes if np.array_equal(full, positions) else None


def _linear_weights(axis: np.ndarray, x: float) -> tuple[tuple[int, int], tuple[float, float]]:
    """Indices and weights of linear interpolation on sorted ``axis``, constant beyond its ends."""
    n = len(axis)
    if n == 1 or x <= axis[0]:
        return (0, 0), (1.0, 0.0)
    if x >= axis[-1]:
        return (n - 1, n - 1), (1.0, 0.0)
    k = int(np.searchsorted(axis, x, side="right")) - 1
    f = (x - axis[k]) / (axis[k + 1] - axis[k])
    if f < _SNAP:  # a grid camera's centre carries round-off: it must not blend in a neighbour
        return (k, k), (1.0, 0.0)
    if f > 1.0 - _SNAP:
        return (k + 1, k + 1), (1.0, 0.0)
    return (k, k + 1), (1.0 - f, f)


@dataclass(frozen=True, eq=False)
class UtilityTable:
    """Per-(object, layer) utilities precomputed on a grid of viewpoints, stored sparse.

    Viewpoints are (position, orientation) pairs; orientations are ``yaw_steps`` yaws evenly
    spaced over 360 degrees times the ``pitches_deg``, cameras without roll about ``up_axis``.
    Utilities are those of an ``intrinsics`` camera: a lookup answers for a camera with the
    table's image size and field of view, whatever the intrinsics of the camera passed.

    Attributes
    ----------
    positions : ndarray, shape [P, 3]
        World positions.
    yaw_steps : int
    pitches_deg : ndarray, shape [Q]
        Increasing, in (-90, 90).
    values : scipy.sparse.csr_matrix, shape [P * O, J * L]
        Row ``p * O + o`` for orientation ``o = yaw_index * Q + pitch_index`` (most objects are
        out of view from most viewpoints).
    shape_jl : tuple of int
    up_axis : int
    intrinsics : tuple
        ``(width, height, fx, fy, cx, cy)`` of the table's cameras (pixels).
    """

    positions: np.ndarray
    yaw_steps: int
    pitches_deg: np.ndarray
    values: sp.csr_matrix
    shape_jl: tuple[int, int]
    up_axis: int
    intrinsics: tuple[int, int, float, float, float, float]

    @property
    def orientations(self) -> np.ndarray:
        """``[O, 2]`` (yaw, pitch) in degrees of each grid orientation."""
        yaws = 360.0 * np.arange(self.yaw_steps) / self.yaw_steps
        return np.stack(np.meshgrid(yaws, self.pitches_deg, indexing="ij"), axis=-1).reshape(-1, 2)

    @cached_property
    def _rotations(self) -> np.ndarray:
        return np.stack([_look_rotation(y, p, self.up_axis) for y, p in self.orientations])

    @cached_property
    def _lattice(self) -> tuple[np.ndarray, ...] | None:
        return _lattice_axes(self.positions)

    def camera(self, p: int, o: int) -> Camera:
        """The grid camera at position ``p``, orientation ``o``."""
        w, h, fx, fy, cx, cy = self.intrinsics
        m = np.eye(4)
        m[:3, :3] = self._rotations[o]
        m[:3, 3] = -self._rotations[o] @ self.positions[p]
        return Camera(width=w, height=h, fx=fx, fy=fy, cx=cx, cy=cy, world_to_camera=m)

    def yaw_pitch(self, camera: Camera) -> tuple[float, float]:
        """``(yaw in [0, 360), pitch)`` in degrees of the camera's viewing direction (roll ignored)."""
        a, b, up = _horizontal_basis(self.up_axis)
        f = camera.world_to_camera[2, :3]
        yaw = math.degrees(math.atan2(float(f @ b), float(f @ a))) % 360.0
        return yaw, math.degrees(math.asin(max(-1.0, min(1.0, float(f @ up)))))

    def nearest(self, camera: Camera) -> tuple[int, int]:
        """Indices (position, orientation) of the grid viewpoint nearest to ``camera``."""
        p = int(np.argmin(np.linalg.norm(self.positions - camera.center, axis=1)))
        return p, int(np.argmax(self._rotations[:, 2] @ camera.world_to_camera[2, :3]))

    def orientation_weights(self, camera: Camera) -> tuple[np.ndarray, np.ndarray]:
        """Bilinear weights over (yaw, pitch): ``(orientation indices [4], weights [4])``.

        Yaw wraps around; a pitch beyond the grid's range takes the nearest grid pitch.
        """
        yaw, pitch = self.yaw_pitch(camera)
        s = yaw * self.yaw_steps / 360.0
        if abs(s - round(s)) < _SNAP:  # a grid camera's atan2 round-off must not blend in a neighbour
            s = float(round(s))
        k0 = int(math.floor(s))
        fy = s - k0
        near = np.flatnonzero(np.abs(self.pitches_deg - pitch) < _SNAP * 360.0 / self.yaw_steps)
        if near.size:
            pitch = float(self.pitches_deg[near[0]])
        ks = (k0 % self.yaw_steps, (k0 + 1) % self.yaw_steps)
        qs, wq = _linear_weights(self.pitches_deg, pitch)
        Q = len(self.pitches_deg)
        idx = np.array([k * Q + q for k in ks for q in qs])
        w = np.array([wk * w_ for wk in (1.0 - fy, fy) for w_ in wq])
        return idx, w

    def position_weights(self, camera: Camera, neighbours: int | None = None) -> tuple[np.ndarray, np.ndarray]:
        """Weights over grid positions: ``(position indices, weights)``, summing to 1.

        On a lattice (:func:`grid_positions`): trilinear, constant beyond the box. Otherwise:
        inverse-distance weights over the ``neighbours`` nearest positions (default
        ``min(8, P)``; all weight on a position the camera sits on).
        """
        c = camera.center
        if self._lattice is not None:
            axes = self._lattice
            (i0, i1), (wi0, wi1) = _linear_weights(axes[0], c[0])
            (j0, j1), (wj0, wj1) = _linear_weights(axes[1], c[1])
            (k0, k1), (wk0, wk1) = _linear_weights(axes[2], c[2])
            ny, nz = len(axes[1]), len(axes[2])
            idx, w = [], []
            for i, wi in ((i0, wi0), (i1, wi1)):
                for j, wj in ((j0, wj0), (j1, wj1)):
                    for k, wk in ((k0, wk0), (k1, wk1)):
                        if wi * wj * wk > 0.0:
                            idx.append((i * ny + j) * nz + k)
                            w.append(wi * wj * wk)
            return np.array(idx), np.array(w)
        if neighbours is None:
            neighbours = min(8, len(self.positions))
        if not 1 <= neighbours <= len(self.positions):
            raise UtilityError(f"neighbours = {neighbours}: must be in [1, {len(self.positions)}]")
        dist = np.linalg.norm(self.positions - c, axis=1)
        near = np.argsort(dist, kind="stable")[:neighbours]
        if neighbours == 1 or dist[near[0]] <= _SNAP * dist[near[1]]:
            return near[:1], np.ones(1)
        w = 1.0 / dist[near]
        return near, w / w.sum()

    def lookup(self, camera: Camera, *, interpolate: bool = True, neighbours: int | None = None) -> np.ndarray:
        """``[J, L]`` utilities seen from ``camera``, from the grid.

        ``interpolate=False``: the entry of the nearest grid viewpoint (nearest position, nearest
        viewing direction). ``interpolate=True``: the weighted mean of the entries at
        :meth:`position_weights` x :meth:`orientation_weights` (bilinear in yaw and pitch), exact at
        a grid viewpoint. Roll is ignored. Utilities are in the table's pixels (see the class).
        """
        O = self.yaw_steps * len(self.pitches_deg)
        if not interpolate:
            p, o = self.nearest(camera)
            return self.values[p * O + o].toarray().reshape(self.shape_jl)
        pi, pw = self.position_weights(camera, neighbours)
        oi, ow = self.orientation_weights(camera)
        rows = (pi[:, None] * O + oi[None, :]).ravel()
        weights = (pw[:, None] * ow[None, :]).ravel()
        keep = weights > 0.0
        return (weights[keep] @ self.values[rows[keep]].toarray()).reshape(self.shape_jl)

    @property
    def nbytes(self) -> int:
        v = self.values
        return int(v.data.nbytes + v.indices.nbytes + v.indptr.nbytes)


def build_utility_table(scene: "SplatScene | UtilityScene", positions: np.ndarray, *, yaw_steps: int = 36,
                        pitches_deg: tuple[float, ...] = (-45.0, -30.0, -15.0, 0.0, 15.0, 30.0),
                        up_axis: int = 2, width: int = 800, height: int = 600, fov_deg: float = 70.0,
                        progress: bool = False, area: str = "square", distance_floor: float = DISTANCE_FLOOR,
                        dtype: torch.dtype | None = None, backend: str = "auto") -> UtilityTable:
    """Utilities of every (object, layer) from every grid position and orientation.

    The paper samples 1,000 positions x 1,728 orientations. Each viewpoint costs one pass over
    the splats, whatever the image size (no pixel is touched): build the table at
    the display's size, since utilities at a smaller size are not a rescaling of the display's
    (the 0.3 px^2 dilation and integer radii weigh small splats differently). The compiled
    backend runs viewpoints on all cores. A table over :func:`grid_positions` interpolates
    trilinearly over position; the error is dominated by the position spacing (see
    ``benchmarks/results/utility.json``).

    Parameters
    ----------
    scene : SplatScene or UtilityScene
    positions : ndarray, shape [P, 3]
        World positions (world units).
    yaw_steps : int, keyword-only
        Yaws per position, evenly spaced over 360 degrees.
    pitches_deg : sequence of float, keyword-only
        Strictly increasing pitches in (-90, 90) degrees (positive looks up ``up_axis``).
    up_axis : {0, 1, 2}, keyword-only
    width, height : int, keyword-only
        The table cameras' image size (pixels): the display's.
    fov_deg : float, keyword-only
        Horizontal field of view (degrees); square pixels.
    progress : bool, keyword-only
        Show a progress bar over positions.
    area, distance_floor, dtype, backend
        As in :func:`splat_utility`.

    Raises
    ------
    UtilityError
        On a bad grid or option, naming it.
    """
    from tqdm import tqdm

    compiled = _check_options(area, distance_floor, backend)
    positions = np.asarray(positions, dtype=np.float64)
    if positions.ndim != 2 or positions.shape[1] != 3 or len(positions) == 0:
        raise UtilityError(f"positions: shape {positions.shape} must be [P, 3] with P >= 1")
    if not np.all(np.isfinite(positions)):
        p = int(np.argwhere(~np.isfinite(positions))[0, 0])
        raise UtilityError(f"positions[{p}] = {positions[p].tolist()}: must be finite")
    check_count("yaw_steps", yaw_steps, high=MAX_YAW_STEPS, error=lambda f, m: UtilityError(f"{f} = {m}"))
    pitches = np.asarray(pitches_deg, dtype=np.float64).ravel()
    if pitches.size == 0:
        raise UtilityError("pitches_deg: need at least one pitch")
    for q, v in enumerate(pitches):
        if not -90.0 < v < 90.0:
            raise UtilityError(f"pitches_deg[{q}] = {v}: must be in (-90, 90)")
        if q and v <= pitches[q - 1]:
            raise UtilityError(f"pitches_deg[{q}] = {v}: must be greater than pitches_deg[{q - 1}]")
    if up_axis not in (0, 1, 2):
        raise UtilityError(f"up_axis = {up_axis!r}: must be 0, 1 or 2")
    if not (0.0 < fov_deg < 180.0):
        raise UtilityError(f"fov_deg = {fov_deg!r}: must be in (0, 180)")
    fx = width / (2 * math.tan(math.radians(fov_deg) / 2))
    prep = _prepared(scene, dtype)
    J, L = prep.shape_jl
    table = UtilityTable(positions, int(yaw_steps), pitches, sp.csr_matrix((0, J * L)), (J, L), up_axis,
                         (int(width), int(height), fx, fx, width / 2, height / 2))
    rots = np.ascontiguousarray(table._rotations)
    O = len(rots)
    blocks = []
    for p in tqdm(range(len(positions)), desc="utility table", disable=not progress):
        if compiled and prep.num_splats:
            # The same arithmetic as table.camera(p, o): t = -R c, centre = -R^T t.
            transs = np.stack([-r @ positions[p] for r in rots])
            centres = np.stack([-r.T @ t for r, t in zip(rots, transs)])
            sums = np.zeros((O, J * L))
            cam = table.camera(p, 0)
            _eq1_views(*prep._kernel_args, rots, transs, centres,
                       *_intrinsics(cam), float(distance_floor), area == "ellipse", sums)
        else:
            sums = np.stack([object_layer_utility(prep, table.camera(p, o), area=area, distance_floor=distance_floor,
                                                  backend=backend).ravel() for o in range(O)])
        blocks.append(sp.csr_matrix(sums))
    values = sp.vstack(blocks, format="csr")
    return UtilityTable(positions, int(yaw_steps), pitches, values, (J, L), up_axis, table.intrinsics)
