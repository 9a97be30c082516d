"""A slow, plainly written per-pixel float64 reference of the renderer (for tests only).

Written from the rules in the issue / reference 3DGS, independently of the fast path: NumPy
float64, one splat at a time for the projection, one pixel at a time and one splat at a time
for the compositing.  Use it on tiny scenes (it costs ``O(pixels x splats)`` Python steps).
"""

from __future__ import annotations

import math

import numpy as np

__all__ = ["_render_reference", "_project_reference"]

_C0 = 0.28209479177387814
_C1 = 0.4886025119029199
_C2 = [1.0925484305920792, -1.0925484305920792, 0.31539156525252005, -1.0925484305920792,
       0.5462742152960396]
_C3 = [-0.5900435899266435, 2.890611442640554, -0.4570457994644658, 0.3731763325901154,
       -0.4570457994644658, 1.445305721320277, -0.5900435899266435]


def _sh_color(sh: np.ndarray, d: np.ndarray) -> np.ndarray:
    """RGB of one splat: sh [K, 3], d unit direction [3]."""
    k = sh.shape[0]
    x, y, z = d
    basis = [_C0]
    if k > 1:
        basis += [-_C1 * y, _C1 * z, -_C1 * x]
    if k > 4:
        basis += [_C2[0] * x * y, _C2[1] * y * z, _C2[2] * (2 * z * z - x * x - y * y),
                  _C2[3] * x * z, _C2[4] * (x * x - y * y)]
    if k > 9:
        basis += [_C3[0] * y * (3 * x * x - y * y), _C3[1] * x * y * z,
                  _C3[2] * y * (4 * z * z - x * x - y * y),
                  _C3[3] * z * (2 * z * z - 3 * x * x - 3 * y * y),
                  _C3[4] * x * (4 * z * z - x * x - y * y), _C3[5] * z * (x * x - y * y),
                  _C3[6] * x * (x * x - 3 * y * y)]
    rgb = np.zeros(3)
    for i, b in enumerate(basis):
        rgb += b * sh[i]
    return np.maximum(rgb + 0.5, 0.0)


def _project_reference(means, log_scales, quats, camera, near=0.01):
    """Per-splat projection; returns a list of dicts (or None for a culled splat)."""
    means, log_scales, quats = (np.asarray(a, np.float64) for a in (means, log_scales, quats))
    w2c = np.asarray(camera.world_to_camera, np.float64)
    R, T = w2c[:3, :3], w2c[:3, 3]
    center = -R.T @ T
    tanx = camera.width / (2.0 * camera.fx)
    tany = camera.height / (2.0 * camera.fy)
    tiles_x = math.ceil(camera.width / 16)
    tiles_y = math.ceil(camera.height / 16)
    out = []
    for i in range(len(means)):
        mu = means[i]
        t = R @ mu + T
        if t[2] < near:
            out.append(None)
            continue
        w, x, y, z = quats[i] / np.linalg.norm(quats[i])
        Rq = np.array([[1 - 2 * (y * y + z * z), 2 * (x * y - w * z), 2 * (x * z + w * y)],
                       [2 * (x * y + w * z), 1 - 2 * (x * x + z * z), 2 * (y * z - w * x)],
                       [2 * (x * z - w * y), 2 * (y * z + w * x), 1 - 2 * (x * x + y * y)]])
        S = np.diag(np.exp(log_scales[i]))
        Sigma = Rq @ S @ S.T @ Rq.T
        tx = min(1.3 * tanx, max(-1.3 * tanx, t[0] / t[2])) * t[2]
        ty = min(1.3 * tany, max(-1.3 * tany, t[1] / t[2])) * t[2]
        J = np.array([[camera.fx / t[2], 0.0, -camera.fx * tx / t[2] ** 2],
                      [0.0, camera.fy / t[2], -camera.fy * ty / t[2] ** 2]])
        cov = J @ R @ Sigma @ R.T @ J.T + 0.3 * np.eye(2)
        det = cov[0, 0] * cov[1, 1] - cov[0, 1] ** 2
        if det <= 0:
            out.append(None)
            continue
        mid = 0.5 * (cov[0, 0] + cov[1, 1])
        lam1 = mid + math.sqrt(max(0.1, mid * mid - det))
        radius = math.ceil(3.0 * math.sqrt(lam1))
        mx = camera.fx * t[0] / t[2] + camera.cx
        my = camera.fy * t[1] / t[2] + camera.cy
        # the reference's getRect, in pixel-centre coordinates (mean - 0.5)
        rx0 = min(tiles_x, max(0, math.floor((mx - 0.5 - radius) / 16)))
        rx1 = min(tiles_x, max(0, math.floor((mx - 0.5 + radius + 15) / 16)))
        ry0 = min(tiles_y, max(0, math.floor((my - 0.5 - radius) / 16)))
        ry1 = min(tiles_y, max(0, math.floor((my - 0.5 + radius + 15) / 16)))
        if radius <= 0 or (rx1 - rx0) * (ry1 - ry0) == 0:
            out.append(None)
            continue
        d = mu - center
        d = d / np.linalg.norm(d)
        out.append({"mean": (mx, my), "conic": np.linalg.inv(cov), "depth": t[2],
                    "rect": (rx0, rx1, ry0, ry1), "cov": cov, "radius": radius, "dir": d})
    return out


def _render_reference(means, log_scales, quats, opacity_logits, sh, camera, background=None):
    """Render in float64, pixel by pixel.

    Parameters
    ----------
    means [N, 3], log_scales [N, 3], quats [N, 4], opacity_logits [N], sh [N, K, 3] : array_like
    camera : l3gs_opt.scene.cameras.Camera
    background : array_like, shape [3], optional (default ``camera.background``)

    Returns
    -------
    dict
        ``image`` [H, W, 3], ``alpha`` [H, W], ``depth`` [H, W], ``weights`` [N], float64.
    """
    means = np.asarray(means, np.float64)
    sh = np.asarray(sh, np.float64)
    n = len(means)
    bg = np.asarray(camera.background if background is None else background, np.float64)
    proj = _project_reference(means, log_scales, quats, camera)
    opac = 1.0 / (1.0 + np.exp(-np.asarray(opacity_logits, np.float64)))
    colors = [None if p is None else _sh_color(sh[i], p["dir"]) for i, p in enumerate(proj)]
    order = sorted([i for i in range(n) if proj[i] is not None], key=lambda i: (proj[i]["depth"], i))
    H, W = camera.height, camera.width
    image = np.zeros((H, W, 3))
    alpha_img = np.zeros((H, W))
    depth_img = np.zeros((H, W))
    weights = np.zeros(n)
    for py in range(H):
        for px in range(W):
            tile_x, tile_y = px // 16, py // 16
            T = 1.0
            C = np.zeros(3)
            D = 0.0
            for i in order:
                p = proj[i]
                rx0, rx1, ry0, ry1 = p["rect"]
                if not (rx0 <= tile_x < rx1 and ry0 <= tile_y < ry1):
                    continue
                d = np.array([p["mean"][0] - (px + 0.5), p["mean"][1] - (py + 0.5)])
                power = -0.5 * d @ p["conic"] @ d
                if power > 0:
                    continue
                alpha = min(0.99, opac[i] * math.exp(power))
                if alpha < 1.0 / 255.0:
                    continue
                test_T = T * (1.0 - alpha)
                if test_T < 1e-4:
                    break
                C += alpha * T * colors[i]
                D += alpha * T * p["depth"]
                weights[i] += alpha * T
                T = test_T
            image[py, px] = C + T * bg
            alpha_img[py, px] = 1.0 - T
            depth_img[py, px] = D
    return {"image": image, "alpha": alpha_img, "depth": depth_img, "weights": weights}
