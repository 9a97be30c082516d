"""Global significance of each splat (LightGaussian's score), used to rank splats for pruning.

Formula (LightGaussian, Fan et al. 2023, ``calculate_v_imp_score``): for splat ``j`` over the
training views ``v`` and the pixels ``p`` it is blended on,

    GS_j = ( sum_v sum_p alpha_j(p) T_j(p) ) * ( V_j / V_ref ) ** beta

* ``alpha_j(p) T_j(p)`` is the splat's blending weight at pixel ``p`` (the renderer's
  :attr:`RenderOutput.weights` summed over the image, so opacity and occlusion are included;
  a splat that is culled or skipped at a pixel contributes 0 there);
* ``V_j = prod_k exp(log_scale_jk)`` is its volume up to the constant ``4 pi / 3``;
* ``V_ref`` is the volume at position ``floor(0.9 N)`` of the volumes sorted in descending
  order (the 10th percentile from below, as LightGaussian does), so most splats have
  ``V_j / V_ref > 1`` and tiny needles are discounted;
* ``beta = 0.1`` (LightGaussian's ``v_pow``): volume only breaks ties between splats of similar
  blending weight.

The sum is accumulated in float64 whatever the render dtype.
"""

from __future__ import annotations

from typing import Sequence

import numpy as np
import torch

from .render import render_gaussians, scene_tensors

__all__ = ["VOLUME_POWER", "VOLUME_QUANTILE", "global_significance", "volume_factor", "significance_order"]

#: Exponent ``beta`` of the normalised volume (LightGaussian's default ``v_pow``).
VOLUME_POWER = 0.1
#: ``V_ref`` is the volume at this fraction of the descending-sorted volumes (LightGaussian: 0.9).
VOLUME_QUANTILE = 0.9


def volume_factor(log_scales, *, power: float = VOLUME_POWER) -> np.ndarray:
    """``(V_j / V_ref) ** power`` per splat (float64; see the module docstring).

    Parameters
    ----------
    log_scales : array_like, shape [N, 3]
        Natural log of the standard deviations (world units).
    power : float, keyword-only

    Returns
    -------
    ndarray, shape [N], float64
    """
    ls = np.asarray(log_scales, dtype=np.float64)
    n = ls.shape[0]
    if n == 0:
        return np.zeros(0)
    log_v = ls.sum(axis=1)  # log of the product of the scales, so no overflow for big splats
    ref = np.sort(log_v)[::-1][int(n * VOLUME_QUANTILE)]
    return np.exp(power * (log_v - ref))


def global_significance(scene, cameras: Sequence, *, power: float = VOLUME_POWER,
                        dtype=torch.float32) -> np.ndarray:
    """LightGaussian global significance of every splat of ``scene`` over ``cameras``.

    Parameters
    ----------
    scene : SplatScene
    cameras : sequence of Camera
        The training views.
    power : float, keyword-only
        ``beta`` (default :data:`VOLUME_POWER`).
    dtype : torch dtype, keyword-only
        Render precision (float64 for tests against a reference).

    Returns
    -------
    ndarray, shape [N], float64
        ``GS_j >= 0`` (0 for splats never blended in any view).
    """
    if len(cameras) == 0:
        raise ValueError("cameras: at least one camera is needed to score splats")
    n = scene.num_splats
    acc = np.zeros(n)
    if n == 0:
        return acc
    from .train import TRAIN_THREADS, threads

    params = scene_tensors(scene, dtype=dtype)
    with torch.no_grad(), threads(TRAIN_THREADS):
        for cam in cameras:
            # SH degree 0 is enough: the weights depend on geometry and opacity only
            out = render_gaussians(**params, camera=cam, sh_degree=0)
            acc += out.weights.numpy()
    return acc * volume_factor(scene.log_scales, power=power)


def significance_order(score: np.ndarray) -> np.ndarray:
    """Indices sorting ``score`` descending (stable: ties keep the original order)."""
    return np.argsort(-np.asarray(score, dtype=np.float64), kind="stable")
