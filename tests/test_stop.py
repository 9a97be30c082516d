"""The stop request (l3gs_opt.stop): the first Ctrl-C of a long solve ends it with its best answer
(status ``time_limit``, a feasible schedule and a valid bound, a message that says so); the second
aborts."""

from __future__ import annotations

import dataclasses
import json
import os
import signal
import threading
import time

import pytest

from solver_helpers import bench_instance, check_answer
from l3gs_opt import solve, stop
from l3gs_opt.cli.main import main
from l3gs_opt.problem.instance_io import save_instance
from l3gs_opt.problem.solution import Status

#: Far beyond how long any of these solves is let run: a run that ends well before it was stopped.
LONG_LIMIT_S = 600.0


@pytest.fixture(autouse=True)
def _no_request_left():
    stop.clear()
    yield
    stop.clear()


def _wait_for(condition, timeout_s: float = 5.0) -> bool:
    end = time.monotonic() + timeout_s
    while time.monotonic() < end:
        if condition():
            return True
        time.sleep(0.01)
    return condition()


def test_expired_follows_the_deadline_and_the_request() -> None:
    assert not stop.expired(None)
    assert not stop.expired(time.perf_counter() + 60)
    assert stop.expired(time.perf_counter() - 1)
    stop.request()
    assert stop.requested() and stop.expired(None) and stop.expired(time.perf_counter() + 60)
    stop.clear()
    assert not stop.requested() and not stop.expired(None)


def test_first_sigint_requests_a_stop_and_the_second_raises() -> None:
    before = signal.getsignal(signal.SIGINT)
    with pytest.raises(KeyboardInterrupt):
        with stop.on_interrupt():
            os.kill(os.getpid(), signal.SIGINT)
            assert _wait_for(stop.requested)        # no KeyboardInterrupt: a request
            os.kill(os.getpid(), signal.SIGINT)
            time.sleep(5.0)                         # the second one raises here
    assert signal.getsignal(signal.SIGINT) is before
    assert not stop.requested()


class _InterruptedDestructor:
    """Ctrl-C lands while Python runs a destructor, which (like a fork hook) drops what it raises."""

    def __del__(self) -> None:
        os.kill(os.getpid(), signal.SIGINT)
        for _ in range(10_000):   # Python code: the handler runs here, and its KeyboardInterrupt is dropped
            pass


@pytest.mark.filterwarnings("ignore::pytest.PytestUnraisableExceptionWarning")   # the drop is the point
def test_noted_interrupts_raises_one_that_python_dropped() -> None:
    before = signal.getsignal(signal.SIGINT)
    with stop.noted_interrupts() as check:
        check()   # nothing noted: no-op
        _InterruptedDestructor()   # collected at once; its KeyboardInterrupt goes nowhere
        with pytest.raises(KeyboardInterrupt):
            check()
        check()   # raised once: the note is spent
    assert signal.getsignal(signal.SIGINT) is before


def test_noted_interrupts_leaves_a_stop_request_alone() -> None:
    with stop.on_interrupt(), stop.noted_interrupts() as check:
        os.kill(os.getpid(), signal.SIGINT)
        assert _wait_for(stop.requested)
        check()   # the first Ctrl-C asked for a stop and raised nothing: nothing to raise again


#: A child that forks tasks while every fork takes a Ctrl-C inside a fork hook (as logging's own
#: hooks can): Python drops that KeyboardInterrupt, and before l3gs_opt.stop.noted_interrupts the
#: local executor ran every task to the end. Prints how many tasks were written, then how it ended.
_FORK_HOOK_CHILD = """
import os, signal, sys
from l3gs_opt.executors import run_tasks

def hit():
    os.kill(os.getpid(), signal.SIGINT)
    for _ in range(10_000):   # Python code: the handler runs here, inside the fork hook
        pass

os.register_at_fork(before=hit)
done = []
try:
    run_tasks(list(range(5)), abs, lambda task, result: done.append(task), jobs=1,
              failed=lambda task, seconds, why: None)
    print(len(done), "finished")
except KeyboardInterrupt:
    print(len(done), "interrupted")
"""


def test_a_ctrl_c_inside_a_fork_hook_stops_the_local_executor() -> None:
    import subprocess
    import sys

    out = subprocess.run([sys.executable, "-c", _FORK_HOOK_CHILD], capture_output=True, text=True, timeout=60,
                         preexec_fn=lambda: signal.signal(signal.SIGINT, signal.SIG_DFL))
    assert out.stdout.split() == ["0", "interrupted"], (out.stdout, out.stderr[-500:])
    assert "Exception ignored" in out.stderr   # the mechanism: Python did drop the first one


def test_stoppable_returns_raises_and_halts_once() -> None:
    assert stop.stoppable(lambda: 42, lambda: None) == 42
    with pytest.raises(ZeroDivisionError):
        stop.stoppable(lambda: 1 / 0, lambda: None)
    halted = threading.Event()
    calls: list[int] = []

    def run() -> str:
        stop.request()
        assert halted.wait(5.0), "halt was not called"
        return "halted"

    def halt() -> None:
        calls.append(1)
        halted.set()

    assert stop.stoppable(run, halt, poll_s=0.01) == "halted"
    assert calls == [1]


@pytest.mark.parametrize("method, J, seed, budget, after_s", [
    ("exact", 20, 0, "per_slot", 0.5),     # during the LP and column generation
    ("exact", 20, 0, "per_slot", 6.0),     # in the primal phases or the branching
    ("exact", 50, 1, "cumulative", 3.0),   # the arrived-by search (HiGHS on the event model)
    ("ilp", 50, 1, "per_slot", 3.0),       # HiGHS branch-and-cut
    ("ilp/cpsat", 20, 0, "per_slot", 3.0),  # CP-SAT through stop_search
    ("ilp/cbc", 20, 0, "per_slot", 3.0),    # CBC: SIGINT to PuLP's child, resent until it acts
])
def test_a_stopped_solve_returns_its_best_answer(method: str, J: int, seed: int, budget: str,
                                                 after_s: float) -> None:
    inst = bench_instance(J, seed, budget)
    heuristic = solve(inst, "rolling-future:bb")
    backend = method.split("/")[1] if "/" in method else "highs"
    timer = threading.Timer(after_s, stop.request)
    timer.start()
    try:
        sol = solve(inst, method.split("/")[0], backend=backend, time_limit_s=LONG_LIMIT_S)
    finally:
        timer.cancel()
    assert sol.runtime_s < after_s + 60.0, "the request did not stop the solve"
    assert sol.status is Status.TIME_LIMIT
    assert stop.STOPPED_NOTE in sol.message
    check_answer(inst, sol)
    assert sol.bound >= heuristic.objective      # a valid bound is above every schedule


def test_only_a_run_the_request_stopped_says_so() -> None:
    """A heuristic that finishes (``feasible``) is not stopped by a request; nor is a run that went
    on to its time limit."""
    from l3gs_opt.methods import _noting_stop
    from l3gs_opt.models.backends import LIMIT_SLACK as STOP_SLACK

    inst = bench_instance(20, 0)
    stop.request()
    sol = solve(inst, "rolling-future:bb")
    assert sol.status is Status.FEASIBLE and stop.STOPPED_NOTE not in sol.message
    timed = dataclasses.replace(sol, status=Status.TIME_LIMIT, runtime_s=30.0)
    assert stop.STOPPED_NOTE not in _noting_stop(timed, 30.0 / STOP_SLACK * 0.999).message
    assert stop.STOPPED_NOTE in _noting_stop(timed, 60.0).message
    assert stop.STOPPED_NOTE in _noting_stop(timed, None).message
    stop.clear()
    assert stop.STOPPED_NOTE not in _noting_stop(timed, 60.0).message


@pytest.mark.parametrize("args", [["--method", "exact"], ["--backend", "cpsat"], ["--backend", "highs"]])
def test_cli_first_ctrl_c_prints_the_best_answer(tmp_path, capsys, monkeypatch, args: list[str]) -> None:
    """A real SIGINT to this process: the handler runs in the main thread, which must not be
    stuck in a C call that runs no Python code (CP-SAT: :func:`stop.stoppable`)."""
    inst = bench_instance(20, 0)
    path = save_instance(inst, tmp_path / "j20.json")
    timer = threading.Timer(3.0, os.kill, (os.getpid(), signal.SIGINT))
    after_first = None
    if args == ["--backend", "highs"]:
        # HiGHS's first schedule worth more than 0 came after 3 s once, in a full local run: the
        # Ctrl-C comes 1 s after that schedule instead (at 30 s without one, and the test fails).
        from l3gs_opt.models.backends import highs as highs_backend

        timer = threading.Timer(30.0, os.kill, (os.getpid(), signal.SIGINT))
        after_first = threading.Timer(1.0, os.kill, (os.getpid(), signal.SIGINT))
        made = highs_backend.new_highs
        seen: list = []

        def first_schedule(event) -> None:
            # (HiGHS's trivial heuristics report the empty schedule, worth 0, first.)
            if not seen and event.data_out.objective_function_value > 0:
                seen.append(True)
                timer.cancel()
                after_first.start()

        def new_highs(**kw):
            h = made(**kw)
            h.cbMipImprovingSolution.subscribe(first_schedule)
            return h

        monkeypatch.setattr(highs_backend, "new_highs", new_highs)
    timer.start()
    try:
        code = main(["solve", str(path), *args, "--time-limit", str(LONG_LIMIT_S), "--json"])
    finally:
        timer.cancel()
        if after_first is not None:
            after_first.cancel()
    captured = capsys.readouterr()
    assert code == 0
    assert "stopping:" in captured.err
    answer = json.loads(captured.out)
    assert answer["status"] == "time_limit" and stop.STOPPED_NOTE in answer["message"]
    assert answer["bound"] >= answer["objective"] > 0
    assert answer["runtime_s"] < 3.0 + 60.0, "the Ctrl-C did not stop the solve"
    assert not stop.requested()


@pytest.mark.skipif(not os.path.exists("/proc/self/task"), reason="finds CBC's process through Linux /proc")
def test_a_terminal_ctrl_c_stops_cbc_with_its_bound() -> None:
    """In a terminal the Ctrl-C reaches PuLP's CBC child as well as Python. CBC then stops as at
    its time limit; it used to be reported as an error with a schedule rounded from its LP values.
    J=20 s2: CBC has no integer schedule in its first 12 s here, so the answer is its bound alone."""
    inst = bench_instance(20, 2)
    heuristic = solve(inst, "rolling-future:bb")
    sent: list[int] = []

    def ctrl_c() -> None:
        if _wait_for(lambda: bool(stop.child_processes("cbc")), 20.0):
            time.sleep(1.5)
            stop.request()
            for pid in stop.child_processes("cbc"):
                os.kill(pid, signal.SIGINT)
                sent.append(pid)

    timer = threading.Thread(target=ctrl_c)
    timer.start()
    sol = solve(inst, "ilp", backend="cbc", time_limit_s=LONG_LIMIT_S)
    timer.join()
    assert sent, "CBC's process was not found"
    assert sol.runtime_s < 60.0, "the Ctrl-C did not stop CBC"
    assert sol.status is Status.TIME_LIMIT, sol.message
    assert "ctrl-c" in sol.message.lower() and stop.STOPPED_NOTE in sol.message
    check_answer(inst, sol)
    assert sol.bound >= heuristic.objective


@pytest.mark.parametrize("requested", [True, False])
def test_a_cbc_killed_at_its_start_is_no_traceback(monkeypatch, requested: bool) -> None:
    """A SIGINT before CBC installs its handler kills it (seen with one sent at once) and PuLP raises
    ``PulpSolverError``: the answer is no schedule and no bound, a time limit when a stop was asked
    for, else an error."""
    import pulp

    def killed(self, solver=None, **kwargs):
        raise pulp.PulpSolverError("Pulp: Error while trying to execute cbc")

    monkeypatch.setattr(pulp.LpProblem, "solve", killed)
    inst = bench_instance(20, 0)
    if requested:
        stop.request()
    try:
        sol = solve(inst, "ilp", backend="cbc", time_limit_s=10.0)
    finally:
        stop.clear()
    assert sol.arrivals == () and sol.bound is None and "CBC ended without an answer" in sol.message
    assert sol.status is (Status.TIME_LIMIT if requested else Status.ERROR)
