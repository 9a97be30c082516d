"""Probe (issue 23 item 2, twenty-second session): the Dantzig-Wolfe bound of Problem A when the
column-generation blocks are runs of ``K`` adjacent slots instead of single slots.

``exact``'s root prices one 0-1 knapsack per slot; its bound is ``max P.x`` over the intersection of
each slot's knapsack hull with the linear "at most once" and precedence rows. Here a column is a
filling of ``K`` adjacent slots at once: one knapsack per slot, each chunk in at most one of them,
and inside the block no layer in an earlier slot than the layer under it (``x[u,s] + x[lo,s'] <= 1``
for ``s' > s``: valid for every schedule, since ``lo`` arrives at most once). ``K = 1`` is
``exact``'s own root bound, which this script reproduces (the check that the master is right).

Master (HiGHS LP, columns added as priced): convexity ``<= 1`` per block (the empty filling is
always there), "at most once" per chunk, and the precedence rows in cumulative form
``sum_{s<=t} x[u,s] - sum_{s<=t} x[lo(u),s] <= 0`` (same-slot layers only). Pricing: one exact MIP
per block (HiGHS, gaps 1e-9 relative and 1e-7 absolute) over the chunks with positive reduced
profit. Each round's ``lagr`` is the Lagrangian value at the master's duals
(``sum mu_once + sum_b max(0, best_b)`` plus presolve's constant), a valid upper bound; at
convergence it equals the master's value. ``--smoothing A`` prices at ``A`` x the best multipliers
so far plus ``1 - A`` x the master's duals (Wentges), falling back to the master's duals when that
finds no column; converged means no column prices out at the master's own duals.

    .venv/bin/python benchmarks/probe_block_dw.py --J 20 --seed 4 --K 2 [--offset 0] [--time-limit 3600]
        [--pool FILE]

``--pool FILE`` saves the columns every 10 rounds and at the end, and starts from them when the
file exists (a long run may be stopped and continued). Prints one line per round.
"""

from __future__ import annotations

import argparse
import os
import pickle
import sys
import time
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))

import highspy  # noqa: E402

from l3gs_opt.bench.suites import paper_spec  # noqa: E402
from l3gs_opt.solvers.exact.lagrange import GapData, gap_data  # noqa: E402

INF = highspy.kHighsInf


def blocks_of(T: int, K: int, offset: int) -> list[list[int]]:
    """Runs of ``K`` adjacent slots; with ``offset`` the first block is slots ``0..offset-1``."""
    starts = ([0] if offset else []) + list(range(offset, T, K))
    return [list(range(a, b)) for a, b in zip(starts, starts[1:] + [T]) if b > a]


class BlockMaster:
    """The restricted master LP over block fillings (see the module doc)."""

    def __init__(self, g: GapData, blocks: list[list[int]]):
        if g.strict:
            raise SystemExit("probe: same-slot layers only (same_slot_layers=True)")
        self.g, self.blocks = g, blocks
        n, T = g.n, g.T
        self.prec_u = [u for u in range(n) if g.lower[u] >= 0]
        self.prow = {(u, t): n + k * T + t for k, u in enumerate(self.prec_u) for t in range(T)}
        self.conv0 = n + len(self.prec_u) * T
        rows = self.conv0 + len(blocks)
        self.h = highspy.Highs()
        self.h.setOptionValue("output_flag", False)
        upper = np.zeros(rows)
        upper[:n] = 1.0
        upper[self.conv0:] = 1.0
        self.h.addRows(rows, np.full(rows, -INF), upper, 0, np.zeros(rows + 1, dtype=np.int32),
                       np.zeros(0, dtype=np.int32), np.zeros(0))
        self.columns: list[tuple[int, tuple]] = []
        self._seen: set = set()

    def add(self, b: int, fill) -> bool:
        """Add block ``b``'s filling ``[(chunk, slot), ...]``; False if the pool holds it."""
        key = (b, tuple(sorted(fill)))
        if key in self._seen:
            return False
        self._seen.add(key)
        g, T = self.g, self.g.T
        co: dict[int, int] = {self.conv0 + b: 1}
        value = 0.0
        for i, s in fill:
            value += g.profit[i, s]
            co[i] = co.get(i, 0) + 1
            for u, sign in ((i, 1), (g.upper[i], -1)):
                if u >= 0 and g.lower[u] >= 0:
                    for t in range(s, T):
                        r = self.prow[(u, t)]
                        co[r] = co.get(r, 0) + sign
        idx = np.array(sorted(r for r, v in co.items() if v), dtype=np.int32)
        self.h.addCol(-value, 0.0, INF, len(idx), idx, np.array([co[r] for r in idx], dtype=np.float64))
        self.columns.append(key)
        return True

    def solve(self) -> tuple[float, np.ndarray]:
        """Master value (without presolve's constant) and the row duals as multipliers >= 0."""
        self.h.run()
        return -self.h.getInfo().objective_function_value, -np.asarray(self.h.getSolution().row_dual)

    def reduced_profits(self, mu: np.ndarray) -> np.ndarray:
        """``p~[i, s]`` at multipliers ``mu``."""
        g, n, T = self.g, self.g.n, self.g.T
        suffix = np.zeros((n, T))
        for u in self.prec_u:
            row = mu[[self.prow[(u, t)] for t in range(T)]]
            suffix[u] = np.flip(np.cumsum(np.flip(row)))
        out = g.profit - mu[:n, None] - suffix
        has_up = g.upper >= 0
        out[has_up] += suffix[g.upper[has_up]]
        return out


def price(g: GapData, block: list[int], p: np.ndarray) -> tuple[float, list[tuple[int, int]]]:
    """The best filling of ``block`` at reduced profits ``p`` (exact MIP) and its value."""
    items = [(i, s) for s in block for i in range(g.n)
             if g.allowed[i, s] and p[i, s] > 1e-9 and g.cost[i] <= g.budget[s]]
    if not items:
        return 0.0, []
    m = highspy.Highs()
    m.setOptionValue("output_flag", False)
    m.setOptionValue("mip_rel_gap", 1e-9)
    m.setOptionValue("mip_abs_gap", 1e-7)
    nv = len(items)
    m.addVars(nv, np.zeros(nv), np.ones(nv))
    cols = np.arange(nv, dtype=np.int32)
    m.changeColsIntegrality(nv, cols, np.array([highspy.HighsVarType.kInteger] * nv))
    m.changeColsCost(nv, cols, -np.array([p[i, s] for i, s in items]))

    def row(ks, coef, upper):
        m.addRow(-INF, float(upper), len(ks), np.array(ks, dtype=np.int32), np.asarray(coef, dtype=np.float64))

    for s in block:
        ks = [k for k, (_, ss) in enumerate(items) if ss == s]
        if sum(g.cost[items[k][0]] for k in ks) > g.budget[s]:
            row(ks, [g.cost[items[k][0]] for k in ks], g.budget[s])
    where: dict[int, list[tuple[int, int]]] = {}
    for k, (i, s) in enumerate(items):
        where.setdefault(i, []).append((s, k))
    for i, lst in where.items():
        if len(lst) > 1:
            row([k for _, k in lst], np.ones(len(lst)), 1)
        lo = g.lower[i]
        for s, k in lst:
            for s2, k2 in where.get(lo, []) if lo >= 0 else []:
                if s2 > s:
                    row([k, k2], np.ones(2), 1)
    m.run()
    if m.getModelStatus() != highspy.HighsModelStatus.kOptimal:
        raise SystemExit(f"probe: pricing MIP ended {m.getModelStatus()}")
    x = np.asarray(m.getSolution().col_value)
    return -m.getInfo().objective_function_value, [items[k] for k in range(nv) if x[k] > 0.5]


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--J", type=int, default=20)
    ap.add_argument("--seed", type=int, default=4)
    ap.add_argument("--K", type=int, default=2, help="slots per block (1: exact's root bound)")
    ap.add_argument("--offset", type=int, default=0, help="slots in a first, shorter block")
    ap.add_argument("--time-limit", type=float, default=3600.0, help="stop after this many seconds (unconverged)")
    ap.add_argument("--smoothing", type=float, default=0.0,
                    help="Wentges smoothing share of the best multipliers (0: price at the master's duals)")
    ap.add_argument("--pool", type=Path, default=None, help="save the columns here; start from them if it exists")
    args = ap.parse_args(argv)
    g = gap_data(paper_spec(args.J, args.seed).build())
    master = BlockMaster(g, blocks_of(g.T, args.K, args.offset))
    if args.pool and args.pool.exists():
        for b, fill in pickle.loads(args.pool.read_bytes()):
            master.add(b, list(fill))
        print(f"loaded {len(master.columns)} columns from {args.pool}", flush=True)
    started = time.perf_counter()
    best, centre = np.inf, None
    value, mu = master.solve()
    for rnd in range(1_000_000):
        # Wentges smoothing: price at a point between the best multipliers so far and the master's;
        # a round that adds nothing there (mispricing) is priced again at the master's own duals.
        alpha = args.smoothing if centre is not None else 0.0
        added = 0
        t_price = time.perf_counter()
        while True:
            at = mu if alpha == 0.0 else alpha * centre + (1 - alpha) * mu
            p = master.reduced_profits(at)
            lagr, fills = at[:g.n].sum(), []
            for b, block in enumerate(master.blocks):
                v, fill = price(g, block, p)
                lagr += max(0.0, v)
                fills.append((b, fill))
            if lagr < best:
                best, centre = lagr, at.copy()
            pm = p if alpha == 0.0 else master.reduced_profits(mu)
            for b, fill in fills:   # a column enters if it prices out at the master's duals
                if fill and sum(pm[i, s] for i, s in fill) - mu[master.conv0 + b] > 1e-6:
                    added += master.add(b, fill)
            if added or alpha == 0.0:
                break
            alpha = 0.0
        t_price = time.perf_counter() - t_price
        value, mu = master.solve()
        elapsed = time.perf_counter() - started
        print(f"round {rnd} t={elapsed:.1f}s pricing {t_price:.1f}s cols {len(master.columns)} added {added} "
              f"master {value + g.constant:.2f} lagr {lagr + g.constant:.2f} best {best + g.constant:.2f}",
              flush=True)
        done = (added == 0 and alpha == 0.0) or elapsed > args.time_limit
        if args.pool and (done or rnd % 10 == 0):
            tmp = args.pool.with_suffix(".tmp")
            tmp.write_bytes(pickle.dumps(master.columns))
            os.replace(tmp, args.pool)
        if done:
            break
    status = "converged" if added == 0 and alpha == 0.0 else "time_limit"
    print(f"FINAL J={args.J} seed={args.seed} K={args.K} offset={args.offset} {status} bound "
          f"{best + g.constant:.2f} master {value + g.constant:.2f} columns {len(master.columns)} "
          f"time {time.perf_counter() - started:.1f}s")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
