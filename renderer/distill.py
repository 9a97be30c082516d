"""Compact-SH distillation: fit a lower SH degree to a splat's full view-dependent colour.

For each splat ``j`` and the unit view directions ``d_v`` from the training cameras' centres
to its mean, the compact coefficients ``c_j`` (degree ``k``) minimise

    sum_v || B_k(d_v) c_j - S_j(d_v) ||^2 + ridge * || c_j[1:] ||^2

where ``S_j(d) = eval_sh(D, sh_j, d)`` is the full expansion (before the +0.5 offset and the
clamp) and ``B_k`` the real SH basis up to degree ``k``.  For ``k = 0`` this is the mean colour
over the views.  The small ridge on the non-DC terms keeps the fit stable when a splat is seen
from few directions.  Closed form, no rendering: geometry and opacity are left untouched, so
the compact and full forms of a splat differ only in their SH bytes.
"""

from __future__ import annotations

from typing import Sequence

import numpy as np
import torch

from .sh import eval_sh, sh_basis

__all__ = ["DISTILL_RIDGE", "distill_sh"]

#: Ridge weight on the non-DC compact coefficients (colour units^2 per coefficient).
DISTILL_RIDGE = 1e-3


def distill_sh(means, sh, cameras: Sequence, degree: int, *, ridge: float = DISTILL_RIDGE) -> np.ndarray:
    """Compact SH coefficients of degree ``degree`` fitted to the full ``sh`` over the cameras' views.

    Parameters
    ----------
    means : array_like, shape [N, 3]
        World positions.
    sh : array_like, shape [N, K, 3]
        Full coefficients (degree ``D`` with ``K = (D + 1)^2``), ``degree < D``.
    cameras : sequence of Camera
        Training cameras (their centres give the view directions).
    degree : int
        Compact degree, ``0 <= degree < D``.
    ridge : float, keyword-only

    Returns
    -------
    ndarray, shape [N, (degree + 1)^2, 3], float32
    """
    m = torch.tensor(np.asarray(means), dtype=torch.float64)
    full = torch.tensor(np.asarray(sh), dtype=torch.float64)
    d_full = {1: 0, 4: 1, 9: 2, 16: 3}[full.shape[1]]
    if not 0 <= degree < d_full:
        raise ValueError(f"degree: {degree} must be in [0, {d_full}) (below the full SH degree)")
    if len(cameras) == 0:
        raise ValueError("cameras: at least one camera is needed")
    centers = torch.tensor(np.array([c.center for c in cameras]), dtype=torch.float64)  # [V, 3]
    dirs = m[None] - centers[:, None]  # [V, N, 3]
    dirs = dirs / torch.linalg.vector_norm(dirs, dim=-1, keepdim=True).clamp_min(1e-12)
    target = eval_sh(d_full, full[None].expand(len(cameras), -1, -1, -1), dirs)  # [V, N, 3]
    basis = sh_basis(degree, dirs).permute(1, 0, 2)  # [N, V, k]
    k = basis.shape[-1]
    gram = basis.transpose(1, 2) @ basis  # [N, k, k]
    reg = torch.full((k,), float(ridge), dtype=torch.float64)
    reg[0] = 0.0
    gram = gram + torch.diag(reg)
    rhs = basis.transpose(1, 2) @ target.permute(1, 0, 2)  # [N, k, 3]
    coef = torch.linalg.solve(gram, rhs)
    return coef.to(torch.float32).numpy()
