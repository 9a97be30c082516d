"""antimatter15 ``.splat`` files: 32 bytes a splat, SH degree 0, no header.

The layout is the one of antimatter15/splat (``convert.py`` writes it, ``main.js`` reads it) and
of the viewers that adopted it. Each splat is one little-endian record:

======  ======  ==========================================================================
bytes   type    content
======  ======  ==========================================================================
0-11    f32 x3  position ``x y z`` (world units)
12-23   f32 x3  scale ``exp(log_scale)``: the standard deviations, linear (not log)
24-27   u8 x4   colour ``r g b`` = ``255 (0.5 + SH_C0 f_dc)``, alpha = ``255 sigmoid(opacity)``
28-31   u8 x4   rotation ``(w, x, y, z) / |q| * 128 + 128`` (PLY order ``rot_0..rot_3``)
======  ======  ==========================================================================

What is kept and what is lost
-----------------------------
* Only the SH DC term: higher bands are dropped on write (the format has no place for them, so
  writing a degree-3 scene is a documented loss, not an error) and the reader returns degree 0.
* Object ids, layers and normals are not carried: dropped on write (the PLY keeps them).
* Colour and alpha are 8-bit: rounded to the nearest step here (antimatter15's ``convert.py``
  truncates; every reader divides by 255 either way), so a colour ``0.5 + SH_C0 f_dc`` inside
  [0, 1] comes back within ``0.5 / 255`` and values outside [0, 1] are clipped.
* Rotations are 8-bit per component: decoded as ``(byte - 128) / 128`` as antimatter15's viewer
  does (not normalised here; the renderer normalises).
* Splats keep the input order (``convert.py`` sorts by size x opacity for progressive loading;
  viewers sort by depth anyway, so the order carries no meaning).

Alpha bytes 0 and 255 would be logits of -inf and +inf: the reader clamps the alpha to
``[ALPHA_EPS, 1 - ALPHA_EPS]`` first, as PlayCanvas splat-transform's ``.splat`` reader does.

This module also holds the constants the other compressed formats share (:data:`SH_C0`,
:data:`ALPHA_EPS`, :func:`alpha_to_logit`).
"""

from __future__ import annotations

from pathlib import Path

import numpy as np

from l3gs_opt.input_files import MAX_BINARY_BYTES, read_bytes
from l3gs_opt.scene.splats import SceneError, SplatScene

__all__ = ["SH_C0", "ALPHA_EPS", "SPLAT_RECORD_BYTES", "alpha_to_logit", "sigmoid", "write_splat",
           "read_splat"]

#: The zeroth real SH basis function ``1 / (2 sqrt(pi))``: colour = ``0.5 + SH_C0 * f_dc``.
SH_C0 = 0.28209479177387814
#: Alphas are clamped to ``[ALPHA_EPS, 1 - ALPHA_EPS]`` before the logit, so that an 8-bit alpha of 0
#: or 255 reads as a finite logit (about -13.8 / +13.8) instead of an infinity the scene refuses.
ALPHA_EPS = 1e-6
#: Bytes per splat of a ``.splat`` file.
SPLAT_RECORD_BYTES = 32

_RECORD = np.dtype([("position", "<f4", (3,)), ("scale", "<f4", (3,)), ("rgba", "u1", (4,)),
                    ("rotation", "u1", (4,))])


def sigmoid(x: np.ndarray) -> np.ndarray:
    """``1 / (1 + exp(-x))`` in float64, without overflow warnings for large ``|x|``."""
    x = np.asarray(x, np.float64)
    e = np.exp(-np.abs(x))
    return np.where(x >= 0, 1.0 / (1.0 + e), e / (1.0 + e))


def alpha_to_logit(alpha: np.ndarray) -> np.ndarray:
    """The opacity logit of ``alpha`` clamped to ``[ALPHA_EPS, 1 - ALPHA_EPS]`` (float64)."""
    a = np.clip(np.asarray(alpha, np.float64), ALPHA_EPS, 1.0 - ALPHA_EPS)
    return np.log(a / (1.0 - a))


def unorm8(x: np.ndarray) -> np.ndarray:
    """``x`` in [0, 1] as a byte ``round(255 x)``, clipped (round half up)."""
    return np.clip(np.floor(np.asarray(x, np.float64) * 255.0 + 0.5), 0, 255).astype(np.uint8)


def write_splat(scene: SplatScene, path) -> Path:
    """Write ``scene`` as an antimatter15 ``.splat`` file (32 bytes a splat, input order kept).

    Higher SH bands, object ids, layers and normals are dropped (see the module docstring).

    Parameters
    ----------
    scene : SplatScene
    path : str or Path
        Destination; parent folders are created.

    Returns
    -------
    Path
        The path written.

    Raises
    ------
    SceneError
        If a scale ``exp(log_scale)`` overflows float32 (``log_scales`` above ~88.7).
    """
    path = Path(path)
    n = scene.num_splats
    scale = np.exp(scene.log_scales.astype(np.float64))
    big = scale > np.finfo(np.float32).max
    if big.any():
        i, j = np.argwhere(big)[0]
        raise SceneError("log_scales", f"{scene.log_scales[i, j]}: exp() overflows the float32 scale of a "
                                       f".splat file", (i, j))
    rec = np.zeros(n, _RECORD)
    rec["position"] = scene.means
    rec["scale"] = scale.astype(np.float32)
    rec["rgba"][:, :3] = unorm8(0.5 + SH_C0 * scene.sh[:, 0, :].astype(np.float64))
    rec["rgba"][:, 3] = unorm8(sigmoid(scene.opacity_logits))
    q = scene.quats.astype(np.float64)
    q = q / np.linalg.norm(q, axis=1, keepdims=True)
    rec["rotation"] = np.clip(np.floor(q * 128.0 + 128.0 + 0.5), 0, 255).astype(np.uint8)
    path.parent.mkdir(parents=True, exist_ok=True)
    path.write_bytes(rec.tobytes())
    return path


def read_splat(path) -> SplatScene:
    """Read an antimatter15 ``.splat`` file into a :class:`SplatScene` (SH degree 0).

    Decoding: ``log_scales = log(scale)``, ``f_dc = (byte / 255 - 0.5) / SH_C0``,
    ``opacity_logit = logit(clamp(alpha / 255))``, ``quat = (byte - 128) / 128``.

    Parameters
    ----------
    path : str or Path

    Returns
    -------
    SplatScene
        Degree 0, no object ids, layers or normals, splats in file order.

    Raises
    ------
    SceneError
        ``file`` when the file is missing, not a regular file, too large or not a whole number
        of 32-byte records; ``x``/``y``/``z`` or ``scale_0..2`` with the splat index for a
        non-finite position or a scale that is not finite and > 0; ``rotation`` for a record
        whose four rotation bytes are all 128 (a zero quaternion).
    """
    data = read_bytes(path, lambda f, m: SceneError(f, m), max_bytes=MAX_BINARY_BYTES)
    if len(data) % SPLAT_RECORD_BYTES:
        raise SceneError("file", f"{path}: {len(data):,} bytes is not a whole number of {SPLAT_RECORD_BYTES}-byte "
                                 f"splat records (truncated or not a .splat file)")
    rec = np.frombuffer(data, _RECORD)
    pos, scale = rec["position"], rec["scale"]
    for j, name in enumerate("xyz"):
        bad = ~np.isfinite(pos[:, j])
        if bad.any():
            i = int(np.argmax(bad))
            raise SceneError(name, f"{path}: {pos[i, j]} is not finite", (i,))
    for j in range(3):
        bad = ~(np.isfinite(scale[:, j]) & (scale[:, j] > 0))
        if bad.any():
            i = int(np.argmax(bad))
            raise SceneError(f"scale_{j}", f"{path}: {scale[i, j]} must be finite and > 0 (a linear scale)", (i,))
    rot = (rec["rotation"].astype(np.float32) - 128.0) / 128.0
    zero = ~rot.any(axis=1)
    if zero.any():
        raise SceneError("rotation", f"{path}: all four bytes are 128 (a zero quaternion)", (int(np.argmax(zero)),))
    rgba = rec["rgba"].astype(np.float64) / 255.0
    return SplatScene(means=pos, log_scales=np.log(scale.astype(np.float64)), quats=rot,
                      opacity_logits=alpha_to_logit(rgba[:, 3]),
                      sh=((rgba[:, :3] - 0.5) / SH_C0)[:, None, :])
