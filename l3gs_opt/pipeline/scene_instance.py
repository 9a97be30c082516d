"""Instances from real scenes: ``bundle + viewer path + bandwidth trace -> Instance``.

* **Costs** are the bundle's chunk bytes (manifest), object ``j`` = the manifest's ``objects[j]``,
  layer/version ``l`` = the bundle's level ``l``. A ``distill`` layer costs its compact chunk plus
  its SH upgrade (Problem I sends a layer whole; the two-step upgrade is the simulator's). An
  (object, level) with no splats has no chunk; the contract wants positive costs, so it costs
  1 byte and is worth nothing (listed in ``meta["empty_chunks"]``).
* **Utilities** (Eq. 1, :mod:`l3gs_opt.pipeline.splat_utility`) per slot: the mean over ``samples_per_slot``
  viewpoints spread evenly over the slot. Layered bundles give the per-layer ``dU`` (the splats a
  layer adds), separate bundles each version's whole ``U``.
* **Viewpoints** come from a headset pose log (timed; mapped to cameras by a
  :class:`~l3gs_opt.traces.poses.PoseMapping`, by default :data:`Z_UP_MAPPING` for z-up scenes) or from a camera path (camera JSON list or 4x4 matrix text,
  one camera per slot). With ``predict=True`` (pose logs only) each slot's viewpoints are the
  linear-regression prediction from the ``hw_s`` seconds of poses before the slot starts, as a
  client would compute them; slot 0, with no history, uses the first pose.
* **Bandwidth**: the trace scaled to a mean of ``mbps`` Mbit/s, the window ``start`` .. ``start +
  slots`` seconds, converted to bytes per slot. What was scaled and used is recorded in ``meta``.
"""

from __future__ import annotations

import math
import os
from pathlib import Path
from typing import Sequence

import numpy as np

from l3gs_opt.scene.bundle import Bundle, read_bundle
from l3gs_opt.scene.cameras import Camera, load_cameras
from l3gs_opt.errors import InstanceError
from l3gs_opt.pipeline.counts import MAX_SAMPLES_PER_SLOT, check_count
from l3gs_opt.problem.instance import Instance, Options
from l3gs_opt.traces.poses import PoseError, PoseMapping, PoseTrace, read_camera_path, read_pose_log
from l3gs_opt.traces.predictors import predict_viewport, wrap_deg
from l3gs_opt.traces.bandwidth import mbps_to_bytes, read_bandwidth_trace
from l3gs_opt.pipeline.splat_utility import _labels
from l3gs_opt.pipeline.utilities import DEFAULT_UTILITY, get_utility

__all__ = ["instance_from_bundle", "bundle_costs", "viewer_cameras", "read_delivery_bundle", "Z_UP_MAPPING"]

#: Head poses (y up) into a z-up scene such as the procedural rooms: log x -> x, y -> z, z -> y.
Z_UP_MAPPING = PoseMapping(world_from_log=((1.0, 0.0, 0.0), (0.0, 0.0, 1.0), (0.0, 1.0, 0.0)))


def read_delivery_bundle(bundle: "str | os.PathLike[str] | Bundle") -> Bundle:
    """A bundle (path or :class:`Bundle`) checked as ``bundle export`` checks it before anything is
    delivered from it (:func:`~l3gs_opt.scene.stream_index.check_streamable`): a duplicated chunk
    would be counted twice in the costs and a wrong ``cumulative_splats`` misstates the levels, so
    simulating or pricing such a bundle would give numbers for a bundle that cannot be streamed.

    Raises
    ------
    l3gs_opt.scene.bundle.BundleError, l3gs_opt.scene.stream_index.StreamError
        Naming the field and index (``chunks[20]``, ``levels[1]``), as ``bundle export`` does.
    """
    from l3gs_opt.scene.stream_index import check_streamable

    b = bundle if isinstance(bundle, Bundle) else read_bundle(bundle)
    check_streamable(b.manifest)
    return b


def bundle_costs(bundle: Bundle) -> tuple[np.ndarray, list[list[int]]]:
    """``[J, L]`` bytes per (object, level) and the (j, l) cells that have no splats (cost 1)."""
    m = bundle.manifest
    index = {obj: j for j, obj in enumerate(m["objects"])}
    cost = np.zeros((len(index), bundle.num_levels), np.int64)
    for c in m["chunks"]:
        if c["sh_form"] in ("full", "compact", "sh_upgrade"):
            cost[index[c["object"]], c["level"]] += int(c["bytes"])
    empty = [[int(j), int(l)] for j, l in zip(*np.nonzero(cost == 0))]
    cost[cost == 0] = 1
    return cost, empty


def _pose_at(trace: PoseTrace, times_s: np.ndarray) -> np.ndarray:
    """``[n, 6]`` poses at ``times_s``: the latest logged sample at or before each time."""
    idx = np.searchsorted(trace.time_s, times_s, side="right") - 1
    return trace.features[np.clip(idx, 0, len(trace.time_s) - 1)]


def _predicted_poses(trace: PoseTrace, slot_start_s: float, times_s: np.ndarray, hw_s: float) -> np.ndarray:
    """Linear-regression prediction of the poses at ``times_s`` from the ``hw_s`` before ``slot_start_s``."""
    past = (trace.time_s < slot_start_s) & (trace.time_s >= slot_start_s - hw_s)
    if not past.any():
        return np.repeat(trace.features[:1], len(times_s), axis=0)
    history = trace.features[past]
    rate = trace.rate_hz if trace.rate_hz > 0 else 1.0
    steps = np.maximum(1, np.rint((times_s - trace.time_s[past][-1]) * rate).astype(int))
    ahead = predict_viewport(history, int(steps.max()), method="lr")
    return ahead[steps - 1]


def viewer_cameras(path: str | os.PathLike[str], *, slots: int, slot_s: float = 1.0, samples_per_slot: int = 4,
                   predict: bool = False, hw_s: float = 0.5, pose_start_s: float = 0.0,
                   mapping: PoseMapping | None = None, width: int = 800, height: int = 600,
                   fov_deg: float = 70.0) -> list[list[Camera]]:
    """Per slot, the cameras whose utilities are averaged (see the module docstring)."""
    from l3gs_opt.scene.camera_paths import intrinsics_from_fov

    p = Path(path)
    if p.suffix.lower() == ".json":
        cams = load_cameras(p)
        return _one_per_slot(cams, slots, predict, str(p))
    if p.suffix.lower() in (".txt", ".cams", ".path"):
        try:
            matrices = read_camera_path(p)
        except PoseError:  # not matrices: read it as a pose log below
            matrices = None
        if matrices is not None:
            cams = [Camera(**intrinsics_from_fov(width, height, fov_deg), world_to_camera=m) for m in matrices]
            return _one_per_slot(cams, slots, predict, str(p))
    trace = read_pose_log(p)
    # Checked here, where the samples are made, so every command that reads a pose log gets it.
    check_count("samples_per_slot", samples_per_slot, high=MAX_SAMPLES_PER_SLOT, error=InstanceError)
    end_s = pose_start_s + slots * slot_s
    if trace.time_s[-1] < end_s - slot_s:
        raise InstanceError("path", f"{p}: the poses end at {trace.time_s[-1]:.1f} s, before the last slot "
                                    f"starts ({end_s - slot_s:.1f} s)")
    mapping = mapping or Z_UP_MAPPING
    intrinsics = intrinsics_from_fov(width, height, fov_deg)
    out = []
    for t in range(slots):
        start = pose_start_s + t * slot_s
        times = start + (np.arange(samples_per_slot) + 0.5) * slot_s / samples_per_slot
        poses = _predicted_poses(trace, start, times, hw_s) if predict else _pose_at(trace, times)
        w2c = mapping.world_to_camera(poses[:, :3], wrap_deg(poses[:, 3:]))
        out.append([Camera(**intrinsics, world_to_camera=m) for m in w2c])
    return out


def _one_per_slot(cams: Sequence[Camera], slots: int, predict: bool, where: str) -> list[list[Camera]]:
    if predict:
        raise InstanceError("predict", f"{where}: a camera path has no times to predict from; use a pose log")
    if len(cams) < slots:
        raise InstanceError("path", f"{where}: {len(cams)} cameras for {slots} slots (one camera per slot)")
    return [[c] for c in cams[:slots]]


def instance_from_bundle(bundle_path: str | os.PathLike[str], path: str | os.PathLike[str], trace: str, *,
                         mbps: float | None = 11.8, start: int = 0, slots: int = 60, slot_s: float = 1.0,
                         predict: bool = False, samples_per_slot: int = 4, hw_s: float = 0.5,
                         pose_start_s: float = 0.0, mapping: PoseMapping | None = None, width: int = 800,
                         height: int = 600, fov_deg: float = 70.0, options: Options | None = None,
                         progress: bool = False, utility: str = DEFAULT_UTILITY) -> Instance:
    """The instance of delivering ``bundle_path`` to a viewer on ``path`` over ``trace``.

    Parameters
    ----------
    bundle_path : path
        A bundle directory (``l3gs-opt scene build``).
    path : path
        Pose log, camera JSON list or 4x4 camera path file.
    trace : str
        Bundled trace name or trace file (one Mbit/s sample per second).
    mbps : float or None
        Scale the trace to this mean (Mbit/s); None keeps it.
    start, slots : int
        The window: first trace sample and number of slots.
    predict : bool
        Utilities for the predicted viewports instead of the true ones (pose logs only).
    options : Options, optional
        The instance's options, e.g. ``Options(budget="cumulative")`` for one link whose unspent
        bytes carry over (a chunk larger than one slot's bytes can then arrive).
    utility : str
        The splat utility (:mod:`l3gs_opt.pipeline.utilities`; default ``eq1``). A held-aware one is
        valued with everything held (its held-free form: an instance's utilities are fixed).
    """
    from tqdm import tqdm

    if slots < 1:
        raise InstanceError("slots", f"{slots}: must be >= 1")
    if not (slot_s > 0 and math.isfinite(slot_s)):
        raise InstanceError("slot_s", f"{slot_s!r}: must be a positive number of seconds")
    bundle = read_delivery_bundle(bundle_path)
    m = bundle.manifest
    cost, empty = bundle_costs(bundle)
    raw = read_bandwidth_trace(trace)
    scaled, factor = raw.scaled(mbps) if mbps is not None else (raw, 1.0)
    window = scaled.window(start, slots)
    cams = viewer_cameras(path, slots=slots, slot_s=slot_s, samples_per_slot=samples_per_slot, predict=predict,
                          hw_s=hw_s, pose_start_s=pose_start_s, mapping=mapping, width=width, height=height,
                          fov_deg=fov_deg)
    objects = list(m["objects"])
    J, L = cost.shape
    # Utility rows are indexed by object id; an unsegmented scene is object 0.
    rows = np.asarray(objects, dtype=np.int64) if m["segmented"] else np.zeros(1, np.int64)
    u = get_utility(utility)
    # Layered: one scene tagged by layer gives every dU at once; separate: one scene per version.
    if m["representation"] == "layered":
        scenes = [(None, bundle.scene(L - 1))]
    else:
        scenes = [(level, bundle.level_scene(level)) for level in range(L)]
    prepared = []
    for level, scene in scenes:
        obj, lay, Jc, Lc = _labels(scene)
        bins = obj * max(Lc, 1) + lay
        order = np.argsort(bins, kind="stable")
        cells = np.split(order, np.cumsum(np.bincount(bins, minlength=Jc * Lc))[:-1])
        prepared.append((level, u.prepare(scene), cells, (Jc, Lc)))
    values = np.zeros((slots, J, L))
    for t in tqdm(range(slots), desc=f"{u.name} utilities", disable=not progress):
        for level, prep, cells, (Jc, Lc) in prepared:
            got = u.chunk_values(prep, cams[t], cells).reshape(Jc, Lc)
            # Pad: an object (or top layer) without splats in this scene has no row (column).
            full = np.zeros((max(int(rows.max()) + 1, Jc), L if level is None else 1))
            full[:Jc, :min(Lc, full.shape[1])] = got[:, :full.shape[1]]
            if level is None:
                values[t] = full[rows]
            else:
                values[t, :, level] = full[rows, 0]
    meta = {
        "generator": "l3gs_opt.pipeline.scene_instance", "bundle": str(Path(bundle_path)), "variant": m["variant"],
        "path": str(Path(path)), "viewport": "predicted (lr)" if predict else "true",
        "samples_per_slot": samples_per_slot, "hw_s": hw_s if predict else None, "pose_start_s": pose_start_s,
        "camera": {"width": width, "height": height, "fov_deg": fov_deg},
        "trace": raw.name, "trace_mean_mbps_raw": float(raw.mbps.mean()), "scale_factor": factor,
        "target_mean_mbps": mbps, "window": {"start_s": start, "length_s": slots},
        "window_mean_mbps": float(window.mbps.mean()), "objects": objects, "empty_chunks": empty,
        "utility": u.describe(),
    }
    return Instance(m["representation"], bandwidth=mbps_to_bytes(window.mbps, slot_s), cost=cost,
                    utility=values, slot_s=slot_s, options=options or Options(), meta=meta)
