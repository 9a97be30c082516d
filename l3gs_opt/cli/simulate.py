"""CLI subcommand ``simulate``: one method over a bundle, a viewer's pose log and a bandwidth trace.

Wire into the main parser with ``register(subparsers)``. Bad input raises
:class:`l3gs_opt.errors.L3gsError` subclasses, which the main CLI prints as one line (exit 2).
"""

from __future__ import annotations

import argparse
from pathlib import Path

__all__ = ["register", "load_viewer_path", "PATH_FORMATS"]


def _cmd_simulate(args: argparse.Namespace) -> int:
    from l3gs_opt.traces.poses import PoseMapping
    from l3gs_opt.pipeline.scene_instance import Z_UP_MAPPING, read_delivery_bundle
    from l3gs_opt.simulator.simulation import SimConfig, Simulation, SimulationError, trace_bytes

    config = SimConfig(slot_s=args.slot_s, budget=args.budget, width=args.width, height=args.height,
                       fov_deg=args.fov, samples_per_slot=args.samples_per_slot, viewport=args.viewport,
                       bandwidth_predictor=args.bandwidth_predictor, robust=args.robust, utility=args.utility,
                       order_utility=args.order_utility, utility_mode=args.utility_mode,
                       splat_order=args.splat_order, carry=args.carry, decision_s=args.decision_s, time_limit_s=args.time_limit, horizon=args.horizon, fill=not args.no_fill,
                       backend=args.backend, substeps=args.substeps, bandwidth_bias=args.bandwidth_bias,
                       sh_upgrade_utility=args.sh_upgrade_utility, last_chunk=args.last_chunk)
    rate = viewer_path_rate(args.path_rate, args.path_format)
    if args.resume and not args.out:
        raise SimulationError("resume", "needs --out (the folder of the interrupted run)")
    if args.save_views and not args.out:
        raise SimulationError("save-views", "needs --out (the pictures go to OUT/views)")
    for option, folder in (("--out", args.out), ("--cache-dir", args.cache_dir)):
        if folder and Path(folder).exists() and not Path(folder).is_dir():
            raise SimulationError(option, f"{folder} is a file: expected a folder")
    cache_dir = args.cache_dir
    if cache_dir is None and args.out and not args.no_cache:
        cache_dir = Path(args.out) / "reference-cache"
    bundle = read_delivery_bundle(args.bundle)   # as `bundle export` checks it
    bandwidth, info = trace_bytes(args.trace, mbps=args.mbps, start=args.start, slots=args.slots,
                                  slot_s=args.slot_s, format=args.trace_format)
    mapping = Z_UP_MAPPING if args.up == "z" else PoseMapping()
    poses = load_viewer_path(args.path, args.path_format, mapping=mapping, rate_hz=rate, eye=args.eye)
    reference = args.teacher
    if reference is None:   # the teacher the bundle was built from
        from l3gs_opt.pipeline.build import IN_MEMORY_TEACHER

        recorded = bundle.manifest.get("build", {}).get("teacher")
        if recorded == IN_MEMORY_TEACHER:   # built from a scene in memory: no file was ever recorded
            recorded = None
        if recorded and not Path(recorded).is_file():
            # Not the largest model instead: scoring the bundle against itself reports SSIM 1.000 for a
            # full delivery, a result that looks real. The largest model is only for bundles that
            # record no teacher (procedural ones).
            raise SimulationError("build.teacher", f"{recorded}: the bundle's recorded teacher is missing; "
                                                   "pass --teacher PLY (the scene to score against)")
        reference = recorded or None
    sim = Simulation(bundle, poses, bandwidth, config=config, reference=reference, mapping=mapping, info=info,
                     cache_dir=None if args.no_cache else cache_dir)
    result = sim.run(args.method, solver=args.solver, out_dir=args.out, progress=not args.no_progress,
                     resume=args.resume, views_dir=Path(args.out) / "views" if args.save_views else None)
    s = result.summary
    if args.json:
        from l3gs_opt.jsonout import dumps

        print(dumps(s.to_dict(), where="summary"))
        return 0
    label = s["method"] + (f" ({s['solver']})" if s["solver"] else "")
    t = s["timings_mean_s"]
    print(f"{label}: SSIM mean {s['ssim_mean']:.4f} over {s['slots']} slots of {s['slot_s']} s "
          f"(reference: {s['reference']})")
    print("  SSIM per slot: " + " ".join(f"{v:.3f}" for v in s["ssim_per_s"]))
    print(f"  bytes: delivered {s['bytes_delivered']}, wasted {s['bytes_wasted']} (replaced {s['bytes_replaced']}), "
          f"idle {s['bytes_idle']} of {s['bytes_trace']} in the trace; model {s['bytes_model']}")
    print("  mean per slot (ms): " + ", ".join(f"{k} {1e3 * v:.1f}" for k, v in t.items())
          + f"; run {s['run_s']:.1f} s, load {s['loadavg_start'][0]:.2f}")
    r = s["renders"]
    print(f"  renders ({s['render_backend']}): view {r['view']} (+{r['view_reused']} cached), reference "
          f"{r['reference']} (+{r['reference_reused']} cached)"
          + (f"; resumed after {s['resumed_slots']} recorded slots" if s["resumed_slots"] else ""))
    if args.out:
        print(f"  records: {Path(args.out) / 'slots.jsonl'}, {Path(args.out) / 'summary.jsonl'}")
    return 0


PATH_FORMATS = ("log", "eyenavgs", "cameras")


def viewer_path_rate(rate_hz: float | None, fmt: str) -> float:
    """``--path-rate`` (camera matrices per second; default 30), refused with a format that has
    its own clock: taken there, it would do nothing."""
    if rate_hz is not None and fmt != "cameras":
        from l3gs_opt.traces.poses import PoseError

        raise PoseError(f"--path-rate: {rate_hz!r}: only --path-format cameras reads it, not {fmt!r}")
    return 30.0 if rate_hz is None else rate_hz


def load_viewer_path(path, fmt: str, *, mapping, rate_hz: float = 30.0, eye: str = "centre"):
    """The viewer's poses from a headset pose log (``log``), an EyeNavGS CSV (``eyenavgs``) or a
    camera path of 4x4 world-to-camera matrices at ``rate_hz`` (``cameras``), as a
    :class:`~l3gs_opt.traces.poses.PoseTrace` whose cameras under ``mapping`` are the file's
    (``log``: the log as it is, mapped as before)."""
    import numpy as np

    from l3gs_opt.traces.poses import PoseError, poses_from_cameras, read_camera_path, read_pose_log

    if fmt == "log":
        return read_pose_log(path)
    if fmt == "eyenavgs":
        from l3gs_opt.traces.eyenavgs import read_eyenavgs

        trace = read_eyenavgs(path, eye=eye)
        return poses_from_cameras(trace.world_to_camera(), trace.timestamps_s - trace.timestamps_s[0], mapping)
    if not (rate_hz > 0 and np.isfinite(rate_hz)):
        raise PoseError(f"--path-rate: {rate_hz!r} must be a positive number (camera matrices per second)")
    mats = read_camera_path(path)
    return poses_from_cameras(mats, np.arange(len(mats)) / rate_hz, mapping)


def _upgrade_utility(text: str):
    """``--sh-upgrade-utility``: a named proxy or a fixed fraction."""
    try:
        return float(text)
    except ValueError:
        return text


def register(subparsers) -> None:
    """Add ``simulate`` to an argparse subparsers object."""
    from l3gs_opt.models.backends import Backend
    from l3gs_opt.simulator.simulation import SIM_METHODS

    p = subparsers.add_parser("simulate", help="simulate delivering a bundle over a trace to a moving viewer "
                                               "and score what it shows (SSIM/PSNR per second)")
    p.add_argument("bundle", help="bundle directory (l3gs-opt scene build)")
    p.add_argument("--trace", required=True, help="bundled trace name or a trace file (Mbit/s per second)")
    p.add_argument("--trace-format", default="auto", choices=["auto", "lumos", "mahimahi", "pensieve"],
                   help="bandwidth trace format (default: detected from the content)")
    p.add_argument("--path", required=True, help="the viewer's path: a headset pose log, an EyeNavGS CSV or a "
                                                 "camera path (--path-format)")
    p.add_argument("--path-format", default="log", choices=list(PATH_FORMATS),
                   help="log: headset pose log (default); eyenavgs: an EyeNavGS 6DoF CSV (scene frame); "
                        "cameras: 4x4 world-to-camera matrices, blank line between, at --path-rate")
    p.add_argument("--path-rate", type=float, default=None,
                   help="--path-format cameras: matrices per second (default 30)")
    p.add_argument("--eye", default="centre", choices=["centre", "left", "right"],
                   help="--path-format eyenavgs: which eye's camera (centre: between the two)")
    p.add_argument("--method", required=True,
                   help=f"{', '.join(SIM_METHODS)}, or a solver method (bb, rolling:bb, rolling-future:bb, mpc:H, "
                        "slope, progressive, static, ...)")
    p.add_argument("--solver", default=None,
                   help="solver of l3gs, l3gs-noseg, separate (one slot's MCKP: bb, dp, greedy, fptas:EPS, ilp) and "
                        "of distill, hierarchy (those, or rolling:S, rolling-future:S, mpc:H); default bb")
    p.add_argument("--mbps", type=float, default=11.8, help="scale the trace to this mean (Mbit/s; default 11.8)")
    p.add_argument("--start", type=int, default=0, help="first second of the trace window")
    p.add_argument("--slots", type=int, default=60, help="slots to simulate (default 60)")
    p.add_argument("--slot-s", type=float, default=1.0, help="slot length in seconds (default 1)")
    p.add_argument("--budget", default="per_slot", choices=["per_slot", "cumulative"],
                   help="cumulative: idle bytes are banked for the next slot")
    p.add_argument("--viewport", default="lr", choices=["lr", "last", "oracle"], help="viewport predictor")
    p.add_argument("--bandwidth-predictor", default="harmonic", choices=["harmonic", "last", "oracle"])
    p.add_argument("--robust", action="store_true", help="RobustMPC's discount on the bandwidth prediction")
    p.add_argument("--utility", default="eq1", metavar="NAME",
                   help="splat utility that values the chunks: eq1 (the paper's Eq. 1, default), visibility, "
                        "visibility-held, coverage, counterfactual, or MODULE:NAME (a user's function or class)")
    p.add_argument("--order-utility", default=None, metavar="NAME",
                   help="utility that orders the splats inside a chunk (default: --utility)")
    p.add_argument("--decision-s", type=float, default=0.0, metavar="S",
                   help="seconds the client plans at each slot start while only the carried-over chunk streams "
                        "(the link idles if it ends first; 0: the paper's model; fetch's records give late_s)")
    p.add_argument("--carry", default="started", choices=["started", "head"],
                   help="what a slot's cut keeps in flight: the chunk that got bytes (default), or also the first "
                        "request still waiting for its first byte (as 'l3gs-opt fetch --carry head' keeps it open)")
    p.add_argument("--last-chunk", default="whole", choices=["whole", "prefix"],
                   help="what the per-slot MCKP of l3gs and l3gs-noseg counts: whole chunks only (the paper), or "
                        "also the first splats of the one chunk the slot's bytes end inside (prefix)")
    p.add_argument("--splat-order", default="method", choices=["method", "stored"],
                   help="a chunk's splats on the wire: as the method says (by predicted utility), or in the "
                        "bundle's stored order, as 'l3gs-opt fetch' receives static chunk files by HTTP Range")
    p.add_argument("--utility-mode", default="exact", choices=["exact", "table"],
                   help="the utility per predicted viewpoint, or a viewpoint table built first (held-free utilities)")
    p.add_argument("--samples-per-slot", type=int, default=2, help="predicted viewpoints averaged per slot")
    p.add_argument("--teacher", default=None,
                   help="reference scene (PLY); default: the bundle's recorded teacher (an error if that file is "
                        "missing), else, when none is recorded, its largest model")
    p.add_argument("--up", default="z", choices=["y", "z"], help="the scene's up axis (pose logs are y up)")
    p.add_argument("--width", type=int, default=160, help="rendered width in pixels (default 160)")
    p.add_argument("--height", type=int, default=120, help="rendered height in pixels (default 120)")
    p.add_argument("--fov", type=float, default=70.0, help="horizontal field of view, degrees")
    p.add_argument("--time-limit", type=float, default=None, metavar="S", help="seconds per scheduling call")
    p.add_argument("--horizon", type=int, default=None, help="multi-slot methods plan at most this many slots")
    p.add_argument("--no-fill", action="store_true", help="request only the slot's picks (the link may idle)")
    p.add_argument("--backend", default="highs", choices=[b.value for b in Backend], help="ILP backend")
    p.add_argument("--substeps", type=int, default=1, metavar="S",
                   help="re-plan S times per slot with the bytes measured so far in the slot (default 1: once)")
    p.add_argument("--bandwidth-bias", type=float, default=1.0, metavar="X",
                   help="multiply the predicted bytes by X (> 1: an over-optimistic predictor)")
    p.add_argument("--sh-upgrade-utility", type=_upgrade_utility, default="residual", metavar="HOW",
                   help="distill: the share of a splat's utility its SH upgrade brings: residual (the SH energy the "
                        "compact fit misses; default), bands (the energy above the compact degree), or a fixed "
                        "fraction in [0, 1]")
    p.add_argument("--out", default=None, help="folder: slots.jsonl (one line per slot, as it goes), summary.jsonl")
    p.add_argument("--resume", action="store_true",
                   help="continue an interrupted run from the slots of this method recorded in --out")
    p.add_argument("--save-views", action="store_true",
                   help="keep what the viewer saw: each slot's picture and the reference as PNG files in OUT/views "
                        "(l3gs-opt replay OUT shows them)")
    p.add_argument("--cache-dir", default=None,
                   help="keep the reference (teacher) renders there, one file per camera, for later runs "
                        "(default: OUT/reference-cache with --out)")
    p.add_argument("--no-cache", action="store_true", help="no reference renders on disk")
    p.add_argument("--no-progress", action="store_true")
    p.add_argument("--json", action="store_true", help="print the summary as one JSON object")
    p.set_defaults(func=_cmd_simulate)
