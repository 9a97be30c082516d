"""Options and the error type of the delivery simulator (:mod:`l3gs_opt.simulator.simulation`)."""

from __future__ import annotations

import math
from dataclasses import dataclass
from typing import Callable

import numpy as np

from l3gs_opt.checks import as_float, is_real, shown
from l3gs_opt.errors import L3gsError, SolveError
from l3gs_opt.problem.arguments import check_time_limit
from l3gs_opt.scene.camera_paths import intrinsics_from_fov
from l3gs_opt.scene.cameras import MAX_IMAGE_PIXELS, MAX_IMAGE_SIDE, CameraError
from l3gs_opt.simulator.last_chunk import LAST_CHUNKS
from l3gs_opt.simulator.link import BUDGETS, CARRIES
from l3gs_opt.traces.bandwidth import MAX_TRACE_SAMPLES

__all__ = ["SimulationError", "SimConfig", "SlotInputs", "TIMING_KEYS", "SH_UPGRADE_UTILITIES"]

#: Per-slot timings kept in every slot record (seconds).
TIMING_KEYS = ("prediction", "utility", "scheduling", "rendering", "reference", "metrics")
#: Named proxies for the utility of a distill SH upgrade (a number in [0, 1] is a fixed fraction).
SH_UPGRADE_UTILITIES = ("residual", "bands")
_VIEWPORT = ("lr", "last", "oracle")
_BANDWIDTH = ("harmonic", "last", "oracle")
_UTILITY_MODES = ("exact", "table")
#: How the splats of a unit are ordered on the wire (``SimConfig.splat_order``).
SPLAT_ORDERS = ("method", "stored")
#: Longest viewport history window ``hw_s`` (seconds): 11.6 days, longer than any pose log the
#: readers take (``MAX_POSE_FILE_BYTES``: ~250,000 poses). A longer window holds the same samples
#: as the whole log, so a larger value is a typo (``hw_s=1e300``), not a setting.
MAX_HW_S = 1e6


class SimulationError(L3gsError, ValueError):
    """Bad simulator input (method, option, bundle, pose log); names the field, and the index where one is at fault."""

    def __init__(self, field: str, message: str, index: int | None = None):
        self.field = field
        self.index = index
        super().__init__(f"{field}{'' if index is None else f'[{index}]'}: {message}")


@dataclass(frozen=True)
class SimConfig:
    """Options of a simulation (see :mod:`l3gs_opt.simulator.simulation`).

    Parameters
    ----------
    slot_s : float
        Slot length, seconds.
    budget : {"per_slot", "cumulative"}
        Idle bytes lost, or banked for the next slot.
    width, height : int
        Rendered (and utility) image size in pixels: 11..:data:`~l3gs_opt.scene.cameras.MAX_IMAGE_SIDE`
        a side, at most :data:`~l3gs_opt.scene.cameras.MAX_IMAGE_PIXELS` in all (a Camera's limits).
    fov_deg : float
        Horizontal field of view, degrees, in [1, 170] (what
        :func:`~l3gs_opt.scene.camera_paths.intrinsics_from_fov` builds the cameras from).
    samples_per_slot : int
        Predicted viewpoints per slot whose utilities are averaged.
    viewport : {"lr", "last", "oracle"}
        Viewport predictor; ``hw_s``: its history window, seconds (at most :data:`MAX_HW_S`).
    bandwidth_predictor : {"harmonic", "last", "oracle"}
        ``bandwidth_window``: slots in the harmonic mean (at most
        :data:`~l3gs_opt.traces.bandwidth.MAX_TRACE_SAMPLES`); ``robust`` (a bool): RobustMPC's discount.
    utility : str
        The splat utility that values the units (a name of
        :func:`l3gs_opt.pipeline.utilities.utility_names`; default ``eq1``, the paper's Eq. 1).
    utility_mode : {"exact", "table"}
        The utility per predicted viewpoint, or a lookup in a viewpoint table of it
        (:meth:`l3gs_opt.pipeline.splat_utility.UtilityTable.lookup` with its defaults; held-free
        utilities only).
    order_utility : str or None
        The utility that orders the splats inside a unit as it streams (None: ``utility``).
    splat_order : {"method", "stored"}
        ``method``: as the method says (the utility-scheduled methods stream a unit's splats in
        descending predicted utility: a server that reorders them per request); ``stored``: every
        unit in its chunks' file order (chunk after chunk, records in order), as a client fetching
        static chunk files by HTTP Range receives them (what ``l3gs-opt fetch`` sees).
    pose_start_s : float
        Pose-log time of slot 0's start, seconds.
    time_limit_s : float or None
        Seconds per scheduling call (passed to the solver), > 0; None or ``inf``: no limit (stored
        as None, as :func:`l3gs_opt.methods.solve` reads it).
    horizon : int or None
        Multi-slot methods plan at most this many slots ahead (None: the rest of the run; at most
        :data:`~l3gs_opt.traces.bandwidth.MAX_TRACE_SAMPLES`).
    fill : bool
        Keep the link busy after the slot's picks (see the module docstring); a bool, not a truthy value.
    backend : str
        ILP backend of ``ilp``, ``mpc:H``, ``rolling:ilp``: a name of :class:`l3gs_opt.models.Backend`
        (checked here; whether it is installed, when a solve runs).
    substeps : int
        Re-plan points per slot (beyond the paper): the slot's bytes are split into this many
        equal parts and before each part the scheduler plans again with the bytes the client
        measured so far in the slot (1: plan once per slot, as in the paper).
    bandwidth_bias : float
        The predicted bytes of a slot are multiplied by this (> 0): 1 is the predictor as is,
        above 1 an over-optimistic predictor (for sensitivity studies).
    carry : {"started", "head"}
        What a slot's cut keeps in flight (:data:`l3gs_opt.simulator.link.CARRIES`): only a unit
        that got bytes (``started``, the default), or also the first request still waiting for
        its first byte (``head``: the request on the wire; ``l3gs-opt fetch`` then keeps it open
        across the cut instead of aborting it).
    decision_s : float
        Seconds the client takes to plan at each re-plan point after the first (>= 0; 0, the
        paper's model: requests go out as the slot starts). Meanwhile only the unit carried over
        streams; the bytes of that time it cannot use are lost (idle), as ``l3gs-opt fetch``
        measures them (its records' ``late_s``).
    last_chunk : {"whole", "prefix"}
        What the per-slot MCKP of ``l3gs`` and ``l3gs-noseg`` counts: whole chunks only (the
        paper's model), or also the first splats of the one chunk the slot's bytes end inside
        (:mod:`l3gs_opt.simulator.last_chunk`; needs per-splat values: ``utility_mode`` exact and
        a utility without its own chunk values).
    sh_upgrade_utility : {"residual", "bands"} or float
        How a ``distill`` splat's Eq. 1 utility ``u`` is split between its compact form and its
        SH upgrade (Eq. 1 is colour-blind): the upgrade gets ``u * f``, the compact form
        ``u * (1 - f)``. ``residual``: ``f`` is the share of the splat's SH energy the compact
        fit misses, ``|sh - compact|^2 / |sh|^2`` (by SH orthonormality, the relative mean
        squared colour error over all view directions); ``bands``: the share in the bands above
        the compact degree; a number in [0, 1]: that fixed fraction. ``residual`` is the
        default because a distill bundle's compact SH is a fit to the full colour over the
        training views, not a truncation: what the upgrade adds is what the fit misses (for a
        truncation the two proxies agree), and unlike a fixed fraction it gives a nearly diffuse
        splat's upgrade almost nothing. Splitting ``u`` (rather than giving the upgrade ``u * f``
        on top) keeps a whole layer worth its Eq. 1 utility, as in every other method.
    """

    slot_s: float = 1.0
    budget: str = "per_slot"
    width: int = 160
    height: int = 120
    fov_deg: float = 70.0
    samples_per_slot: int = 2
    viewport: str = "lr"
    hw_s: float = 0.5
    bandwidth_predictor: str = "harmonic"
    bandwidth_window: int = 5
    robust: bool = False
    utility: str = "eq1"
    utility_mode: str = "exact"
    order_utility: str | None = None
    splat_order: str = "method"
    pose_start_s: float = 0.0
    time_limit_s: float | None = None
    horizon: int | None = None
    fill: bool = True
    backend: str = "highs"
    substeps: int = 1
    bandwidth_bias: float = 1.0
    carry: str = "started"
    decision_s: float = 0.0
    sh_upgrade_utility: str | float = "residual"
    last_chunk: str = "whole"

    def __post_init__(self) -> None:
        def positive(name: str, integer: bool = False) -> None:
            v = getattr(self, name)
            ok = isinstance(v, (int, np.integer)) if integer else isinstance(v, (int, float, np.integer, np.floating))
            if isinstance(v, bool) or not ok or not math.isfinite(as_float(v)) or v <= 0:
                kind = "a positive integer" if integer else "a positive number"
                raise SimulationError(name, f"{shown(v)}: must be {kind}")

        for name in ("slot_s", "fov_deg", "hw_s", "bandwidth_bias"):
            positive(name)
        for name in ("width", "height", "samples_per_slot", "bandwidth_window", "substeps"):
            positive(name, integer=True)
        d = self.decision_s
        if isinstance(d, bool) or not isinstance(d, (int, float, np.integer, np.floating)) \
                or not math.isfinite(as_float(d)) or not 0 <= d <= self.slot_s / self.substeps:
            raise SimulationError("decision_s", f"{shown(d)}: must be seconds in [0, slot_s / substeps]")
        # Each is work per slot: a huge value is a typo that would run for days, not a setting.
        from l3gs_opt.pipeline.counts import MAX_SAMPLES_PER_SLOT, MAX_SUBSTEPS, check_count

        check_count("samples_per_slot", self.samples_per_slot, high=MAX_SAMPLES_PER_SLOT, error=SimulationError)
        check_count("substeps", self.substeps, high=MAX_SUBSTEPS, error=SimulationError)
        # Every slot renders images of this size: the Camera's limits (and words), checked before any slot runs.
        for name in ("width", "height"):
            if getattr(self, name) > MAX_IMAGE_SIDE:
                raise SimulationError(name, f"{getattr(self, name)} must be a positive integer <= {MAX_IMAGE_SIDE} "
                                            f"(MAX_IMAGE_SIDE)")
        if self.width * self.height > MAX_IMAGE_PIXELS:
            raise SimulationError("width", f"{self.width} x {self.height} = {self.width * self.height:,} pixels, more "
                                           f"than {MAX_IMAGE_PIXELS:,} (MAX_IMAGE_PIXELS)")
        if self.width < 11 or self.height < 11:
            raise SimulationError("width", f"{self.width}x{self.height}: SSIM needs at least 11x11 pixels")
        # The cameras the simulation builds from these (fov_deg in [1, 170]): refused here rather
        # than when the run starts; a field of view of 180 or more has no pinhole focal length.
        try:
            intrinsics_from_fov(int(self.width), int(self.height), self.fov_deg)
        except CameraError as exc:
            message = str(exc).split(": ", 1)[-1]
            raise SimulationError("fov_deg", message) from None
        # Slots are trace samples: a window or horizon longer than the longest trace means "all of it".
        in_trace = lambda f, m: SimulationError(f, f"{m} slots (MAX_TRACE_SAMPLES)")  # noqa: E731
        check_count("bandwidth_window", self.bandwidth_window, high=MAX_TRACE_SAMPLES, error=in_trace)
        if self.hw_s > MAX_HW_S:
            raise SimulationError("hw_s", f"{shown(self.hw_s)}: must be at most {MAX_HW_S:g} seconds (MAX_HW_S)")
        # Flags are bools, as Options.same_slot_layers: "no" is truthy and would switch them on.
        for name in ("robust", "fill"):
            v = getattr(self, name)
            if not isinstance(v, (bool, np.bool_)):
                raise SimulationError(name, f"{v!r}: must be true or false")
            object.__setattr__(self, name, bool(v))
        # The backend's name only (models is a lower layer): whether it is installed is the solve's question.
        from l3gs_opt.models import Backend

        try:
            Backend.parse(self.backend)
        except (SolveError, TypeError):
            raise SimulationError("backend", f"{self.backend!r} is not one of "
                                             f"{', '.join(b.value for b in Backend)}") from None
        for name, allowed in (("budget", BUDGETS), ("viewport", _VIEWPORT), ("bandwidth_predictor", _BANDWIDTH),
                              ("utility_mode", _UTILITY_MODES), ("splat_order", SPLAT_ORDERS),
                              ("carry", CARRIES), ("last_chunk", LAST_CHUNKS)):
            if getattr(self, name) not in allowed:
                raise SimulationError(name, f"{getattr(self, name)!r} is not one of {', '.join(allowed)}")
        from l3gs_opt.pipeline.utilities import UtilityNameError, get_utility, utility_names

        for name in ("utility", "order_utility"):
            v = getattr(self, name)
            if v is None and name == "order_utility":
                continue
            if v in _UTILITY_MODES:
                raise SimulationError(name, f"{v!r} is a utility mode: use utility_mode={v!r} (utility names a splat "
                                            f"utility: {', '.join(utility_names())})")
            try:
                get_utility(v)
            except UtilityNameError as exc:
                raise SimulationError(name, str(exc)) from None
        self._check_time_limit()
        if self.horizon is not None:
            positive("horizon", integer=True)
            check_count("horizon", self.horizon, high=MAX_TRACE_SAMPLES, error=in_trace)
        p = self.pose_start_s
        if not is_real(p) or not math.isfinite(as_float(p)) or p < 0:
            raise SimulationError("pose_start_s", f"{shown(p)}: must be a number >= 0 (seconds)")
        f = self.sh_upgrade_utility
        if isinstance(f, str):
            if f not in SH_UPGRADE_UTILITIES:
                raise SimulationError("sh_upgrade_utility", f"{f!r} is not one of {', '.join(SH_UPGRADE_UTILITIES)} "
                                                            "or a number in [0, 1]")
        elif isinstance(f, bool) or not isinstance(f, (int, float, np.integer, np.floating)) \
                or not (0.0 <= as_float(f) <= 1.0):
            raise SimulationError("sh_upgrade_utility", f"{shown(f)}: must be 'residual', 'bands' or a number in [0, 1]")

    def _check_time_limit(self) -> None:
        """``time_limit_s`` by solve()'s own rule (:func:`~l3gs_opt.problem.arguments.check_time_limit`):
        ``inf`` is no limit, stored as None, so that the config says what every solve call gets."""
        v = self.time_limit_s
        try:
            seconds = check_time_limit(v)
        except SolveError as exc:   # "time_limit_s = -1: must be ...": the value, then solve()'s words
            raise SimulationError("time_limit_s", f"{shown(v)}: {str(exc).rsplit(': ', 1)[-1]}") from None
        object.__setattr__(self, "time_limit_s", seconds)


@dataclass(frozen=True)
class SlotInputs:
    """What :class:`~l3gs_opt.simulator.simulation.Simulation` hands a client at the start of a slot.

    ``prediction``: the slot's predicted cameras (and, in exact mode, the predicted per-splat
    utility); ``unit_utility``: predicted utility per unit (shape of the client's catalogue grid);
    ``lookup_s``: seconds the utility look-up took; ``predicted_bytes``: the bandwidth predictor's
    bytes for the slot; ``splat_order(k)``: the rows of unit ``k`` in the order they are sent
    (descending predicted utility); ``splat_values()`` (``last_chunk="prefix"``, else None): the
    value utility's predicted per-splat values, computed on the first call.
    """

    slot: int
    prediction: dict
    unit_utility: np.ndarray
    lookup_s: float
    predicted_bytes: int
    splat_order: Callable[[int], np.ndarray]
    splat_values: Callable[[], np.ndarray] | None = None

