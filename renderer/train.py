"""The CPU training loop (standard 3DGS recipe): ``Recovery`` (with densification) and ``Finetune``.

Per iteration: one training view (a random permutation per epoch), render with the current
active SH degree, loss ``(1 - lambda) * L1 + lambda * (1 - SSIM)`` with ``lambda = 0.2``
(:data:`LAMBDA_SSIM`; SSIM with the 11 x 11 Gaussian window of sigma 1.5, as the reference
``ssim`` in ``utils/loss_utils.py``), one Adam step (``eps = 1e-15``) with the reference
per-group learning rates:

==================  ==================================================================
group               learning rate
==================  ==================================================================
means               ``1.6e-4 * extent`` decaying log-linearly to ``1.6e-6 * extent``
SH degree 0 (DC)    ``2.5e-3``
SH degrees 1-3      ``2.5e-3 / 20``
opacity logits      ``0.05``
log-scales          ``5e-3``
quaternions         ``1e-3``
==================  ==================================================================

``extent`` is 1.1 x the largest distance of a camera centre from their mean (reference
``getNerfppNorm``).  The active SH degree starts at ``sh_degree_start`` and rises by one every
``sh_up_every`` iterations up to the scene's degree.  Training images are given as
:class:`View` (a camera and its target image, e.g. a teacher render: :func:`teacher_views`).

The first ``frozen`` splats can be held fixed: they are kept in tensors without gradient that
are never written, so they come out bit-identical (ProgressiveTraining's lower layers).
"""

from __future__ import annotations

import contextlib
import dataclasses
import math
from typing import Callable, NamedTuple, Optional, Sequence

import numpy as np
import torch
import torch.nn.functional as F

from .densify import densify_and_prune, reset_opacity, view_space_grad
from .render import render_gaussians, scene_tensors

__all__ = ["LAMBDA_SSIM", "TrainConfig", "View", "TrainResult", "train", "recovery", "finetune",
           "teacher_views", "scene_extent", "threads", "TRAIN_THREADS", "ssim_torch", "training_loss", "scene_from_params"]

#: Intra-op threads used while training.  The tensors are small (thousands of splats, images of
#: ~10^4 pixels), and on a shared 2-core machine waking a second thread (torch's and numba's OpenMP
#: pools spin-wait) costs far more than the work: measured 0.07 s per iteration with 1 thread
#: against 1.1 s with 2 (5k splats, 128 x 96, load average 4.5).
TRAIN_THREADS = 1
#: Weight of the D-SSIM term in the loss (reference 3DGS).
LAMBDA_SSIM = 0.2
_PARAM_KEYS = ("means", "log_scales", "quats", "opacity_logits", "sh")


@dataclasses.dataclass(frozen=True)
class TrainConfig:
    """Schedule and hyper-parameters of one training run (defaults: reference 3DGS, see module doc).

    Attributes
    ----------
    iterations : int
        Optimiser steps (one view each).
    lr_means, lr_means_final : float
        Mean learning rate at the start / end, times the scene extent (world units per step).
    lr_sh_dc, lr_sh_rest, lr_opacity, lr_scales, lr_quats : float
        Per-group Adam learning rates.
    lambda_ssim : float
        Weight of ``1 - SSIM`` in the loss.
    sh_degree_start : int or None
        Active SH degree at iteration 0 (None: the scene's degree from the start, as for a
        warm start from a trained scene).
    sh_up_every : int
        Iterations between SH degree increases.
    densify_from, densify_until, densify_every : int
        Densification runs at iterations ``densify_from < it <= densify_until`` that are
        multiples of ``densify_every`` (Recovery only).
    opacity_reset_every : int
        Opacity reset period (0 = never); only within the densification window.
    grad_threshold : float
        View-space gradient threshold (NDC units).
    percent_dense : float
        Clone/split boundary as a fraction of the extent.
    min_opacity : float
        Prune threshold.
    seed : int
        Seed of the view order and of split sampling.
    """

    iterations: int = 1000
    lr_means: float = 1.6e-4
    lr_means_final: float = 1.6e-6
    lr_sh_dc: float = 2.5e-3
    lr_sh_rest: float = 2.5e-3 / 20.0
    lr_opacity: float = 0.05
    lr_scales: float = 5e-3
    lr_quats: float = 1e-3
    lambda_ssim: float = LAMBDA_SSIM
    sh_degree_start: Optional[int] = None
    sh_up_every: int = 1000
    densify_from: int = 100
    densify_until: int = 15000
    densify_every: int = 100
    opacity_reset_every: int = 3000
    grad_threshold: float = 2e-4
    percent_dense: float = 0.01
    min_opacity: float = 0.005
    seed: int = 0

    def __post_init__(self) -> None:
        for f in dataclasses.fields(self):
            v = getattr(self, f.name)
            if f.name == "sh_degree_start":
                if v is not None and v not in (0, 1, 2, 3):
                    raise ValueError(f"sh_degree_start: {v!r} must be None or 0..3")
                continue
            if isinstance(v, bool) or not isinstance(v, (int, float)) or not math.isfinite(v) or v < 0:
                raise ValueError(f"{f.name}: {v!r} must be a finite number >= 0")
        if self.sh_up_every < 1 or self.densify_every < 1:
            raise ValueError("sh_up_every and densify_every: must be >= 1")

    def replace(self, **changes) -> "TrainConfig":
        """A copy with ``changes`` applied."""
        return dataclasses.replace(self, **changes)


class View(NamedTuple):
    """A training view: a camera and its target image ``[H, W, 3]`` (float32 tensor in [0, 1])."""

    camera: object
    image: torch.Tensor


class TrainResult(NamedTuple):
    """Output of :func:`train`.

    Attributes
    ----------
    scene : SplatScene
        The trained splats (frozen ones first, unchanged), with object ids carried along.
    losses : ndarray, shape [iterations], float64
        Loss of each iteration.
    densify_log : list of dict
        One entry per densification step: ``iteration, cloned, split, pruned, splats``.
    """

    scene: object
    losses: np.ndarray
    densify_log: list


def teacher_views(teacher, cameras: Sequence) -> list[View]:
    """Render ``teacher`` (a SplatScene) from every camera, clamped to [0, 1], as training views."""
    from .render import render_scene

    return [View(cam, render_scene(teacher, cam).image.clamp(0.0, 1.0).contiguous()) for cam in cameras]


def scene_extent(cameras: Sequence) -> float:
    """1.1 x the largest distance of a camera centre from their mean (world units), at least 1e-6.

    A single camera gets extent 1 (the reference uses the same radius formula; with one camera
    it is 0, which would freeze the means).
    """
    c = np.array([cam.center for cam in cameras], dtype=np.float64)
    if len(c) < 2:
        return 1.0
    return max(1.1 * float(np.linalg.norm(c - c.mean(0), axis=1).max()), 1e-6)


@contextlib.contextmanager
def threads(n: Optional[int] = TRAIN_THREADS):
    """Run the block with ``n`` torch and numba threads (``None``: leave as is); restores both."""
    if n is None:
        yield
        return
    from . import _kernels

    old_t = torch.get_num_threads()
    old_n = _kernels.numba.get_num_threads() if _kernels.HAVE_NUMBA else None
    torch.set_num_threads(n)
    if old_n is not None:
        _kernels.numba.set_num_threads(min(n, _kernels.numba.config.NUMBA_NUM_THREADS))
    try:
        yield
    finally:
        torch.set_num_threads(old_t)
        if old_n is not None:
            _kernels.numba.set_num_threads(old_n)


def _gauss_window(size: int = 11, sigma: float = 1.5, dtype=torch.float32) -> torch.Tensor:
    x = torch.arange(size, dtype=torch.float64) - (size - 1) / 2.0
    g = torch.exp(-x * x / (2.0 * sigma * sigma))
    return (g / g.sum()).to(dtype)


def ssim_torch(image: torch.Tensor, reference: torch.Tensor) -> torch.Tensor:
    """Differentiable mean SSIM of two ``[H, W, 3]`` images in [0, 1] (a 0-dim tensor).

    Same settings as :func:`l3gs_opt.renderer.metrics.ssim` (11 x 11 Gaussian window, sigma 1.5,
    population statistics, ``K1 = 0.01``, ``K2 = 0.03``, data range 1, mean over the valid area
    and the channels), so the training objective and the reported metric agree.
    """
    c1, c2 = 0.01 ** 2, 0.03 ** 2
    g = _gauss_window(dtype=image.dtype)
    x = image.permute(2, 0, 1)[:, None]  # [3, 1, H, W]
    y = reference.to(image.dtype).permute(2, 0, 1)[:, None]

    def blur(t):
        t = F.conv2d(t, g.view(1, 1, 1, -1))
        return F.conv2d(t, g.view(1, 1, -1, 1))

    mx, my = blur(x), blur(y)
    sxx = blur(x * x) - mx * mx
    syy = blur(y * y) - my * my
    sxy = blur(x * y) - mx * my
    s = ((2 * mx * my + c1) * (2 * sxy + c2)) / ((mx * mx + my * my + c1) * (sxx + syy + c2))
    return s.mean()


def training_loss(image: torch.Tensor, target: torch.Tensor, lambda_ssim: float = LAMBDA_SSIM) -> torch.Tensor:
    """``(1 - lambda) * mean|image - target| + lambda * (1 - SSIM(image, target))``; images [H, W, 3]."""
    l1 = torch.abs(image - target).mean()
    if lambda_ssim == 0:
        return l1
    return (1.0 - lambda_ssim) * l1 + lambda_ssim * (1.0 - ssim_torch(image, target))


def scene_from_params(params: dict, object_ids, template):
    """A SplatScene from parameter tensors (float32), keeping ``template``'s optional fields off."""
    from l3gs_opt.scene.splats import SplatScene

    arr = {k: params[k].detach().to(torch.float32).numpy() for k in _PARAM_KEYS}
    return SplatScene(**arr, object_ids=None if object_ids is None else np.asarray(object_ids))


def _param_groups(params: dict, cfg: TrainConfig, extent: float) -> list[dict]:
    groups = [("means", params["means"], cfg.lr_means * extent),
              ("sh_dc", params["sh_dc"], cfg.lr_sh_dc),
              ("opacity_logits", params["opacity_logits"], cfg.lr_opacity),
              ("log_scales", params["log_scales"], cfg.lr_scales),
              ("quats", params["quats"], cfg.lr_quats)]
    if "sh_rest" in params:
        groups.append(("sh_rest", params["sh_rest"], cfg.lr_sh_rest))
    return [{"params": [t], "lr": lr, "name": name} for name, t, lr in groups]


def _split_sh(params: dict) -> dict:
    """Leaf tensors per optimiser group (the SH is split into DC and rest, with their own rates)."""
    out = {k: params[k].detach().clone().requires_grad_(True) for k in _PARAM_KEYS if k != "sh"}
    out["sh_dc"] = params["sh"][:, :1].detach().clone().requires_grad_(True)
    if params["sh"].shape[1] > 1:
        out["sh_rest"] = params["sh"][:, 1:].detach().clone().requires_grad_(True)
    return out


def _joined(leaves: dict) -> dict:
    sh = leaves["sh_dc"] if "sh_rest" not in leaves else torch.cat([leaves["sh_dc"], leaves["sh_rest"]], 1)
    out = {k: leaves[k] for k in _PARAM_KEYS if k != "sh"}
    out["sh"] = sh
    return out


def _remap_optimizer(opt: torch.optim.Adam, leaves: dict, new_leaves: dict, source: torch.Tensor,
                     is_new: torch.Tensor) -> None:
    """Point ``opt`` at ``new_leaves``, carrying Adam moments of surviving rows (new rows start at 0)."""
    for group in opt.param_groups:
        name = group["name"]
        old, new = group["params"][0], new_leaves[name]
        state = opt.state.pop(old, None)
        group["params"][0] = new
        if state:
            for key in ("exp_avg", "exp_avg_sq"):
                m = state[key][source].clone()
                m[is_new] = 0.0
                state[key] = m
            opt.state[new] = state


def train(scene, views: Sequence[View], *, config: TrainConfig = TrainConfig(), densify: bool = False,
          frozen: int = 0, max_new: Optional[int] = None, min_splats: int = 0,
          progress: Optional[Callable[[int, float], None]] = None) -> TrainResult:
    """Optimise ``scene`` against ``views`` (see the module docstring for the recipe).

    Parameters
    ----------
    scene : SplatScene
        Starting splats (object ids are carried along; layer tags are dropped).
    views : sequence of View
        Cameras and target images.
    config : TrainConfig, keyword-only
    densify : bool, keyword-only
        Run adaptive density control (``Recovery``); otherwise the splat count is fixed.
    frozen : int, keyword-only
        Number of leading splats held fixed (bit-identical on output).  Not combinable with ``densify``.
    max_new : int, optional, keyword-only
        Cap on splats added over the whole run by densification.
    min_splats : int, keyword-only
        Densification never prunes below this count.
    progress : callable(iteration, loss), optional, keyword-only
        Called after every iteration (e.g. a tqdm update).

    Returns
    -------
    TrainResult

    Raises
    ------
    ValueError
        On no views, ``frozen`` out of ``[0, N]``, or ``frozen > 0`` with ``densify``.
    """
    n = scene.num_splats
    if len(views) == 0:
        raise ValueError("views: at least one training view is needed")
    if isinstance(frozen, bool) or not 0 <= int(frozen) <= n:
        raise ValueError(f"frozen: {frozen!r} must be in [0, {n}] (the scene's splat count)")
    if frozen and densify:
        raise ValueError("frozen: densification with frozen splats is not supported")
    with threads(TRAIN_THREADS):
        return _train(scene, views, config, densify, frozen, max_new, min_splats, progress)


def _train(scene, views, cfg: TrainConfig, densify: bool, frozen: int, max_new, min_splats: int,
           progress) -> TrainResult:
    """The loop of :func:`train` (arguments already checked)."""
    extent = scene_extent([v.camera for v in views])
    full = scene_tensors(scene, dtype=torch.float32)
    fixed = {k: v[:frozen] for k, v in full.items()}
    leaves = _split_sh({k: v[frozen:] for k, v in full.items()})
    ids = None if scene.object_ids is None else np.array(scene.object_ids)
    max_deg = scene.sh_degree
    start_deg = max_deg if cfg.sh_degree_start is None else min(cfg.sh_degree_start, max_deg)
    opt = torch.optim.Adam(_param_groups(leaves, cfg, extent), eps=1e-15)
    gen = torch.Generator().manual_seed(cfg.seed)
    rng = np.random.default_rng(cfg.seed)
    order: list[int] = []
    losses = np.zeros(cfg.iterations)
    log: list[dict] = []
    m = leaves["means"].shape[0]
    grad_sum, count = torch.zeros(m, dtype=torch.float64), torch.zeros(m, dtype=torch.float64)
    added = 0
    lr0, lr1 = cfg.lr_means * extent, cfg.lr_means_final * extent
    for it in range(cfg.iterations):
        frac = it / max(cfg.iterations - 1, 1)
        opt.param_groups[0]["lr"] = math.exp((1 - frac) * math.log(lr0) + frac * math.log(lr1)) if lr0 > 0 else 0.0
        deg = min(max_deg, start_deg + it // cfg.sh_up_every)
        if not order:
            order = list(rng.permutation(len(views)))
        view = views[order.pop()]
        trainable = _joined(leaves)
        p = {k: torch.cat([fixed[k], trainable[k]]) if frozen else trainable[k] for k in _PARAM_KEYS}
        out = render_gaussians(**p, camera=view.camera, sh_degree=deg)
        if densify:
            out.projection.means2d.retain_grad()
        loss = training_loss(out.image, view.image, cfg.lambda_ssim)
        opt.zero_grad(set_to_none=True)
        loss.backward()
        opt.step()
        losses[it] = float(loss.detach())
        if densify and it < cfg.densify_until:
            vis = out.projection.visible[frozen:]
            g = view_space_grad(out.projection.means2d.grad[frozen:], view.camera.width, view.camera.height)
            grad_sum[vis] += g[vis].to(torch.float64)
            count[vis] += 1
            step = it + 1
            if step > cfg.densify_from and step % cfg.densify_every == 0:
                budget = None if max_new is None else max(0, max_new - added)
                res = densify_and_prune(_joined(leaves), ids, grad_sum, count, grad_threshold=cfg.grad_threshold,
                                        extent=extent, percent_dense=cfg.percent_dense,
                                        min_opacity=cfg.min_opacity, max_new=budget, min_splats=min_splats,
                                        generator=gen)
                added += int(res.is_new.sum())
                new_leaves = _split_sh(res.params)
                _remap_optimizer(opt, leaves, new_leaves, res.source, res.is_new)
                leaves, ids = new_leaves, res.object_ids
                m = leaves["means"].shape[0]
                grad_sum, count = torch.zeros(m, dtype=torch.float64), torch.zeros(m, dtype=torch.float64)
                log.append({"iteration": step, "cloned": res.cloned, "split": res.split, "pruned": res.pruned,
                            "splats": m + frozen})
            if cfg.opacity_reset_every and (it + 1) % cfg.opacity_reset_every == 0:
                with torch.no_grad():
                    leaves["opacity_logits"].copy_(reset_opacity(leaves["opacity_logits"]))
                # the reference also zeroes the opacity moments so the reset is not undone at once
                st = opt.state.get(leaves["opacity_logits"])
                if st:
                    st["exp_avg"].zero_()
                    st["exp_avg_sq"].zero_()
        if progress is not None:
            progress(it, losses[it])
    trainable = _joined(leaves)
    final = {k: torch.cat([fixed[k], trainable[k].detach()]) if frozen else trainable[k].detach()
             for k in _PARAM_KEYS}
    return TrainResult(scene=scene_from_params(final, ids, scene), losses=losses, densify_log=log)


def recovery(scene, views: Sequence[View], *, config: TrainConfig = TrainConfig(), max_new: Optional[int] = None,
             min_splats: int = 0, progress=None) -> TrainResult:
    """``Recovery``: training with densification (clone / split / prune / opacity reset)."""
    return train(scene, views, config=config, densify=True, max_new=max_new, min_splats=min_splats,
                 progress=progress)


def finetune(scene, views: Sequence[View], *, config: TrainConfig = TrainConfig(), frozen: int = 0,
             progress=None) -> TrainResult:
    """``Finetune``: training with the splat count fixed (optionally the first ``frozen`` held fixed)."""
    return train(scene, views, config=config, densify=False, frozen=frozen, progress=progress)
