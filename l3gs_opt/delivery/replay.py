"""A replay page of a simulated run: what each method's viewer saw, second by second.

:func:`write_replay` reads a ``l3gs-opt simulate --out RUN`` folder (``RUN/slots.jsonl``, the
``RUN/summary.jsonl`` lines when present, and the pictures of ``simulate --save-views`` under
``RUN/views``) and writes one self-contained HTML page: inline CSS, inline JavaScript, the charts
as inline SVG and the pictures as PNG files beside the page (copied, linked relatively), so it
opens from disk with no network. Per run (method, solver, utility, client) it shows

* the client's view of the current slot beside the reference (the full scene);
* SSIM per slot, and bytes per second (delivered as bars; the trace as a line), with a cursor;
* what arrived: a grid of chunks (objects down, layers -- and forms -- across), each coloured by
  its state at the end of the slot (arrived in this slot, held from before, partly arrived,
  requested but not started, not held).

One slider moves every run to a slot. A run without pictures (no ``--save-views``, or pictures
from a run with other inputs: their ``views.json`` names another ``run_id``) shows its curves and
arrivals and says that its views were not saved.
"""

from __future__ import annotations

import html
import json
import math
import os
import shutil
from dataclasses import dataclass
from pathlib import Path
from typing import Any, Sequence
from urllib.parse import quote

from l3gs_opt.errors import L3gsError
from l3gs_opt.input_files import check_regular_file
from l3gs_opt.output_files import write_atomic
from l3gs_opt.records import read_records
from l3gs_opt.simulator.client import REFERENCE_VIEWS, VIEWS_FILE, views_folder

__all__ = ["ReplayError", "write_replay", "PAGE_NAME", "UNIT_STATES"]

#: The page's file name inside the output folder.
PAGE_NAME = "index.html"
#: A chunk's state at the end of a slot, as the page's grid colours it (index = code).
UNIT_STATES = ("not held", "requested", "partly arrived", "arrived in this slot", "held from before")
#: Largest picture copied (bytes): a 4K PNG is ~25 MB; more is not a picture of ours.
_MAX_PICTURE_BYTES = 64 << 20
#: Largest views.json read (bytes).
_MAX_VIEWS_FILE_BYTES = 1 << 16
_PALETTE = ("#2563eb", "#dc2626", "#16a34a", "#9333ea", "#ea580c", "#0891b2", "#4d7c0f", "#be185d")


class ReplayError(L3gsError, ValueError):
    """A run folder cannot be replayed: no records, or a record that lacks a field the page needs.

    Attributes
    ----------
    field : str
        The field or file at fault (``"slots.jsonl"``, ``"slot"``, ``"out_dir"``, ...).
    index : tuple of int or None
        The 1-based number of the record at fault, when one record is.
    """

    def __init__(self, field: str, message: str, index: tuple[int, ...] | int | None = None):
        if isinstance(index, int):
            index = (index,)
        self.field = field
        self.index = tuple(int(i) for i in index) if index is not None else None
        where = field + "".join(f"[{i}]" for i in self.index or ())
        super().__init__(f"{where}: {message}")


@dataclass(frozen=True)
class _Run:
    """One run's slot records (sorted by slot) and what the page needs of them."""

    key: tuple
    records: tuple[dict, ...]
    summary: dict | None

    @property
    def label(self) -> str:
        method, solver, client, utility = self.key
        extra = [f"solver {solver}"] if solver else []
        extra += [f"utility {utility}"] if utility not in (None, "eq1") else []
        extra += [f"client {client}"] if client is not None else []
        return method + (f" ({', '.join(extra)})" if extra else "")

    @property
    def folder(self) -> str:
        method, solver, client, utility = self.key
        return views_folder(method, solver, utility, client)


def _key(record: dict) -> tuple:
    # As simulator.records keys a run (records without a utility were all eq1).
    return record.get("method"), record.get("solver"), record.get("client"), record.get("utility", "eq1")


def _is_number(v: Any) -> bool:
    return isinstance(v, (int, float)) and not isinstance(v, bool) and math.isfinite(v)


def _summary_limits(summary: dict | None) -> tuple[int, tuple[int, ...] | None]:
    """The slots a run's records may number (``[0, limit)``) and its chunk grid, from its summary:
    its ``slots`` and ``units``; without one (an interrupted run), the longest trace a simulation
    reads and no grid (the labels then define it)."""
    from l3gs_opt.traces.bandwidth import MAX_TRACE_SAMPLES

    s = summary or {}
    slots = s.get("slots")
    limit = slots if isinstance(slots, int) and not isinstance(slots, bool) and 0 < slots <= MAX_TRACE_SAMPLES \
        else MAX_TRACE_SAMPLES
    units = s.get("units")
    ok = isinstance(units, list) and 2 <= len(units) <= 3 and all(
        isinstance(v, int) and not isinstance(v, bool) and v > 0 for v in units)
    return limit, tuple(units) if ok else None


def _check_record(r: dict, i: int, summary: dict | None = None) -> None:
    """Refuse a record the page cannot show (``i``: its 1-based number in slots.jsonl), against its
    run's ``summary`` when there is one (its slot count and chunk grid)."""
    if not isinstance(r.get("method"), str) or not r["method"]:
        raise ReplayError("method", "missing or not a name", i)
    limit, units = _summary_limits(summary)
    slot = r.get("slot")
    if not isinstance(slot, int) or isinstance(slot, bool) or slot < 0:
        raise ReplayError("slot", f"{slot!r} must be an integer >= 0", i)
    # The page draws every slot up to the largest: a slot no run could have would hang it.
    if slot >= limit:
        raise ReplayError("slot", f"{slot} must be below {limit} (the run's "
                                  f"{'slots' if summary and summary.get('slots') == limit else 'longest trace'})", i)
    for field in ("ssim", "psnr"):
        if r.get(field) is not None and not _is_number(r[field]):
            raise ReplayError(field, f"{r[field]!r} must be a number or null", i)
    # SSIM is at most 1 (a picture equal to the reference) and at least -1.
    if r.get("ssim") is not None and not -1.0 <= r["ssim"] <= 1.0:
        raise ReplayError("ssim", f"{r['ssim']!r} must be in [-1, 1]", i)
    for field in ("bytes_delivered", "bytes_trace"):
        if not _is_number(r.get(field)) or r[field] < 0:
            raise ReplayError(field, f"{r.get(field)!r} must be a number of bytes >= 0", i)
    for field in ("requests", "completed", "in_flight"):
        labels = r.get(field, [])
        if not isinstance(labels, list):
            raise ReplayError(field, f"must be a list of chunk labels, not {type(labels).__name__}", i)
        for label in labels:
            if not (isinstance(label, list) and 2 <= len(label) <= 4
                    and all(isinstance(v, int) and not isinstance(v, bool) and v >= 0 for v in label)):
                raise ReplayError(field, f"{label!r} is not a chunk label (object, level[, form]) of integers >= 0", i)
            chunk = label[:-1] if field == "in_flight" else label   # in flight: the last entry is bytes left
            if units is not None and len(chunk) == len(units) and any(v >= n for v, n in zip(chunk, units)):
                raise ReplayError(field, f"{label!r}: no such chunk (the run's grid is "
                                         f"{' x '.join(map(str, units))})", i)


def _read_runs(run_dir: Path) -> list[_Run]:
    slots_path = check_regular_file(run_dir / "slots.jsonl", ReplayError, field="slots.jsonl")
    records = read_records(slots_path)
    if not records:
        raise ReplayError("slots.jsonl", f"{slots_path} holds no slot records")
    summaries = {}
    summary_path = run_dir / "summary.jsonl"
    if summary_path.exists():   # first: it bounds the records' slots and chunks
        for s in read_records(check_regular_file(summary_path, ReplayError, field="summary.jsonl")):
            if isinstance(s, dict):
                summaries[_key(s)] = s
    by_key: dict[tuple, dict[int, dict]] = {}
    for i, r in enumerate(records, start=1):
        _check_record(r, i, summaries.get(_key(r)) if isinstance(r, dict) else None)
        by_key.setdefault(_key(r), {})[r["slot"]] = r   # a later line of a slot replaces an earlier one
    return [_Run(key, tuple(slots[t] for t in sorted(slots)), summaries.get(key)) for key, slots in by_key.items()]


# -- chunks -------------------------------------------------------------------------------------------
def _grid_shape(run: _Run) -> tuple[int, ...]:
    """The chunk grid (objects, levels[, forms]): the summary's ``units``, else the labels' extent."""
    units = (run.summary or {}).get("units")
    if isinstance(units, list) and 2 <= len(units) <= 3 and all(isinstance(v, int) and v > 0 for v in units):
        return tuple(units)
    labels = [lab[:3] if name != "in_flight" else lab[:-1]
              for r in run.records for name in ("requests", "completed", "in_flight") for lab in r.get(name, [])]
    width = max((len(lab) for lab in labels), default=2)
    return tuple(max((lab[d] for lab in labels if len(lab) == width), default=0) + 1 for d in range(width))


def _unit_states(run: _Run, shape: tuple[int, ...]) -> list[str]:
    """Per slot, each chunk's :data:`UNIT_STATES` code at the slot's end, as a string of digits in
    row-major order of ``shape`` (objects, levels[, forms])."""
    def index(label: Sequence[int]) -> int | None:
        if len(label) != len(shape) or any(v >= n for v, n in zip(label, shape)):
            return None
        k = 0
        for v, n in zip(label, shape):
            k = k * n + v
        return k

    held = [False] * math.prod(shape)
    out = []
    expected = 0
    for r in run.records:
        if r["slot"] != expected:   # a gap (records of an interrupted rewrite): start over, nothing held
            held = [False] * len(held)
        expected = r["slot"] + 1
        state = [4 if h else 0 for h in held]
        for lab in r.get("requests", []):
            k = index(lab)
            if k is not None and not held[k]:
                state[k] = 1
        for lab in r.get("in_flight", []):
            k = index(lab[:-1])   # the last entry: bytes left
            if k is not None:
                state[k] = 2
        for lab in r.get("completed", []):
            k = index(lab)
            if k is not None:
                state[k] = 3
                held[k] = True
        out.append("".join(map(str, state)))
    return out


# -- pictures -----------------------------------------------------------------------------------------
def _views_run_id(folder: Path) -> str | None:
    """The ``run_id`` a picture folder names (None: no readable views.json)."""
    path = folder / VIEWS_FILE
    if not path.is_file():
        return None
    try:
        check_regular_file(path, ReplayError, field=VIEWS_FILE, max_bytes=_MAX_VIEWS_FILE_BYTES)
        value = json.loads(path.read_text(encoding="utf-8")).get("run_id")
    except (OSError, ValueError, AttributeError):
        return None
    return value if isinstance(value, str) else None


def _copy_picture(src: Path, dst: Path, same: bool) -> str | None:
    """``dst``'s path relative to the page (None: no picture at ``src``); copied unless the page
    sits in the run folder."""
    if not src.is_file():
        return None
    check_regular_file(src, ReplayError, field="views", max_bytes=_MAX_PICTURE_BYTES)
    if not same:
        dst.parent.mkdir(parents=True, exist_ok=True)
        shutil.copyfile(src, dst)
    return "/".join(quote(part) for part in dst.parts[-3:])


def _pictures(run: _Run, run_dir: Path, out_dir: Path, same: bool) -> tuple[list[str | None], str | None]:
    """The page-relative picture of each of ``run``'s slots (None: none), and why there are none."""
    folder = run_dir / "views" / run.folder
    if not folder.is_dir():
        return [None] * len(run.records), "views were not saved (simulate --save-views keeps them)"
    run_ids = {r.get("run_id") for r in run.records}
    if _views_run_id(folder) not in run_ids:
        return [None] * len(run.records), "the saved views belong to another run of this method: not shown"
    frames = [_copy_picture(folder / f"{r['slot']:03d}.png", out_dir / "views" / run.folder / f"{r['slot']:03d}.png",
                            same) for r in run.records]
    return frames, None if any(frames) else "views were not saved (simulate --save-views keeps them)"


# -- charts -------------------------------------------------------------------------------------------
_W, _H, _LEFT, _RIGHT, _TOP, _BOTTOM = 420, 164, 46, 10, 22, 24


def _fmt(v: float) -> str:
    return f"{v:.4g}"


def _chart(slots: int, *, ymin: float, ymax: float, ylabel: str, body) -> str:
    """An SVG chart over ``slots`` slots (centres at ``x(t)``), ``body(x, y)`` its marks, with a
    cursor line the page's script moves."""
    pw, ph = _W - _LEFT - _RIGHT, _H - _TOP - _BOTTOM
    dx = pw / max(slots, 1)
    span = (ymax - ymin) or 1.0

    def x(t: float) -> float:
        return _LEFT + (t + 0.5) * dx

    def y(v: float) -> float:
        return _TOP + ph * (1.0 - (v - ymin) / span)

    parts = [f'<svg class="chart" viewBox="0 0 {_W} {_H}" width="{_W}" height="{_H}" role="img" '
             f'aria-label="{html.escape(ylabel)}">',
             f'<rect x="{_LEFT}" y="{_TOP}" width="{pw:.1f}" height="{ph:.1f}" class="plot"/>']
    for frac in (0.0, 0.5, 1.0):
        v = ymin + frac * span
        parts.append(f'<line x1="{_LEFT}" x2="{_LEFT + pw:.1f}" y1="{y(v):.1f}" y2="{y(v):.1f}" class="tick"/>'
                     f'<text x="{_LEFT - 4}" y="{y(v) + 4:.1f}" text-anchor="end">{_fmt(v)}</text>')
    step = max(1, math.ceil(slots / 8))
    for t in range(0, slots, step):
        parts.append(f'<text x="{x(t):.1f}" y="{_H - 8}" text-anchor="middle">{t}</text>')
    parts.append(body(x, y, dx))
    parts.append(f'<text x="{_LEFT}" y="{_TOP - 8}" class="ylabel">{html.escape(ylabel)}</text>')
    parts.append(f'<line class="cursor" x1="{x(0):.1f}" x2="{x(0):.1f}" y1="{_TOP}" y2="{_TOP + ph:.1f}" '
                 f'data-x0="{x(0):.3f}" data-dx="{dx:.3f}"/></svg>')
    return "".join(parts)


def _polyline(points: list[tuple[float, float]], cls: str, colour: str | None = None) -> str:
    stroke = f' stroke="{colour}"' if colour else ""
    return f'<polyline class="{cls}"{stroke} points="' + " ".join(f"{a:.1f},{b:.1f}" for a, b in points) + '"/>'


def _ssim_chart(run: _Run, slots: int, colour: str) -> str:
    def body(x, y, dx):
        out, segment = [], []
        for r in run.records:   # a gap in the slots (or a missing value) breaks the line
            if r.get("ssim") is None or (segment and r["slot"] != segment[-1][0] + 1):
                if segment:
                    out.append(segment)
                segment = []
            if r.get("ssim") is not None:
                segment.append((r["slot"], r["ssim"]))
        if segment:
            out.append(segment)
        lines = "".join(_polyline([(x(t), y(v)) for t, v in seg], "line", colour) for seg in out)
        dots = "".join(f'<circle cx="{x(t):.1f}" cy="{y(v):.1f}" r="2" fill="{colour}"/>'
                       for seg in out for t, v in seg)
        return lines + dots

    values = [r["ssim"] for r in run.records if r.get("ssim") is not None]
    low = min(0.0, *values) if values else 0.0
    return _chart(slots, ymin=low, ymax=1.0, ylabel="SSIM per slot", body=body)


def _bytes_chart(run: _Run, slots: int, slot_s: float, colour: str) -> str:
    kb = lambda v: v / slot_s / 1000.0  # noqa: E731  (bytes per slot -> kB per second)
    top = max([kb(r["bytes_delivered"]) for r in run.records] + [kb(r["bytes_trace"]) for r in run.records] + [1e-9])

    def body(x, y, dx):
        bars = "".join(f'<rect x="{x(r["slot"]) - 0.4 * dx:.1f}" y="{y(kb(r["bytes_delivered"])):.1f}" '
                       f'width="{0.8 * dx:.1f}" height="{y(0) - y(kb(r["bytes_delivered"])):.1f}" fill="{colour}" '
                       f'opacity="0.55"><title>slot {r["slot"]}: {r["bytes_delivered"]} bytes delivered</title></rect>'
                       for r in run.records)
        return bars + _polyline([(x(r["slot"]), y(kb(r["bytes_trace"]))) for r in run.records], "trace")

    return _chart(slots, ymin=0.0, ymax=top, ylabel="kB per second: delivered (bars), trace (line)", body=body)


def _grid_table(shape: tuple[int, ...]) -> str:
    J, L = shape[0], shape[1]
    F = shape[2] if len(shape) == 3 else 1
    head = "".join(f"<th>L{lv}</th>" if F == 1 else f"<th>L{lv}.{f}</th>" for lv in range(L) for f in range(F))
    rows = "".join(f"<tr><th>obj {j}</th>" + '<td class="unit s0"></td>' * (L * F) + "</tr>" for j in range(J))
    return f'<table class="grid"><tr><th></th>{head}</tr>{rows}</table>'


# -- the page -----------------------------------------------------------------------------------------
_CSS = """
[hidden]{display:none!important}
body{font:14px/1.4 system-ui,sans-serif;margin:16px;color:#111;background:#fff}
h1{font-size:20px;margin:0 0 4px}h2{font-size:16px;margin:0 0 6px}
.controls{position:sticky;top:0;background:#fff;padding:8px 0;border-bottom:1px solid #ddd;z-index:1}
.controls input[type=range]{width:min(640px,70vw);vertical-align:middle}
section.run{border:1px solid #ddd;border-radius:6px;padding:10px;margin:12px 0}
.row{display:flex;flex-wrap:wrap;gap:12px;align-items:flex-start}
figure{margin:0}figcaption{font-size:12px;color:#555}
img.view,img.reference{image-rendering:pixelated;width:320px;border:1px solid #ccc;background:#f4f4f4}
.missing{width:320px;height:80px;display:flex;align-items:center;justify-content:center;text-align:center;
 border:1px dashed #bbb;color:#666;font-size:12px}
.note{color:#92400e}.metrics{font-variant-numeric:tabular-nums}
svg.chart text{font-size:10px;fill:#444}svg.chart .plot{fill:#fafafa;stroke:#ccc}
svg.chart .tick{stroke:#e5e5e5}svg.chart .line{fill:none;stroke-width:1.5}
svg.chart .trace{fill:none;stroke:#111;stroke-width:1;stroke-dasharray:3 2}
svg.chart .cursor{stroke:#f59e0b;stroke-width:2}svg.chart .ylabel{font-size:11px;fill:#111}
table.grid{border-collapse:collapse;font-size:10px}table.grid th{font-weight:normal;color:#555;padding:0 3px}
td.unit{width:14px;height:14px;border:1px solid #fff}
.s0{background:#e5e7eb}.s1{background:#fde68a}.s2{background:#f59e0b}.s3{background:#16a34a}.s4{background:#1e3a8a}
.legend span{display:inline-block;width:10px;height:10px;margin:0 3px 0 10px;vertical-align:middle}
"""

_JS = """
(function () {
  "use strict";
  var data = JSON.parse(document.getElementById("replay-data").textContent);
  var slider = document.getElementById("slot");
  var label = document.getElementById("slot-label");
  function picture(img, note, src, why) {
    if (src) { img.setAttribute("src", src); img.hidden = false; note.hidden = true; }
    else { img.hidden = true; note.hidden = false; note.textContent = why; }
  }
  function fmt(v, digits) { return v === null || v === undefined ? "-" : Number(v).toFixed(digits); }
  function show(t) {
    label.textContent = "slot " + t + " (" + fmt((t + 1) * data.slot_s, 1) + " s)";
    data.runs.forEach(function (run, i) {
      var sec = document.getElementById("run-" + i);
      var at = run.slots.indexOf(t);
      var rec = at < 0 ? null : run.records[at];
      var missing = at < 0 ? "no record of slot " + t + " (the run has slots " + run.slots[0] + "-" +
        run.slots[run.slots.length - 1] + ")" : run.why;
      picture(sec.querySelector("img.view"), sec.querySelector(".view-missing"),
              at < 0 ? null : run.frames[at], missing || "view not saved for this slot");
      picture(sec.querySelector("img.reference"), sec.querySelector(".reference-missing"),
              data.reference[t] || null, data.reference_why || "reference not saved for this slot");
      Array.prototype.forEach.call(sec.querySelectorAll("line.cursor"), function (line) {
        var x = parseFloat(line.getAttribute("data-x0")) + t * parseFloat(line.getAttribute("data-dx"));
        line.setAttribute("x1", x.toFixed(1)); line.setAttribute("x2", x.toFixed(1));
      });
      sec.querySelector(".metrics").textContent = rec === null ? "no record" :
        "SSIM " + fmt(rec.ssim, 4) + ", PSNR " + fmt(rec.psnr, 2) + " dB, " + rec.bytes_delivered +
        " bytes delivered of " + rec.bytes_trace + " in the trace, " + rec.arrived + " chunks arrived, " +
        rec.splats_shown + " splats shown";
      var states = at < 0 ? "" : run.states[at];
      Array.prototype.forEach.call(sec.querySelectorAll("td.unit"), function (cell, k) {
        cell.className = "unit s" + (states.charAt(k) || "0");
      });
    });
  }
  slider.addEventListener("input", function () { show(parseInt(slider.value, 10)); });
  var timer = null, play = document.getElementById("play");
  play.addEventListener("click", function () {
    if (timer !== null) { clearInterval(timer); timer = null; play.textContent = "play"; return; }
    play.textContent = "pause";
    timer = setInterval(function () {
      var t = (parseInt(slider.value, 10) + 1) % (parseInt(slider.max, 10) + 1);
      slider.value = String(t); show(t);
    }, 1000 * Math.min(Math.max(data.slot_s, 0.2), 2));
  });
  show(parseInt(slider.value, 10));
}());
"""


def _json_for_script(obj: Any) -> str:
    # "</" would end the <script> element early; "<\\/" is the same JSON string.
    return json.dumps(obj, allow_nan=False).replace("</", "<\\/")


def write_replay(run_dir: str | os.PathLike, out_dir: str | os.PathLike) -> Path:
    """Write the replay page of the simulated run in ``run_dir`` into ``out_dir`` (see the module docstring).

    Parameters
    ----------
    run_dir : path
        A ``l3gs-opt simulate --out`` folder: ``slots.jsonl``, optionally ``summary.jsonl`` and
        ``views/`` (``simulate --save-views``).
    out_dir : path
        The page's folder (created): ``index.html`` and the pictures it shows under ``views/``.
        It may be ``run_dir`` itself (the pictures are then linked where they are, not copied).

    Returns
    -------
    Path
        The page, ``out_dir/index.html``.

    Raises
    ------
    ReplayError
        ``run_dir`` has no ``slots.jsonl`` or no record in it, a record lacks a field the page
        shows, or ``out_dir`` is a file.
    RecordFileError
        A line of ``slots.jsonl`` or ``summary.jsonl`` (other than a torn last one) is not JSON.

    Example
    -------
    >>> write_replay("runs/lumos", "runs/lumos-page")     # doctest: +SKIP
    PosixPath('runs/lumos-page/index.html')
    """
    run_dir, out_dir = Path(run_dir), Path(out_dir)
    if not run_dir.is_dir():
        raise ReplayError("run_dir", f"{run_dir}: no such folder (a simulate --out folder)")
    if out_dir.exists() and not out_dir.is_dir():
        raise ReplayError("out_dir", f"{out_dir} is a file: expected a folder")
    runs = _read_runs(run_dir)
    out_dir.mkdir(parents=True, exist_ok=True)
    same = out_dir.resolve() == run_dir.resolve()
    slot_s = next((float(r["slot_s"]) for r in (run.summary for run in runs) if r and _is_number(r.get("slot_s"))
                   and r["slot_s"] > 0), None)
    if slot_s is None:   # time_s = (slot + 1) * slot_s in every record
        first = runs[0].records[0]
        slot_s = float(first["time_s"]) / (first["slot"] + 1) if _is_number(first.get("time_s")) and \
            first["time_s"] > 0 else 1.0
    slots = max(r["slot"] for run in runs for r in run.records) + 1
    reference = [_copy_picture(run_dir / "views" / REFERENCE_VIEWS / f"{t:03d}.png",
                               out_dir / "views" / REFERENCE_VIEWS / f"{t:03d}.png", same) for t in range(slots)]

    data_runs, sections = [], []
    for i, run in enumerate(runs):
        colour = _PALETTE[i % len(_PALETTE)]
        shape = _grid_shape(run)
        states = _unit_states(run, shape)
        frames, why = _pictures(run, run_dir, out_dir, same)
        records = [{"ssim": r.get("ssim"), "psnr": r.get("psnr"), "bytes_delivered": r["bytes_delivered"],
                    "bytes_trace": r["bytes_trace"], "arrived": len(r.get("completed", [])),
                    "splats_shown": r.get("splats_shown")} for r in run.records]
        data_runs.append({"label": run.label, "slots": [r["slot"] for r in run.records], "frames": frames,
                          "why": why, "records": records, "states": states, "shape": list(shape)})
        s = run.summary or {}
        mean = f", SSIM mean {s['ssim_mean']:.4f}" if _is_number(s.get("ssim_mean")) else ""
        note = f'<p class="note">{html.escape(why)}</p>' if why else ""
        first = frames[0] if frames and frames[0] else None
        img = (f'<img class="view" alt="client view" src="{html.escape(first)}">' if first
               else '<img class="view" alt="client view" hidden>')
        sections.append(
            f'<section class="run" id="run-{i}"><h2 style="color:{colour}">{html.escape(run.label)}</h2>'
            f'<p>{len(run.records)} slots{html.escape(mean)}; chunks: {" x ".join(map(str, shape))} '
            f'(objects x levels{" x forms" if len(shape) == 3 else ""})</p>{note}'
            f'<p class="metrics"></p><div class="row">'
            f'<figure>{img}<div class="missing view-missing" hidden></div><figcaption>client view</figcaption></figure>'
            f'<figure><img class="reference" alt="reference view" hidden><div class="missing reference-missing" hidden>'
            f'</div><figcaption>reference (full scene)</figcaption></figure></div><div class="row">'
            f'{_ssim_chart(run, slots, colour)}{_bytes_chart(run, slots, slot_s, colour)}'
            f'<figure>{_grid_table(shape)}<figcaption>chunks at the end of the slot</figcaption></figure></div>'
            f'</section>')
    legend = "".join(f'<span class="s{k}"></span>{html.escape(name)}' for k, name in enumerate(UNIT_STATES))
    summary = next((run.summary for run in runs if run.summary), {}) or {}
    about = ", ".join(html.escape(f"{k} {summary[k]}") for k in ("bundle", "variant", "reference") if summary.get(k))
    data = {"slot_s": slot_s, "slots": slots, "runs": data_runs, "reference": reference,
            "reference_why": None if any(reference) else "reference views were not saved"}
    title = f"replay of {run_dir.resolve().name}"
    page = (f'<!DOCTYPE html>\n<html lang="en"><head><meta charset="utf-8">'
            f'<meta name="viewport" content="width=device-width, initial-scale=1">'
            f'<title>{html.escape(title)}</title><style>{_CSS}</style></head><body>'
            f'<h1>{html.escape(title)}</h1><p>{len(runs)} run(s), {slots} slots of {_fmt(slot_s)} s'
            f'{"; " + about if about else ""}</p>'
            f'<div class="controls"><button id="play" type="button">play</button> '
            f'<input id="slot" type="range" min="0" max="{slots - 1}" step="1" value="0" aria-label="slot"> '
            f'<span id="slot-label">slot 0</span><div class="legend">{legend}</div></div>'
            + "".join(sections)
            + f'<script type="application/json" id="replay-data">{_json_for_script(data)}</script>'
            f'<script>{_JS}</script></body></html>\n')
    return write_atomic(out_dir / PAGE_NAME, page)
