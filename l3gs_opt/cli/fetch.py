"""CLI subcommands ``fetch`` (stream a served bundle over HTTP, slot by slot, and score it) and
``serve`` (serve a stream export, optionally paced to a bandwidth trace).

Wire into the main parser with ``register(subparsers)``. Bad input raises
:class:`l3gs_opt.errors.L3gsError` subclasses, which the main CLI prints as one line (exit 2).
"""

from __future__ import annotations

import argparse
from pathlib import Path

__all__ = ["register"]


def _cmd_fetch(args: argparse.Namespace) -> int:
    from l3gs_opt.cli.simulate import load_viewer_path, viewer_path_rate
    from l3gs_opt.delivery.fetch import FetchError, fetch
    from l3gs_opt.pipeline.scene_instance import Z_UP_MAPPING
    from l3gs_opt.simulator.simulation import SimConfig
    from l3gs_opt.traces.poses import PoseMapping

    if Path(args.out).exists() and not Path(args.out).is_dir():
        raise FetchError("--out", f"{args.out} is a file: expected a folder")
    rate = viewer_path_rate(args.path_rate, args.path_format)
    config = SimConfig(slot_s=args.slot_s, budget=args.budget, width=args.width, height=args.height,
                       fov_deg=args.fov, samples_per_slot=args.samples_per_slot, viewport=args.viewport,
                       bandwidth_predictor=args.bandwidth_predictor, utility=args.utility, carry=args.carry,
                       last_chunk=args.last_chunk)
    mapping = Z_UP_MAPPING if args.up == "z" else PoseMapping()
    poses = load_viewer_path(args.path, args.path_format, mapping=mapping, rate_hz=rate)
    result = fetch(args.url, args.trace, poses, args.method, args.out, slots=args.slots, resume=args.resume,
                   config=config, solver=args.solver, mbps=args.mbps, start=args.start,
                   trace_format=args.trace_format, mapping=mapping, reference=args.teacher,
                   retry_s=args.retry_s, catalogue=args.catalogue, progress=not args.no_progress)
    s = result.summary
    if args.json:
        from l3gs_opt.jsonout import dumps

        print(dumps(s.to_dict(), where="summary"))
        return 0
    label = s["method"] + (f" ({s['solver']})" if s["solver"] else "")
    print(f"{label} over {args.url}: SSIM mean {s['ssim_mean']:.4f} over {s['slots']} slots of {s['slot_s']} s")
    print("  SSIM per slot: " + " ".join(f"{v:.3f}" for v in s["ssim_per_s"]))
    print(f"  bytes: received {s['bytes_delivered']} of {s['bytes_trace']} in the trace; model {s['bytes_model']}"
          + (f"; resumed after {s['resumed_slots']} recorded slots" if s["resumed_slots"] else ""))
    print(f"  records: {Path(args.out) / 'slots.jsonl'}, {Path(args.out) / 'summary.jsonl'}")
    return 0


def _cmd_serve(args: argparse.Namespace) -> int:
    from l3gs_opt.delivery.server import ServerError, run_server
    from l3gs_opt.delivery.shaping import trace_shaper

    if args.trace is None:
        # Both only shape a trace: without one they would be taken and do nothing.
        for flag, value in (("--mbps", args.mbps), ("--trace-format", args.trace_format)):
            if value is not None:
                raise ServerError(flag, f"{value!r}: needs --trace (without one the server does not pace)")
    trace = None if args.trace is None else trace_shaper(args.trace, mbps=args.mbps,
                                                         format=args.trace_format or "auto")
    run_server(args.folder, host=args.host, port=args.port, trace=trace,
               shape_anonymous=not args.no_anonymous_pacing, verify=not args.no_verify,
               announce=f"serving {args.folder} on http://{args.host}:{args.port}"
                        + ("" if trace is None else f", paced to {args.trace}") + " (Ctrl-C stops)")
    return 0


def register(subparsers) -> None:
    """Add ``fetch`` and ``serve`` to an argparse subparsers object."""
    from l3gs_opt.cli.simulate import PATH_FORMATS
    from l3gs_opt.simulator.simulation import SIM_METHODS

    p = subparsers.add_parser("fetch", help="stream a served bundle over HTTP slot by slot with a simulator "
                                            "method, measuring the bytes that arrive, and score what it shows")
    p.add_argument("url", help="base URL of 'l3gs-opt serve' (http://127.0.0.1:8000)")
    p.add_argument("--trace", required=True, help="the bandwidth trace the client assumes (bundled name or file; "
                                                  "Mbit/s per second): the records' trace bytes and slot 0's guess")
    p.add_argument("--trace-format", default="auto", choices=["auto", "lumos", "mahimahi", "pensieve"])
    p.add_argument("--mbps", type=float, default=None, help="scale the trace to this mean (Mbit/s)")
    p.add_argument("--start", type=int, default=0, help="first second of the trace window")
    p.add_argument("--path", required=True, help="the viewer's path (as for simulate)")
    p.add_argument("--path-format", default="log", choices=list(PATH_FORMATS))
    p.add_argument("--path-rate", type=float, default=None,
                   help="--path-format cameras: matrices per second (default 30)")
    p.add_argument("--up", default="z", choices=["z", "y"], help="the scene's up axis (default z)")
    p.add_argument("--method", required=True, help=f"{', '.join(SIM_METHODS)}, or a solver method")
    p.add_argument("--solver", default=None, help="as for simulate")
    p.add_argument("--out", required=True, help="folder for slots.jsonl, summary.jsonl and the received bytes")
    p.add_argument("--slots", type=int, default=60, help="slots to run, each slot-s seconds of real time")
    p.add_argument("--slot-s", type=float, default=1.0, help="slot length, seconds (at least 0.01: wall-clock time)")
    p.add_argument("--resume", action="store_true", help="continue an interrupted fetch into --out")
    p.add_argument("--catalogue", default="full", choices=["full", "tables"],
                   help="what the client knows before slot 0: full (the whole bundle, read unpaced: any utility, as "
                        "the simulator's client) or tables (the index and the server's utility tables only: "
                        "'l3gs-opt bundle tables'; renders only what arrived)")
    p.add_argument("--retry-s", type=float, default=30.0,
                   help="seconds a transfer retries a lost connection (a server restart) without a byte before "
                        "the fetch fails (at most 3600)")
    p.add_argument("--budget", default="per_slot", choices=["per_slot", "cumulative"])
    p.add_argument("--carry", default="started", choices=["started", "head"],
                   help="at a slot's cut: abort a request with no byte yet (default), or keep the first one open "
                        "(as simulate --carry)")
    p.add_argument("--last-chunk", default="whole", choices=["whole", "prefix"],
                   help="as simulate --last-chunk (l3gs and l3gs-noseg with the full catalogue): also count the first "
                        "splats of the chunk a slot's bytes end inside; they arrive in the file's order")
    p.add_argument("--viewport", default="lr", choices=["lr", "last", "oracle"])
    p.add_argument("--bandwidth-predictor", default="harmonic", choices=["harmonic", "last", "oracle"])
    p.add_argument("--utility", default="eq1", metavar="NAME")
    p.add_argument("--samples-per-slot", type=int, default=2)
    p.add_argument("--width", type=int, default=160)
    p.add_argument("--height", type=int, default=120)
    p.add_argument("--fov", type=float, default=70.0)
    p.add_argument("--teacher", default=None, help="reference scene (PLY); default the bundle's largest model")
    p.add_argument("--json", action="store_true", help="print the summary as JSON")
    p.add_argument("--no-progress", action="store_true", help="no per-slot line")
    p.set_defaults(func=_cmd_fetch)

    s = subparsers.add_parser("serve", help="serve a stream export (bundle export) over HTTP with Range "
                                            "requests, optionally paced to a bandwidth trace")
    s.add_argument("folder", help="stream export folder (holding index.json)")
    s.add_argument("--host", default="127.0.0.1",
                   help="loopback address to bind (127.0.0.0/8, ::1 or localhost; default 127.0.0.1): the server "
                        "is for local viewing and tests, other addresses are refused")
    s.add_argument("--port", type=int, default=8000)
    s.add_argument("--trace", default=None, help="pace each client session to this trace (name or file)")
    s.add_argument("--trace-format", default=None, choices=["auto", "lumos", "mahimahi", "pensieve"],
                   help="with --trace (default auto)")
    s.add_argument("--mbps", type=float, default=None, help="with --trace: scale it to this mean (Mbit/s)")
    s.add_argument("--no-anonymous-pacing", action="store_true",
                   help="do not pace requests without an X-L3gs-Client name (e.g. a fetch's catalogue)")
    s.add_argument("--no-verify", action="store_true",
                   help="start without hashing every chunk against the index (by default a corrupt or stale "
                        "export is refused before the server listens)")
    s.set_defaults(func=_cmd_serve)
