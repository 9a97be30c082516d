"""Utility fidelity: how well each splat utility ranks chunks by what they do to the picture.

At sampled slots of a viewer's path, a *held state* is drawn (per object, a random number of its
layers held, 0..L-1, seeded: the states a client passes through). The candidates are the chunks a
scheduler could add next: each object's next layer. Each candidate is added alone and the gain in
SSIM and PSNR of the held picture is measured against the full scene's picture, from the slot's
viewpoints at the full size (:func:`l3gs_opt.pipeline.utilities.chunk_gains`, ``scale=1``). Each
utility values the same candidates (held-aware ones given the held state), and the report gives,
per utility, the Spearman and Kendall rank correlations of its values with the measured gains,
per sample (then averaged; samples with fewer than three candidates or constant values skipped)
and pooled over all samples, both for values and per byte (value / bytes against gain / bytes:
what a knapsack ranks by), and its time per viewpoint.

Layered bundles only (a chunk of a separate bundle replaces a version; "adding it alone" is not
defined the same way).
"""

from __future__ import annotations

import os
import time
from dataclasses import dataclass, field
from typing import Callable, Sequence

import numpy as np

from l3gs_opt.errors import L3gsError
from l3gs_opt.pipeline.counts import MAX_FIDELITY_SAMPLES, MAX_SAMPLES_PER_SLOT, check_count
from l3gs_opt.pipeline.utilities import ScenePictures, chunk_gains, get_utility

__all__ = ["FidelityError", "FidelityReport", "utility_fidelity", "DEFAULT_FIDELITY_UTILITIES"]

#: The utilities compared when none are named.
DEFAULT_FIDELITY_UTILITIES = ("eq1", "visibility", "visibility-held", "coverage")


class FidelityError(L3gsError, ValueError):
    """A bad argument of the fidelity check (names it)."""


@dataclass
class FidelityReport:
    """Per utility: correlations with the measured gains and seconds per viewpoint; the raw samples."""

    utilities: list[str]
    correlations: dict[str, dict[str, float | None]]
    seconds_per_viewpoint: dict[str, float]
    samples: list[dict] = field(default_factory=list)
    setup: dict = field(default_factory=dict)

    def to_dict(self) -> dict:
        return {"utilities": self.utilities, "correlations": self.correlations,
                "seconds_per_viewpoint": self.seconds_per_viewpoint, "setup": self.setup, "samples": self.samples}


def _rank_stats(x: np.ndarray, y: np.ndarray) -> tuple[float | None, float | None]:
    from scipy.stats import kendalltau, spearmanr

    if len(x) < 3 or np.ptp(x) == 0 or np.ptp(y) == 0:
        return None, None
    return float(spearmanr(x, y).statistic), float(kendalltau(x, y).statistic)


def _mean(values: list) -> float | None:
    vals = [v for v in values if v is not None]
    return float(np.mean(vals)) if vals else None


def utility_fidelity(bundle_path: str | os.PathLike[str], path: str | os.PathLike[str], *,
                     utilities: Sequence[str] = DEFAULT_FIDELITY_UTILITIES, samples: int = 8, slots: int = 30,
                     samples_per_slot: int = 1, width: int = 128, height: int = 96, fov_deg: float = 70.0,
                     seed: int = 0, up: str = "z",
                     progress: Callable[[int, int], None] | None = None) -> FidelityReport:
    """Measure each utility's rank correlation with the measured SSIM / PSNR gain of adding a chunk.

    Parameters
    ----------
    bundle_path : path
        A layered bundle.
    path : path
        Viewer: pose log, camera JSON list or camera path file (as ``instance from-scene``).
    utilities : names
    samples : int
        Sampled (slot, held state) pairs, at slots spread evenly over the first ``slots``.
    samples_per_slot : int
        Viewpoints per slot (the gain and the values are means over them).
    width, height, fov_deg : picture size (pixels) and horizontal field of view (degrees)
    seed : int
        Seed of the held states.

    Raises
    ------
    FidelityError
        A separate bundle, a count out of range, an unknown utility.
    """
    from l3gs_opt.pipeline.scene_instance import Z_UP_MAPPING, read_delivery_bundle, viewer_cameras
    from l3gs_opt.traces.poses import PoseMapping

    from l3gs_opt.scene.cameras import MAX_IMAGE_SIDE
    from l3gs_opt.traces.bandwidth import MAX_TRACE_SAMPLES

    # upper limits too: a mistyped count would render for days (width and height >= 11: SSIM's window)
    for name, v, lo, hi in (("samples", samples, 1, MAX_FIDELITY_SAMPLES), ("slots", slots, 1, MAX_TRACE_SAMPLES),
                            ("samples_per_slot", samples_per_slot, 1, MAX_SAMPLES_PER_SLOT),
                            ("width", width, 11, MAX_IMAGE_SIDE), ("height", height, 11, MAX_IMAGE_SIDE)):
        check_count(name, v, low=lo, high=hi, error=lambda f, m: FidelityError(f"{f}: {m}"))
    if isinstance(seed, bool) or not isinstance(seed, (int, np.integer)) or seed < 0:
        raise FidelityError(f"seed = {seed!r}: must be an integer >= 0")
    try:
        chosen = [get_utility(u) for u in utilities]
    except L3gsError as exc:
        raise FidelityError(str(exc)) from None
    if not chosen:
        raise FidelityError("utilities: name at least one")
    bundle = read_delivery_bundle(bundle_path)
    m = bundle.manifest
    if m["representation"] != "layered":
        raise FidelityError(f"{bundle_path}: a {m['representation']} bundle; the fidelity check needs a layered one")
    L = bundle.num_levels
    scene = bundle.scene(L - 1)
    obj = np.zeros(scene.num_splats, np.int64) if scene.object_ids is None else scene.object_ids.astype(np.int64)
    lay = scene.layers.astype(np.int64)
    objects = np.unique(obj)
    chunk_rows = {(int(j), int(l)): np.flatnonzero((obj == j) & (lay == l)) for j in objects for l in range(L)}
    bytes_per_splat = float(np.mean([c["bytes"] / max(c["splats"], 1) for c in m["chunks"] if c["splats"]]))
    cams = viewer_cameras(path, slots=slots, samples_per_slot=samples_per_slot, width=width, height=height,
                          fov_deg=fov_deg, mapping=Z_UP_MAPPING if up == "z" else PoseMapping())
    at = np.unique(np.linspace(0, slots - 1, samples).round().astype(int))
    rng = np.random.default_rng(seed)
    prepared = {u.name: u.prepare(scene) for u in chosen}
    pictures = ScenePictures(scene, None)
    per_view_s = {u.name: [] for u in chosen}
    out_samples: list[dict] = []
    for i, t in enumerate(at):
        if progress is not None:
            progress(i, len(at))
        levels = {int(j): int(rng.integers(0, L)) for j in objects}   # layers held per object
        held = np.zeros(scene.num_splats, bool)
        for j, h in levels.items():
            for l in range(h):
                held[chunk_rows[(j, l)]] = True
        cands = [(j, h) for j, h in levels.items() if h < L and chunk_rows[(j, h)].size]
        if not cands:
            continue
        rows = [chunk_rows[c] for c in cands]
        gains = chunk_gains(pictures, cams[t], rows, held=held, scale=1.0)
        record = {"slot": int(t), "held_layers": levels, "candidates": [list(c) for c in cands],
                  "splats": [int(r.size) for r in rows], "gain_ssim": gains["ssim"].tolist(),
                  "gain_psnr": gains["psnr"].tolist(), "values": {}}
        for u in chosen:
            t0 = time.perf_counter()
            vals = u.chunk_values(prepared[u.name], cams[t], rows, held=held if u.held_aware else None)
            per_view_s[u.name].append((time.perf_counter() - t0) / len(cams[t]))
            record["values"][u.name] = [float(v) for v in vals]
        out_samples.append(record)
    correlations: dict[str, dict[str, float | None]] = {}
    for u in chosen:
        per: dict[str, list] = {k: [] for k in ("spearman_ssim", "kendall_ssim", "spearman_psnr", "kendall_psnr",
                                                "spearman_ssim_per_byte", "kendall_ssim_per_byte")}
        pooled: dict[str, list] = {"v": [], "g": [], "vb": [], "gb": []}
        for s in out_samples:
            v, size = np.array(s["values"][u.name]), np.array(s["splats"], dtype=np.float64) * bytes_per_splat
            g, p = np.array(s["gain_ssim"]), np.array(s["gain_psnr"])
            sp, kd = _rank_stats(v, g)
            per["spearman_ssim"].append(sp)
            per["kendall_ssim"].append(kd)
            sp, kd = _rank_stats(v, p)
            per["spearman_psnr"].append(sp)
            per["kendall_psnr"].append(kd)
            sp, kd = _rank_stats(v / size, g / size)
            per["spearman_ssim_per_byte"].append(sp)
            per["kendall_ssim_per_byte"].append(kd)
            pooled["v"] += v.tolist()
            pooled["g"] += g.tolist()
            pooled["vb"] += (v / size).tolist()
            pooled["gb"] += (g / size).tolist()
        row = {k: _mean(vals) for k, vals in per.items()}
        # Pooled over samples: across viewpoints the values' scale changes (pixels in view), so
        # this asks more than per-sample ranking does.
        row["spearman_ssim_pooled"], row["kendall_ssim_pooled"] = _rank_stats(np.array(pooled["v"]),
                                                                              np.array(pooled["g"]))
        row["spearman_ssim_per_byte_pooled"], _ = _rank_stats(np.array(pooled["vb"]), np.array(pooled["gb"]))
        correlations[u.name] = row
    # A reference point: chunk size alone (bigger chunks, bigger gains).
    sizes = [_rank_stats(np.array(s["splats"], dtype=np.float64), np.array(s["gain_ssim"]))[0] for s in out_samples]
    setup = {"bundle": str(bundle_path), "path": str(path), "samples": len(out_samples), "slots": slots,
             "samples_per_slot": samples_per_slot, "width": width, "height": height, "fov_deg": fov_deg,
             "seed": seed, "splats": int(scene.num_splats), "objects": int(len(objects)), "layers": int(L),
             "candidates": int(sum(len(s["candidates"]) for s in out_samples)),
             "spearman_ssim_chunk_size": _mean(sizes),
             "utilities": {u.name: u.describe() for u in chosen}}
    return FidelityReport(utilities=[u.name for u in chosen], correlations=correlations,
                          seconds_per_viewpoint={k: float(np.median(v)) if v else float("nan")
                                                 for k, v in per_view_s.items()},
                          samples=out_samples, setup=setup)
