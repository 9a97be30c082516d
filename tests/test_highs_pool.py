"""HiGHS's per-process thread pool across a fork (models/backends/highs.py, ``_fresh_pool_in_child``)."""

from __future__ import annotations

import json
import subprocess
import sys
import textwrap
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]

# A parent whose HiGHS pool has two threads (1.14's default on 4 or more cores), then a MIP in a
# worker the local executor forks. Before the fork hook the child's MIP never returned and the
# worker was killed at its hard limit.
SCRIPT = textwrap.dedent("""
    import json
    import numpy as np, highspy
    from l3gs_opt.executors import run_tasks
    from l3gs_opt.models.backends.highs import new_highs

    def mip(threads=None):
        rng = np.random.default_rng(0)
        n = 300
        h = new_highs(mip=True)
        if threads:
            h.setOptionValue("threads", threads)
        w = rng.integers(10, 100, n)
        for _ in range(n):
            h.addVar(0.0, 1.0)
        idx = np.arange(n, dtype=np.int32)
        h.changeColsIntegrality(n, idx, np.array([highspy.HighsVarType.kInteger] * n))
        h.changeColsCost(n, idx, -(w + rng.integers(0, 10, n)).astype(float))
        for _ in range(3):
            h.addRow(-highspy.kHighsInf, float(w.sum() // 3), n, idx, rng.permutation(w).astype(float))
        h.run()
        return h.getModelStatus().name, round(h.getInfo().objective_function_value, 6)

    highspy.Highs.resetGlobalScheduler(True)
    here = mip(threads=2)
    got = {}
    run_tasks([0], lambda task: mip(), lambda task, res: got.update(res=res), jobs=1, hard_limit_s=30,
              failed=lambda task, seconds, why: why)
    print(json.dumps({"parent": here, "child": got["res"]}))
""")


def test_a_forked_worker_solves_after_the_parent_made_a_two_thread_pool():
    out = subprocess.run([sys.executable, "-c", SCRIPT], cwd=ROOT, capture_output=True, text=True, timeout=120)
    assert out.returncode == 0, out.stderr[-2000:]
    got = json.loads(out.stdout.strip().splitlines()[-1])
    assert got["parent"][0] == "kOptimal"
    assert got["child"] == got["parent"], got   # the same optimum (before the fix: 'killed')
