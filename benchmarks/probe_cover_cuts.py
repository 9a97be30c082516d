"""Probe (issue 23 item 2, twenty-second session): cover cuts of the arrived-by knapsack in ``exact``'s
root Dantzig-Wolfe master.

Under per-slot budgets, the chunks that have arrived by slot ``t`` fit the bytes of slots ``0..t``:
``sum_i c[i] y[i,t] <= C[t]`` with ``y[i,t] = sum_{s<=t} x[i,s]`` and ``C[t] = sum_{s<=t} B[s]``. So
for every set ``S`` of chunks with ``c(S) > C[t]`` the cover inequality ``sum_{i in S} y[i,t] <=
|S| - 1`` holds for every schedule. In the master it is a row over the columns (a filling of slot
``s <= t`` has coefficient ``|filling & S|``); its dual ``d`` only lowers the reduced profit of the
chunks of ``S`` in slots ``0..t``, so the pricing stays one knapsack per slot (a "robust" cut,
unlike subset-row cuts). The bound after each round is the Lagrangian value at the master's duals
(``sum mu_once + sum_cuts (|S| - 1) d + sum_t max(0, knapsack_t)`` plus presolve's constant),
a valid upper bound.

Each round: column generation to convergence (pricing by exact MIPs, :mod:`probe_block_dw`),
then for every ``t`` the most violated cover of the master's ``y[., t]`` (an exact MIP: minimise
``sum (1 - y[i,t]) z[i]`` subject to ``c.z >= C[t] + 1``), made minimal (the items that add most
slack dropped first while it stays a cover); the round's violated covers are added. It starts from
``exact``'s own converged root (:func:`l3gs_opt.solvers.exact.colgen.column_generation`).

    .venv/bin/python benchmarks/probe_cover_cuts.py --J 20 --seed 4 [--rounds 30] [--with-lower]

Kept as the record of ``cover_cuts_probe_dev.txt``. The twenty-third session built the same cuts into
``exact`` (``solvers/exact/covers.py``, ``search.COVER_CUTS``), with knapsack separation and exact's master.
"""

from __future__ import annotations

import argparse
import sys
import time
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))
sys.path.insert(0, str(Path(__file__).resolve().parent))

import highspy  # noqa: E402

import probe_block_dw as blocks  # noqa: E402
from l3gs_opt.bench.suites import paper_spec  # noqa: E402
from l3gs_opt.solvers.exact.colgen import ColumnPool, column_generation  # noqa: E402
from l3gs_opt.solvers.exact.lagrange import gap_data  # noqa: E402

INF = highspy.kHighsInf


class CoverMaster(blocks.BlockMaster):
    """The per-slot master (blocks of one slot) with cover rows after the convexity rows."""

    def __init__(self, g):
        super().__init__(g, blocks.blocks_of(g.T, 1, 0))
        self.cut0 = self.conv0 + len(self.blocks)
        self.cuts: list[tuple[np.ndarray, int, set]] = []

    def _coef(self, fill, k: int) -> int:
        members, t = self.cuts[k][2], self.cuts[k][1]
        return sum(1 for i, s in fill if s <= t and i in members)

    def add(self, b: int, fill) -> bool:
        if not super().add(b, fill):
            return False
        j = len(self.columns) - 1
        for k in range(len(self.cuts)):
            c = self._coef(fill, k)
            if c:
                self.h.changeCoeff(self.cut0 + k, j, float(c))
        return True

    def add_cut(self, S: np.ndarray, t: int) -> None:
        self.cuts.append((S, t, set(S.tolist())))
        k = len(self.cuts) - 1
        idx, val = [], []
        for j, (_, fill) in enumerate(self.columns):
            c = self._coef(fill, k)
            if c:
                idx.append(j)
                val.append(float(c))
        self.h.addRow(-INF, float(len(S) - 1), len(idx), np.array(idx, dtype=np.int32), np.array(val))

    def reduced_profits(self, mu: np.ndarray) -> np.ndarray:
        p = super().reduced_profits(mu)
        for k, (S, t, _) in enumerate(self.cuts):
            if mu[self.cut0 + k] > 0:
                p[np.ix_(S, np.arange(t + 1))] -= mu[self.cut0 + k]
        return p

    def constant_part(self, mu: np.ndarray) -> float:
        """The rows' right-hand sides times their multipliers."""
        return float(mu[:self.g.n].sum() + sum((len(S) - 1) * mu[self.cut0 + k]
                                               for k, (S, _, _) in enumerate(self.cuts)))

    def xbar(self) -> np.ndarray:
        lam = np.asarray(self.h.getSolution().col_value)
        x = np.zeros((self.g.n, self.g.T))
        for j, (_, fill) in enumerate(self.columns):
            if lam[j] > 1e-12:
                for i, s in fill:
                    x[i, s] += lam[j]
        return x


def converge(m: CoverMaster) -> tuple[float, float]:
    """Column generation to convergence; (master value, best Lagrangian value), without the constant."""
    best = np.inf
    while True:
        value, mu = m.solve()
        p = m.reduced_profits(mu)
        lagr, added = m.constant_part(mu), 0
        for b, block in enumerate(m.blocks):
            v, fill = blocks.price(m.g, block, p)
            lagr += max(0.0, v)
            if fill and v - mu[m.conv0 + b] > 1e-6:
                added += m.add(b, fill)
        best = min(best, lagr)
        if added == 0:
            return value, best


def closure(g, z: np.ndarray) -> np.ndarray:
    """``z`` and every layer under one of its chunks (that presolve kept: held ones cost nothing)."""
    out = set(int(i) for i in z)
    stack = list(out)
    while stack:
        lo = int(g.lower[stack.pop()])
        if lo >= 0 and lo not in out:
            out.add(lo)
            stack.append(lo)
    return np.array(sorted(out), dtype=np.int64)


def separate(g, x: np.ndarray, with_lower: bool = False) -> list[tuple[np.ndarray, int, float]]:
    """The most violated minimal cover of each slot's arrived-by knapsack: (items, t, slack < 1).

    ``with_lower``: a set counts as a cover when it and the layers under its chunks (which must
    have arrived by then too) exceed the bytes: ``sum_{i in S} y[i,t] <= |S| - 1`` stays valid."""
    y = np.clip(np.cumsum(x, axis=1), 0.0, 1.0)
    cap = np.cumsum(g.budget)
    out = []
    n = g.n
    for t in range(g.T):
        if int(g.cost.sum()) <= int(cap[t]):
            continue
        yt = y[:, t]
        h = highspy.Highs()
        h.setOptionValue("output_flag", False)
        cols = np.arange(n, dtype=np.int32)
        # z[i]: i in S (costs 1 - y); w[i]: i in S's closure (costs nothing)
        nv = 2 * n if with_lower else n
        h.addVars(nv, np.zeros(nv), np.ones(nv))
        h.changeColsIntegrality(nv, np.arange(nv, dtype=np.int32), np.array([highspy.HighsVarType.kInteger] * nv))
        h.changeColsCost(n, cols, 1.0 - yt)
        if with_lower:
            for i in range(n):   # w[i] >= z[i], w[lo] >= w[i]; w[i] <= z[i] + w[up]: w is z's closure
                h.addRow(0.0, INF, 2, np.array([n + i, i], dtype=np.int32), np.array([1.0, -1.0]))
                if g.lower[i] >= 0:
                    h.addRow(0.0, INF, 2, np.array([n + g.lower[i], n + i], dtype=np.int32), np.array([1.0, -1.0]))
                up = [n + int(g.upper[i])] if g.upper[i] >= 0 else []
                h.addRow(-INF, 0.0, 2 + len(up), np.array([n + i, i, *up], dtype=np.int32),
                         np.array([1.0, -1.0, -1.0][:2 + len(up)]))
            h.addRow(float(cap[t] + 1), INF, n, cols + n, g.cost.astype(float))
        else:
            h.addRow(float(cap[t] + 1), INF, n, cols, g.cost.astype(float))
        h.run()
        z = np.nonzero(np.asarray(h.getSolution().col_value)[:n] > 0.5)[0]
        size = (lambda zz: int(g.cost[closure(g, zz)].sum())) if with_lower else (lambda zz: int(g.cost[zz].sum()))
        for i in sorted(z, key=lambda i: -(1.0 - yt[i])):
            if size(z[z != i]) > int(cap[t]):
                z = z[z != i]
        slack = float((1.0 - yt[z]).sum())
        if slack < 1 - 1e-6:
            out.append((np.sort(z), t, slack))
    return out


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--J", type=int, default=20)
    ap.add_argument("--seed", type=int, default=4)
    ap.add_argument("--rounds", type=int, default=30)
    ap.add_argument("--with-lower", action="store_true",
                    help="covers whose chunks and the layers under them exceed the bytes (precedence-closed)")
    args = ap.parse_args(argv)
    g = gap_data(paper_spec(args.J, args.seed).build())
    started = time.perf_counter()
    pool = ColumnPool(g)
    root = column_generation(g, pool, [], allowed=g.allowed.copy(), forced={}, incumbent=0.0,
                             max_iterations=100_000, stall_iterations=100_000)
    print(f"exact's root {root.bound + g.constant:.2f} converged {root.converged} columns {len(pool)} "
          f"{time.perf_counter() - started:.1f}s", flush=True)
    m = CoverMaster(g)
    for t, items in zip(pool.slot, pool.items):
        m.add(t, [(int(i), t) for i in items])
    for rnd in range(args.rounds):
        value, best = converge(m)
        print(f"cut round {rnd}: cuts {len(m.cuts)} master {value + g.constant:.2f} "
              f"lagr {best + g.constant:.2f} columns {len(m.columns)} {time.perf_counter() - started:.1f}s", flush=True)
        found = [c for c in separate(g, m.xbar(), args.with_lower)
                 if not any(t == c[1] and np.array_equal(S, c[0]) for S, t, _ in m.cuts)]
        if not found:
            print("no violated cover")
            break
        for S, t, _ in found:
            m.add_cut(S, t)
        print("  added (t, |S|, slack):", [(int(t), len(S), round(slack, 3)) for S, t, slack in found], flush=True)
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
