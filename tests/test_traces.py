"""Bandwidth traces: bundled copies, junk lines, scaling, windows, bytes per slot."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest

from l3gs_opt.traces.bandwidth import TraceError, bundled_traces, mbps_to_bytes, read_bandwidth_trace

SHARED = Path(__file__).resolve().parents[1].parent / "shared" / "data" / "bandwidth" / "lumos5g"


def test_bundled_traces_are_the_shared_ones():
    bundled = bundled_traces()
    assert len(bundled) == 9
    if SHARED.is_dir():  # only on the project's own machines
        for path in SHARED.glob("*.txt"):
            assert bundled[path.stem].read_bytes() == path.read_bytes()


def test_read_and_scale():
    trace = read_bandwidth_trace("lumos-throughput-mid-11")
    assert trace.skipped == 0 and 700 <= len(trace.mbps) <= 900
    scaled, factor = trace.scaled(11.8)
    assert scaled.mbps.mean() == pytest.approx(11.8)
    assert factor == pytest.approx(11.8 / trace.mbps.mean())
    window = scaled.window(10, 60)
    np.testing.assert_array_equal(window.mbps, scaled.mbps[10:70])
    with pytest.raises(TraceError, match="does not fit"):
        scaled.window(len(trace.mbps) - 5, 60)


def test_junk_lines_are_counted_and_warned(tmp_path):
    path = tmp_path / "t.txt"
    path.write_text("10\nabc\n\n12.5\n--\n0\n")
    with pytest.warns(UserWarning, match="skipped 2 line"):
        trace = read_bandwidth_trace(path)
    assert trace.mbps.tolist() == [10.0, 12.5, 0.0] and trace.skipped == 2


def test_csv_and_errors(tmp_path):
    csv = tmp_path / "t.csv"
    csv.write_text("time_s,mbps\n0,5\n1,6\n2,7\n")
    with pytest.warns(UserWarning):
        assert read_bandwidth_trace(csv).mbps.tolist() == [5.0, 6.0, 7.0]
    (tmp_path / "empty.txt").write_text("")
    with pytest.raises(TraceError, match="no throughput sample"):
        read_bandwidth_trace(tmp_path / "empty.txt")
    (tmp_path / "neg.txt").write_text("5\n-3\n")
    with pytest.raises(TraceError, match="line 2: throughput -3.0"):
        read_bandwidth_trace(tmp_path / "neg.txt")


def test_mbps_to_bytes():
    assert mbps_to_bytes(np.array([11.8, 0.0, 8.0])).tolist() == [1_475_000, 0, 1_000_000]
    assert mbps_to_bytes(np.array([8.0]), slot_s=0.5).tolist() == [500_000]


def test_synthetic_bandwidth_mean_outages_and_determinism():
    from l3gs_opt.traces.bandwidth import synthetic_bandwidth

    a = synthetic_bandwidth(600, 11.8, outage_rate=0.05, seed=3)
    b = synthetic_bandwidth(600, 11.8, outage_rate=0.05, seed=3)
    assert np.array_equal(a.mbps, b.mbps)
    assert a.mbps.mean() == pytest.approx(11.8, rel=1e-12)
    assert (a.mbps >= 0).all() and np.isfinite(a.mbps).all()
    # Outage runs: zero samples in runs of 1..4 s, starting at roughly the requested rate.
    zero = a.mbps == 0
    starts = np.flatnonzero(zero & ~np.concatenate([[False], zero[:-1]]))
    ends = np.flatnonzero(zero & ~np.concatenate([zero[1:], [False]]))
    runs = ends - starts + 1
    assert len(runs) > 5 and runs.min() >= 1 and runs.max() <= 4 * 2  # two adjacent outages may touch
    assert not synthetic_bandwidth(300, 5.0, outage_rate=0.0, seed=1).mbps.min() == 0
    # No variability and no outage: a constant trace at the mean.
    flat = synthetic_bandwidth(10, 3.0, variability=0.0, outage_rate=0.0)
    assert np.allclose(flat.mbps, 3.0)
    # Fades persist: neighbouring samples correlate in log space.
    c = synthetic_bandwidth(2000, 10.0, outage_rate=0.0, correlation=0.9, seed=2)
    g = np.log(c.mbps)
    assert np.corrcoef(g[:-1], g[1:])[0, 1] > 0.8


@pytest.mark.parametrize("kw, match", [({"seconds": 0}, "seconds"), ({"mean_mbps": -1.0}, "mean_mbps"),
                                       ({"outage_rate": 1.0}, "outage_rate"), ({"correlation": 1.0}, "correlation"),
                                       ({"variability": float("nan")}, "variability"),
                                       ({"outage_s": (3, 2)}, "outage_s")])
def test_synthetic_bandwidth_bad_arguments(kw, match):
    from l3gs_opt.traces.bandwidth import TraceError, synthetic_bandwidth

    with pytest.raises(TraceError, match=match):
        synthetic_bandwidth(**kw)
