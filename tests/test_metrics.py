"""PSNR / SSIM: identities, range checks, and SSIM against an independent Gaussian-window SSIM."""

from __future__ import annotations

import numpy as np
import pytest
import torch
from scipy.ndimage import gaussian_filter

from l3gs_opt.errors import L3gsError
from l3gs_opt.renderer import MetricError, psnr, ssim


def _ssim_wang(x, y, sigma=1.5, truncate=3.5, k1=0.01, k2=0.03):
    """Wang et al. (2004) SSIM with a Gaussian window, per channel, mean over the valid area."""
    c1, c2 = (k1 * 1.0) ** 2, (k2 * 1.0) ** 2
    pad = int(truncate * sigma + 0.5)
    vals = []
    for c in range(x.shape[2]):
        a, b = x[..., c], y[..., c]
        f = lambda im: gaussian_filter(im, sigma, truncate=truncate)  # noqa: E731
        ma, mb = f(a), f(b)
        va, vb, cov = f(a * a) - ma ** 2, f(b * b) - mb ** 2, f(a * b) - ma * mb
        s = ((2 * ma * mb + c1) * (2 * cov + c2)) / ((ma ** 2 + mb ** 2 + c1) * (va + vb + c2))
        vals.append(s[pad:-pad, pad:-pad].mean())
    return float(np.mean(vals))


def _pair(seed=0, noise=0.05):
    rng = np.random.default_rng(seed)
    a = gaussian_filter(rng.uniform(0, 1, (40, 50, 3)), (2, 2, 0))
    b = np.clip(a + rng.normal(0, noise, a.shape), 0, 1)
    return a, b


def test_identities():
    a, _ = _pair()
    assert psnr(a, a) == float("inf")
    assert ssim(a, a) == pytest.approx(1.0, abs=1e-12)


def test_psnr_formula():
    a, b = _pair()
    assert psnr(a, b) == pytest.approx(10 * np.log10(1.0 / np.mean((a - b) ** 2)), rel=1e-12)


def test_ssim_matches_independent_gaussian_ssim():
    # skimage filters with the same Gaussian (scipy.ndimage) and crops the same border: equal to
    # rounding; 1e-6 allows for its float32/float64 handling differences.
    a, b = _pair(1, 0.1)
    assert ssim(b, a) == pytest.approx(_ssim_wang(b, a), abs=1e-6)
    assert 0.1 < ssim(b, a) < 0.95  # a non-trivial value


def test_more_noise_is_worse_and_tensors_are_accepted():
    a, b1 = _pair(2, 0.02)
    _, b2 = _pair(2, 0.2)
    assert ssim(b1, a) > ssim(b2, a) and psnr(b1, a) > psnr(b2, a)
    assert ssim(torch.tensor(b1), torch.tensor(a)) == pytest.approx(ssim(b1, a))


@pytest.mark.parametrize("bad,match", [
    (np.full((40, 50, 3), 1.5), r"image: values in \[1.5, 1.5\] must be in \[0, 1\]"),
    (np.zeros((40, 50)), r"image: shape \(40, 50\)"),
    (np.zeros((40, 51, 3)), r"image: shape \(40, 51, 3\) differs"),
    (np.full((40, 50, 3), np.nan), r"image\[0, 0, 0\]: nan is not finite"),
])
def test_bad_input(bad, match):
    a, _ = _pair()
    for fn in (psnr, ssim):
        with pytest.raises(MetricError, match=match) as info:
            fn(bad, a)
        assert isinstance(info.value, L3gsError)
    with pytest.raises(MetricError, match=">= 11"):
        ssim(np.zeros((8, 8, 3)), np.zeros((8, 8, 3)))
