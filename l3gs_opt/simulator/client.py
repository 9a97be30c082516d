"""One simulated client's state through a run, and the loop that drives clients over a trace.

:class:`Client` holds what one method's client has (bytes per unit, complete units, each
chunk's splat order), its link and its records; :func:`drive` runs clients slot by slot and, in
each part of a slot (``SimConfig.substeps``), lets every client plan, splits the part's bytes
max-min fairly among their demands (:func:`l3gs_opt.simulator.link.max_min_shares`; a single client gets
all of them) and delivers. :meth:`Simulation.run` drives one client, :func:`l3gs_opt.simulator.shared.run_shared`
several.

With ``views_dir`` a client also keeps what its viewer saw: each slot's image as
``VIEWS/<views_folder(...)>/SSS.png`` and the reference as ``VIEWS/reference/SSS.png`` (``SSS``: the
slot, three digits or more), written atomically before the slot's record, so a record implies its
pictures and an interrupted run keeps every finished slot's; ``VIEWS/<folder>/views.json`` names the
run (``run_id``) the pictures belong to. The runs written to one folder share the reference
pictures (the latest run's): they are meant to share the viewer and the reference scene.
"""

from __future__ import annotations

import dataclasses
import json
import math
import os
import re
import time
from pathlib import Path
from typing import Sequence

import numpy as np

from l3gs_opt.output_files import write_atomic
from l3gs_opt.simulator.link import Link, max_min_shares, split_bytes
from l3gs_opt.simulator.config import TIMING_KEYS, SimulationError, SlotInputs
from l3gs_opt.simulator.records import RecordWriter, RunSummary, SimulationResult
from l3gs_opt.simulator.schedulers import ItemSlotView, SlotView

__all__ = ["Client", "drive", "views_folder", "REFERENCE_VIEWS", "VIEWS_FILE"]

#: Folder of the reference pictures under a views folder; ``views_folder`` never returns it.
REFERENCE_VIEWS = "reference"
#: The file beside a method's pictures that names the run they belong to.
VIEWS_FILE = "views.json"
_PICTURE = re.compile(r"[0-9]{3,}\.png")


def _finite_or_none(v: float) -> float | None:
    return float(v) if math.isfinite(v) else None


def views_folder(method: str, solver: str | None = None, utility: str | None = "eq1",
                 client: int | None = None) -> str:
    """The folder name of a run's pictures under a views folder: the method, then the solver,
    the utility (when not ``eq1``) and the client (when shared), joined by ``__``; characters
    other than letters, digits, ``.``, ``-`` and ``_`` become ``-`` (``rolling:bb`` -> ``rolling-bb``)."""
    parts = [method] + ([solver] if solver else []) + ([utility] if utility not in (None, "eq1") else []) \
        + ([f"c{client}"] if client is not None else [])
    name = "__".join(re.sub(r"[^A-Za-z0-9._-]+", "-", str(p)) for p in parts)
    return name if name != REFERENCE_VIEWS else name + "__"


def _save_png(path: Path, image: np.ndarray) -> None:
    """``image`` (float ``[H, W, 3]`` in [0, 1]) as an 8-bit PNG, replaced atomically (a reader or an
    interruption never sees half a file)."""
    from PIL import Image   # matplotlib's own PNG writer; a dependency through it

    pixels = np.round(np.clip(image, 0.0, 1.0) * 255.0).astype(np.uint8)
    write_atomic(path, lambda fh: Image.fromarray(pixels, "RGB").save(fh, format="PNG"))


class Client:
    """One method's client on a :class:`~l3gs_opt.simulator.simulation.Simulation` (see the module docstring).

    ``index`` / ``clients``: its place among the clients of a shared link (None / 1: alone).
    With ``resume``, the recorded slots are replayed first (:attr:`first_slot` is where the run
    goes on).
    """

    def __init__(self, sim, spec, *, index: int | None = None, clients: int = 1, out_dir=None, resume: bool = False,
                 views_dir=None):
        self.sim, self.spec = sim, spec
        self.cfg = cfg = sim.config
        self.cat = cat = sim.catalog(spec.view)
        K = cat.units
        self.got = np.zeros(K, np.int64)            # bytes delivered per unit
        self.complete = cat.splats == 0
        self.order: list = [None] * K
        if spec.preload:
            for k in cat.top_units():
                self.complete[k] = True
                self.order[k] = cat.rows[k]
        # Capacities are set part by part (a shared link's share is decided as the slot runs).
        self.link = Link([0] * (sim.T * cfg.substeps), budget=cfg.budget, carry=cfg.carry)
        # A kept-busy link never idles while something is left, and a chunk cut off carries over:
        # the bytes arriving by slot t are bounded by the bytes up to t, the cumulative budget.
        self.plan_budget = "cumulative" if cfg.budget == "cumulative" or cfg.fill else "per_slot"
        self.index, self.clients = index, clients
        self.history: list[int] = []                # bytes the link gave this client per slot
        self.records: list[dict] = []
        self.idle_total = 0
        self.load_start = list(os.getloadavg())
        self.started = time.perf_counter()
        self.renders_before = dict(sim.renders)
        self.run = sim.run_id(spec, index, clients)
        self.writer = RecordWriter(out_dir, spec.name, spec.solver, client=index, run=self.run, resume=resume,
                                   utility=spec.utility)
        for record in self.writer.resumed:
            self._replay(record)
        self.first_slot = len(self.records)
        try:
            self.views = None if views_dir is None else self._start_views(Path(views_dir), resume)
        except BaseException:
            self.writer.close()
            raise

    def _start_views(self, views: Path, resume: bool) -> tuple[Path, Path]:
        """This run's picture folder and the reference folder, created; a fresh run first drops
        the pictures an earlier run of the same key left (they would pass for this run's)."""
        spec = self.spec
        mine = views / views_folder(spec.name, spec.solver, spec.utility, self.index)
        reference = views / REFERENCE_VIEWS
        for folder in (views, mine, reference):
            if folder.exists() and not folder.is_dir():
                raise SimulationError("views", f"{folder} is a file: expected a folder")
            folder.mkdir(parents=True, exist_ok=True)
        if not resume:
            for old in mine.iterdir():
                if _PICTURE.fullmatch(old.name):
                    old.unlink()
        (mine / VIEWS_FILE).write_text(json.dumps({"run_id": self.run, "method": spec.name, "solver": spec.solver,
                                                   "utility": spec.utility, "client": self.index}) + "\n")
        return mine, reference

    # -- one slot -----------------------------------------------------------------------------------
    def slot_inputs(self, t: int) -> SlotInputs:
        """What the simulation computes for this client's slot ``t``: by its utilities, given the
        rows it shows now (held-aware utilities only)."""
        sim, spec = self.sim, self.spec
        held = None
        if sim.valuation(spec.utility, spec.order_utility).held_aware:
            rows = sim.shown_rows(self.cat, self.got, self.complete, self.order, spec.preload)[0]
            held = np.zeros(sim.scene.num_splats, bool)
            held[rows] = True
        return sim.slot_inputs(t, self.cat, self.history, self.clients, utility=spec.utility,
                               order_utility=spec.order_utility, held=held)

    def begin_slot(self, inputs: SlotInputs) -> None:
        """Start slot ``inputs.slot`` with what the simulation computed for it."""
        self.t = inputs.slot
        self.inputs = inputs
        self.unit_u, lookup_s = inputs.unit_utility, inputs.lookup_s
        self.predicted = inputs.predicted_bytes
        self.part = 0
        self.acc = {"share": 0, "capacity": self.link.bank, "delivered": 0, "requests": [], "parts": [],
                    "part_bytes": [], "part_predicted": [], "completed": [], "schedule_s": 0.0, "order_s": 0.0,
                    "lookup_s": lookup_s, "delivery": None}

    def view(self) -> SlotView:
        """The scheduler's view before the current part of the slot."""
        cat, cfg, S, s = self.cat, self.cfg, self.cfg.substeps, self.part
        # Before a later part: what this slot gave so far, extrapolated over the parts left.
        predicted = self.predicted if s == 0 else (self.acc["share"] * (S - s)) // s
        flight = np.zeros(cat.units, bool)
        for transfer in self.link.in_flight:
            flight[transfer.key] = True
        grid = cat.grid
        kw = dict(slot=self.t, slots_left=self.sim.T - self.t, representation=cat.representation, cost=cat.cost,
                  utility=self.unit_u, predicted_bytes=int(predicted), bank_bytes=self.link.bank,
                  in_flight_bytes=self.link.in_flight_bytes, held=self.complete.reshape(grid).copy(),
                  in_flight=flight.reshape(grid), empty=cat.empty, budget=self.plan_budget, slot_s=cfg.slot_s,
                  predicted_bytes_later=self.predicted if S > 1 else None)
        if cat.view in ("distill", "hierarchy"):
            return ItemSlotView(variant=cat.view, **kw)
        values = self.inputs.splat_values
        if values is not None:
            def prefix(unit: tuple[int, ...]) -> np.ndarray:
                rows = self.stream_rows(int(np.ravel_multi_index(unit, grid)))
                return np.concatenate([[0.0], np.cumsum(values()[rows])])

            kw.update(prefix=prefix, bytes_per_splat=cat.bytes_per_splat.reshape(grid))
        return SlotView(**kw)

    def stream_rows(self, k: int) -> np.ndarray:
        """Rows of unit ``k`` in the order the link sends them to this client in this slot."""
        if self.spec.order == "utility":
            return self.inputs.splat_order(k)
        return self.cat.stored_rows(k) if self.spec.order == "file" else self.cat.rows[k]

    def plan(self) -> list[int]:
        """The unit ids this client requests in the current part of the slot."""
        view = self.view()
        self.acc["part_predicted"].append(view.predicted_bytes)
        t0 = time.perf_counter()
        wanted = self.spec.scheduler.requests(view)
        self.acc["schedule_s"] += time.perf_counter() - t0
        return self.sim.check_requests(wanted, view, self.spec.name)

    def demand(self, ids: Sequence[int]) -> int:
        return self.link.demand([(k, int(self.cat.bytes[k])) for k in ids])

    def deliver(self, ids: Sequence[int], share: int) -> None:
        """Move ``share`` bytes of the bottleneck (plus the bank) for the current part."""
        cat, acc = self.cat, self.acc
        head = 0
        if self.cfg.decision_s and (self.t > 0 or self.part > 0):   # slot 0's clock starts with its requests
            head = int(round(int(share) * self.cfg.decision_s * self.cfg.substeps / self.cfg.slot_s))
        delivery = self.link.step([(k, int(cat.bytes[k])) for k in ids], bandwidth=share, head_bytes=head)
        t1 = time.perf_counter()
        for k in delivery.started:
            self.order[k] = self.stream_rows(k)
        acc["order_s"] += time.perf_counter() - t1
        for k, b in delivery.delivered.items():
            self.got[k] += b
        for k in delivery.completed:
            self.complete[k] = True
        acc["share"] += int(share)
        acc["capacity"] += int(share)
        acc["delivered"] += delivery.bytes
        acc["requests"] += list(ids)
        acc["parts"].append(list(ids))
        acc["part_bytes"].append(int(share))
        acc["completed"] += list(delivery.completed)
        acc["delivery"] = delivery
        self.part += 1

    def _slot_record(self) -> dict:
        """The record of the slot just delivered, without the rendering fields."""
        cat, acc, t = self.cat, self.acc, self.t
        d = acc["delivery"]
        label = lambda k: list(cat.label(k))  # noqa: E731
        record = {"method": self.spec.name, "solver": self.spec.solver, "utility": self.spec.utility,
                  "order_utility": self.spec.order_utility, "slot": t,
                  "time_s": (t + 1) * self.cfg.slot_s, "ssim": None, "psnr": None, "splats_shown": None,
                  "bytes_trace": int(self.sim.link_bytes[t]), "bytes_share": acc["share"],
                  "bytes_capacity": int(acc["capacity"]), "bytes_delivered": int(acc["delivered"]),
                  "bytes_idle": int(acc["capacity"] - acc["delivered"]), "bytes_banked": int(d.banked),
                  "predicted_bytes": int(self.predicted), "requests": [label(k) for k in acc["requests"]],
                  "completed": [label(k) for k in acc["completed"]],
                  "in_flight": [[*label(k), int(r)] for k, r in d.in_flight], "run_id": self.run}
        if self.cfg.substeps > 1:
            record["substep_requests"] = [[label(k) for k in ids] for ids in acc["parts"]]
            record["substep_bytes"] = acc["part_bytes"]
            record["substep_predicted"] = acc["part_predicted"]
        if self.index is not None:
            record["client"] = self.index
            record["clients"] = self.clients
        return record

    def end_slot(self, *, defer: bool = False):
        """Render what is held from the true viewpoint, score it, record the slot.

        ``defer``: close the slot's bookkeeping now (the bandwidth history, what is shown) and
        return a callable that renders, scores and records it later -- a real client plans the
        next slot first and draws while its requests stream (``l3gs-opt fetch``). Call it before
        the next ``end_slot``. Returns the record (or that callable).
        """
        sim, acc, t = self.sim, self.acc, self.t
        self.history.append(acc["share"])
        record = self._slot_record()
        self.idle_total += record["bytes_idle"]
        rows, _, full = sim.shown_rows(self.cat, self.got, self.complete, self.order, self.spec.preload)
        timings = {"prediction": self.inputs.prediction["prediction_s"], "utility": acc["lookup_s"] + acc["order_s"],
                   "scheduling": acc["schedule_s"]}

        def finish() -> dict:
            from l3gs_opt.renderer.metrics import psnr, ssim

            t2 = time.perf_counter()
            image, reused = sim.client_image(rows, full, sim.true_camera(t))
            render_s = time.perf_counter() - t2
            ref, reference_s = sim.reference_image(t)
            t3 = time.perf_counter()
            s, p = ssim(image, ref), psnr(image, ref)
            metrics_s = time.perf_counter() - t3
            record.update(ssim=s, psnr=_finite_or_none(p), splats_shown=int(rows.size), render_reused=reused,
                          timings_s={**timings, "rendering": render_s, "reference": reference_s,
                                     "metrics": metrics_s})
            if full is not None:
                record["splats_full_sh"] = int(full.sum())
            if self.views is not None:
                _save_png(self.views[0] / f"{t:03d}.png", image)
                _save_png(self.views[1] / f"{t:03d}.png", ref)
            self.records.append(record)
            self.writer.slot(record)
            return record

        return finish if defer else finish()

    # -- resume ---------------------------------------------------------------------------------------
    def _replay(self, record: dict) -> None:
        """Re-run a recorded slot's deliveries (no scheduling, no rendering) and check them."""
        t = len(self.records)
        cat = self.cat
        self.begin_slot(self.slot_inputs(t))
        parts = record.get("substep_requests", [record["requests"]])
        shares = record.get("substep_bytes", [record.get("bytes_share", record["bytes_trace"])])
        if len(parts) != self.cfg.substeps or len(shares) != len(parts):
            raise SimulationError("resume", f"slot {t}: recorded with {len(parts)} parts per slot, this run has "
                                            f"{self.cfg.substeps}")
        for labels, share in zip(parts, shares):
            self.deliver([cat.unit(u) for u in labels], int(share))
        self.history.append(self.acc["share"])
        again = self._slot_record()
        for key in ("bytes_trace", "bytes_capacity", "bytes_delivered", "bytes_idle", "bytes_banked",
                    "predicted_bytes", "completed", "in_flight"):
            if again[key] != record.get(key):
                raise SimulationError("resume", f"slot {t}: replaying the recorded requests gives {key} = "
                                                f"{again[key]!r}, the record says {record.get(key)!r}: the records do "
                                                "not come from this run; run without resume to start over")
        self.idle_total += record["bytes_idle"]
        self.records.append(record)

    # -- the end --------------------------------------------------------------------------------------
    def finish(self):
        """The :class:`SimulationResult` (and the summary line written)."""
        sim, cat, cfg, spec = self.sim, self.cat, self.cfg, self.spec
        K = cat.units
        J, L = cat.shape
        rows, shown_units, full = sim.shown_rows(cat, self.got, self.complete, self.order, spec.preload)
        got = self.got
        delivered = int(got.sum())
        useful = int(sum(int(min(got[k], (got[k] // cat.bytes_per_splat[k]) * cat.bytes_per_splat[k]))
                         for k in shown_units if cat.bytes_per_splat[k]))
        replaced = int(sum(int(got[k]) for k in range(K) if self.complete[k] and k not in shown_units))
        result = SimulationResult(spec.name, spec.solver, records=self.records)
        timings = {key: float(np.mean([r["timings_s"][key] for r in self.records])) for key in TIMING_KEYS}
        ssims = result.ssim_per_s
        psnrs = [r["psnr"] for r in self.records]
        renders = {k: sim.renders[k] - self.renders_before[k] for k in sim.renders}
        m = sim.bundle.manifest
        result.summary = RunSummary(
            method=spec.name, solver=spec.solver, utility=spec.utility, order_utility=spec.order_utility,
            slots=sim.T, slot_s=cfg.slot_s,
            ssim_mean=float(np.mean(ssims)), ssim_per_s=tuple(ssims), psnr_per_s=tuple(psnrs),
            psnr_mean=float(np.mean([p for p in psnrs if p is not None])) if any(p is not None for p in psnrs)
            else None,
            bytes_delivered=delivered, bytes_wasted=delivered - useful, bytes_replaced=replaced,
            bytes_unshown=delivered - useful - replaced, bytes_idle=int(self.idle_total),
            bytes_trace=int(sum(sim.link_bytes)), bytes_share=int(sum(self.history)),
            bytes_model=int(cat.bytes[cat.top_units()].sum()),
            splats_final=int(rows.size), timings_mean_s=timings, run_s=time.perf_counter() - self.started,
            loadavg_start=tuple(self.load_start), loadavg_end=tuple(os.getloadavg()),
            bundle=str(sim.bundle.path), variant=m["variant"], representation=cat.representation,
            view=cat.view, units=tuple(cat.grid), reference=sim.reference_label,
            config=dataclasses.asdict(cfg), render_backend=sim.render_backend, renders=renders,
            resumed_slots=self.first_slot, run_id=self.run, client=self.index,
            clients=None if self.index is None else self.clients, info=dict(sim.info))
        result.final_rows = rows
        self.writer.summary(result.summary.to_dict())
        return result


def drive(clients: Sequence[Client], bandwidth: Sequence[int], *, start: int = 0, progress: bool = False) -> None:
    """Run ``clients`` from slot ``start`` to the end of ``bandwidth`` (bytes per slot) on one bottleneck."""
    from tqdm import tqdm

    parts = clients[0].cfg.substeps
    name = clients[0].spec.name if len(clients) == 1 else f"{len(clients)} clients"
    for t in tqdm(range(start, len(bandwidth)), desc=f"simulate {name}", unit="slot", disable=not progress,
                  initial=start, total=len(bandwidth)):
        for c in clients:
            c.begin_slot(c.slot_inputs(t))
        for total in split_bytes(int(bandwidth[t]), parts):
            ids = [c.plan() for c in clients]
            shares = max_min_shares(total, [c.demand(i) for c, i in zip(clients, ids)])
            for c, i, share in zip(clients, ids, shares):
                c.deliver(i, share)
        for c in clients:
            c.end_slot()
