"""Mahimahi and Pensieve bandwidth traces: hand-computed values, round trips, a second
implementation of the time-weighted resampling, format sniffing and its refusals."""

from __future__ import annotations

import warnings

import numpy as np
import pytest
from hypothesis import given, settings, strategies as st

from l3gs_opt.traces.bandwidth import (MIN_AUTO_MAHIMAHI_LINES, AmbiguousTraceError, BandwidthTrace, TraceError,
                                       _parse_pensieve, bundled_traces, detect_format, read_bandwidth_trace,
                                       write_mahimahi)

PACKET_MBIT = 1500 * 8 / 1e6  # one 1500-byte opportunity a second, in Mbit/s
PROPERTY = settings(max_examples=60, deadline=None, derandomize=True)


def _write(tmp_path, name, text):
    path = tmp_path / name
    path.write_text(text)
    return path


# ------------------------------------------------------------------------------------ Mahimahi
def test_mahimahi_counts_per_second_by_hand(tmp_path):
    # T = 2000 ms -> 2 s; the line at 2000 is the next loop's ms 0, so second 0 holds 0, 0, 500,
    # 999 and 2000 (5 packets) and second 1 holds 1000 and 1500 (2 packets).
    path = _write(tmp_path, "m.down", "0\n0\n500\n999\n1000\n1500\n2000\n")
    trace = read_bandwidth_trace(path, format="mahimahi")
    np.testing.assert_allclose(trace.mbps, [5 * PACKET_MBIT, 2 * PACKET_MBIT], rtol=1e-12)
    assert trace.sample_s == 1.0 and trace.name == "m"


def test_mahimahi_short_loops_are_unrolled(tmp_path):
    # The classic one-line "1" trace: one packet every ms = 12 Mbit/s.
    np.testing.assert_allclose(read_bandwidth_trace(_write(tmp_path, "a", "1\n"), format="mahimahi").mbps, [12.0])
    # Period 3 ms, one packet each ms: lcm(3, 1000) = 3000 ms = 3 seconds of 1000 packets.
    np.testing.assert_allclose(read_bandwidth_trace(_write(tmp_path, "b", "1\n2\n3\n"), format="mahimahi").mbps,
                               [12.0, 12.0, 12.0])
    # A partial last second is dropped: T = 2500 ms -> 2 seconds.
    assert len(read_bandwidth_trace(_write(tmp_path, "c", "0\n2500\n"), format="mahimahi").mbps) == 2


@pytest.mark.parametrize("text, message", [
    ("0\n5\n3\n", r"line 3: column 1 \(timestamp_ms\) 3 must not decrease \(previous 5\)"),
    ("0\nabc\n7\n", r"line 2: column 1 \(timestamp_ms\) 'abc' is not a non-negative integer"),
    ("0\n-4\n", r"line 2: column 1 \(timestamp_ms\) '-4' is not a non-negative integer"),
    ("0\n1 2\n", r"line 2: column 1 \(timestamp_ms\) '1 2' has more than one column"),
    ("0\n0\n", r"every time is 0 ms"),
    ("\n\n", r"no delivery opportunity"),
])
def test_mahimahi_errors_name_line_and_column(tmp_path, text, message):
    with pytest.raises(TraceError, match=message):
        read_bandwidth_trace(_write(tmp_path, "bad", text), format="mahimahi")


@PROPERTY
@given(counts=st.lists(st.integers(0, 3000), min_size=1, max_size=12).map(lambda c: [max(c[0], 1)] + c[1:]))
def test_mahimahi_round_trip_of_whole_packets(tmp_path_factory, counts):
    # Rates that are whole packets a second come back exactly.
    path = tmp_path_factory.mktemp("rt") / "t.down"
    mbps = np.asarray(counts, dtype=np.float64) * PACKET_MBIT
    write_mahimahi(BandwidthTrace("t", mbps), path)
    back = read_bandwidth_trace(path, format="mahimahi")
    np.testing.assert_allclose(back.mbps, mbps, rtol=0, atol=1e-9)


@PROPERTY
@given(mbps=st.lists(st.floats(0, 200, allow_nan=False), min_size=1, max_size=10))
def test_mahimahi_round_trip_keeps_every_prefix_within_one_packet(tmp_path_factory, mbps):
    path = tmp_path_factory.mktemp("rt") / "t.down"
    write_mahimahi(BandwidthTrace("t", np.asarray(mbps)), path)
    back = read_bandwidth_trace(path, format="mahimahi").mbps
    assert len(back) == len(mbps)
    # Second 0 may gain the one packet that marks the loop period (write_mahimahi's docstring).
    slack = PACKET_MBIT * (1 + 1e-9) + (PACKET_MBIT if mbps[0] < PACKET_MBIT else 0)
    assert np.all(np.abs(np.cumsum(back) - np.cumsum(mbps)) <= slack + 1e-9)


def test_write_mahimahi_refuses_bad_traces(tmp_path):
    with pytest.raises(TraceError, match=r"mbps\[1\] = -1.0"):
        write_mahimahi(BandwidthTrace("t", np.array([1.0, -1.0])), tmp_path / "x")
    with pytest.raises(TraceError, match="sample_s = 0.5"):
        write_mahimahi(BandwidthTrace("t", np.array([1.0]), sample_s=0.5), tmp_path / "x")


def test_bundled_lumos_trace_through_mahimahi_and_auto(tmp_path):
    # A real trace, scaled as the L3GS paper does (mean 11.8 Mbit/s), 60 s window.
    lumos = read_bandwidth_trace("lumos-throughput-mid-11").scaled(11.8)[0].window(0, 60)
    path = write_mahimahi(lumos, tmp_path / "lumos.down")
    assert detect_format(path.read_text()) == "mahimahi"
    back = read_bandwidth_trace(path)  # auto
    assert len(back.mbps) == 60
    assert np.max(np.abs(np.cumsum(back.mbps) - np.cumsum(lumos.mbps))) <= 2 * PACKET_MBIT


# ------------------------------------------------------------------------------------ Pensieve
def test_pensieve_time_weighted_seconds_by_hand(tmp_path):
    # Holds: [0, .5) 2, [.5, 1.5) 4, [1.5, 2) 6, [2, 2.5) 8 (the last for the median spacing 0.5 s).
    path = _write(tmp_path, "norway_bus_1", "0.0\t2.0\n0.5 4.0\n1.5\t6.0\n2.0 8.0\n")
    trace = read_bandwidth_trace(path)  # auto -> pensieve
    np.testing.assert_allclose(trace.mbps, [0.5 * 2 + 0.5 * 4, 0.5 * 4 + 0.5 * 6], rtol=1e-12)


def _per_second_by_sampling(times: np.ndarray, mbps: np.ndarray) -> np.ndarray:
    """A second implementation: the held value sampled every 1/4096 s (exact binary steps) and
    averaged per whole second."""
    t = times - times[0]
    last = float(np.median(np.diff(t))) if len(t) > 1 else 1.0
    seconds = int(np.floor(t[-1] + last + 1e-9))
    grid = (np.arange(seconds * 4096) + 0.5) / 4096
    held = mbps[np.searchsorted(t, grid, side="right") - 1]
    return held.reshape(seconds, 4096).mean(axis=1)


@PROPERTY
@given(steps=st.lists(st.integers(1, 24), min_size=2, max_size=30),
       values=st.lists(st.floats(0, 100, allow_nan=False), min_size=30, max_size=30))
def test_pensieve_resampling_matches_fine_sampling(steps, values):
    # Times on a 1/8 s grid, so the 1/4096 s samples never straddle a change of value.
    times = np.concatenate([[0.0], np.cumsum(steps) / 8.0])
    mbps = np.asarray(values[:len(times)])
    if times[-1] + np.median(np.diff(times)) < 1:
        return
    text = "".join(f"{float(t)!r} {float(v)!r}\n" for t, v in zip(times, mbps))
    got, skipped = _parse_pensieve(text, "p")
    assert skipped == 0
    np.testing.assert_allclose(got, _per_second_by_sampling(times, mbps), rtol=1e-9, atol=1e-9)


@pytest.mark.parametrize("text, message", [
    ("0 1\n1 2\n0.5 3\n", r"line 3: column 1 \(time_s\) 0.5 must increase \(previous 1.0\)"),
    ("0 1\n1 -2\n", r"line 2: column 2 \(mbps\) -2.0 Mbit/s must be finite, >= 0"),
    ("0 1\n1 nan\n", r"line 2: column 2 \(mbps\) nan"),
    ("0 1\n1 2 3\n", r"line 2: 3 columns, a Pensieve trace has two: time_s mbps"),
    ("1453121790686 39287 51.03 3.73 2493100 1000\n", r"line 1: 6 columns.*Ghent 4G/LTE log"),
    ("0 1\n0.25 2\n", r"less than one whole second"),
])
def test_pensieve_errors_name_line_and_column(tmp_path, text, message):
    with pytest.raises(TraceError, match=message):
        read_bandwidth_trace(_write(tmp_path, "bad", text), format="pensieve")


def test_pensieve_header_is_skipped_with_a_warning(tmp_path):
    path = _write(tmp_path, "h", "time bandwidth\n0 5\n1 7\n")
    with pytest.warns(UserWarning, match="skipped 1 line"):
        trace = read_bandwidth_trace(path)
    assert trace.mbps.tolist() == [5.0, 7.0] and trace.skipped == 1


# ------------------------------------------------------------------------------------ auto
def test_auto_keeps_every_bundled_lumos_trace_unchanged():
    for name, path in bundled_traces().items():
        text = path.read_text()
        assert detect_format(text) == "lumos", name
        np.testing.assert_array_equal(read_bandwidth_trace(path).mbps, read_bandwidth_trace(path, format="lumos").mbps)


@pytest.mark.parametrize("text, expected", [
    ("5\n" * 10, "lumos"),                      # one repeated value: the old reading
    ("10\n12.5\n0\n", "lumos"),                 # a decimal
    ("30\n20\n10\n", "lumos"),                  # decreasing
    ("time_s,mbps\n0,5\n1,6\n", "lumos"),       # CSV
    ("0.0\t2.5\n1.0\t3.0\n", "pensieve"),
    ("".join(f"{k // 3}\n" for k in range(MIN_AUTO_MAHIMAHI_LINES)), "mahimahi"),
])
def test_auto_detection(text, expected):
    assert detect_format(text) == expected


@pytest.mark.parametrize("text, message", [
    ("1\n2\n3\n", r"3 never-decreasing integer lines fit both"),
    ("0 5\n7\n1 6\n", r"line 2 has one number .* line 1 two"),
])
def test_auto_refuses_ambiguous_content(tmp_path, text, message):
    with pytest.raises(AmbiguousTraceError, match=message):
        read_bandwidth_trace(_write(tmp_path, "amb.txt", text))
    # Naming the format resolves it.
    if "never" in message:
        assert read_bandwidth_trace(_write(tmp_path, "amb.txt", text), format="lumos").mbps.tolist() == [1, 2, 3]
        np.testing.assert_allclose(read_bandwidth_trace(tmp_path / "amb.txt", format="mahimahi").mbps, [12.0] * 3)


def test_a_thousands_digit_number_is_a_named_error_in_every_format(tmp_path):
    # Python refuses to convert an integer of more than 4300 digits (a bare ValueError).
    big = "9" * 5000
    path = _write(tmp_path, "lumos", "5\n3\n8\n" + big + "\n")
    with pytest.raises(TraceError, match=r"line 4: throughput inf Mbit/s must be finite"):
        read_bandwidth_trace(path)
    path = _write(tmp_path, "mahimahi", "0\n" + big + "\n")
    with pytest.raises(TraceError, match=r"line 2: column 1 \(timestamp_ms\) 10{30} ms is more than"):
        read_bandwidth_trace(path, format="mahimahi")


def test_unknown_format_is_named(tmp_path):
    with pytest.raises(TraceError, match=r"format = 'csv': must be one of auto, lumos, mahimahi, pensieve"):
        read_bandwidth_trace(_write(tmp_path, "x", "5\n"), format="csv")


def test_lumos_warning_still_points_at_the_caller(tmp_path):
    path = _write(tmp_path, "w.txt", "10\nabc\n7\n")
    with warnings.catch_warnings(record=True) as caught:
        warnings.simplefilter("always")
        read_bandwidth_trace(path)
    assert len(caught) == 1 and caught[0].filename == __file__
