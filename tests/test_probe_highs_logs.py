"""The HiGHS log reader of benchmarks/probe_highspy_version.py (``exact --log``): read against a log
HiGHS itself writes for a small MIP (the pinned release), and against the lines HiGHS 1.16 adds."""

from __future__ import annotations

import highspy
import numpy as np

from script_helpers import load_script


def _knapsack_log(tmp_path, n: int = 40):
    rng = np.random.default_rng(3)
    w = rng.integers(50, 120, n).astype(float)
    h = highspy.Highs()
    h.setOptionValue("output_flag", True)
    h.setOptionValue("log_to_console", False)
    h.setOptionValue("log_file", str(tmp_path / "mip.log"))
    lp = highspy.HighsLp()
    lp.num_col_, lp.num_row_ = n, 2
    lp.col_cost_ = -(w + rng.integers(0, 10, n))          # (correlated: presolve does not close it)
    lp.col_lower_, lp.col_upper_ = np.zeros(n), np.ones(n)
    lp.row_lower_, lp.row_upper_ = np.array([-highspy.kHighsInf] * 2), np.array([w.sum() / 2, w.sum() / 1.5])
    lp.a_matrix_.format_ = highspy.MatrixFormat.kRowwise
    lp.a_matrix_.start_ = np.array([0, n, 2 * n], dtype=np.int32)
    lp.a_matrix_.index_ = np.tile(np.arange(n, dtype=np.int32), 2)
    lp.a_matrix_.value_ = np.concatenate([w, rng.integers(50, 120, n).astype(float)])
    lp.integrality_ = [highspy.HighsVarType.kInteger] * n
    h.passModel(lp)
    h.run()
    return tmp_path / "mip.log", h


def test_log_phases_reads_a_real_log(tmp_path) -> None:
    probe = load_script("probe_highspy_version")
    path, h = _knapsack_log(tmp_path)
    got = probe.log_phases(path, 1.5)
    assert got["log"] == "mip.log" and got["start_s"] == 1.5
    assert (got["rows"], got["cols"]) == (2, 40)
    assert got["status"] == "Optimal" == h.modelStatusToString(h.getModelStatus())
    assert 0.0 <= got["total_s"] <= h.getRunTime() + 0.01
    assert "0.00%" in path.read_text()   # node lines: the search did not end in presolve
    assert 0.0 <= got["first_node_line_s"] <= got["total_s"] + 0.1


def test_log_phases_prefers_the_presolve_time_newer_releases_report(tmp_path) -> None:
    probe = load_script("probe_highspy_version")
    path = tmp_path / "new.log"
    path.write_text("MIP has 10 rows; 12 cols; 30 nonzeros\nPresolving model\n10 rows, 12 cols, 30 nonzeros 0s\n"
                    "8 rows, 9 cols, 25 nonzeros 3s\nPresolve reductions: rows 8(-2)\n\n"
                    "         0       0         0   0.00%   -inf            -5.0      Large        0      0      0"
                    "         0    61.6s\n\nSolving report\n  Status            Interrupted by user\n"
                    "  Timing            61.59\n                    5.75 (Presolve)\n")
    got = probe.log_phases(path, 0.0)
    assert got == {"log": "new.log", "start_s": 0.0, "rows": 10, "cols": 12, "presolve_s": 5.75,
                   "first_node_line_s": 61.6, "total_s": 61.59, "status": "Interrupted by user"}
    path.write_text(path.read_text().replace("                    5.75 (Presolve)\n", ""))
    assert probe.log_phases(path, 0.0)["presolve_s"] == 3.0   # 1.14: presolve's last progress line
