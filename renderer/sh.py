"""Real spherical harmonics of degree 0-3, as used by 3DGS (and Plenoxels / the reference code).

The colour of a splat seen along the unit direction ``d = (x, y, z)`` (camera centre to splat
mean, world frame) is ``max(0, sum_k c_k Y_k(d) + 0.5)`` per channel, with the constants below
and the sign convention of the reference implementation's ``eval_sh`` (``utils/sh_utils.py``).
"""

from __future__ import annotations

import torch

__all__ = ["SH_C0", "SH_C1", "SH_C2", "SH_C3", "eval_sh", "sh_basis", "sh_to_color"]

SH_C0 = 0.28209479177387814
SH_C1 = 0.4886025119029199
SH_C2 = (1.0925484305920792, -1.0925484305920792, 0.31539156525252005,
         -1.0925484305920792, 0.5462742152960396)
SH_C3 = (-0.5900435899266435, 2.890611442640554, -0.4570457994644658, 0.3731763325901154,
         -0.4570457994644658, 1.445305721320277, -0.5900435899266435)


def eval_sh(degree: int, sh: torch.Tensor, dirs: torch.Tensor) -> torch.Tensor:
    """Evaluate the SH expansion (without the +0.5 offset).

    Parameters
    ----------
    degree : int
        0..3; only the first ``(degree + 1) ** 2`` coefficients are used.
    sh : Tensor, shape [..., K, 3]
        Coefficients, ``K >= (degree + 1) ** 2``.
    dirs : Tensor, shape [..., 3]
        Unit view directions.

    Returns
    -------
    Tensor, shape [..., 3]
    """
    if degree not in (0, 1, 2, 3):
        raise ValueError(f"degree: {degree} must be 0, 1, 2 or 3")
    if sh.shape[-2] < (degree + 1) ** 2:
        raise ValueError(f"sh: {sh.shape[-2]} coefficients cannot hold degree {degree}")
    k = (degree + 1) ** 2
    basis = sh_basis(degree, dirs)  # [..., K]
    return torch.einsum("...k,...kc->...c", basis, sh[..., :k, :])


def sh_basis(degree: int, dirs: torch.Tensor) -> torch.Tensor:
    """The real SH basis values (reference 3DGS signs and order) of unit directions.

    Parameters
    ----------
    degree : int
        0..3.
    dirs : Tensor, shape [..., 3]

    Returns
    -------
    Tensor, shape [..., (degree + 1) ** 2]
    """
    x, y, z = dirs[..., 0], dirs[..., 1], dirs[..., 2]
    out = [torch.full_like(x, SH_C0)]
    if degree >= 1:
        out += [-SH_C1 * y, SH_C1 * z, -SH_C1 * x]
    if degree >= 2:
        xx, yy, zz, xy, yz, xz = x * x, y * y, z * z, x * y, y * z, x * z
        out += [SH_C2[0] * xy, SH_C2[1] * yz, SH_C2[2] * (2.0 * zz - xx - yy), SH_C2[3] * xz,
                SH_C2[4] * (xx - yy)]
    if degree >= 3:
        out += [SH_C3[0] * y * (3.0 * xx - yy), SH_C3[1] * xy * z, SH_C3[2] * y * (4.0 * zz - xx - yy),
                SH_C3[3] * z * (2.0 * zz - 3.0 * xx - 3.0 * yy), SH_C3[4] * x * (4.0 * zz - xx - yy),
                SH_C3[5] * z * (xx - yy), SH_C3[6] * x * (xx - 3.0 * yy)]
    return torch.stack(out, dim=-1)


def sh_to_color(sh: torch.Tensor, means: torch.Tensor, camera_center: torch.Tensor,
                degree: int | None = None) -> torch.Tensor:
    """View-dependent RGB of each splat: ``clamp_min(eval_sh(d) + 0.5, 0)``.

    Parameters
    ----------
    sh : Tensor, shape [N, K, 3]
    means : Tensor, shape [N, 3]
        World positions.
    camera_center : Tensor, shape [3]
        Camera centre in world coordinates.
    degree : int, optional
        Defaults to the degree of ``K``.

    Returns
    -------
    Tensor, shape [N, 3]
        Not clamped from above (as in the reference rasteriser).
    """
    if degree is None:
        degree = {1: 0, 4: 1, 9: 2, 16: 3}[sh.shape[-2]]
    if degree == 0:
        return torch.clamp_min(SH_C0 * sh[..., 0, :] + 0.5, 0.0)
    d = means - camera_center
    # (clamped so that a splat at the camera centre, culled anyway, cannot give NaN gradients)
    d = d / torch.linalg.vector_norm(d, dim=-1, keepdim=True).clamp_min(1e-12)
    return torch.clamp_min(eval_sh(degree, sh, d) + 0.5, 0.0)
