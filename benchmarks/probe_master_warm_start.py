"""Probe (issue 23 item 2, twenty-sixth session): how `exact` warm-starts its master LP, A/B, one
JSON line per run appended to ``--out`` (tables: ``--report``, as in probe_exact_lean_root.py).

``--arm now`` is the code as it is: primal simplex after new columns only
(:data:`~l3gs_opt.solvers.exact.colgen.PRIMAL_SIMPLEX`), dual simplex after new rows or a node's
bound changes, and a branch-and-price node starts from its parent's last basis
(:data:`~l3gs_opt.solvers.exact.search.PARENT_BASIS`). ``--arm last-basis`` starts each node from
the last node's basis instead; ``--arm before`` also re-solves with dual simplex only (the code
before this session). Runs are meant to be made one after another on an otherwise idle machine.

    .venv/bin/python benchmarks/probe_master_warm_start.py --J 20 --seeds 0-9 --arm before --out runs.jsonl
"""

from __future__ import annotations

import sys
from pathlib import Path

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))
sys.path.insert(0, str(Path(__file__).resolve().parent))

from l3gs_opt.solvers.exact import colgen, search  # noqa: E402
from probe_exact_lean_root import _seeds, arguments, run  # noqa: E402


def main(argv=None) -> int:
    args = arguments(__doc__, ("now", "last-basis", "before"), "0-9", argv)
    if args is None:
        return 0
    if args.arm in ("last-basis", "before"):
        search.PARENT_BASIS = False
    if args.arm == "before":
        colgen.PRIMAL_SIMPLEX = colgen.DUAL_SIMPLEX
    run(args.J, _seeds(args.seeds), args.arm, args.branching, args.time_limit, args.out)
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
