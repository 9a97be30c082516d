"""Segmentation of a scene without object ids into objects, from its splat centres alone.

A trained scene rarely carries object ids (Gaussian Grouping and similar tools write them; most
PLYs do not), but per-object delivery needs objects: things that enter and leave the viewport
together.  :func:`segment_scene` finds them in three optional steps, all on the splat means in
world units and reproducible by seed:

1. **Background** (``background=True``): splats farther from the scene's centre (the coordinate-wise
   median) than :data:`BACKGROUND_FACTOR` times the median distance form one object.  Captured
   scenes have a shell of far, large splats (sky, distant buildings) that is seen from everywhere.
2. **Planes** (``planes=P``): up to ``P`` dominant planes (floor, then walls), found one after the
   other by RANSAC (:data:`RANSAC_TRIALS` seeded trials, inliers within :data:`PLANE_TOL` voxels, support counted in
   occupied voxels, refined by a
   least-squares fit), each kept while its inliers occupy at least :data:`MIN_PLANE_FRACTION` of the occupied voxels.
   Without this step a floor joins every object standing on it into one component.
3. **The rest**, by ``method``:

   - ``"components"`` (default): connected components of the occupied voxels (26-neighbourhood) of a
     grid whose voxel is :data:`VOXEL_NN_FACTOR` times the median nearest-neighbour distance of the
     splats (dense enough that one surface stays one piece; bounded so that the grid has at most
     :data:`MAX_GRID_CELLS` cells a side).  Components with fewer than :data:`MIN_COMPONENT_FRACTION`
     of the splats (floaters, specks) join the component of their nearest large splat.
   - ``"kmeans"``: Lloyd's k-means with k-means++ seeding (:func:`scipy.cluster.vq.kmeans2`), fitted
     on at most :data:`SAMPLE` splats; compact, roughly equal-volume clusters that ignore boundaries.

``objects`` is the number of objects wanted, or ``"auto"``: the groups the steps find (components
above), capped at :data:`MAX_AUTO_OBJECTS`.  When a count is given, groups are merged (the smallest
into the group with the nearest centroid) or split (the largest by 2-means) until it is met.
Ids are finally renumbered ``0..k-1`` by decreasing size (ties by centroid), so the result does not
depend on the order in which groups were found.
"""

from __future__ import annotations

import dataclasses
from typing import Union

import numpy as np

from l3gs_opt.scene.splats import SceneError, SplatScene, check_seed

__all__ = ["SAMPLE", "METHODS", "segment_scene", "segment_labels", "object_counts",
           "BACKGROUND_FACTOR", "MIN_PLANE_FRACTION", "MIN_COMPONENT_FRACTION", "MAX_AUTO_OBJECTS"]

#: Largest number of splats k-means fits its centroids on (the rest are only assigned).
SAMPLE = 50_000
METHODS = ("components", "kmeans")
#: Background: farther from the centre than this many median distances.
BACKGROUND_FACTOR = 3.0
#: A plane is kept while its inliers occupy at least this share of the occupied voxels.
MIN_PLANE_FRACTION = 0.05
#: Plane inliers: within this many voxels of the plane.
PLANE_TOL = 0.25
#: Components below this share of all splats are specks and join their nearest large neighbour.
MIN_COMPONENT_FRACTION = 0.005
#: ``objects="auto"`` never returns more objects than this (the smallest merge first).
MAX_AUTO_OBJECTS = 32
#: Voxel edge = ``VOXEL_NN_FACTOR`` x this quantile of the splats' nearest-neighbour distances: a
#: high quantile, so that the sparsest surfaces (walls, floors) still join up across their gaps.
VOXEL_NN_QUANTILE = 0.75
VOXEL_NN_FACTOR = 2.0
#: The voxel grid is at most this many cells along its longest side.
MAX_GRID_CELLS = 1024
#: RANSAC trials per plane.
RANSAC_TRIALS = 256
#: Nearest neighbours are measured on at most this many splats, plane support on this many voxels.
_NN_SAMPLE = 200_000
_PLANE_SAMPLE = 20_000


def _check(scene: SplatScene, objects, method: str, planes: int) -> None:
    n = scene.num_splats
    if n == 0:
        raise SceneError("scene", "has no splats to segment")
    if objects != "auto" and (isinstance(objects, bool) or not isinstance(objects, (int, np.integer))
                              or not 1 <= objects <= n):
        raise SceneError("objects", f"{objects!r}: must be 'auto' or an integer in [1, {n}] (the splat count)")
    if method not in METHODS:
        raise SceneError("method", f"{method!r}: must be one of {', '.join(METHODS)}")
    if isinstance(planes, bool) or not isinstance(planes, (int, np.integer)) or not 0 <= planes <= 16:
        raise SceneError("planes", f"{planes!r}: must be an integer in [0, 16]")


def voxel_size(points: np.ndarray, *, seed: int = 0) -> float:
    """Voxel edge (world units) for the components step: see the module docstring."""
    from scipy.spatial import cKDTree

    rng = np.random.default_rng(seed)
    sample = points if len(points) <= _NN_SAMPLE else points[rng.choice(len(points), _NN_SAMPLE, replace=False)]
    if len(sample) < 2:
        return 1.0
    d, _ = cKDTree(sample).query(sample, k=2)
    nn = float(np.quantile(d[:, 1], VOXEL_NN_QUANTILE))
    # A sample is sparser than the scene: scale back as for points on surfaces (area ~ count).
    nn *= np.sqrt(len(sample) / len(points))
    extent = float(np.ptp(points, axis=0).max())
    v = VOXEL_NN_FACTOR * nn
    return max(v, extent / MAX_GRID_CELLS, 1e-12)


def _components(points: np.ndarray, voxel: float) -> np.ndarray:
    """Connected components (26-neighbourhood) of the occupied voxels; a label per point."""
    from scipy.sparse import coo_matrix
    from scipy.sparse.csgraph import connected_components

    cells = np.floor((points - points.min(axis=0)) / voxel).astype(np.int64) + 1
    dims = cells.max(axis=0) + 2
    keys = (cells[:, 0] * dims[1] + cells[:, 1]) * dims[2] + cells[:, 2]
    occupied, point_cell = np.unique(keys, return_inverse=True)
    rows, cols = [], []
    for dx in (-1, 0, 1):
        for dy in (-1, 0, 1):
            for dz in (-1, 0, 1):
                if (dx, dy, dz) <= (0, 0, 0):
                    continue   # half the offsets: the graph is undirected
                other = occupied + (dx * dims[1] + dy) * dims[2] + dz
                at = np.searchsorted(occupied, other)
                at = np.minimum(at, len(occupied) - 1)
                hit = occupied[at] == other
                rows.append(np.nonzero(hit)[0])
                cols.append(at[hit])
    r, c = np.concatenate(rows), np.concatenate(cols)
    graph = coo_matrix((np.ones(len(r), np.int8), (r, c)), shape=(len(occupied),) * 2)
    _, cell_label = connected_components(graph, directed=False)
    return cell_label[point_cell]


def _absorb_small(points: np.ndarray, labels: np.ndarray, min_count: int) -> np.ndarray:
    """Points of groups with fewer than ``min_count`` points take the group of their nearest
    point in a large group (all points stay if no group is large)."""
    from scipy.spatial import cKDTree

    ids, counts = np.unique(labels, return_counts=True)
    small = np.isin(labels, ids[counts < min_count])
    if not small.any() or small.all():
        return labels
    big = np.nonzero(~small)[0]
    if len(big) > _NN_SAMPLE:  # a sample of the large groups is as good a neighbour, and much faster
        big = np.sort(np.random.default_rng(0).choice(big, _NN_SAMPLE, replace=False))
    _, nearest = cKDTree(points[big]).query(points[small], k=1)
    out = labels.copy()
    out[small] = labels[big[nearest]]
    return out


def _fit_plane(points: np.ndarray, cells: np.ndarray, tol: float, rng: np.random.Generator) -> np.ndarray:
    """Inlier mask of the best RANSAC plane (refined by least squares on its inliers).

    RANSAC draws and scores on the voxels' centroids (``cells``: a voxel key per point), not on
    the splats: a plane's support is the area it covers, so a floor wins over a plane through the
    dense middles of several objects, and sparse surfaces are drawn as often as dense ones.
    """
    _, inverse, counts = np.unique(cells, return_inverse=True, return_counts=True)
    reps = np.stack([np.bincount(inverse, weights=points[:, i]) for i in range(3)], axis=1) / counts[:, None]
    if len(reps) > _PLANE_SAMPLE:  # scoring on a sample of the voxels ranks planes the same way
        reps = reps[rng.choice(len(reps), _PLANE_SAMPLE, replace=False)]
    m = len(reps)
    if m < 3:
        return np.zeros(len(points), bool)
    best, best_support = None, -1
    for _ in range(RANSAC_TRIALS):
        a, b, c = reps[rng.choice(m, 3, replace=False)]
        normal = np.cross(b - a, c - a)
        norm = np.linalg.norm(normal)
        if norm == 0:
            continue
        normal /= norm
        support = int(np.count_nonzero(np.abs((reps - a) @ normal) < tol))
        if support > best_support:
            best, best_support = (a, normal), support
    if best is None:
        return np.zeros(len(points), bool)
    a, normal = best
    inl = np.abs((reps - a) @ normal) < tol
    centre = reps[inl].mean(axis=0)
    normal = np.linalg.svd(reps[inl] - centre, full_matrices=False)[2][-1]
    return np.abs((points - centre) @ normal) < tol


def _cells(points: np.ndarray, voxel: float) -> np.ndarray:
    """A voxel key per point (int64)."""
    c = np.floor((points - points.min(axis=0)) / voxel).astype(np.int64)
    dims = c.max(axis=0) + 1
    return (c[:, 0] * dims[1] + c[:, 1]) * dims[2] + c[:, 2]


def _kmeans(points: np.ndarray, k: int, rng: np.random.Generator, iterations: int) -> np.ndarray:
    from scipy.cluster.vq import kmeans2, vq

    if k <= 1 or len(points) <= 1:
        return np.zeros(len(points), np.int64)
    k = min(k, len(points))
    sample = points if len(points) <= SAMPLE else points[rng.choice(len(points), SAMPLE, replace=False)]
    centroids, _ = kmeans2(sample, k, iter=iterations, minit="++", seed=rng)
    labels, _ = vq(points, centroids)
    return labels.astype(np.int64)


def _to_count(points: np.ndarray, labels: np.ndarray, k: int, rng: np.random.Generator,
              iterations: int) -> np.ndarray:
    """Merge the smallest group into the nearest centroid's, or split the largest by 2-means,
    until there are ``k`` groups."""
    labels = np.unique(labels, return_inverse=True)[1].astype(np.int64)
    m = int(labels.max()) + 1
    if m > k:
        counts = np.bincount(labels, minlength=m).astype(np.float64)
        centroids = np.stack([np.bincount(labels, weights=points[:, i], minlength=m) for i in range(3)], axis=1)
        centroids /= counts[:, None]
        into = np.arange(m)
        alive = np.ones(m, bool)
        for _ in range(m - k):
            s = int(np.argmin(np.where(alive, counts, np.inf)))
            d = np.linalg.norm(centroids - centroids[s], axis=1)
            d[~alive | (np.arange(m) == s)] = np.inf
            t = int(np.argmin(d))
            centroids[t] = (centroids[t] * counts[t] + centroids[s] * counts[s]) / (counts[t] + counts[s])
            counts[t] += counts[s]
            alive[s] = False
            into[into == s] = t
        labels = np.unique(into[labels], return_inverse=True)[1].astype(np.int64)
    while int(labels.max()) + 1 < k:
        counts = np.bincount(labels)
        at = np.nonzero(labels == int(np.argmax(counts)))[0]
        if len(at) < 2:
            break  # every group is one splat: more groups than splats is impossible
        halves = _kmeans(points[at], 2, rng, iterations)
        if halves.min() == halves.max():  # identical points: cut by order
            halves = (np.arange(len(at)) >= len(at) // 2).astype(np.int64)
        labels[at[halves == 1]] = labels.max() + 1
    return labels


def segment_labels(scene: SplatScene, objects: Union[int, str] = "auto", *, method: str = "components",
                   planes: int = 0, background: bool = False, seed: int = 0, iterations: int = 30,
                   features: np.ndarray | None = None) -> np.ndarray:
    """Object id of every splat, ``0..k-1`` by decreasing size (see the module docstring).

    Parameters
    ----------
    scene : SplatScene
    objects : int or "auto"
        Number of objects wanted, ``1 <= objects <= N``, or ``"auto"``.
    method : {"components", "kmeans"}, keyword-only
    planes : int, keyword-only
        Dominant planes to split off first (0..16; e.g. 1 for a floor, 5 for a room).
    background : bool, keyword-only
        Split the far background off first.
    seed : int, keyword-only
        Seed of the plane fits and k-means, >= 0.
    iterations : int, keyword-only
        Lloyd iterations of each k-means.
    features : ndarray [N, K], optional, keyword-only
        Per-splat identity encodings (Gaussian Grouping's ``obj_dc_*``,
        :func:`l3gs_opt.scene.splats.read_identity_features`): the splats left after planes and
        background are grouped by k-means on the unit-normalised encodings (``method`` is then
        ignored; ``"auto"`` takes the components' count, as ``kmeans`` does).

    Returns
    -------
    ndarray, shape [N], int32

    Raises
    ------
    SceneError
        On an empty scene or an argument out of range (naming it).
    """
    _check(scene, objects, method, planes)
    seed = check_seed(seed)
    pts = scene.means.astype(np.float64)
    n = len(pts)
    if features is not None:
        features = np.asarray(features, np.float64)
        if features.ndim != 2 or features.shape[0] != n or not np.isfinite(features).all():
            raise SceneError("features", f"shape {features.shape}: must be finite [N, K] (N = {n})")
        features = features / np.maximum(np.linalg.norm(features, axis=1, keepdims=True), 1e-12)
    rng = np.random.default_rng(seed)
    labels = np.full(n, -1, np.int64)
    nxt = 0
    if background and n > 1:
        centre = np.median(pts, axis=0)
        dist = np.linalg.norm(pts - centre, axis=1)
        far = dist > BACKGROUND_FACTOR * np.median(dist)
        if far.any() and not far.all():
            labels[far] = nxt
            nxt += 1
    voxel = voxel_size(pts[labels < 0], seed=seed)
    cells = _cells(pts, voxel)
    occupied = len(np.unique(cells[labels < 0]))
    for _ in range(planes):
        rest = np.nonzero(labels < 0)[0]
        if len(rest) < 3:
            break
        inl = _fit_plane(pts[rest], cells[rest], PLANE_TOL * voxel, rng)
        if len(np.unique(cells[rest[inl]])) < MIN_PLANE_FRACTION * occupied:
            break
        labels[rest[inl]] = nxt
        nxt += 1
    rest = np.nonzero(labels < 0)[0]
    if len(rest):
        wanted = None if objects == "auto" else max(1, int(objects) - nxt)
        if features is not None:
            sub = _kmeans(features[rest], wanted or _auto_count(pts[rest], voxel, n), rng, iterations)
        elif method == "kmeans":
            sub = _kmeans(pts[rest], wanted or _auto_count(pts[rest], voxel, n), rng, iterations)
        else:
            sub = _components(pts[rest], voxel)
            sub = _absorb_small(pts[rest], sub, max(1, int(np.ceil(MIN_COMPONENT_FRACTION * n))))
        labels[rest] = nxt + np.unique(sub, return_inverse=True)[1]
    target = min(MAX_AUTO_OBJECTS, len(np.unique(labels))) if objects == "auto" else int(objects)
    labels = _to_count(pts, labels, target, rng, iterations)
    return _by_size(pts, labels).astype(np.int32)


def _auto_count(points: np.ndarray, voxel: float, n_all: int) -> int:
    """The object count ``kmeans`` uses for ``"auto"``: the large components' count."""
    sub = _absorb_small(points, _components(points, voxel), max(1, int(np.ceil(MIN_COMPONENT_FRACTION * n_all))))
    return int(len(np.unique(sub)))


def _by_size(points: np.ndarray, labels: np.ndarray) -> np.ndarray:
    ids, inverse, counts = np.unique(labels, return_inverse=True, return_counts=True)
    centroids = np.stack([points[inverse == i].mean(axis=0) for i in range(len(ids))])
    order = np.lexsort((centroids[:, 2], centroids[:, 1], centroids[:, 0], -counts))
    rank = np.empty(len(ids), np.int64)
    rank[order] = np.arange(len(ids))
    return rank[inverse]


def segment_scene(scene: SplatScene, objects: Union[int, str] = "auto", *, method: str = "components",
                  planes: int = 0, background: bool = False, seed: int = 0, iterations: int = 30,
                  features: np.ndarray | None = None) -> SplatScene:
    """Return ``scene`` with ``object_ids`` from :func:`segment_labels` (existing ids are replaced;
    the splats are untouched)."""
    return dataclasses.replace(scene, object_ids=segment_labels(scene, objects, method=method, planes=planes,
                                                                background=background, seed=seed,
                                                                iterations=iterations, features=features))


def object_counts(scene: SplatScene) -> list[int]:
    """Splats per object id ``0..max`` (``[N]`` for an unsegmented scene)."""
    if scene.object_ids is None:
        return [scene.num_splats]
    return np.bincount(scene.object_ids).tolist()


def adjusted_rand_index(truth: np.ndarray, labels: np.ndarray) -> float:
    """Adjusted Rand index of two labellings of the same splats (1 = the same partition, ~0 = chance).

    Hubert and Arabie (1985): ``(sum_ij C(n_ij, 2) - E) / (0.5 (sum_i C(a_i, 2) + sum_j C(b_j, 2)) - E)``
    with ``E = sum_i C(a_i, 2) sum_j C(b_j, 2) / C(n, 2)`` over the contingency table ``n_ij``.
    Used to score a segmentation against known ids (the procedural scenes carry them).
    """
    truth, labels = np.asarray(truth).ravel(), np.asarray(labels).ravel()
    if truth.shape != labels.shape:
        raise SceneError("labels", f"shape {labels.shape}: must equal the truth's {truth.shape}")
    n = truth.size
    if n < 2:
        return 1.0
    _, t = np.unique(truth, return_inverse=True)
    _, l_ = np.unique(labels, return_inverse=True)
    table = np.bincount(t * (l_.max() + 1) + l_, minlength=(t.max() + 1) * (l_.max() + 1)).astype(np.float64)
    pairs = lambda x: float((x * (x - 1) / 2).sum())  # noqa: E731
    cells = pairs(table)
    rows = pairs(table.reshape(t.max() + 1, -1).sum(axis=1))
    cols = pairs(table.reshape(t.max() + 1, -1).sum(axis=0))
    expected = rows * cols / (n * (n - 1) / 2)
    top = 0.5 * (rows + cols) - expected
    return 1.0 if top == 0 else (cells - expected) / top
