"""Synthetic L3GS-like instances: a real bandwidth trace and a walking viewer among objects.

The scene: J objects at random places in a square room (``room_m`` metres), each with a share
of ``total_splats`` splats (Dirichlet), split into L equal layers (layered) or L nested
versions (separate, version l = the first l+1 layers trained alone). Costs are splats times
``bytes_per_splat`` (248 B: 62 float32 per splat, SH degree 3 with normals, as the L3GS code
stores them). A viewer walks through the room at ``speed_mps`` with a slowly turning heading;
an object's utility at slot t is ``splats x visibility x closeness`` with a soft field-of-view
cone and ``1 / max(distance, 0.5 m)``, shared across layers with diminishing returns
(``layer_decay ** l``), in the spirit of the paper's Eq. 1 (a real scene's utilities come from
the utility issue). Everything is seeded and recorded in ``meta``.
"""

from __future__ import annotations

import math

import numpy as np

from l3gs_opt.errors import InstanceError
from l3gs_opt.problem.instance import Instance, Options
from l3gs_opt.traces.bandwidth import mbps_to_bytes, read_bandwidth_trace

__all__ = ["DEFAULT_TRACE", "BYTES_PER_SPLAT", "MAX_SYNTH_ENTRIES", "synth_instance", "walking_viewer"]

DEFAULT_TRACE = "lumos-throughput-mid-11"
BYTES_PER_SPLAT = 248
#: Most utility entries (slots x objects x layers) of a synthetic instance: the generator holds a
#: few arrays of this size at once (about 1 GB at the limit).
MAX_SYNTH_ENTRIES = 2**24


def walking_viewer(slots: int, *, rng: np.random.Generator, room_m: float = 10.0, speed_mps: float = 0.6,
                   slot_s: float = 1.0) -> tuple[np.ndarray, np.ndarray]:
    """Positions ``[T, 2]`` (m) and headings ``[T]`` (rad) of a viewer walking inside the room,
    turning smoothly and bouncing off the walls."""
    pos = np.empty((slots, 2))
    heading = np.empty(slots)
    p = rng.uniform(0.2 * room_m, 0.8 * room_m, size=2)
    h = rng.uniform(-math.pi, math.pi)
    turn = 0.0
    for t in range(slots):
        pos[t], heading[t] = p, h
        turn = 0.8 * turn + rng.normal(0.0, 0.25)
        h = (h + turn + math.pi) % (2 * math.pi) - math.pi
        step = speed_mps * slot_s * np.array([math.cos(h), math.sin(h)])
        nxt = p + step
        for axis in range(2):
            if not 0.0 <= nxt[axis] <= room_m:
                step[axis] = -step[axis]
                h = math.atan2(step[1], step[0])
        p = np.clip(p + step, 0.0, room_m)
    return pos, heading


def synth_instance(*, objects: int = 20, layers: int = 4, slots: int = 60, seed: int = 0,
                   trace: str = DEFAULT_TRACE, mbps: float | None = 11.8, start: int = 0,
                   representation: str = "layered", total_splats: int = 180_000,
                   bytes_per_splat: int = BYTES_PER_SPLAT, fov_deg: float = 90.0, layer_decay: float = 0.6,
                   slot_s: float = 1.0, options: Options | None = None) -> Instance:
    """A seeded L3GS-like instance.

    Parameters
    ----------
    objects, layers, slots : int
        J, L and T.
    trace : str
        A bundled trace name (see :func:`l3gs_opt.traces.bandwidth.bundled_traces`) or a trace file path.
    mbps : float or None
        Scale the trace so that its mean over the whole trace is this many Mbit/s (the L3GS
        paper uses 11.8); None keeps the raw trace.
    start : int
        First trace sample of the window (one sample per second); the window has ``slots`` samples.
    total_splats : int
        Splats of the whole scene (all objects, all layers).

    Raises
    ------
    InstanceError
        A count or the seed that is not a non-negative integer (``layers``, ``slots`` >= 1), more
        than :data:`MAX_SYNTH_ENTRIES` utilities, a trace window that does not fit.
    """
    for name, value, low in (("objects", objects, 0), ("layers", layers, 1), ("slots", slots, 1), ("seed", seed, 0)):
        if isinstance(value, bool) or not isinstance(value, (int, np.integer)) or value < low:
            raise InstanceError(name, f"= {value!r}: must be an integer >= {low}")
    if objects * layers * slots > MAX_SYNTH_ENTRIES:
        raise InstanceError("objects", f"objects x layers x slots = {objects} x {layers} x {slots} utilities, more "
                                       f"than the limit of {MAX_SYNTH_ENTRIES:,} for a synthetic instance")
    rng = np.random.default_rng(seed)
    raw = read_bandwidth_trace(trace)
    scaled, factor = raw.scaled(mbps) if mbps is not None else (raw, 1.0)
    window = scaled.window(start, slots)
    bandwidth = mbps_to_bytes(window.mbps, slot_s)

    share = rng.dirichlet(np.full(max(objects, 1), 1.0))[:objects]
    splats = np.maximum(np.round(share * total_splats), 4 * layers).astype(np.int64)  # per object
    per_layer = np.diff(np.round(np.linspace(0, 1, layers + 1)[None, :] * splats[:, None]).astype(np.int64), axis=1)
    per_layer = np.maximum(per_layer, 1)
    room = 10.0
    where = rng.uniform(0.5, room - 0.5, size=(objects, 2))
    pos, heading = walking_viewer(slots, rng=rng, room_m=room, slot_s=slot_s)
    delta = where[None, :, :] - pos[:, None, :]                      # [T, J, 2]
    dist = np.linalg.norm(delta, axis=2)
    angle = np.arctan2(delta[..., 1], delta[..., 0]) - heading[:, None]
    cos_off = np.cos((angle + math.pi) % (2 * math.pi) - math.pi)
    edge = math.cos(math.radians(fov_deg) / 2)
    visible = np.clip((cos_off - edge) / (1 - edge), 0.0, 1.0) ** 0.5
    closeness = 1.0 / np.maximum(dist, 0.5)
    weight = per_layer * layer_decay ** np.arange(layers)[None, :]   # [J, L]
    object_utility = visible * closeness                              # [T, J]
    layer_utility = object_utility[:, :, None] * weight[None, :, :]   # per-layer dU
    if representation == "layered":
        cost = per_layer * bytes_per_splat
        utility = layer_utility
    else:
        cost = np.cumsum(per_layer, axis=1) * bytes_per_splat
        utility = np.cumsum(layer_utility, axis=2)
    meta = {
        "generator": "l3gs_opt.pipeline.synth.synth_instance",
        "seed": seed,
        "trace": raw.name,
        "trace_mean_mbps_raw": float(raw.mbps.mean()),
        "scale_factor": factor,
        "target_mean_mbps": mbps,
        "window": {"start_s": start, "length_s": slots},
        "window_mean_mbps": float(window.mbps.mean()),
        "bytes_per_splat": bytes_per_splat,
        "total_splats": int(splats.sum()),
    }
    return Instance(representation=representation, bandwidth=bandwidth, cost=cost, utility=utility,
                    slot_s=slot_s, options=options or Options(), names=[f"object-{j}" for j in range(objects)],
                    meta=meta)
