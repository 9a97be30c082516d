"""exact's numba kernels on a machine that has not compiled them (``l3gs_opt.solvers.exact.kernels``).

Each case runs in a subprocess whose numba cache (``NUMBA_CACHE_DIR``) starts empty, as on a fresh
install. Before the kernels module, the first ``exact`` under a 5 s limit compiled for 8.8 s and
returned its start schedule with a bound four times the optimum.
"""

from __future__ import annotations

import json
import os
import subprocess
import sys
import textwrap
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[1]
#: Seconds past its limit a timed ``exact`` may run here (its own margins are well under one);
#: the cold compile it must not wait for takes ~9 s on our 2-core box.
OVERRUN_S = 2.0

SOLVE = textwrap.dedent("""
    import json, sys
    from l3gs_opt import solve
    from l3gs_opt.bench.suites import suite_specs

    spec = [s for s in suite_specs("l3gs", sizes=[10], seeds=1, quick=True) if s.kind == "problem"][0]
    inst = spec.build()
    sol = solve(inst, "exact", time_limit_s=float(sys.argv[1]))
    print(json.dumps({"status": sol.status.value, "objective": sol.objective, "bound": sol.bound,
                      "runtime_s": sol.runtime_s, "kernels": sol.details.get("kernels")}))
""")

# The compile thread started, then a fork at once: the child uses the pricing kernel. A fork that
# did not wait for the compile left the child holding numba's compiler lock with no thread to
# release it.
FORK = textwrap.dedent("""
    import json
    import numpy as np
    from l3gs_opt.executors import run_tasks
    from l3gs_opt.solvers.exact import kernels
    from l3gs_opt.solvers.exact import pricing

    def work(_task):
        chosen, best, done = pricing.solve_kp01_float(np.array([3, 4, 5]), np.array([1.0, 2.0, 3.5]), 8)
        return [int(c) for c in chosen], best, done

    kernels.prepare("pricing")
    out = []
    run_tasks([0], work, lambda _t, r: out.append(r), jobs=1, hard_limit_s=60.0,
              failed=lambda _t, s, why: ("killed", why))
    print(json.dumps(out))
""")


def _run(script: str, cache: Path, *args: str, timeout: float = 180.0) -> dict | list:
    env = dict(os.environ, NUMBA_CACHE_DIR=str(cache), PYTHONPATH=str(ROOT))
    proc = subprocess.run([sys.executable, "-c", script, *args], capture_output=True, text=True, env=env,
                          timeout=timeout, cwd=ROOT)
    assert proc.returncode == 0, proc.stderr[-3000:]
    return json.loads(proc.stdout.strip().splitlines()[-1])


@pytest.fixture(scope="module")
def optimum() -> float:
    from l3gs_opt import solve
    from l3gs_opt.bench.suites import suite_specs

    spec = [s for s in suite_specs("l3gs", sizes=[10], seeds=1, quick=True) if s.kind == "problem"][0]
    sol = solve(spec.build(), "ilp", backend="highs", time_limit_s=60.0)
    assert sol.status.value == "optimal"
    return sol.objective


def test_a_timed_exact_does_not_wait_for_a_compile_and_the_next_process_has_the_kernels(tmp_path, optimum):
    cold = _run(SOLVE, tmp_path, "3")
    assert cold["runtime_s"] <= 3.0 + OVERRUN_S, cold
    # The answer is still exact (a second backend's optimum), or an honest time limit.
    assert cold["objective"] <= optimum * (1 + 1e-9) and cold["bound"] >= optimum * (1 - 1e-9)
    assert cold["status"] in ("optimal", "time_limit")
    # The process waited at exit for the compile it had started, so it reached the disk cache.
    assert any(tmp_path.rglob("*.nbi")), list(tmp_path.rglob("*"))
    warm = _run(SOLVE, tmp_path, "3")
    assert warm["status"] == "optimal" and abs(warm["objective"] - optimum) <= 1e-9 * optimum
    assert warm["kernels"] is None   # the annealing ran with its kernel


def test_a_fork_during_a_compile_leaves_the_child_able_to_use_the_kernel(tmp_path):
    out = _run(FORK, tmp_path)
    assert out == [[[0, 2], 4.5, True]], out
