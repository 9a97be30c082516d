"""``benchmarks/bench_exact_long.py``'s command line: seed lists, and bad input as one line (exit 2)."""

from __future__ import annotations

import argparse
import subprocess
import sys

import pytest
from hypothesis import given, settings
from hypothesis import strategies as st
from script_helpers import BENCHMARKS, load_script

_SCRIPT = BENCHMARKS / "bench_exact_long.py"


@pytest.fixture(scope="module")
def long_bench():
    return load_script("bench_exact_long")


@pytest.mark.parametrize("text, seeds", [("7", [7]), ("5-9", [5, 6, 7, 8, 9]), ("1,4", [1, 4]),
                                         ("4, 0-1", [0, 1, 4]), ("2-3,3", [2, 3])])
def test_seed_list(long_bench, text, seeds):
    assert long_bench.seed_list(text) == seeds


@settings(max_examples=200, deadline=None)
@given(parts=st.lists(st.tuples(st.integers(0, 10_000), st.integers(0, 5), st.booleans()), min_size=1, max_size=6),
       space=st.booleans())
def test_seed_list_reads_back_what_it_is_given(long_bench, parts, space):
    """Any comma list of seeds and ranges ("a" or "a-b"), spaces after commas or not, reads as the
    sorted union of what it names."""
    text = (", " if space else ",").join(f"{a}-{a + w}" if ranged else str(a) for a, w, ranged in parts)
    expected = sorted({s for a, w, ranged in parts for s in (range(a, a + w + 1) if ranged else [a])})
    assert long_bench.seed_list(text) == expected


@pytest.mark.parametrize("text, part", [("1,x", "part 1"), ("3-1", "part 0"), ("", "part 0"), ("-2", "part 0")])
def test_seed_list_refuses_with_the_part(long_bench, text, part):
    with pytest.raises(argparse.ArgumentTypeError, match=part):
        long_bench.seed_list(text)


def test_bad_seeds_exit_2_in_one_line(tmp_path):
    run = subprocess.run([sys.executable, str(_SCRIPT), "--J", "20", "--seeds", "1,x", "--out", str(tmp_path)],
                         capture_output=True, text=True, timeout=120)
    assert run.returncode == 2
    assert "Traceback" not in run.stderr
    assert [line for line in run.stderr.splitlines() if "error:" in line] == \
        ["bench_exact_long.py: error: argument --seeds: part 1 ('x') is not a seed or a range like 5-9"]
    assert not any(tmp_path.iterdir())
