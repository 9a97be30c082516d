"""CBC with Clp's scaling on (the default below ``cbc.STIFF_OBJECTIVE_RANGE``) against off, at the
paper's scale: the LP relaxation's time and a 60 s MIP (objective, bound, wall time) per instance.

One JSON line per run (the first: the machine), written as it goes:

    python benchmarks/probe_cbc_scaling.py benchmarks/results/cbc_scaling.jsonl
"""

from __future__ import annotations

import os
import sys
import time
from pathlib import Path

sys.path.insert(0, str(Path(__file__).resolve().parent))
from machine import machine_info  # noqa: E402

from l3gs_opt.bench.suites import paper_spec  # noqa: E402
from l3gs_opt.jsonout import dumps  # noqa: E402
from l3gs_opt.models import solve_ilp  # noqa: E402
from l3gs_opt.models.backends import cbc  # noqa: E402

SIZES = (20, 50, 200)
SEEDS = (0, 1)
LIMIT_S = 60.0
SETTINGS = {"auto": cbc.STIFF_OBJECTIVE_RANGE, "off": 0.0}   # range threshold 0: scaling always off


def main() -> int:
    out = open(sys.argv[1], "a", encoding="utf-8")
    out.write(dumps({"machine": machine_info()}) + "\n")
    for J in SIZES:
        for seed in SEEDS:
            inst = paper_spec(J, seed).build()
            for name, threshold in SETTINGS.items():
                cbc.STIFF_OBJECTIVE_RANGE = threshold
                for relax in (True, False):
                    load = os.getloadavg()
                    began = time.perf_counter()
                    sol = solve_ilp(inst, backend="cbc", relax=relax, time_limit_s=None if relax else LIMIT_S)
                    wall = time.perf_counter() - began
                    row = {"instance": f"T60-J{J}-s{seed}", "scaling": name, "relax": relax, "wall_s": wall,
                           "status": sol.status.value, "objective": sol.objective, "bound": sol.bound,
                           "cbc_args": sol.details.get("cbc_args"), "loadavg": load}
                    print(row, flush=True)
                    out.write(dumps(row) + "\n")
                    out.flush()
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
