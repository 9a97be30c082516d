"""Probe (issue 23 item 2, twenty-sixth session): which simplex re-solves `exact`'s master LP, A/B,
one JSON line per run appended to ``--out`` (tables: ``--report``, as in probe_exact_lean_root.py).

``--arm mixed`` is the code as it is (:data:`~l3gs_opt.solvers.exact.colgen.PRIMAL_SIMPLEX`
after new columns only, dual simplex after new rows or a node's bound changes); ``--arm dual``
patches every re-solve back to HiGHS's dual simplex, as before. Runs are meant to be made one
after another on an otherwise idle machine.

    .venv/bin/python benchmarks/probe_master_simplex.py --J 20 --seeds 0-9 --arm dual --out runs.jsonl
"""

from __future__ import annotations

import sys
from pathlib import Path

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))
sys.path.insert(0, str(Path(__file__).resolve().parent))

from l3gs_opt.solvers.exact import colgen  # noqa: E402
from probe_exact_lean_root import _seeds, arguments, run  # noqa: E402


def main(argv=None) -> int:
    args = arguments(__doc__, ("mixed", "dual"), "0-9", argv)
    if args is None:
        return 0
    if args.arm == "dual":
        colgen.PRIMAL_SIMPLEX = colgen.DUAL_SIMPLEX
    run(args.J, _seeds(args.seeds), args.arm, args.branching, args.time_limit, args.out)
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
