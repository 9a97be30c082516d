"""Image metrics: PSNR and SSIM through scikit-image, on RGB images in [0, 1].

Settings (fixed, so numbers are comparable across runs and with the 3DGS literature):

* ``psnr``: ``10 log10(data_range^2 / MSE)`` over all pixels and channels,
  ``data_range = 1.0`` (``skimage.metrics.peak_signal_noise_ratio``); ``inf`` for equal images.
* ``ssim``: ``skimage.metrics.structural_similarity`` with ``data_range=1.0``,
  ``channel_axis=-1`` (mean over channels), ``gaussian_weights=True``, ``sigma=1.5``,
  ``use_sample_covariance=False`` and the default ``K1 = 0.01``, ``K2 = 0.03`` — the settings of
  Wang et al. (2004) that the 3DGS papers' SSIM uses (an 11 x 11 Gaussian window, truncated at
  3.5 sigma).  The mean SSIM over the valid area (borders of half a window are excluded).

LPIPS is **not** provided: it needs pretrained network weights (AlexNet/VGG) that cannot be
downloaded in this environment.
"""

from __future__ import annotations

import numpy as np

__all__ = ["psnr", "ssim", "SSIM_SETTINGS", "MetricError"]

from l3gs_opt.errors import L3gsError

#: Keyword arguments passed to ``skimage.metrics.structural_similarity`` (besides ``data_range``).
SSIM_SETTINGS = {"channel_axis": -1, "gaussian_weights": True, "sigma": 1.5,
                 "use_sample_covariance": False}
#: Smallest image edge SSIM accepts (the 11 x 11 Gaussian window).
SSIM_MIN_SIZE = 11
#: How far outside [0, 1] an input may stray (float32 rounding of a composited image).
RANGE_TOL = 1e-6


class MetricError(L3gsError, ValueError):
    """Images given to a metric are malformed (shape, range, non-finite)."""


def _as_image(name: str, img, min_size: int = 1) -> np.ndarray:
    try:
        import torch
        if isinstance(img, torch.Tensor):
            img = img.detach().cpu().numpy()
    except ImportError:  # pragma: no cover
        pass
    a = np.asarray(img, dtype=np.float64)
    if a.ndim != 3 or a.shape[2] != 3 or a.shape[0] < min_size or a.shape[1] < min_size:
        raise MetricError(f"{name}: shape {a.shape} must be [H, W, 3] with H, W >= {min_size}")
    if not np.all(np.isfinite(a)):
        idx = tuple(int(i) for i in np.argwhere(~np.isfinite(a))[0])
        raise MetricError(f"{name}{list(idx)}: {a[idx]} is not finite")
    lo, hi = a.min(), a.max()
    if lo < -RANGE_TOL or hi > 1 + RANGE_TOL:
        raise MetricError(f"{name}: values in [{lo:.4g}, {hi:.4g}] must be in [0, 1] (clip the render first)")
    return np.clip(a, 0.0, 1.0)


def _pair(image, reference, min_size=1):
    a, b = _as_image("image", image, min_size), _as_image("reference", reference, min_size)
    if a.shape != b.shape:
        raise MetricError(f"image: shape {a.shape} differs from reference shape {b.shape}")
    return a, b


def psnr(image, reference) -> float:
    """Peak signal-to-noise ratio in dB (``data_range = 1``; ``inf`` when equal).

    Parameters
    ----------
    image, reference : array_like or Tensor, shape [H, W, 3]
        RGB in [0, 1].

    Returns
    -------
    float

    Raises
    ------
    MetricError
        On a shape mismatch, non-finite values or values outside [0, 1].
    """
    from skimage.metrics import peak_signal_noise_ratio

    a, b = _pair(image, reference)
    if np.array_equal(a, b):
        return float("inf")
    return float(peak_signal_noise_ratio(b, a, data_range=1.0))


def ssim(image, reference) -> float:
    """Mean structural similarity (settings in the module docstring; 1.0 when equal).

    Parameters
    ----------
    image, reference : array_like or Tensor, shape [H, W, 3]
        RGB in [0, 1] (H, W >= 11, the Gaussian window).

    Returns
    -------
    float
        In [-1, 1].

    Raises
    ------
    MetricError
        On a shape mismatch, non-finite values or values outside [0, 1].
    """
    from skimage.metrics import structural_similarity

    a, b = _pair(image, reference, SSIM_MIN_SIZE)
    return float(structural_similarity(b, a, data_range=1.0, **SSIM_SETTINGS))
