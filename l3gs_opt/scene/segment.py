"""Segmentation of an unsegmented scene into objects by 3D clustering of the splat centres.

Method: k-means (Lloyd's algorithm) on the splat means in world units, with k-means++
initialisation, via :func:`scipy.cluster.vq.kmeans2` (``minit="++"``, a seeded
``numpy.random.Generator``).  For large scenes the centroids are fitted on a random sample
of at most ``SAMPLE`` splats and every splat is then assigned to its nearest centroid
(:func:`scipy.cluster.vq.vq`).  Object ids are renumbered ``0..k-1`` by decreasing cluster
size (ties by centroid coordinates), so the result does not depend on the order of the
centroids.  Deterministic for a given seed.

Only positions are used: a splat's object is where it is, which is what per-object
delivery (frustum and distance of the object) needs.  k-means gives compact, roughly
equal-volume clusters; it does not know object boundaries, so a large wall may be split and
two touching objects merged — bring ids from a real segmentation when that matters.
"""

from __future__ import annotations

import dataclasses

import numpy as np

from l3gs_opt.scene.splats import SceneError, SplatScene

__all__ = ["SAMPLE", "segment_scene"]

#: Largest number of splats the centroids are fitted on (the rest are only assigned).
SAMPLE = 50_000


def segment_scene(scene: SplatScene, objects: int, *, seed: int = 0, iterations: int = 30) -> SplatScene:
    """Return ``scene`` with ``object_ids`` from k-means on its splat means (see module docstring).

    Parameters
    ----------
    scene : SplatScene
    objects : int
        Number of clusters ``k``, ``1 <= k <= N``.
    seed : int, keyword-only
    iterations : int, keyword-only
        Lloyd iterations.

    Returns
    -------
    SplatScene
        Same splats, ids ``0..k-1`` (0 = largest cluster).  Existing ids are replaced.

    Raises
    ------
    SceneError
        If ``objects`` is not an integer in ``[1, N]``.
    """
    from scipy.cluster.vq import kmeans2, vq

    n = scene.num_splats
    if isinstance(objects, bool) or not isinstance(objects, (int, np.integer)) or not 1 <= objects <= max(n, 1):
        raise SceneError("objects", f"{objects!r}: must be an integer in [1, {n}] (the splat count)")
    pts = scene.means.astype(np.float64)
    rng = np.random.default_rng(seed)
    sample = pts if n <= SAMPLE else pts[rng.choice(n, SAMPLE, replace=False)]
    if objects == 1:
        labels = np.zeros(n, np.int64)
        return dataclasses.replace(scene, object_ids=labels)
    centroids, _ = kmeans2(sample, objects, iter=iterations, minit="++", seed=rng)
    labels, _ = vq(pts, centroids)
    counts = np.bincount(labels, minlength=objects)
    order = np.lexsort((centroids[:, 2], centroids[:, 1], centroids[:, 0], -counts))
    rank = np.empty(objects, np.int64)
    rank[order] = np.arange(objects)
    return dataclasses.replace(scene, object_ids=rank[labels])
