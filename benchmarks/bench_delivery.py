"""Real delivery against the simulator, and the server's cost (issue 24's goals).

Usage::

    .venv/bin/python benchmarks/bench_delivery.py [--windows 0,20,40] [--slots 16]
        [--methods l3gs,sort] [--load-s 10] [--clients 50] [--carry started|head]
        [--out benchmarks/results/delivery]

1. **The demo room** (as ``l3gs-opt demo`` builds it: 12k splats, 4 objects, a ``sort`` bundle of
   1.5k/3k/6k/12k splats, QUICK schedule), exported as a stream (``index.json`` + ``chunks.bin``),
   the demo's orbiting viewer, the bundled Lumos5G trace ``mid-11`` scaled so the scene takes ~12 s
   at its mean.
2. **fetch against simulate.** ``l3gs-opt serve`` runs in its own process, pacing each session to the
   same scaled trace. For every trace window (``--windows``: first seconds) and method, ``fetch``
   streams ``--slots`` one-second slots over loopback; then ``simulate`` runs the same window, viewer
   and method on the trace's bytes (what a simulation study would do), and once more on the bytes
   ``fetch`` measured (which separates the link's throughput from the link model). Reported per slot:
   the bytes that arrived against the trace's bytes for the slot, counted only in *busy* slots (the
   client still had a unit in flight or a request not started at the cut, so the link was never idle
   for want of work; slot 0 is excluded, as the issue says); and the per-second SSIM difference of
   each simulation against ``fetch``.
3. **Server cost.** The same server without pacing under ``--clients`` concurrent sessions for
   ``--load-s`` seconds, each asking (a) whole chunks, (b) 1 KiB ranges, in a loop: requests per
   second, MB/s and the server process's CPU seconds (``/proc/PID/stat``) per MB served. The client
   runs in this process on the same 2 cores, so these are lower bounds of what the server can do.

Writes ``<out>.json`` and ``<out>.md`` (machine, load, versions).
"""

from __future__ import annotations

import argparse
import asyncio
import dataclasses
import datetime
import json
import os
import random
import signal
import socket
import subprocess
import sys
import time
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parent))
from machine import machine_info  # noqa: E402
from l3gs_opt.jsonout import dumps  # noqa: E402

TRACE = "lumos-throughput-mid-11"
ROOT = Path(__file__).resolve().parents[1]


def build_room(work: Path) -> tuple[Path, object, float, Path]:
    """The demo's room as a stream export; returns (export folder, teacher, mbps, viewer log)."""
    from l3gs_opt.pipeline.build import QUICK, build_bundle
    from l3gs_opt.scene.bundle import read_bundle
    from l3gs_opt.scene.camera_paths import orbit_path
    from l3gs_opt.scene.procedural import make_scene
    from l3gs_opt.scene.stream_index import export_stream
    from l3gs_opt.traces.poses import synthetic_poses, write_pose_log

    teacher = make_scene(12_000, objects=4, sh_degree=1, seed=0)
    bundle_dir = work / "bundle"
    if not (bundle_dir / "manifest.json").exists():
        build_bundle(teacher, orbit_path(12, width=160, height=120), [1500, 3000, 6000, 12_000], "sort",
                     bundle_dir, schedule=QUICK, show_progress=False)
    total = sum(c["bytes"] for c in read_bundle(bundle_dir).manifest["chunks"])
    mbps = total * 8 / 1e6 / 12.0
    export = export_stream(bundle_dir, work / "stream", pack="single").parent
    log = write_pose_log(synthetic_poses("orbit", seconds=80, rate_hz=30, seed=0), work / "viewer.log")
    return export, teacher, mbps, log


def _free_port() -> int:
    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        return s.getsockname()[1]


class Server:
    """``l3gs-opt serve`` in its own process (so its CPU time is its own)."""

    def __init__(self, folder: Path, *, trace: str | None = None, mbps: float | None = None):
        self.port = _free_port()
        cmd = [str(ROOT / ".venv" / "bin" / "l3gs-opt"), "serve", str(folder), "--port", str(self.port)]
        if trace is not None:
            cmd += ["--trace", trace, "--mbps", repr(mbps), "--no-anonymous-pacing"]
        self.proc = subprocess.Popen(cmd, stdout=subprocess.DEVNULL, stderr=subprocess.PIPE)
        deadline = time.monotonic() + 30
        while time.monotonic() < deadline:
            try:
                with socket.create_connection(("127.0.0.1", self.port), timeout=0.5):
                    break
            except OSError:
                time.sleep(0.1)
        else:
            raise RuntimeError(f"the server did not start: {self.proc.stderr.read().decode()[-500:]}")
        self.url = f"http://127.0.0.1:{self.port}"

    def cpu_s(self) -> float:
        """User + system CPU seconds of the server process so far."""
        fields = Path(f"/proc/{self.proc.pid}/stat").read_text().rsplit(")", 1)[1].split()
        return (int(fields[11]) + int(fields[12])) / os.sysconf("SC_CLK_TCK")

    def stop(self) -> None:
        self.proc.send_signal(signal.SIGINT)
        try:
            self.proc.wait(10)
        except subprocess.TimeoutExpired:
            self.proc.kill()


def _busy(rec: dict) -> bool:
    """The link had work until the slot's cut: a unit in flight, or a request that did not start."""
    done = {tuple(u[:2]) for u in rec["completed"]} | {tuple(u[:2]) for u in rec["in_flight"]}
    waiting = [r for r in rec["requests"] if tuple(r[:2]) not in done]
    return bool(rec["in_flight"]) or bool(waiting)


def compare_run(export: Path, teacher, mbps: float, log: Path, method: str, window: int, slots: int,
                work: Path, server: Server, carry: str = "started") -> dict:
    """One fetch and its simulations. ``method``: ``NAME[:UTILITY][@tables]`` (``@tables``: the client
    knows only the index and the server's utility tables)."""
    from l3gs_opt.delivery.fetch import fetch
    from l3gs_opt.delivery.tables import load_table, read_tables
    from l3gs_opt.pipeline.scene_instance import Z_UP_MAPPING
    from l3gs_opt.scene.stream_index import read_stream, stream_bundle
    from l3gs_opt.simulator.simulation import SimConfig, Simulation, trace_bytes

    spec, _, catalogue = method.partition("@")
    catalogue = catalogue or "full"
    name, _, utility = spec.partition(":")
    config = SimConfig(width=160, height=120, utility=utility or "eq1", carry=carry)
    out = work / f"fetch-{name}-{utility or 'eq1'}-{catalogue}-w{window}-{carry}"
    cpu0, t0 = server.cpu_s(), time.monotonic()
    got = fetch(server.url, TRACE, log, name, out, slots=slots, start=window, mbps=mbps, config=config,
                mapping=Z_UP_MAPPING, reference=teacher, catalogue=catalogue)
    wall, cpu = time.monotonic() - t0, server.cpu_s() - cpu0
    recs = [json.loads(line) for line in (out / "slots.jsonl").read_text().splitlines()]
    trace, _ = trace_bytes(TRACE, mbps=mbps, start=window, slots=slots)
    bundle = stream_bundle(read_stream(export))
    measured = [r["fetch"]["bytes_received"] for r in recs]
    stored = dataclasses.replace(config, splat_order="stored")
    # The client's planning time as fetch measured it (median over slots after the first).
    decision = float(np.median([r["fetch"]["late_s"] for r in recs[1:]])) if slots > 1 else 0.0
    tables = None
    if catalogue == "tables":
        tables = {(e["utility"], e["view"]): load_table(e, (export / e["file"]).read_bytes())
                  for e in read_tables(export)}
        stored = dataclasses.replace(stored, utility_mode="table")
    sims = {"sim_trace": (trace, stored, tables), "sim_measured": (measured, stored, tables),
            "sim_trace_decision": (trace, dataclasses.replace(stored, decision_s=decision), tables)}
    if catalogue == "tables":
        sims["sim_trace_exact_utilities"] = (trace, dataclasses.replace(stored, utility_mode="exact"), None)
    else:
        sims["sim_trace_utility_order"] = (trace, config, None)
    f_ssim = np.array(got.summary["ssim_per_s"])
    per_s, diff, mean = {}, {}, {"fetch": float(f_ssim.mean())}
    for key, (bw, cfg, tabs) in sims.items():
        sim = Simulation(bundle, log, bw, config=cfg, reference=teacher, mapping=Z_UP_MAPPING, utility_tables=tabs)
        s = sim.run(name).summary
        per_s[key] = s["ssim_per_s"]
        diff[key] = float(np.max(np.abs(np.array(s["ssim_per_s"]) - f_ssim)))
        mean[key] = s["ssim_mean"]
    busy = [t for t in range(1, slots) if _busy(recs[t])]
    ratio = [measured[t] / trace[t] for t in busy if trace[t] > 0]
    bundle_bytes = sum(c.bytes for c in read_stream(export).chunks)
    return {
        "method": method, "catalogue": catalogue, "carry": carry, "window_start_s": window, "slots": slots, "wall_s": wall,
        "metadata_bytes": got.summary.get("metadata_bytes"),
        "trace_bytes": [int(b) for b in trace], "fetch_bytes": measured,
        "busy_slots": busy, "bytes_ratio_busy": ratio,
        "max_bytes_error_busy": max((abs(r - 1) for r in ratio), default=None),
        "late_s": [r["fetch"]["late_s"] for r in recs], "retries": sum(r["fetch"]["retries"] for r in recs),
        "cut_late_s": [r["fetch"].get("cut_late_s", 0.0) for r in recs],
        "ssim_fetch": f_ssim.tolist(), "ssim_per_s": per_s, "max_ssim_diff": diff, "mean_ssim": mean,
        "decision_s": decision,
        "server_cpu_s": cpu, "bytes_served": int(sum(measured)) + (bundle_bytes if catalogue == "full" else 0),
        "catalogue_bytes": bundle_bytes,
    }


async def _load(url: str, ranges: list[tuple[int, int]], clients: int, seconds: float) -> dict:
    import aiohttp

    counts, sizes, errors = [0] * clients, [0] * clients, [0] * clients
    stop = time.monotonic() + seconds

    async def worker(i: int, session) -> None:
        rng = random.Random(i)
        while time.monotonic() < stop:
            lo, hi = ranges[rng.randrange(len(ranges))]
            try:
                async with session.get(f"{url}/chunks.bin", headers={"Range": f"bytes={lo}-{hi - 1}"}) as r:
                    body = await r.read()
                    if r.status != 206 or len(body) != hi - lo:
                        errors[i] += 1
                        continue
            except aiohttp.ClientError:
                errors[i] += 1
                continue
            counts[i] += 1
            sizes[i] += len(body)

    conn = aiohttp.TCPConnector(limit=clients)
    async with aiohttp.ClientSession(connector=conn, timeout=aiohttp.ClientTimeout(total=60)) as session:
        t0 = time.monotonic()
        await asyncio.gather(*(worker(i, session) for i in range(clients)))
        wall = time.monotonic() - t0
    return {"requests": sum(counts), "bytes": sum(sizes), "errors": sum(errors), "wall_s": wall}


def load_test(export: Path, clients: int, seconds: float) -> list[dict]:
    from l3gs_opt.scene.stream_index import read_stream

    chunks = [c for c in read_stream(export).chunks if c.bytes]
    cases = {"whole chunks": [(c.start, c.end) for c in chunks],
             "1 KiB ranges": [(c.start, c.start + min(1024, c.bytes)) for c in chunks]}
    out = []
    for label, ranges in cases.items():
        server = Server(export)
        try:
            cpu0 = server.cpu_s()
            r = asyncio.run(_load(server.url, ranges, clients, seconds))
            cpu = server.cpu_s() - cpu0
        finally:
            server.stop()
        mb = r["bytes"] / 1e6
        out.append({"case": label, "clients": clients, **r, "requests_per_s": r["requests"] / r["wall_s"],
                    "mb_per_s": mb / r["wall_s"], "server_cpu_s": cpu,
                    "server_cpu_s_per_mb": cpu / mb if mb else None,
                    "server_cpu_ms_per_request": 1e3 * cpu / r["requests"] if r["requests"] else None,
                    "mean_range_bytes": r["bytes"] / max(r["requests"], 1)})
        print(f"  load {label}: {out[-1]['requests_per_s']:.0f} req/s, {out[-1]['mb_per_s']:.1f} MB/s, "
              f"server CPU {cpu:.2f} s, {r['errors']} errors", flush=True)
    return out


def _fmt_ssim(x) -> str:
    return f"{x:.3f}"


def write_report(data: dict, out: Path) -> None:
    out.with_suffix(".json").write_text(dumps(data, indent=1))
    m = data["machine"]
    lines = [
        "# Real delivery against the simulator, and the server's cost (issue 24)", "",
        f"Run {data['date']} on {m['cpu']} ({m['cores']} cores), Python {m['python']}, "
        f"aiohttp {data['aiohttp']}, load average at start {m['loadavg_at_start'][0]:.2f}, at end "
        f"{data['loadavg_at_end'][0]:.2f}; {data['elapsed_s']:.0f} s in all. Command: "
        f"`{data['command']}`.", "",
        f"The demo room (12k splats, 4 objects, `sort` bundle of 4 levels, {data['catalogue_bytes']:,} bytes), "
        f"the demo's orbiting viewer, Lumos5G `{TRACE}` scaled to {data['mbps']:.3f} Mbit/s (the scene in ~12 s), "
        f"160x120, {data['slots']} one-second slots per window. `l3gs-opt serve` paces each session to the trace "
        "in its own process; `fetch` streams over loopback.", "",
        f"What a slot's cut keeps on the wire (`--carry`, the same in fetch and every simulation): "
        f"**{data.get('carry', 'started')}** -- " + (
            "the first request not finished stays open across the cut even with no byte yet."
            if data.get("carry") == "head" else
            "only a unit that got bytes carries over; a request with no byte yet is aborted and re-planned."), "",
        "## Bytes: fetch against the trace (busy slots after slot 0)", "",
        "`late`: seconds from a slot's start until its requests went out (the client's planning: only the "
        "unit carried over streams meanwhile, and the link idles if it ends first; the simulator's link plans in no "
        "time); `cut late`: slots whose bytes were counted more than 10 ms after their end.", "",
        "| method | window | busy slots | fetch / trace bytes: min | median | max | max error | late: median / max (ms) "
        "| cut late | retries |",
        "|---|---|---|---|---|---|---|---|---|---|"]
    for r in data["runs"]:
        q = r["bytes_ratio_busy"]
        if q:
            late = 1e3 * np.array(r["late_s"][1:])
            cut = sum(x > 0.01 for x in r.get("cut_late_s", []))
            lines.append(f"| {r['method']} | {r['window_start_s']} s | {len(q)} | {min(q):.3f} | "
                         f"{float(np.median(q)):.3f} | {max(q):.3f} | {100 * r['max_bytes_error_busy']:.1f} % | "
                         f"{np.median(late):.0f} / {late.max():.0f} | {cut} | {r['retries']} |")
        else:
            lines.append(f"| {r['method']} | {r['window_start_s']} s | 0 | - | - | - | - | - | - | {r['retries']} |")
    lines += ["", "## SSIM: simulate against fetch", "",
              "`sim(trace)`: the simulator on the trace's bytes with what the fetch client knew -- each chunk's "
              "splats in the stored order (static files fetched by Range: `--splat-order stored`), and for "
              "`@tables` runs the server's utility tables (`utility_mode` table); `sim(measured)`: the same on the "
              "bytes fetch measured (it differs from fetch only in slot 0's bandwidth guess, which is the trace's "
              "for fetch). Last column, for full-catalogue runs: the simulator's default (each chunk's splats "
              "re-sorted by predicted utility, a server that could reorder per request); for `@tables` runs: the "
              "simulator valuing by exact utilities from every splat (what knowing the whole bundle is worth).", "",
              "`sim(trace, d)`: sim(trace) with the client's planning time `--decision-s d` (d = the median of "
              "fetch's `late_s`), during which only the carried-over unit streams.", "",
              "| method | window | mean SSIM fetch | sim(trace) | sim(measured) | sim(trace, d) (d, ms) | last column's sim | "
              "max per-second diff: sim(trace) | sim(measured) | sim(trace, d) | last column's sim |",
              "|---|---|---|---|---|---|---|---|---|---|---|"]
    for r in data["runs"]:
        s, d = r["mean_ssim"], r["max_ssim_diff"]
        last = "sim_trace_exact_utilities" if r["catalogue"] == "tables" else "sim_trace_utility_order"
        dec = (f"{s['sim_trace_decision']:.4f} ({1e3 * r['decision_s']:.0f})" if "sim_trace_decision" in s else "-")
        ddec = f"{d['sim_trace_decision']:.4f}" if "sim_trace_decision" in d else "-"
        lines.append(f"| {r['method']} | {r['window_start_s']} s | {s['fetch']:.4f} | {s['sim_trace']:.4f} | "
                     f"{s['sim_measured']:.4f} | {dec} | {s[last]:.4f} | {d['sim_trace']:.4f} | "
                     f"{d['sim_measured']:.4f} | {ddec} | {d[last]:.4f} |")
    within = sum(r["max_ssim_diff"]["sim_trace"] <= 0.02 for r in data["runs"])
    lines += ["", f"Runs whose simulated per-second SSIM (sim(trace)) is within 0.02 of fetch's every second: "
                  f"**{within} of {len(data['runs'])}**."]
    if all("sim_trace_decision" in r["max_ssim_diff"] for r in data["runs"]):
        within_d = sum(r["max_ssim_diff"]["sim_trace_decision"] <= 0.02 for r in data["runs"])
        lines += [f"With the planning time modelled (sim(trace, d)): **{within_d} of {len(data['runs'])}**."]
    tab = [r for r in data["runs"] if r["catalogue"] == "tables"]
    if tab:
        lines += [f"`@tables` runs read {tab[0]['metadata_bytes']:,} bytes of metadata (tables.json and the tables) "
                  f"before slot 0, against the {data['catalogue_bytes']:,} bytes of the whole bundle a "
                  "full-catalogue client reads."]
    lines += ["", "Per-second SSIM (fetch / sim(trace)):", ""]
    for r in data["runs"]:
        lines.append(f"- {r['method']} @ {r['window_start_s']} s: " + " ".join(
            f"{a:.3f}/{b:.3f}" for a, b in zip(r["ssim_fetch"], r["ssim_per_s"]["sim_trace"])))
    busy = [q for r in data["runs"] for q in r["bytes_ratio_busy"]]
    if busy:
        lines += ["", f"Bytes, all runs: {len(busy)} busy slots after slot 0, fetch/trace from {min(busy):.3f} to "
                      f"{max(busy):.3f}; within 5 %: {sum(abs(q - 1) <= 0.05 for q in busy)} of {len(busy)}."]
    paced_cpu = sum(r["server_cpu_s"] for r in data["runs"])
    paced_mb = sum(r["bytes_served"] for r in data["runs"]) / 1e6
    lines += ["", "## Server cost", "",
              f"Paced runs above: {paced_cpu:.2f} server CPU s for {paced_mb:.1f} MB served (catalogue included): "
              f"**{paced_cpu / paced_mb:.3f} CPU s per MB** at trace pace.", "",
              "Unpaced, concurrent sessions on loopback (client in the same 2 cores):", "",
              "| case | clients | requests/s | MB/s | server CPU s per MB | server CPU ms per request | errors |",
              "|---|---|---|---|---|---|---|"]
    for r in data["load"]:
        lines.append(f"| {r['case']} (mean {r['mean_range_bytes']:.0f} B) | {r['clients']} | "
                     f"{r['requests_per_s']:.0f} | {r['mb_per_s']:.1f} | {r['server_cpu_s_per_mb']:.4f} | "
                     f"{r['server_cpu_ms_per_request']:.3f} | {r['errors']} |")
    out.with_suffix(".md").write_text("\n".join(lines) + "\n")


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--windows", default="0,20,40")
    ap.add_argument("--slots", type=int, default=16)
    ap.add_argument("--methods", default="l3gs:visibility,l3gs:eq1,sort,l3gs:visibility@tables,l3gs:eq1@tables")
    ap.add_argument("--load-s", type=float, default=10.0)
    ap.add_argument("--clients", type=int, default=50)
    ap.add_argument("--carry", default="started", choices=["started", "head"],
                    help="what a slot's cut keeps on the wire, in fetch and the simulations (SimConfig.carry)")
    ap.add_argument("--work", default="/tmp/l3gs-bench-delivery")
    ap.add_argument("--out", default=str(ROOT / "benchmarks" / "results" / "delivery"))
    ap.add_argument("--report", action="store_true", help="rewrite <out>.md from <out>.json")
    args = ap.parse_args()
    if args.report:
        data = json.loads(Path(args.out).with_suffix(".json").read_text())
        for r in data["runs"]:   # records of a run before the catalogue field was fixed
            r["catalogue"] = "tables" if r["method"].endswith("@tables") else "full"
        write_report(data, Path(args.out))
        return
    import aiohttp

    t_start = time.monotonic()
    machine = machine_info()
    work = Path(args.work)
    work.mkdir(parents=True, exist_ok=True)
    export, teacher, mbps, log = build_room(work)
    print(f"room exported to {export}; trace scaled to {mbps:.3f} Mbit/s", flush=True)
    utilities = sorted({m.partition("@")[0].partition(":")[2] or "eq1" for m in args.methods.split(",") if "@tables" in m})
    if utilities:
        from l3gs_opt.delivery.tables import TABLES_NAME, export_tables, read_tables

        have = {e["utility"] for e in read_tables(export)} if (export / TABLES_NAME).exists() else set()
        for u in utilities:
            if u not in have:
                t0 = time.monotonic()
                export_tables(export, utility=u, views=("object",))
                print(f"  tables for {u}: {time.monotonic() - t0:.0f} s", flush=True)
                have.add(u)
    runs = []
    server = Server(export, trace=TRACE, mbps=mbps)
    try:
        for window in [int(w) for w in args.windows.split(",")]:
            for method in args.methods.split(","):
                r = compare_run(export, teacher, mbps, log, method, window, args.slots, work, server, args.carry)
                runs.append(r)
                print(f"  {method} @ {window}: bytes max error {r['max_bytes_error_busy']}, SSIM fetch "
                      f"{r['mean_ssim']['fetch']:.4f} sim {r['mean_ssim']['sim_trace']:.4f}, max diff "
                      f"{r['max_ssim_diff']}", flush=True)
    finally:
        server.stop()
    load = load_test(export, args.clients, args.load_s)
    data = {"date": datetime.datetime.now(datetime.timezone.utc).isoformat(timespec="seconds"),
            "machine": machine, "aiohttp": aiohttp.__version__, "command": " ".join(sys.argv),
            "mbps": mbps, "slots": args.slots, "carry": args.carry, "catalogue_bytes": runs[0]["catalogue_bytes"] if runs else None,
            "runs": runs, "load": load, "loadavg_at_end": os.getloadavg(), "elapsed_s": time.monotonic() - t_start}
    write_report(data, Path(args.out))
    print(f"wrote {args.out}.md / .json")


if __name__ == "__main__":
    main()
