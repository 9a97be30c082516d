"""Bad input found by a sweep (2026-11-27, nineteenth session) of ``bench``, ``demo``, ``utility check`` and the
executors: each is refused as one line naming the option, exit 2, before any work.

1. a malformed Dask scheduler ``--address`` (a traceback from ``distributed`` before), an empty one
   (a local cluster in silence), or one given to the local executor (ignored in silence);
2. ``bench --methods greedy,greedy`` / ``--sizes 2,2`` (duplicate record ids, counted twice in the
   report) and ``--seeds`` beyond :data:`~l3gs_opt.bench.suites.MAX_SEEDS`;
3. ``demo --time-limit -1`` (started the quick benchmark first) or ``inf``;
4. ``utility check --utilities eq1,eq1`` (the same row twice);
5. an empty ``--out`` (wrote into the current folder).
"""

from __future__ import annotations

import pytest

from cli_helpers import one_error_line
from l3gs_opt.bench.suites import MAX_SEEDS
from l3gs_opt.executors import ExecutorError, check_executor, run_tasks

BENCH = ("bench", "--suite", "l3gs", "--sizes", "2", "--seeds", "1", "--time-limit", "1", "--no-progress",
         "--methods", "greedy")


@pytest.mark.parametrize("address, why", [
    ("not an address", "missing port number"),
    ("127.0.0.1:notaport", "invalid literal"),
    ("nosuchproto://x:1", "unknown address scheme"),
    ("tcp://127.0.0.1:99999", "port 99999"),
])
def test_malformed_dask_address_is_one_line(capsys, tmp_path, address, why):
    line = one_error_line(capsys, *BENCH, "--out", tmp_path / "b", "--executor", "dask", "--address", address)
    assert line.startswith(f"error: --address {address!r}: not a Dask scheduler address (") and why in line, line
    assert not (tmp_path / "b").exists()


def test_address_only_with_dask_and_not_empty(capsys, tmp_path):
    line = one_error_line(capsys, *BENCH, "--out", tmp_path / "b", "--address", "127.0.0.1:8786")
    assert line == "error: --address '127.0.0.1:8786': only the dask executor uses a scheduler address"
    line = one_error_line(capsys, *BENCH, "--out", tmp_path / "b", "--executor", "dask", "--address", "")
    assert line.startswith("error: --address '': empty")
    # the library call refuses the same, before any task runs
    ran = []
    with pytest.raises(ExecutorError, match="not a Dask scheduler address"):
        run_tasks([1], ran.append, lambda t, r: None, jobs=1, executor="dask", address="x", failed=lambda *a: None)
    assert ran == []
    check_executor("dask", 1, "tcp://127.0.0.1:8786")   # well formed: accepted (nothing connects here)
    check_executor("local", 2, None)


@pytest.mark.parametrize("extra, want", [
    (("--methods", "greedy,bb,greedy"), "error: --methods[2]: 'greedy' is named twice"),
    (("--sizes", "2,3,2"), "error: --sizes[2] = 2: named twice"),
    (("--seeds", str(MAX_SEEDS + 1)), f"error: --seeds = {MAX_SEEDS + 1}: must be 1..{MAX_SEEDS} seeds per size"),
])
def test_bench_duplicates_and_seed_limit(capsys, tmp_path, extra, want):
    line = one_error_line(capsys, *BENCH, "--out", tmp_path / "b", *extra)
    assert line.startswith(want), line
    assert not (tmp_path / "b").exists()


@pytest.mark.parametrize("limit, want", [("-1", "error: --time-limit"), ("inf", "error: --time-limit: inf: the demo")])
def test_demo_refuses_a_bad_time_limit_before_any_step(capsys, tmp_path, limit, want):
    line = one_error_line(capsys, "demo", "--out", tmp_path / "d", "--time-limit", limit)
    assert line.startswith(want), line
    assert not (tmp_path / "d").exists()


def test_utility_check_names_a_utility_twice(capsys, tmp_path):
    line = one_error_line(capsys, "utility", "check", tmp_path / "none", "--path", tmp_path / "none.log",
                          "--utilities", "eq1,visibility,eq1", "--out", tmp_path / "o")
    assert line == "error: --utilities: 'eq1' is named twice"


@pytest.mark.parametrize("argv", [
    ("bench", "--suite", "l3gs", "--out", ""),
    ("demo", "--out", " "),
    ("render", "x.ply", "--camera", "c.json", "--out", ""),
    ("instance", "synth", "--objects", "2", "-o", ""),
])
def test_an_empty_output_path_is_refused(capsys, monkeypatch, tmp_path, argv):
    monkeypatch.chdir(tmp_path)
    line = one_error_line(capsys, *argv)
    assert line.startswith("error: --") and ": empty: name a path" in line, line
    assert list(tmp_path.iterdir()) == []
