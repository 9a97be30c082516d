"""Machine and version facts recorded next to every benchmark result."""

from __future__ import annotations

import json
import os
import platform
from importlib.metadata import PackageNotFoundError, version


def machine_info() -> dict:
    cpu = "unknown"
    try:
        with open("/proc/cpuinfo", encoding="utf-8") as fh:
            for line in fh:
                if line.startswith("model name"):
                    cpu = line.split(":", 1)[1].strip()
                    break
    except OSError:
        pass
    packages = {}
    for name in ("l3gs-opt", "numpy", "scipy", "pulp", "highspy", "ortools", "torch"):
        try:
            packages[name] = version(name)
        except PackageNotFoundError:
            packages[name] = None
    return {"cpu": cpu, "cores": os.cpu_count(), "python": platform.python_version(),
            "platform": platform.platform(), "packages": packages, "loadavg_at_start": os.getloadavg()}


def machines_line(recs: list[dict]) -> str:
    """Which machine ran which rows (each record carries its own): one clause per machine, with its
    labels and the UTC span of their records."""
    groups: dict[tuple, dict] = {}
    for r in recs:
        m = r["machine"]
        key = (m["cpu"], m["cores"], m["python"], json.dumps(m["packages"], sort_keys=True))
        g = groups.setdefault(key, {"labels": set(), "when": []})
        g["labels"].add(r["label"])
        if r.get("finished_utc"):
            g["when"].append(r["finished_utc"])
    parts = []
    for (cpu, cores, py, packages), g in groups.items():
        when = f"; {min(g['when'])[:16]} to {max(g['when'])[:16]} UTC" if g["when"] else ""
        parts.append(f"{cpu}, {cores} cores, Python {py}, packages {packages} (rows: {', '.join(sorted(g['labels']))}"
                     f"{when})")
    return ("Machines: " if len(parts) > 1 else "Machine: ") + "; ".join(parts) + "."
