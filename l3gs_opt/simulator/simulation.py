"""The trace-driven delivery simulator: a client fetches a bundle over a real link, slot by slot,
and what it shows each second is scored against the full teacher scene.

Each slot ``t`` (``slot_s`` seconds, 1 s by default):

1. **Predict.** The client predicts its viewport for the coming slot from the poses before the
   slot starts (``viewport``: ``lr`` -- the paper's linear regression over ``hw_s`` seconds --,
   ``last`` or ``oracle``), ``samples_per_slot`` viewpoints spread over the slot, and the slot's
   bandwidth from the bytes the link gave it in earlier slots (``bandwidth_predictor``:
   ``harmonic`` mean of the last ``bandwidth_window`` slots, optionally ``robust``; ``last``;
   ``oracle``), times ``bandwidth_bias``. Slot 0 has no history: the client knows the
   throughput of its manifest fetch, modelled as slot 0's own bytes.
2. **Utility.** A named splat utility (:mod:`l3gs_opt.pipeline.utilities`: ``eq1``, the paper's
   Eq. 1, by default; ``visibility``, ``visibility-held``, ``coverage``, ``counterfactual`` or a
   user's) of every splat, averaged over the predicted viewpoints (``utility_mode="exact"``), or
   per (object, layer) from a precomputed viewpoint table (``utility_mode="table"``), summed per
   deliverable unit (:mod:`l3gs_opt.simulator.valuation`). Each run may name its own utility and,
   separately, the one that orders the splats inside a unit.
3. **Schedule.** The method's :class:`Scheduler` gets a :class:`SlotView` (predicted utilities
   and bytes, what is held and in flight; an :class:`ItemSlotView` for the item-form methods)
   and returns an ordered list of units to request. The simulator decides nothing itself; it
   only checks the list (no unit twice, nothing held, prerequisites first).
4. **Deliver.** The link (:class:`l3gs_opt.simulator.link.Link`) moves the slot's bytes of the trace: first
   the chunk cut off at the end of the last slot, then the requests in order. A chunk streams
   its splats in descending utility for the viewpoints predicted when its first byte is sent (as
   in the paper; ``sort`` keeps the bundle's global-significance order), and each splat is usable
   as soon as its bytes have arrived. Idle bytes are lost, or banked with ``budget="cumulative"``.
   With ``substeps = S > 1`` (beyond the paper, which lists re-planning within a slot as a
   limitation) the slot's bytes come in S equal parts and before each later part the scheduler
   plans again, given the bytes it measured so far in the slot (``predicted_bytes`` of the view
   is then ``measured / s * (S - s)`` before part s); a chunk already started is never aborted.
5. **Render.** At the end of the slot the client renders what it holds from the *true* viewpoint
   (the last pose at or before the slot's end); SSIM and PSNR against the reference scene
   (the full teacher) rendered from the same viewpoint. Renders use the numba kernels when
   installed and are cached by content (:mod:`l3gs_opt.simulator.render`): the teacher is rendered
   once per camera for every run in the process (and, with ``cache_dir``, across processes),
   and a client view that shows the same splats from the same camera as any earlier render
   (nothing new arrived, the viewer did not move; or another method holding the same splats)
   is not rendered again.

Units (what a scheduler requests) follow the method's *view* of the bundle
(:mod:`l3gs_opt.simulator.catalog`): ``object`` -- one unit per (object, level), the bundle's chunks;
``scene`` -- one unit per level, the objects merged; ``distill`` -- per (object, layer) a compact
chunk and its SH upgrade; ``hierarchy`` -- per (object, version). Layered bundles (``layered``,
``sort``, ``distill``) stack layers: every arrived splat is shown. Separate bundles
(``separate``, ``hierarchy``) hold versions: an object shows its highest *complete* version,
and a better version replaces a worse one as a whole. In the ``distill`` view a splat shows
with its compact SH until its upgrade's bytes arrived; in the other views a ``distill`` layer
is one stream of compact chunk plus upgrade (a splat usable once both parts arrived).

Methods (:data:`SIM_METHODS`, plus every solver method of :func:`l3gs_opt.method_names`):

* ``l3gs`` -- layered and segmented: each slot the single-slot MCKP (Lemma 3) over the predicted
  bytes, given what is held or in flight, solved by ``solver`` (``bb`` by default; ``dp``,
  ``greedy``, ``fptas:EPS``, ``ilp``, ...);
* ``l3gs-noseg`` -- the same on whole-scene layers;
* ``separate`` -- the same on whole-scene versions of a separate bundle (versions replace each
  other);
* ``distill`` -- a ``distill`` bundle through the item form (:func:`l3gs_opt.problem.items.distill_items`:
  layer l's compact chunk after layer l-1's, its SH upgrade after it), each slot the item MCKP
  over precedence-closed sets by ``solver`` (``bb``; ``dp``, ``greedy``, ``fptas:EPS``, ``ilp``,
  or an item method over the rest of the run: ``rolling:S``, ``rolling-future:S``, ``mpc:H``).
  Eq. 1 is colour-blind, so a splat's utility ``u`` is split: ``u * f`` for its upgrade and
  ``u * (1 - f)`` for its compact form, with ``f`` from ``sh_upgrade_utility`` (default
  ``residual``, the share of the splat's SH energy the compact fit misses); a layer with both
  parts is worth its Eq. 1 utility, as in every other method;
* ``hierarchy`` -- a ``hierarchy`` (or any separate) bundle through the item form
  (:func:`l3gs_opt.problem.items.hierarchy_items`: an object's versions one replacement group, sent
  whole), the same solvers;
* ``sort`` -- a ``sort`` bundle's splats in global-significance order, one stream, not
  view-dependent;
* ``preload`` -- the largest model is on the client from the start (the upper reference);
* a single-slot solver name (``bb``, ``dp``, ``greedy``, ``fptas:EPS``) -- ``l3gs`` with that solver;
* a multi-slot method (``rolling:SOLVER``, ``rolling-future:SOLVER``, ``mpc:H``, ``slope``,
  ``progressive``, ``static``, ``ilp``, ``exact``) -- each slot, an instance over the remaining
  horizon (at most ``horizon`` slots) whose utilities and bandwidth hold the slot's prediction
  constant; the slot-0 arrivals are requested first.

``fill`` (default on): the link does not idle while something useful is left -- after the slot's
picks come the plan's later arrivals (multi-slot methods), then every other unit by predicted
utility per byte (layered; prerequisites first) or the next larger versions (separate). What
does not arrive in the slot is re-planned next slot, except the chunk cut off, which carries
over. ``fill=False`` requests the slot's picks only.

Several clients can share one bottleneck (:func:`l3gs_opt.simulator.shared.run_shared`): each part
of a slot is split max-min fairly among their demands (:func:`l3gs_opt.simulator.link.max_min_shares`).

Results: one record per slot (``ssim``, ``psnr``, bytes, requests, per-slot timings of prediction,
utility, scheduling, rendering, reference and metrics -- time actually spent, so a cache hit
costs ~0) and a summary whose ``ssim_per_s`` has one value per slot (per second at the default
slot length). With ``out_dir`` the records are appended to ``OUT/slots.jsonl`` as they finish
and ``resume`` continues an interrupted run from them (:mod:`l3gs_opt.simulator.records`): the
recorded requests are replayed through the link to rebuild the client's state, checked slot by
slot against the records, and the run goes on from the first slot missing; the result equals
that of an uninterrupted run.

``bytes_wasted``: bytes delivered that the last rendered frame does not use: versions replaced
(separate), chunks still incomplete at the end (separate), and the bytes of splats cut in half at
the end (layered).
"""

from __future__ import annotations

import dataclasses
import hashlib
import json
import math
import os
import time
from typing import Any, Mapping, Sequence

import numpy as np

from l3gs_opt.simulator.link import Link
from l3gs_opt.simulator.catalog import Catalog, _base_scene, build_catalog, compact_sh, upgrade_fraction
from l3gs_opt.simulator.config import TIMING_KEYS, SimConfig, SimulationError, SlotInputs
from l3gs_opt.simulator.methods import ITEM_SOLVERS, SIM_METHODS, SLOT_SOLVERS, MethodSpec, method_spec
from l3gs_opt.simulator.records import SimulationResult, run_id
from l3gs_opt.simulator.valuation import Valuation
from l3gs_opt.simulator.schedulers import (FixedOrderScheduler, HorizonScheduler, ItemSlotView, PreloadScheduler, Scheduler,
                             SlotSolverScheduler, SlotView, order_requests)

__all__ = ["SimulationError", "SimConfig", "Catalog", "build_catalog", "SlotView", "ItemSlotView", "Scheduler",
           "SlotSolverScheduler", "HorizonScheduler", "FixedOrderScheduler", "PreloadScheduler", "order_requests",
           "MethodSpec", "method_spec", "SIM_METHODS", "SLOT_SOLVERS", "ITEM_SOLVERS", "Simulation",
           "SimulationResult", "simulate", "trace_bytes", "TIMING_KEYS"]


def trace_bytes(trace: str, *, mbps: float | None = None, start: int = 0, slots: int = 60,
                slot_s: float = 1.0, format: str = "auto") -> tuple[np.ndarray, dict]:
    """Bytes per slot of a trace window (scaled to a mean of ``mbps`` Mbit/s first) and what was used;
    ``format`` as :func:`l3gs_opt.traces.bandwidth.read_bandwidth_trace`'s."""
    from l3gs_opt.pipeline.counts import check_count
    from l3gs_opt.traces.bandwidth import MAX_TRACE_SAMPLES, mbps_to_bytes, read_bandwidth_trace

    # By name here: the trace window's own message ("length=0 does not fit") does not say it was --slots.
    check_count("slots", slots, high=MAX_TRACE_SAMPLES, error=SimulationError)
    raw = read_bandwidth_trace(trace, format=format)
    scaled, factor = raw.scaled(mbps) if mbps is not None else (raw, 1.0)
    window = scaled.window(start, slots)
    info = {"trace": raw.name, "trace_mean_mbps_raw": float(raw.mbps.mean()), "scale_factor": factor,
            "target_mean_mbps": mbps, "window": {"start_s": start, "length_s": slots},
            "window_mean_mbps": float(window.mbps.mean())}
    return mbps_to_bytes(window.mbps, slot_s), info


# ---------------------------------------------------------------------------------------- simulation
class Simulation:
    """A bundle, a viewer and a link, prepared once; :meth:`run` simulates one method.

    Predictions and utilities depend on the slot only, so they are computed once and shared by
    every method run on the same simulation (a cached value keeps the time it took, so each
    run's latency breakdown still shows it). Renders are cached by content (see the module
    docstring).

    Parameters
    ----------
    bundle : path or Bundle
    poses : path or PoseTrace
        The viewer's headset pose log (y up; mapped into the scene by ``mapping``).
    bandwidth_bytes : int array [T]
        Bytes the link allows per slot; T is the number of slots.
    config : SimConfig
    reference : SplatScene, path or None
        The full teacher scene the renders are scored against; None: the bundle's largest model.
    mapping : PoseMapping, optional
        Head pose -> camera (default: :data:`l3gs_opt.pipeline.scene_instance.Z_UP_MAPPING`, z-up scenes).
    utility_tables : mapping view or (utility, view) -> UtilityTable, optional
        Tables for ``utility_mode="table"``, labelled like the view's (object, level) cells: under a
        view, Eq. 1's; under (utility, view), that utility's (e.g. a server's tables,
        :mod:`l3gs_opt.delivery.tables`). A missing one is built on a 3 x 3 grid over the viewer's
        positions (12 yaws x 3 pitches).
    info : mapping, optional
        Free-form provenance copied into every summary (e.g. the trace window).
    cache_dir : path, optional
        Also keep the reference images on disk there (one ``.npy`` per camera and teacher), so
        later processes scoring the same teacher from the same path render none.
    render_cache, view_cache : RenderCache, optional
        Caches for reference images and client views (default: the process-wide
        :data:`l3gs_opt.simulator.render.REFERENCE_CACHE` and ``VIEW_CACHE``).
    """

    def __init__(self, bundle, poses, bandwidth_bytes: Sequence[int], *, config: SimConfig = SimConfig(),
                 reference=None, mapping=None, utility_tables: Mapping[str, Any] | None = None,
                 info: Mapping[str, Any] | None = None, cache_dir: str | os.PathLike | None = None,
                 render_cache=None, view_cache=None):
        from l3gs_opt.scene.camera_paths import intrinsics_from_fov
        from l3gs_opt.traces.poses import PoseTrace, read_pose_log
        from l3gs_opt.pipeline.scene_instance import Z_UP_MAPPING, read_delivery_bundle
        from l3gs_opt.scene.scene_files import read_scene
        from l3gs_opt.scene.splats import SplatScene
        from l3gs_opt.simulator.render import REFERENCE_CACHE, VIEW_CACHE, RenderCache, render_backend
        if not isinstance(config, SimConfig):
            raise SimulationError("config", f"{type(config).__name__} is not a SimConfig")
        self.config = config
        self.bundle = read_delivery_bundle(bundle)
        self.poses = poses if isinstance(poses, PoseTrace) else read_pose_log(poses)
        self.link_bytes = [int(b) for b in Link(list(bandwidth_bytes)).bandwidth]   # validated there
        if not self.link_bytes:
            raise SimulationError("bandwidth_bytes", "needs at least one slot")
        self.T = len(self.link_bytes)
        last_start = config.pose_start_s + (self.T - 1) * config.slot_s
        if self.poses.time_s[-1] < last_start:
            raise SimulationError("path", f"the poses end at {self.poses.time_s[-1]:.1f} s, before the last slot "
                                          f"starts ({last_start:.1f} s): fewer slots, or a longer log")
        self.mapping = mapping or Z_UP_MAPPING
        self.intrinsics = intrinsics_from_fov(config.width, config.height, config.fov_deg)
        self.info = dict(info or {})
        self._base = _base_scene(self.bundle)
        self.scene = self._base[0]
        self._catalogs: dict[str, Catalog] = {}
        #: Eq. 1 tables given by the caller (by view), and every table built or taken (by (utility, view)).
        self.given_tables = dict(utility_tables or {})
        self.tables: dict[tuple[str, str], Any] = {}
        #: Per-splat values of held-free utilities, by (slot, utility name); prepared scenes by utility name.
        self.values_cache: dict[tuple[int, str], np.ndarray] = {}
        self._prepared: dict[str, Any] = {}
        self._valuations: dict[tuple[str, str], Valuation] = {}
        if isinstance(reference, (str, os.PathLike)):
            self.reference_label = f"teacher:{reference}"
            reference = read_scene(reference)
        elif isinstance(reference, SplatScene):
            self.reference_label = "given"
        elif reference is None:
            self.reference_label = "bundle:largest"
        else:
            raise SimulationError("reference", f"{type(reference).__name__}: must be a SplatScene, a PLY path or None")
        self._reference = reference
        self._pred: dict[int, dict] = {}
        self._ref: dict[int, tuple] = {}
        self.render_backend = render_backend()
        self.reference_cache = render_cache if render_cache is not None else (
            RenderCache(directory=cache_dir) if cache_dir is not None else REFERENCE_CACHE)
        self.view_cache = view_cache if view_cache is not None else VIEW_CACHE
        #: Renders done by this simulation: ``view`` and ``reference``, and cache hits ``*_reused``.
        self.renders = {"view": 0, "view_reused": 0, "reference": 0, "reference_reused": 0}
        self._fingerprints: dict[str, bytes] = {}
        self._distill: tuple | None = None

    # -- per-slot inputs shared by all methods -------------------------------------------
    def reload_scene(self, bundle) -> None:
        """Take the splats of ``bundle`` from now on (a client whose bundle fills as bytes arrive,
        :mod:`l3gs_opt.delivery.fetch`): the rows, their objects and levels must stay the ones the
        catalogues were built on; renders are keyed by the new content.

        Raises
        ------
        SimulationError
            ``bundle`` puts a row in another object or level.
        """
        base = _base_scene(bundle)
        if not (np.array_equal(base[1], self._base[1]) and np.array_equal(base[2], self._base[2])):
            raise SimulationError("bundle", "a reloaded bundle moved rows between objects or levels")
        self._base, self.scene = base, base[0]
        self._fingerprints.clear()

    def catalog(self, view: str) -> Catalog:
        if view not in self._catalogs:
            self._catalogs[view] = build_catalog(self.bundle, view, base=self._base)
        return self._catalogs[view]

    def cameras_of(self, poses: np.ndarray) -> list:
        """Cameras (the config's intrinsics) of head poses ``[n, 6]`` (position, yaw/pitch/roll)."""
        from l3gs_opt.scene.cameras import Camera
        from l3gs_opt.traces.predictors import wrap_deg

        w2c = self.mapping.world_to_camera(poses[:, :3], wrap_deg(poses[:, 3:]))
        return [Camera(**self.intrinsics, world_to_camera=m) for m in w2c]

    def _predicted_bytes(self, t: int, history: Sequence[int] | None = None, clients: int = 1) -> int:
        """Predicted bytes of slot ``t`` from ``history`` (bytes per earlier slot; default the trace's)
        times ``bandwidth_bias``; slot 0 and ``oracle``: the trace's bytes / ``clients`` (a shared
        link's equal share)."""
        from l3gs_opt.traces.predictors import predict_bandwidth

        cfg = self.config
        b = self.link_bytes if history is None else list(history)
        if cfg.bandwidth_predictor == "oracle" or t == 0:
            value = self.link_bytes[t] // clients   # slot 0: the manifest fetch's throughput
        elif cfg.bandwidth_predictor == "last":
            value = b[t - 1]
        else:
            window = min(cfg.bandwidth_window, t)
            hist = np.asarray(b[:t] + [0], dtype=np.float64)   # the 0 stands for the unknown slot t
            value = predict_bandwidth(hist, window=window, robust=cfg.robust)[t]
        return int(math.floor(value * cfg.bandwidth_bias))

    def prediction(self, t: int) -> dict:
        """Slot ``t``'s predicted cameras and bytes, cached."""
        if t in self._pred:
            return self._pred[t]
        from l3gs_opt.traces.predictors import predict_viewport
        from l3gs_opt.pipeline.scene_instance import _pose_at, _predicted_poses

        cfg = self.config
        t0 = time.perf_counter()
        start = cfg.pose_start_s + t * cfg.slot_s
        times = start + (np.arange(cfg.samples_per_slot) + 0.5) * cfg.slot_s / cfg.samples_per_slot
        if cfg.viewport == "oracle":
            poses = _pose_at(self.poses, times)
        elif cfg.viewport == "lr":
            poses = _predicted_poses(self.poses, start, times, cfg.hw_s)
        else:
            past = self.poses.features[self.poses.time_s < start]
            last = past[-1:] if len(past) else self.poses.features[:1]
            poses = predict_viewport(last, len(times), method="last")
        cams = self.cameras_of(poses)
        predicted = self._predicted_bytes(t)
        self._pred[t] = {"cameras": cams, "predicted_bytes": predicted, "prediction_s": time.perf_counter() - t0}
        return self._pred[t]

    def prepared(self, utility: Any) -> Any:
        """``utility.prepare(scene)``, once per utility name."""
        if utility.name not in self._prepared:
            self._prepared[utility.name] = utility.prepare(self.scene)
        return self._prepared[utility.name]

    def valuation(self, utility: str | None = None, order_utility: str | None = None) -> Valuation:
        """The :class:`Valuation` of a (utility, order utility) pair (default: the config's)."""
        utility = utility or self.config.utility
        order = order_utility or self.config.order_utility or utility
        if (utility, order) not in self._valuations:
            self._valuations[(utility, order)] = Valuation(self, utility, order)
        return self._valuations[(utility, order)]

    def splat_values(self, t: int, utility: str | None = None, held: np.ndarray | None = None) -> np.ndarray:
        """Per-splat values of ``utility`` (default the config's) over slot ``t``'s predicted viewpoints."""
        val = self.valuation(utility)
        return val.splat_values(val.utility, t, held)

    def true_camera(self, t: int):
        from l3gs_opt.pipeline.scene_instance import _pose_at

        end = self.config.pose_start_s + (t + 1) * self.config.slot_s
        return self.cameras_of(_pose_at(self.poses, np.array([end])))[0]

    # -- rendering ------------------------------------------------------------------------
    def _render(self, scene, camera) -> np.ndarray:
        from l3gs_opt.simulator.render import render_image

        return render_image(scene, camera, self.render_backend)

    def _fingerprint(self, what: str) -> bytes:
        if what not in self._fingerprints:
            from l3gs_opt.simulator.render import scene_fingerprint

            if what == "reference":
                self._fingerprints[what] = scene_fingerprint(self.reference_scene())
            else:   # the bundle scene (with the distill compact SH when views mix them)
                extra = (self.distill_arrays()[0],) if what == "distill" else ()
                self._fingerprints[what] = scene_fingerprint(self.scene, *extra)
        return self._fingerprints[what]

    def reference_scene(self):
        """The scene renders are scored against (the teacher, or the bundle's largest model)."""
        if self._reference is None:
            cat = self.catalog("scene")
            rows = np.concatenate([cat.rows[k] for k in cat.top_units()])
            self._reference = self.scene.subset(np.sort(rows))
        return self._reference

    def reference_image(self, t: int) -> tuple[np.ndarray, float]:
        """The reference scene seen from slot ``t``'s true viewpoint, and the seconds this call took
        (cached per slot, and by content across simulations: see the module docstring)."""
        t0 = time.perf_counter()
        if t not in self._ref:
            from l3gs_opt.simulator.render import camera_key

            camera = self.true_camera(t)
            key = self.reference_cache.key(b"reference", self.render_backend.encode(),
                                           self._fingerprint("reference"), camera_key(camera))
            image = self.reference_cache.get(key)
            if image is None:
                image = self._render(self.reference_scene(), camera)
                self.reference_cache.put(key, image)
                self.renders["reference"] += 1
            else:
                self.renders["reference_reused"] += 1
            self._ref[t] = image
        return self._ref[t], time.perf_counter() - t0

    def distill_arrays(self) -> tuple[np.ndarray, np.ndarray]:
        """``distill`` bundles: per row of :attr:`scene` the zero-padded compact SH ``[N, K, 3]`` and
        the upgrade's share ``f`` of the splat's utility ``[N]`` (``SimConfig.sh_upgrade_utility``)."""
        if self._distill is None:
            if self.bundle.manifest["variant"] != "distill":
                raise SimulationError("view", "compact SH exists only in distill bundles")
            full = self.scene.sh
            compact = compact_sh(self.bundle, full.shape[1])
            ck = (self.bundle.manifest["compact_sh_degree"] + 1) ** 2
            self._distill = (compact, upgrade_fraction(full, compact, self.config.sh_upgrade_utility, ck))
        return self._distill

    def client_image(self, rows: np.ndarray, full_sh: np.ndarray | None, camera) -> tuple[np.ndarray, bool]:
        """What the client shows: rows of :attr:`scene` (``full_sh``: per row, whether its full SH
        arrived; None: all full) seen by ``camera``, and whether the image came from the cache."""
        if rows.size == 0:
            return self._render(None, camera), False
        from l3gs_opt.simulator.render import camera_key

        mixed = full_sh is not None and not full_sh.all()
        key = self.view_cache.key(b"view", self.render_backend.encode(),
                                  self._fingerprint("distill" if mixed else "scene"),
                                  np.ascontiguousarray(rows, np.int64).tobytes(),
                                  np.packbits(full_sh).tobytes() if mixed else b"", camera_key(camera))
        image = self.view_cache.get(key)
        if image is not None:
            self.renders["view_reused"] += 1
            return image, True
        scene = self.scene.subset(rows)
        if mixed:
            compact = self.distill_arrays()[0][rows]
            scene = dataclasses.replace(scene, sh=np.where(full_sh[:, None, None], scene.sh, compact))
        image = self._render(scene, camera)
        self.view_cache.put(key, image)
        self.renders["view"] += 1
        return image, False

    # -- utilities ------------------------------------------------------------------------
    def slot_inputs(self, t: int, cat: Catalog, history: Sequence[int], clients: int = 1, *,
                    utility: str | None = None, order_utility: str | None = None,
                    held: np.ndarray | None = None) -> SlotInputs:
        """Slot ``t``'s inputs for a client on ``cat`` whose earlier slots delivered ``history``
        (bytes per slot), one of ``clients`` on the link, valued by ``utility`` (splats ordered by
        ``order_utility``; defaults: the config's) given the rows it holds (``held``, a mask over
        :attr:`scene`; used by held-aware utilities): what it is handed, rather than asking."""
        pred = self.prediction(t)
        val = self.valuation(utility, order_utility)
        unit_utility, utility_s = val.unit_values(t, cat, held)
        values = val.value_source(t, cat, held) if self.config.last_chunk == "prefix" else None
        return SlotInputs(slot=t, prediction=pred, unit_utility=unit_utility, lookup_s=utility_s,
                          predicted_bytes=self._predicted_bytes(t, history, clients),
                          splat_order=lambda k: val.splat_order(t, cat, k, held), splat_values=values)

    # -- one method ----------------------------------------------------------------------
    def spec(self, method: "str | MethodSpec", solver: str | None = None, *, utility: str | None = None,
             order_utility: str | None = None) -> MethodSpec:
        """The :class:`MethodSpec` of ``method`` for this bundle and config, with its utilities
        (``utility`` and ``order_utility``; defaults: the spec's own, then the config's)."""
        if isinstance(method, MethodSpec):
            if solver is not None:
                raise SimulationError("solver", "give it in the MethodSpec")
            spec = method
        else:
            m = self.bundle.manifest
            spec = method_spec(method, solver=solver, representation=m["representation"], variant=m["variant"],
                               config=self.config)
        utility = utility or spec.utility or self.config.utility
        order = order_utility or spec.order_utility or self.config.order_utility or utility
        self.valuation(utility, order)   # checks both names now
        stream = "file" if self.config.splat_order == "stored" else spec.order
        return dataclasses.replace(spec, utility=utility, order_utility=order, order=stream)

    def run_id(self, spec: MethodSpec, client: int | None = None, clients: int = 1) -> str:
        """Digest of everything that decides a run of ``spec`` (see :mod:`l3gs_opt.simulator.records`)."""
        poses = hashlib.sha1()
        for a in (self.poses.time_s, self.poses.position, self.poses.rotation_deg):
            poses.update(np.ascontiguousarray(a, np.float64).tobytes())
        manifest = hashlib.sha1(json.dumps(self.bundle.manifest, sort_keys=True).encode()).hexdigest()
        return run_id({"bundle": str(self.bundle.path), "manifest": manifest, "poses": poses.hexdigest(),
                       "mapping": repr(self.mapping), "bandwidth": self.link_bytes, "reference": self.reference_label,
                       "config": dataclasses.asdict(self.config), "method": spec.name, "solver": spec.solver,
                       "view": spec.view, "order": spec.order, "preload": spec.preload,
                       "scheduler": type(spec.scheduler).__name__, "client": client, "clients": clients,
                       "utility": spec.utility, "order_utility": spec.order_utility})

    def run(self, method: "str | MethodSpec", *, solver: str | None = None, utility: str | None = None,
            order_utility: str | None = None, out_dir: str | os.PathLike | None = None,
            progress: bool = False, resume: bool = False,
            views_dir: str | os.PathLike | None = None) -> SimulationResult:
        """Simulate ``method`` over every slot (see the module docstring).

        Parameters
        ----------
        method : str or MethodSpec
            One of :data:`SIM_METHODS` or a solver method name; a :class:`MethodSpec` runs any
            :class:`Scheduler` (how new methods plug in).
        solver : str, optional
            The solver of ``l3gs``, ``l3gs-noseg``, ``separate`` (a single-slot solver, default
            ``bb``), ``distill`` and ``hierarchy`` (one of :data:`ITEM_SOLVERS`, default ``bb``).
        utility, order_utility : str, optional
            The splat utility that values units, and the one that orders splats inside a unit
            (:func:`l3gs_opt.pipeline.utilities.utility_names`; defaults ``config.utility``, then
            ``config.order_utility`` or ``utility``). Both are part of the run's identity.
        out_dir : path, optional
            Append one JSON line per slot to ``OUT/slots.jsonl`` as it finishes, and the summary
            to ``OUT/summary.jsonl``; earlier lines of the same method and solver are replaced.
        progress : bool
            A tqdm bar over the slots (stderr).
        resume : bool
            Continue from the slots of this method already in ``OUT/slots.jsonl`` (needs
            ``out_dir``); nothing recorded: a fresh run.
        views_dir : path, optional
            Keep what the viewer saw: each slot's client image and reference image as PNG files
            in this folder (:class:`l3gs_opt.simulator.client.Client`; ``l3gs-opt replay`` shows
            them), written as the slots finish.

        Returns
        -------
        SimulationResult

        Raises
        ------
        SimulationError
            Bad method or solver; ``resume`` without ``out_dir``, or with records from a run
            with other inputs or that the replay does not reproduce.
        """
        from l3gs_opt.simulator.client import Client, drive

        if resume and out_dir is None:
            raise SimulationError("resume", "needs out_dir (the folder with slots.jsonl)")
        client = Client(self, self.spec(method, solver, utility=utility, order_utility=order_utility),
                        out_dir=out_dir, resume=resume, views_dir=views_dir)
        drive([client], self.link_bytes, start=client.first_slot, progress=progress)
        return client.finish()

    def check_requests(self, wanted, view: SlotView, method: str) -> list[int]:
        """Unit ids of a scheduler's requests, each checked against ``view``."""
        grid = view.cost.shape
        what = "(object, level) pairs" if len(grid) == 2 else "(object, level, form) triples"
        taken = view.taken()
        listed = np.zeros(grid, bool)
        ids = []
        for i, req in enumerate(wanted):
            try:
                u = tuple(int(v) for v in req)
            except (TypeError, ValueError):
                u = ()
            if len(u) != len(grid):
                raise SimulationError("requests", f"{req!r}: scheduler {method!r} must return {what}", i)
            if not all(0 <= v < n for v, n in zip(u, grid)):
                raise SimulationError("requests", f"{u} is outside the {' x '.join(map(str, grid))} units", i)
            if taken[u] or listed[u]:
                kind = "requested twice" if listed[u] else ("empty" if view.empty[u] else "held or in flight")
                raise SimulationError("requests", f"{u} is {kind} (scheduler {method!r})", i)
            for p in reversed(view.prerequisites(u)):
                if not (taken[p] or listed[p]):
                    before = f"its layer {p[1]}" if len(grid) == 2 else str(p)
                    raise SimulationError("requests", f"{u} before {before} (scheduler {method!r})", i)
            listed[u] = True
            ids.append(int(np.ravel_multi_index(u, grid)))
        return ids

    def shown_rows(self, cat: Catalog, got: np.ndarray, complete: np.ndarray, order: list,
               preload: bool) -> tuple[np.ndarray, set, np.ndarray | None]:
        """Rows the client shows (sorted), the units they come from, and (``distill`` view) per
        row whether its SH upgrade arrived (else None: every row shows its full SH)."""
        J, L = cat.shape
        F = len(cat.forms)
        parts, units, upgraded = [], set(), []
        if cat.representation == "layered":
            for k in range(cat.units):
                if not cat.splats[k]:
                    continue
                n = cat.splats[k] if complete[k] else int(got[k] // cat.bytes_per_splat[k])
                if n > 0:
                    prefix = (order[k] if order[k] is not None else cat.rows[k])[:n]
                    (upgraded if F > 1 and k % F == 1 else parts).append(prefix)
                    units.add(k)
        else:
            for j in range(J):
                done = [l for l in range(L) if complete[j * L + l] and cat.splats[j * L + l]]
                if done:
                    k = j * L + max(done)
                    parts.append(cat.rows[k])
                    units.add(k)
        rows = np.sort(np.concatenate(parts)) if parts else np.zeros(0, np.int64)
        if F == 1:
            return rows, units, None
        full = np.isin(rows, np.concatenate(upgraded)) if upgraded else np.zeros(rows.size, bool)
        return rows, units, full


def simulate(bundle, poses, bandwidth_bytes: Sequence[int], method: str, *, solver: str | None = None,
             config: SimConfig = SimConfig(), reference=None, mapping=None, out_dir=None,
             progress: bool = False, resume: bool = False, cache_dir=None,
             utility: str | None = None) -> SimulationResult:
    """One method over one bundle, viewer and link (:class:`Simulation` + :meth:`Simulation.run`).

    Example
    -------
    >>> from l3gs_opt.simulator.simulation import simulate, trace_bytes        # doctest: +SKIP
    >>> bw, _ = trace_bytes("lumos-throughput-mid-11", mbps=2.0, slots=20)   # doctest: +SKIP
    >>> r = simulate("bundle/", "viewer.log", bw, "l3gs")         # doctest: +SKIP
    >>> r.ssim_mean, r.summary["bytes_delivered"]                 # doctest: +SKIP
    """
    sim = Simulation(bundle, poses, bandwidth_bytes, config=config, reference=reference, mapping=mapping,
                     cache_dir=cache_dir)
    return sim.run(method, solver=solver, utility=utility, out_dir=out_dir, progress=progress, resume=resume)
