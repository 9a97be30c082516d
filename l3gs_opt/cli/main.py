"""The l3gs-opt command line: thin subcommands over the library API.

Every error the library raises on purpose (bad instance, bad option, unreadable file) is printed
as one line on stderr with exit code 2; argparse's own usage errors also exit 2.
"""

from __future__ import annotations

import argparse
import re
import sys
import warnings
from pathlib import Path
from typing import Sequence

from l3gs_opt import stop
from l3gs_opt.errors import L3gsError

__all__ = ["main", "build_parser"]


def _cmd_solve(args: argparse.Namespace) -> int:
    from l3gs_opt.methods import check_slot, check_time_limit, solve
    from l3gs_opt.problem.items_io import load_problem
    from l3gs_opt.bench.report_table import comparison_table

    time_limit = check_time_limit(args.time_limit, name="--time-limit")
    instance = load_problem(args.instance)
    slot = check_slot(args.slot, instance.T, name="--slot")
    # The first Ctrl-C stops the solve with its best schedule and bound so far; a second aborts.
    with stop.on_interrupt("stopping: finishing with the best schedule and bound so far (Ctrl-C again to abort)"):
        solution = solve(instance, args.method, backend=args.backend, form=args.form, slot=slot,
                         time_limit_s=time_limit, presolve=not args.no_presolve)
    if args.json:
        from l3gs_opt.jsonout import dumps

        print(dumps(solution.to_dict(), where="solution"))
    else:
        label = args.method + (f"/{solution.backend}" if solution.backend else "")
        print(comparison_table([(label, solution)]))
        if solution.message:
            print(f"note: {solution.message}")
    return 0


def _window(text: str) -> tuple[int, int]:
    try:
        start, length = (int(v) for v in text.split(":"))
    except ValueError:
        raise argparse.ArgumentTypeError(f"window {text!r}: expected START:LEN in whole seconds") from None
    if start < 0 or length < 1:
        raise argparse.ArgumentTypeError(f"window {text!r}: START must be >= 0 and LEN >= 1")
    return start, length


def _cmd_from_scene(args: argparse.Namespace) -> int:
    from l3gs_opt.problem.instance import Options
    from l3gs_opt.problem.instance_io import save_instance
    from l3gs_opt.traces.poses import PoseMapping
    from l3gs_opt.pipeline.scene_instance import Z_UP_MAPPING, instance_from_bundle

    start, length = args.window
    instance = instance_from_bundle(args.bundle, args.path, args.trace, mbps=args.mbps, start=start, slots=length,
                                    predict=args.predict, samples_per_slot=args.samples_per_slot,
                                    mapping=Z_UP_MAPPING if args.up == "z" else PoseMapping(),
                                    width=args.width, height=args.height, fov_deg=args.fov,
                                    options=Options(budget=args.budget), progress=True, utility=args.utility)
    path = save_instance(instance, args.output)
    print(f"wrote {path}: {instance!r}")
    return 0


def _cmd_synth(args: argparse.Namespace) -> int:
    from l3gs_opt.problem.instance import Options
    from l3gs_opt.problem.instance_io import save_instance
    from l3gs_opt.pipeline.synth import synth_instance

    options = Options(availability=args.availability, same_slot_layers=not args.strict_layers, budget=args.budget)
    instance = synth_instance(objects=args.objects, layers=args.layers, slots=args.slots, seed=args.seed,
                              trace=args.trace, mbps=args.mbps, start=args.start,
                              representation=args.representation, options=options)
    path = save_instance(instance, args.output)
    print(f"wrote {path}: {instance!r}")
    return 0


def _cmd_check(args: argparse.Namespace) -> int:
    from l3gs_opt.problem.items import ItemInstance
    from l3gs_opt.problem.items_io import load_problem
    from l3gs_opt.problem.items_presolve import presolve_items
    from l3gs_opt.problem.presolve import presolve

    instance = load_problem(args.instance)
    items = isinstance(instance, ItemInstance)
    red = presolve_items(instance) if items else presolve(instance)
    print(f"{args.instance}: valid {instance!r}")
    print(f"  total bytes {int(instance.cost.sum())}, bandwidth {int(instance.bandwidth.sum())} bytes over "
          f"{instance.T} slots of {instance.slot_s} s; held {'items' if items else 'chunks'} "
          f"{int(instance.held.sum())}")
    print(f"  presolve: {red.stats}")
    return 0


def _cmd_demo(args: argparse.Namespace) -> int:
    from l3gs_opt.cli.demo import run_demo
    from l3gs_opt.errors import SolveError
    from l3gs_opt.methods import check_time_limit

    # before the first step (the quick benchmark took a negative limit and ran 439 records first)
    if check_time_limit(args.time_limit, name="--time-limit") is None:
        raise SolveError("--time-limit: inf: the demo needs a finite limit (it runs every ILP backend with it)")
    return run_demo(out_dir=Path(args.out), time_limit_s=args.time_limit, bench=not args.no_bench,
                    scene=not args.no_scene, experiments=not args.no_experiments)


def _csv(text: str | None, kind: type = str) -> list | None:
    if text is None:
        return None
    try:
        return [kind(part.strip()) for part in text.split(",") if part.strip()]
    except ValueError:
        raise argparse.ArgumentTypeError(f"{text!r}: expected a comma-separated list of {kind.__name__}") from None


def _check_methods(methods: list[str] | None) -> None:
    from l3gs_opt.bench.run import BenchError
    from l3gs_opt.bench.suites import check_label

    if methods is not None and not methods:   # "--methods ," must not mean "every method"
        raise BenchError("--methods", "names no method (expected comma-separated labels, e.g. ilp/highs,bb)")
    for i, m in enumerate(methods or []):
        check_label(m)
        if m in methods[:i]:   # its records would share one record_id and count twice in the report
            raise BenchError("--methods", f"{m!r} is named twice", i)


def _check_bench_args(args: argparse.Namespace) -> list[int] | None:
    """``--sizes`` (checked), after checking ``--seeds``, the executor and that ``--out`` is no file."""
    from l3gs_opt.bench.run import BenchError
    from l3gs_opt.bench.suites import MAX_SEEDS
    from l3gs_opt.executors import check_executor

    if args.sizes is not None:
        if not args.sizes:
            raise BenchError("--sizes", "names no size (expected comma-separated object counts, e.g. 10,20)")
        for i, size in enumerate(args.sizes):
            if size < 1:
                raise BenchError("--sizes", f"= {size}: an object count must be >= 1", i)
            if size in args.sizes[:i]:
                raise BenchError("--sizes", f"= {size}: named twice", i)
    if args.seeds is not None and not 1 <= args.seeds <= MAX_SEEDS:
        raise BenchError("--seeds", f"= {args.seeds}: must be 1..{MAX_SEEDS} seeds per size (MAX_SEEDS)")
    check_executor(args.executor, args.jobs, args.address)
    if Path(args.out).exists() and not Path(args.out).is_dir():
        raise BenchError("--out", f"{args.out} is a file: expected a folder (for results.jsonl and report.md)")
    return args.sizes


def _cmd_bench(args: argparse.Namespace) -> int:
    from l3gs_opt.bench.run import BenchError, BenchTask, run_bench
    from l3gs_opt.bench.report import write_report
    from l3gs_opt.bench.suites import ALL_SUITES, default_methods, suite_specs

    suites = list(ALL_SUITES) if args.suite == "all" else [args.suite]
    methods = _csv(args.methods)
    _check_methods(methods)
    sizes = _check_bench_args(args)
    tasks = []
    for suite in suites:
        seeds = args.seeds if args.seeds is not None else (1 if args.quick else 3)
        for spec in suite_specs(suite, sizes=sizes, seeds=seeds, quick=args.quick):
            tasks += [BenchTask(spec, m) for m in (methods or default_methods(spec, quick=args.quick))]
    if not tasks:
        raise BenchError("--suite", f"{args.suite} with these options gives no records to run (an empty plan)")
    out = Path(args.out)
    time_limit = args.time_limit if args.time_limit is not None else (5.0 if args.quick else 60.0)
    records = run_bench(tasks, out / "results.jsonl", time_limit_s=time_limit, jobs=args.jobs,
                        executor=args.executor, address=args.address, resume=args.resume,
                        progress=not args.no_progress)
    report = write_report(records, out)
    print(f"records: {records}\nreport: {report}")
    return 0


def _cmd_report(args: argparse.Namespace) -> int:
    from l3gs_opt.errors import SolveError
    from l3gs_opt.bench.report import write_report
    from l3gs_opt.records import read_records

    if not Path(args.records).exists():
        raise SolveError(f"{args.records}: no such results file")
    if not read_records(args.records):   # a report of nothing is a wrong path, not a result
        raise SolveError(f"{args.records}: holds no records (expected the results.jsonl of l3gs-opt bench or compare)")
    print(f"report: {write_report(args.records, args.out)}")
    return 0


def _cmd_compare(args: argparse.Namespace) -> int:
    from l3gs_opt.methods import check_slot, check_time_limit
    from l3gs_opt.bench.run import BenchTask, read_records, run_bench
    from l3gs_opt.errors import SolveError
    from l3gs_opt.problem.items import ItemInstance
    from l3gs_opt.problem.items_io import load_problem
    from l3gs_opt.bench.report import annotate, write_report
    from l3gs_opt.bench.suites import InstanceSpec, default_methods

    time_limit = check_time_limit(args.time_limit, name="--time-limit")
    inst = load_problem(args.instance)  # fail early, with the instance's own error
    if isinstance(inst, ItemInstance):
        raise SolveError(f"instance: {args.instance} is an item instance (l3gs-opt/items@1); compare runs "
                         "l3gs-opt/instance@1 files (run 'l3gs-opt solve --method M' per method)")
    check_slot(args.slot, inst.T, name="--slot")   # here, not in a worker (its traceback would print first)
    single = args.slot is not None or inst.T == 1
    spec = InstanceSpec("compare", Path(args.instance).stem, "file",
                        {"path": str(Path(args.instance).resolve()), "slot": args.slot}, single)
    methods = _csv(args.methods)
    _check_methods(methods)   # before the default: "--methods ," is an error, not every method
    methods = methods or default_methods(spec)
    out = Path(args.out)
    path = out / "compare.jsonl"
    run_bench([BenchTask(spec, m) for m in methods], path, time_limit_s=time_limit, jobs=1,
              progress=not args.no_progress, fresh=True)
    rows = annotate(read_records(path))
    width = max(len(r["method"]) for r in rows)
    print(f"{'method'.ljust(width)}  status      objective     bound         rel. error  time (s)  flags")
    for r in sorted(rows, key=lambda r: r["runtime_s"]):
        bound = "-" if r.get("bound") is None else f"{r['bound']:<12.6g}"
        obj = "-" if r.get("objective") is None else f"{r['objective']:<12.6g}"
        err = "-" if r.get("rel_error") is None else f"{r['rel_error']:.2e}"
        print(f"{r['method'].ljust(width)}  {r['status']:<10}  {obj:<12}  {bound:<12}  {err:<10}  "
              f"{r['runtime_s']:<8.3f}  {','.join(r.get('flags', [])) or '-'}")
    print(f"report: {write_report(path, out, title=f'compare {args.instance}')}")
    return 0


def _cmd_predict(args: argparse.Namespace) -> int:
    from l3gs_opt.traces.predictors import bandwidth_errors, viewport_errors

    if args.target == "viewport":
        from l3gs_opt.traces.poses import read_pose_log

        result = viewport_errors(read_pose_log(args.input), hw_s=args.hw, pw_s=args.pw, method=args.method).to_dict()
    else:
        from l3gs_opt.traces.bandwidth import read_bandwidth_trace

        trace = read_bandwidth_trace(args.input)
        result = bandwidth_errors(trace.mbps, window=args.window, robust=args.robust, method=args.method)
    if args.json:
        from l3gs_opt.jsonout import dumps

        print(dumps(result, where="result"))   # NaN/inf errors as null (see l3gs_opt.jsonout)
    else:
        print("  ".join(f"{k} {v:.4g}" if isinstance(v, float) else f"{k} {v}" for k, v in result.items()))
    return 0


def build_parser() -> argparse.ArgumentParser:
    from l3gs_opt.models.backends import Backend

    parser = argparse.ArgumentParser(prog="l3gs-opt", description=__doc__.splitlines()[0])
    sub = parser.add_subparsers(dest="command", required=True)

    p = sub.add_parser("solve", help="solve an instance and print the answer",
                       description="Solve an instance and print the answer. The first Ctrl-C stops the solve "
                                   "with its best schedule and a valid bound (exact, HiGHS, CP-SAT, and CBC, which the "
                                   "terminal's Ctrl-C reaches itself; not SCIP); "
                                   "a second one aborts.")
    p.add_argument("instance", help="instance file (.json or .npz)")
    p.add_argument("--method", default="ilp", help="ilp (default), lp, brute, or a solver method name")
    p.add_argument("--backend", default="highs", choices=[b.value for b in Backend])
    p.add_argument("--form", default="standard", choices=["standard", "gap"])
    p.add_argument("--slot", type=int, default=None, help="solve the single-slot MCKP of this slot (0-based)")
    p.add_argument("--time-limit", type=float, default=None, metavar="S", help="seconds (> 0; inf: no limit)")
    p.add_argument("--no-presolve", action="store_true", help="build the naive model")
    p.add_argument("--json", action="store_true", help="print one JSON object")
    p.set_defaults(func=_cmd_solve)

    inst = sub.add_parser("instance", help="make or check instance files").add_subparsers(dest="action",
                                                                                           required=True)
    s = inst.add_parser("synth", help="a synthetic L3GS-like instance from a real bandwidth trace")
    s.add_argument("--objects", type=int, default=20)
    s.add_argument("--layers", type=int, default=4)
    s.add_argument("--slots", type=int, default=60)
    s.add_argument("--seed", type=int, default=0)
    s.add_argument("--trace", default="lumos-throughput-mid-11", help="bundled trace name or a trace file")
    s.add_argument("--mbps", type=float, default=11.8, help="scale the trace to this mean (Mbit/s)")
    s.add_argument("--start", type=int, default=0, help="first second of the trace window")
    s.add_argument("--representation", default="layered", choices=["layered", "separate"])
    s.add_argument("--availability", default="same_slot", choices=["same_slot", "next_slot"])
    s.add_argument("--strict-layers", action="store_true", help="layer l only in a slot after layer l-1")
    s.add_argument("--budget", default="per_slot", choices=["per_slot", "cumulative"])
    s.add_argument("-o", "--output", required=True, help="output file (.json or .npz)")
    s.set_defaults(func=_cmd_synth)
    f = inst.add_parser("from-scene", help="an instance from a bundle, a viewer path and a bandwidth trace")
    f.add_argument("bundle", help="bundle directory (l3gs-opt scene build)")
    f.add_argument("--path", required=True, help="headset pose log, camera JSON list or 4x4 camera path file")
    f.add_argument("--trace", default="lumos-throughput-mid-11", help="bundled trace name or a trace file")
    f.add_argument("--mbps", type=float, default=11.8, help="scale the trace to this mean (Mbit/s)")
    f.add_argument("--window", default="0:60", type=_window, help="START:LEN in seconds of the trace (default 0:60)")
    f.add_argument("--predict", action="store_true", help="utilities for the predicted viewports (pose logs)")
    f.add_argument("--samples-per-slot", type=int, default=4, help="viewpoints averaged per slot (pose logs)")
    f.add_argument("--up", default="z", choices=["y", "z"], help="the scene's up axis (pose logs are y up)")
    f.add_argument("--budget", default="per_slot", choices=["per_slot", "cumulative"],
                   help="cumulative: one link, unspent bytes carry over")
    f.add_argument("--width", type=int, default=800)
    f.add_argument("--height", type=int, default=600)
    f.add_argument("--fov", type=float, default=70.0, help="horizontal field of view, degrees")
    f.add_argument("--utility", default="eq1", metavar="NAME",
                   help="splat utility: eq1 (default), visibility, visibility-held, coverage, counterfactual, "
                        "or MODULE:NAME")
    f.add_argument("-o", "--output", required=True, help="output file (.json or .npz)")
    f.set_defaults(func=_cmd_from_scene)
    c = inst.add_parser("check", help="validate an instance file and summarise it")
    c.add_argument("instance")
    c.set_defaults(func=_cmd_check)

    b = sub.add_parser("bench", help="run benchmark suites: one JSONL record per (instance, method)")
    b.add_argument("--suite", default="all", choices=["all", "l3gs", "pisinger", "stiff", "problems", "knapsack-sets"],
                   help="all: the built-in suites; knapsack-sets: the public 0-1 knapsack files with known optima "
                        "($L3GS_KNAPSACK_DIR, else ../shared/data/reference/knapsack), named only")
    b.add_argument("--methods", default=None, help="comma-separated labels, e.g. ilp/highs,bb,fptas:0.01")
    b.add_argument("--sizes", default=None, type=lambda text: _csv(text, int),
                   help="comma-separated object counts J")
    b.add_argument("--seeds", type=int, default=None, help="seeds per size (default 3, 1 with --quick)")
    b.add_argument("--time-limit", type=float, default=None, metavar="S",
                   help="seconds per record (default 60, 5 with --quick)")
    b.add_argument("--jobs", type=int, default=1, help="parallel processes (0: in this process)")
    b.add_argument("--executor", default="local", choices=["local", "dask"])
    b.add_argument("--address", default=None, help="Dask scheduler address (default: a local cluster)")
    b.add_argument("--out", default="bench-out", help="folder for results.jsonl, report.md and plots")
    b.add_argument("--quick", action="store_true", help="a representative subset (minutes)")
    b.add_argument("--resume", action="store_true", help="continue a results file, skipping finished records")
    b.add_argument("--no-progress", action="store_true")
    b.set_defaults(func=_cmd_bench)

    r = sub.add_parser("report", help="write report.md and PNG plots from a results file")
    r.add_argument("records", help="results.jsonl")
    r.add_argument("--out", required=True)
    r.set_defaults(func=_cmd_report)

    k = sub.add_parser("compare", help="run several methods on one instance: table and plot")
    k.add_argument("instance")
    k.add_argument("--methods", default=None)
    k.add_argument("--slot", type=int, default=None)
    k.add_argument("--time-limit", type=float, default=60.0, metavar="S", help="seconds per method (> 0; inf: none)")
    k.add_argument("--out", default="compare-out")
    k.add_argument("--no-progress", action="store_true")
    k.set_defaults(func=_cmd_compare)

    pr = sub.add_parser("predict", help="viewport and bandwidth predictors and their errors").add_subparsers(
        dest="target", required=True)
    pv = pr.add_parser("viewport", help="mean errors of a viewport predictor on a headset log")
    pv.add_argument("input", metavar="LOG")
    pv.add_argument("--hw", type=float, default=0.5, help="history window (s)")
    pv.add_argument("--pw", type=float, default=1.0, help="prediction window (s)")
    pv.add_argument("--method", default="lr", choices=["lr", "last", "oracle"])
    pv.add_argument("--json", action="store_true")
    pv.set_defaults(func=_cmd_predict)
    pb = pr.add_parser("bandwidth", help="mean absolute error of a bandwidth predictor on a trace")
    pb.add_argument("input", metavar="TRACE")
    pb.add_argument("--window", type=int, default=5, help="samples in the harmonic mean")
    pb.add_argument("--robust", action="store_true", help="RobustMPC's discount by past errors")
    pb.add_argument("--method", default="harmonic", choices=["harmonic", "last", "oracle"])
    pb.add_argument("--json", action="store_true")
    pb.set_defaults(func=_cmd_predict)

    from l3gs_opt.cli.scene import register as register_scene_commands

    register_scene_commands(sub)  # render, scene make, scene info (the renderer's subcommands)
    from l3gs_opt.cli.simulate import register as register_simulate

    register_simulate(sub)
    from l3gs_opt.cli.utility import register as register_utility

    register_utility(sub)
    from l3gs_opt.cli.experiments import register as register_experiments

    register_experiments(sub)
    from l3gs_opt.cli.bundle import register as register_bundle

    register_bundle(sub)   # bundle export|info: the streamable chunk index
    from l3gs_opt.cli.replay import register as register_replay

    register_replay(sub)   # replay RUN --out PAGE: an HTML page of a simulated run
    from l3gs_opt.cli.fetch import register as register_fetch

    register_fetch(sub)   # fetch, serve: real delivery over HTTP

    d = sub.add_parser("demo", help="the README's demo: solve, compare and report on a real trace")
    d.add_argument("--out", default="demo-out", help="folder for the demo's files")
    d.add_argument("--time-limit", type=float, default=10.0, metavar="S", help="seconds per exact solve")
    d.add_argument("--no-bench", action="store_true", help="skip the quick benchmark (seconds instead of minutes)")
    d.add_argument("--no-scene", action="store_true", help="skip the scene -> schedule -> picture step")
    d.add_argument("--no-experiments", action="store_true",
                   help="skip step 5, the quick run of the paper's experiments (~6-15 min)")
    d.set_defaults(func=_cmd_demo)
    _record_options(parser)
    return parser


def _record_options(parser: argparse.ArgumentParser) -> None:
    """Give each command's parser the map of its options (``dest -> --option``), which
    :func:`option_wording` reads."""
    for action in parser._actions:
        if isinstance(action, argparse._SubParsersAction):
            for sub in action.choices.values():
                _record_options(sub)
            return
    options = {a.dest: max(a.option_strings, key=len) for a in parser._actions
               if a.option_strings and a.dest != "help"}
    parser.set_defaults(cli_options=options)


#: Library fields whose command-line option has another name (field -> the option's ``dest``).
FIELD_OPTIONS = {"fov_deg": "fov", "fov_x_deg": "fov", "time_limit_s": "time_limit",
                 "ceiling_time_limit_s": "time_limit", "ceiling_check_s": "check_time", "window_s": "window",
                 "alignment": "align", "num_splats": "splats", "n_views": "views", "last_chunks": "last_chunk"}
_LEADING_FIELD = re.compile(r"([A-Za-z_][A-Za-z0-9_]*)(?=[:\[ ]|$)")


def option_wording(text: str, options: dict[str, str]) -> str:
    """An error line as the command line's user wrote it: a message that starts with a library
    field (``slot_s: -7.0: ...``) names the option the value came from (``--slot-s: -7.0: ...``),
    when the command has that option. Other messages are left as they are."""
    m = _LEADING_FIELD.match(text)
    if m is None:
        return text
    option = options.get(FIELD_OPTIONS.get(m.group(1), m.group(1)))
    return text if option is None else option + text[m.end():]


#: Options that name where a command writes: an empty one would mean the current folder.
OUTPUT_OPTIONS = ("out", "output", "cache")


def main(argv: Sequence[str] | None = None) -> int:
    parser = build_parser()
    args = parser.parse_args(argv)
    for dest in OUTPUT_OPTIONS:
        value = getattr(args, dest, None)
        if isinstance(value, str) and not value.strip():
            print(f"error: --{dest}: empty: name a path ('.' for the current folder)", file=sys.stderr)
            return 2
    shown = warnings.showwarning
    warnings.showwarning = _one_line_warning
    try:
        return int(args.func(args) or 0)
    except L3gsError as exc:
        print(f"error: {option_wording(str(exc), getattr(args, 'cli_options', {}))}", file=sys.stderr)
        return 2
    except KeyboardInterrupt:
        print("interrupted", file=sys.stderr)
        return 130
    except BrokenPipeError:
        # The reader went away (``l3gs-opt ... | head``): stop quietly, as Unix tools do; point
        # stdout at /dev/null so the interpreter's final flush does not fail again.
        import os

        os.dup2(os.open(os.devnull, os.O_WRONLY), sys.stdout.fileno())
        return 141
    except OSError as exc:
        # A path the user gave cannot be written or read (a file where a folder belongs, no
        # permission, a full disk) somewhere the command's own checks did not foresee: one line
        # naming the path, as for any other bad input.
        print(f"error: {os_error_line(exc)}", file=sys.stderr)
        return 2
    finally:
        warnings.showwarning = shown


def os_error_line(exc: OSError) -> str:
    """``path: reason`` of an OSError (both paths of a rename), or its text when it names none."""
    from l3gs_opt.errors import os_error_reason

    paths = [str(p) for p in (exc.filename, exc.filename2) if p is not None]
    reason = os_error_reason(exc)
    return f"{' -> '.join(paths)}: {reason}" if paths else reason


def _one_line_warning(message, category, filename, lineno, file=None, line=None) -> None:
    """A warning on the command line is one line, like an error: ``warning: <message>``."""
    print(f"warning: {message}", file=sys.stderr if file is None else file)


if __name__ == "__main__":
    sys.exit(main())
