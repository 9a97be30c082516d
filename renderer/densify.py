"""Adaptive density control of 3DGS (Kerbl et al. 2023, ``densify_and_prune``), on plain tensors.

Rules, applied every ``densify_every`` iterations of a ``Recovery`` run:

* **view-space gradient**: for every iteration in which splat ``j`` is visible, the norm of the
  loss gradient with respect to its projected mean, converted from pixels to NDC units
  (``dL/dx_ndc = dL/dx_px * W / 2``, as the reference rasteriser's ``means2D`` gradient), is added
  to ``grad_sum[j]`` and ``count[j]`` is incremented; ``g_j = grad_sum[j] / count[j]``;
* **clone**: ``g_j >= grad_threshold`` and ``max scale <= percent_dense * extent`` (a small splat
  in an under-reconstructed region): a copy of the splat is appended (same parameters);
* **split**: ``g_j >= grad_threshold`` and ``max scale > percent_dense * extent`` (a large splat
  over high-frequency detail): it is replaced by ``SPLIT_N = 2`` splats whose means are drawn from
  the splat's own Gaussian and whose scales are divided by ``0.8 * SPLIT_N = 1.6``;
  rotation, opacity, SH and object id are inherited;
* **prune**: splats with ``sigmoid(opacity) < min_opacity`` (near-transparent) are removed
  (clones and split children are judged as well, as in the reference);
* **opacity reset**: every ``opacity_reset_every`` iterations, ``opacity = min(opacity, 0.01)``.

Object ids are carried through clone and split (a child belongs to its parent's object).
"""

from __future__ import annotations

from typing import NamedTuple, Optional

import numpy as np
import torch

from .projection import quat_to_rotmat

__all__ = ["SPLIT_N", "SPLIT_SCALE_DIV", "RESET_OPACITY", "DensifyResult", "densify_and_prune",
           "reset_opacity", "view_space_grad"]

#: Children of a split splat.
SPLIT_N = 2
#: A split child's scales are the parent's divided by this (reference: 0.8 * N).
SPLIT_SCALE_DIV = 0.8 * SPLIT_N
#: Opacity ceiling applied by an opacity reset.
RESET_OPACITY = 0.01


class DensifyResult(NamedTuple):
    """Output of :func:`densify_and_prune`.

    Attributes
    ----------
    params : dict of Tensor
        New parameters (keys as in ``render_gaussians``), detached.
    object_ids : ndarray, shape [M], int or None
    source : Tensor, shape [M], int64
        Index of the old splat each new row comes from (for carrying optimizer state).
    is_new : Tensor, shape [M], bool
        Rows that did not exist before (clones and split children); their optimizer state starts at 0.
    cloned, split, pruned : int
        Counts of splats cloned, split (parents) and removed.
    """

    params: dict
    object_ids: Optional[np.ndarray]
    source: torch.Tensor
    is_new: torch.Tensor
    cloned: int
    split: int
    pruned: int


def view_space_grad(means2d_grad: torch.Tensor, width: int, height: int) -> torch.Tensor:
    """Norm of the view-space positional gradient in NDC units, shape [N] (see module docstring).

    Parameters
    ----------
    means2d_grad : Tensor, shape [N, 2]
        ``dL / d means2d`` in pixels^-1 (loss per pixel).
    width, height : int
        Image size in pixels.
    """
    g = means2d_grad.detach() * torch.tensor([0.5 * width, 0.5 * height], dtype=means2d_grad.dtype)
    return torch.linalg.vector_norm(g, dim=-1)


def densify_and_prune(params: dict, object_ids: Optional[np.ndarray], grad_sum: torch.Tensor,
                      count: torch.Tensor, *, grad_threshold: float, extent: float,
                      percent_dense: float = 0.01, min_opacity: float = 0.005,
                      max_new: Optional[int] = None, min_splats: int = 0, generator: Optional[torch.Generator] = None
                      ) -> DensifyResult:
    """Clone, split and prune (rules in the module docstring).

    Parameters
    ----------
    params : dict of Tensor
        ``means [N, 3]``, ``log_scales [N, 3]``, ``quats [N, 4]``, ``opacity_logits [N]``, ``sh [N, K, 3]``.
    object_ids : ndarray, shape [N], optional
    grad_sum : Tensor, shape [N]
        Accumulated view-space gradient norms (NDC units).
    count : Tensor, shape [N]
        Iterations in which each splat was visible.
    grad_threshold : float, keyword-only
        NDC units (reference 0.0002).
    extent : float, keyword-only
        Scene extent in world units (radius of the camera centres, times 1.1, as the reference).
    percent_dense : float, keyword-only
        Clone/split boundary as a fraction of ``extent``.
    min_opacity : float, keyword-only
        Prune below this opacity.
    max_new : int, optional, keyword-only
        Cap on splats added (clones + extra split children); the candidates with the largest
        gradients win.  ``Prune2TargetSize`` uses it so that its loop always shrinks the scene.
    min_splats : int, keyword-only
        Never prune below this count: if the transparent splats outnumber the margin, only the
        most transparent ones go (``Prune2TargetSize`` must not undershoot its target).
    generator : torch.Generator, optional, keyword-only
        Randomness of the split children's positions.

    Returns
    -------
    DensifyResult
    """
    p = {k: v.detach() for k, v in params.items()}
    n = p["means"].shape[0]
    avg = torch.where(count > 0, grad_sum / count.clamp_min(1), torch.zeros_like(grad_sum))
    big = torch.exp(p["log_scales"]).max(dim=1).values > percent_dense * extent
    cand = avg >= grad_threshold
    clone = cand & ~big
    split = cand & big
    if max_new is not None:
        # a clone adds 1 splat, a split adds SPLIT_N - 1; keep the largest gradients first
        idx = torch.nonzero(cand).flatten()
        idx = idx[torch.argsort(-avg[idx], stable=True)]
        cost = torch.where(split[idx], SPLIT_N - 1, 1)
        ok = torch.cumsum(cost, 0) <= max(0, int(max_new))
        keep_cand = torch.zeros(n, dtype=torch.bool)
        keep_cand[idx[ok]] = True
        clone &= keep_cand
        split &= keep_cand
    clone_idx = torch.nonzero(clone).flatten()
    split_idx = torch.nonzero(split).flatten()
    # split children: sample in the splat's frame, scales / 1.6
    rep = split_idx.repeat_interleave(SPLIT_N)
    std = torch.exp(p["log_scales"][rep])
    noise = torch.randn(std.shape, generator=generator, dtype=std.dtype) * std
    child_means = (quat_to_rotmat(p["quats"][rep]) @ noise[..., None])[..., 0] + p["means"][rep]
    child = {k: v[rep].clone() for k, v in p.items()}
    child["means"] = child_means
    child["log_scales"] = child["log_scales"] - float(np.log(SPLIT_SCALE_DIV))
    keep_old = ~split
    old_idx = torch.nonzero(keep_old).flatten()
    source = torch.cat([old_idx, clone_idx, rep])
    is_new = torch.cat([torch.zeros(old_idx.numel(), dtype=torch.bool),
                        torch.ones(clone_idx.numel() + rep.numel(), dtype=torch.bool)])
    new = {k: torch.cat([v[old_idx], v[clone_idx], child[k]]) for k, v in p.items()}
    ids = None if object_ids is None else np.asarray(object_ids)[source.numpy()]
    # prune near-transparent splats (after densification, as the reference)
    alive = torch.sigmoid(new["opacity_logits"]) >= min_opacity
    m = alive.numel()
    if m - int(alive.sum()) > max(0, m - min_splats):
        # too many to drop: keep the min_splats most opaque (stable, so ties keep their order)
        keep = torch.argsort(-new["opacity_logits"], stable=True)[:min(min_splats, m)]
        alive = torch.zeros(m, dtype=torch.bool)
        alive[keep] = True
    pruned = int((~alive).sum())
    new = {k: v[alive].contiguous() for k, v in new.items()}
    if ids is not None:
        ids = ids[alive.numpy()]
    return DensifyResult(params=new, object_ids=ids, source=source[alive], is_new=is_new[alive],
                         cloned=int(clone_idx.numel()), split=int(split_idx.numel()), pruned=pruned)


def reset_opacity(opacity_logits: torch.Tensor, ceiling: float = RESET_OPACITY) -> torch.Tensor:
    """Opacity logits with ``sigmoid(logit) <= ceiling`` (``min(opacity, ceiling)``), shape [N]."""
    cap = float(np.log(ceiling / (1.0 - ceiling)))
    return torch.clamp_max(opacity_logits.detach(), cap)
