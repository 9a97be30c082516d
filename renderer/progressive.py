"""Prune2TargetSize and ProgressiveTraining (the L3GS paper's Algorithms 1 and 2, on the CPU).

**Prune2TargetSize(scene, d, r)**::

    while |scene| > d:
        score = global significance of every splat (renderer.significance)
        k = ceil(r * |scene|)
        if |scene| - k > d:   drop the k lowest-score splats, then Recovery (densification may
                              re-add at most floor(k / 2) splats and never prunes below d, so
                              every round shrinks the scene and the loop ends)
        else:                 keep the d highest-score splats, then Finetune (count fixed)
    sort by a final significance, descending

The result has exactly ``d`` splats (``d = |scene|`` returns the scene sorted, untrained).

**ProgressiveTraining(sorted scene, d_1 < ... < d_L)**: layer 1 is the first ``d_1`` splats,
fine-tuned alone; layer ``l`` appends splats ``d_{l-1} .. d_l - 1`` of the sorted scene to the
trained layers ``< l`` and fine-tunes with those lower layers frozen (bit-identical).  The
result is tagged ``layers`` 0..L-1 (0 = base layer).
"""

from __future__ import annotations

import math
from typing import Callable, NamedTuple, Optional, Sequence

import numpy as np

from l3gs_opt.errors import L3gsError

from .significance import global_significance, significance_order
from .train import TRAIN_THREADS, TrainConfig, View, finetune, recovery, threads

__all__ = ["SizeError", "DEFAULT_PRUNE_RATIO", "check_sizes", "PruneResult", "prune_to_target_size",
           "train_layer", "progressive_training"]

#: Fraction of the splats pruned per round when the target is still far (r of the paper).
DEFAULT_PRUNE_RATIO = 0.3


class SizeError(L3gsError, ValueError):
    """A target size or list of layer/version sizes is invalid; names the field and index."""

    def __init__(self, field: str, message: str, index: Optional[int] = None):
        self.field = field
        self.index = index
        super().__init__(f"{field}{'' if index is None else f'[{index}]'}: {message}")


def check_sizes(sizes, available: int, *, field: str = "layers") -> list[int]:
    """Validate layer / version sizes: integers, ``0 < d_1 < ... < d_L <= available``.

    Parameters
    ----------
    sizes : sequence of int
        Cumulative splat counts (layer ``l`` holds ``sizes[l] - sizes[l-1]`` new splats).
    available : int
        Splats of the teacher.
    field : str, keyword-only
        Name used in error messages (the CLI passes ``"--layers"``).

    Returns
    -------
    list of int

    Raises
    ------
    SizeError
        Naming the first bad entry: not an integer, zero or negative, not increasing, or more
        than the teacher has.
    """
    out: list[int] = []
    if len(sizes) == 0:
        raise SizeError(field, "at least one size is needed")
    for i, v in enumerate(sizes):
        if isinstance(v, bool) or not isinstance(v, (int, float, np.integer, np.floating)) \
                or not float(v).is_integer():
            raise SizeError(field, f"{v!r} is not an integer", i)
        v = int(v)
        if v <= 0:
            raise SizeError(field, f"{v} must be > 0", i)
        if out and v <= out[-1]:
            raise SizeError(field, f"{v} must be greater than the previous size {out[-1]} (sizes increase)", i)
        if v > available:
            raise SizeError(field, f"{v} is more than the {available} splats the teacher has", i)
        out.append(v)
    return out


class PruneResult(NamedTuple):
    """Output of :func:`prune_to_target_size`.

    Attributes
    ----------
    scene : SplatScene
        Exactly ``d`` splats, sorted by ``significance`` descending.
    significance : ndarray, shape [d], float64
        Final global significance of each splat (descending).
    rounds : list of dict
        One per round: ``splats_before, pruned, action ("recovery" / "finetune"), splats_after``.
    """

    scene: object
    significance: np.ndarray
    rounds: list


def _cameras(views: Sequence[View]) -> list:
    return [v.camera for v in views]


def prune_to_target_size(scene, d: int, views: Sequence[View], *, r: float = DEFAULT_PRUNE_RATIO,
                         recovery_config: TrainConfig = TrainConfig(iterations=300),
                         finetune_config: TrainConfig = TrainConfig(iterations=300),
                         progress: Optional[Callable[[int, float], None]] = None,
                         start: Optional[tuple] = None,
                         on_round: Optional[Callable[[object, list], None]] = None) -> PruneResult:
    """Prune ``scene`` to exactly ``d`` splats by significance, recovering quality as it goes.

    Parameters
    ----------
    scene : SplatScene
    d : int
        Target splat count, ``1 <= d <= N``.
    views : sequence of View
        Training views (cameras + target images); significance uses their cameras.
    r : float, keyword-only
        Fraction pruned per round, ``0 < r < 1``.
    recovery_config, finetune_config : TrainConfig, keyword-only
        Schedules of the Recovery and final Finetune runs.
    progress : callable(iteration, loss), optional, keyword-only
        Passed to every training run.
    start : (SplatScene, list of dict), optional, keyword-only
        Resume: the scene after some rounds of an earlier run with the same inputs, and those
        rounds' records (what ``on_round`` was given); the rounds go on from there.
    on_round : callable(SplatScene, list of dict), optional, keyword-only
        Called after every round with the scene so far and the rounds' records (a checkpoint:
        one round of a million-splat scene can take most of an hour on two cores).

    Returns
    -------
    PruneResult

    Raises
    ------
    SizeError
        If ``d`` is not in ``[1, N]`` or ``r`` not in ``(0, 1)``.
    """
    n0 = scene.num_splats
    (d,) = check_sizes([d], n0, field="d")
    if not (isinstance(r, (int, float)) and 0.0 < r < 1.0):
        raise SizeError("r", f"{r!r} must be in (0, 1)")
    cams = _cameras(views)
    rounds: list[dict] = []
    cur = scene
    if start is not None:
        cur, rounds = start[0], [dict(r) for r in start[1]]
        if not d <= cur.num_splats <= n0:
            raise SizeError("start", f"{cur.num_splats} splats: a resumed round holds between {d} and {n0}")
    with threads(TRAIN_THREADS):
        while cur.num_splats > d:
            n = cur.num_splats
            order = significance_order(global_significance(cur, cams))
            k = max(1, math.ceil(r * n))
            if n - k > d:
                cur = recovery(cur.subset(order[:n - k]), views, config=recovery_config, max_new=k // 2,
                               min_splats=d, progress=progress).scene
                rounds.append({"splats_before": n, "pruned": k, "action": "recovery", "splats_after": cur.num_splats})
            else:
                cur = finetune(cur.subset(order[:d]), views, config=finetune_config, progress=progress).scene
                rounds.append({"splats_before": n, "pruned": n - d, "action": "finetune", "splats_after": d})
            if on_round is not None:
                on_round(cur, rounds)
        sig = global_significance(cur, cams)
    order = significance_order(sig)
    return PruneResult(scene=cur.subset(order), significance=sig[order], rounds=rounds)


def train_layer(lower, new_splats, views: Sequence[View], *, config: TrainConfig,
                progress: Optional[Callable[[int, float], None]] = None):
    """One ProgressiveTraining step: fine-tune ``new_splats`` on top of the frozen ``lower`` layers.

    Parameters
    ----------
    lower : SplatScene or None
        Trained lower layers (tagged 0..l-1), held fixed; None for the base layer.
    new_splats : SplatScene
        The splats of the new layer (from the significance-sorted scene).
    views : sequence of View
    config : TrainConfig, keyword-only

    Returns
    -------
    SplatScene
        ``lower`` (bit-identical) followed by the trained new layer, with ``layers`` tags.
    """
    import dataclasses

    from l3gs_opt.scene.splats import SplatScene

    level = 0 if lower is None else lower.num_layers
    if lower is None:
        stacked, frozen = new_splats, 0
    else:
        cat = lambda a, b: None if a is None or b is None else np.concatenate([a, b])  # noqa: E731
        stacked = SplatScene(means=cat(lower.means, new_splats.means),
                             log_scales=cat(lower.log_scales, new_splats.log_scales),
                             quats=cat(lower.quats, new_splats.quats),
                             opacity_logits=cat(lower.opacity_logits, new_splats.opacity_logits),
                             sh=cat(lower.sh, new_splats.sh), object_ids=cat(lower.object_ids, new_splats.object_ids))
        frozen = lower.num_splats
    out = finetune(stacked, views, config=config, frozen=frozen, progress=progress).scene
    tags = np.full(out.num_splats, level, np.int32)
    if lower is not None:
        tags[:frozen] = lower.layers if lower.layers is not None else 0
    return dataclasses.replace(out, layers=tags)


def progressive_training(sorted_scene, sizes: Sequence[int], views: Sequence[View], *,
                         config: TrainConfig = TrainConfig(iterations=300),
                         on_layer: Optional[Callable[[int, object], None]] = None,
                         progress: Optional[Callable[[int, float], None]] = None):
    """Train layers ``d_1 < ... < d_L`` from a significance-sorted scene (see module docstring).

    Parameters
    ----------
    sorted_scene : SplatScene
        Splats sorted by significance, descending (e.g. :func:`prune_to_target_size`), at least ``d_L``.
    sizes : sequence of int
        Cumulative layer sizes ``d_1 < ... < d_L``.
    views : sequence of View
    config : TrainConfig, keyword-only
        Schedule of each layer's fine-tuning.
    on_layer : callable(layer_index, scene_so_far), optional, keyword-only
        Called after each layer (checkpointing).

    Returns
    -------
    SplatScene
        ``d_L`` splats tagged with ``layers`` 0..L-1; splats of layer ``l`` are rows ``d_{l-1}..d_l - 1``.
    """
    sizes = check_sizes(sizes, sorted_scene.num_splats)
    cur = None
    prev = 0
    for i, d in enumerate(sizes):
        cur = train_layer(cur, sorted_scene.subset(np.arange(prev, d)), views, config=config, progress=progress)
        if on_layer is not None:
            on_layer(i, cur)
        prev = d
    return cur
