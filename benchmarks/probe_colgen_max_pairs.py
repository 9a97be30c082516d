"""Probe (issue 23 item 2, twenty-eighth session): `exact` at J=50 with and without the root column
generation, A/B, one JSON line per run appended to ``--out`` (tables: ``--report``, as in
probe_exact_lean_root.py).

``--arm skip`` is the code as it is: J=50 (n * T = 12,000) is above
:data:`~l3gs_opt.solvers.exact.search.COLGEN_MAX_PAIRS`, so it takes the large instances' path (no
column generation, annealing or branch-and-price; the LP and band neighbourhoods, the window LNS,
HiGHS on the model fixed at the LP duals' certificate). ``--arm colgen`` sets the limit back to
20,000 (the code before this session). Runs are meant to be made one after another on an otherwise
idle machine.

    .venv/bin/python benchmarks/probe_colgen_max_pairs.py --J 50 --seeds 0-9 --arm colgen --out runs.jsonl
"""

from __future__ import annotations

import sys
from pathlib import Path

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))
sys.path.insert(0, str(Path(__file__).resolve().parent))

from l3gs_opt.solvers.exact import search  # noqa: E402
from probe_exact_lean_root import _seeds, arguments, run  # noqa: E402


def main(argv=None) -> int:
    args = arguments(__doc__, ("skip", "colgen"), "0-9", argv)
    if args is None:
        return 0
    if args.arm == "colgen":
        search.COLGEN_MAX_PAIRS = 20_000
    run(args.J, _seeds(args.seeds), args.arm, args.branching, args.time_limit, args.out)
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
