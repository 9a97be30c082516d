"""Bad input to the public trace API (``l3gs_opt.traces.bandwidth`` and ``.poses``) is refused with
the module's own error, one message naming the field: the sweep's findings A4, B1, B3, C8-C15,
D9-D12, D18, E1 and E5 (``FINDINGS.md`` of the API sweep). Each test failed before its fix, with a
raw Python/numpy exception, a huge allocation, a NaN trace or silent acceptance.
"""

from __future__ import annotations

import math

import numpy as np
import pytest
from hypothesis import given, settings, strategies as st

from l3gs_opt.errors import L3gsError
from l3gs_opt.traces.bandwidth import (MAX_MBPS, MAX_TRACE_SAMPLES, MIN_MBPS, MAX_VARIABILITY, BandwidthTrace, TraceError,
                                       mbps_to_bytes, read_bandwidth_trace, synthetic_bandwidth)
from l3gs_opt.traces.poses import (MAX_POSE_SAMPLES, PoseError, PoseTrace, read_camera_path, read_pose_log,
                                   synthetic_poses, write_camera_path)

PROPERTY = settings(max_examples=60, deadline=None, derandomize=True)
#: How close a synthetic trace's mean is to the one asked for (relative): the scaling is one
#: division and one product per sample, so the only error is float64 rounding of the sum.
MEAN_RTOL = 1e-9
TRACE = "lumos-throughput-mid-11"  # a bundled trace


def _one_line(error: Exception) -> str:
    message = str(error)
    assert "\n" not in message
    return message


# ------------------------------------------------------------------------- synthetic_bandwidth

@pytest.mark.parametrize("variability", [800, 1e10, MAX_VARIABILITY * 1.01, math.inf, -0.5])
def test_a4_synthetic_bandwidth_refuses_a_variability_that_makes_nan(variability):
    with pytest.raises(TraceError, match=r"^variability = .*MAX_VARIABILITY") as caught:
        synthetic_bandwidth(10, variability=variability)
    _one_line(caught.value)


@pytest.mark.parametrize("seconds", [MAX_TRACE_SAMPLES + 1, 10**13])
def test_b1_synthetic_bandwidth_caps_seconds_at_max_trace_samples(seconds):
    with pytest.raises(TraceError, match=rf"^seconds: {seconds}: must be an integer in \[1, {MAX_TRACE_SAMPLES}\]"):
        synthetic_bandwidth(seconds)


@pytest.mark.parametrize("seconds", [True, np.True_, False])
def test_c8_synthetic_bandwidth_refuses_a_bool_as_seconds(seconds):
    with pytest.raises(TraceError, match=r"^seconds: (np\.)?(True|False)"):
        synthetic_bandwidth(seconds)


@pytest.mark.parametrize("kw, field", [({"mean_mbps": "5"}, "mean_mbps"), ({"mean_mbps": None}, "mean_mbps"),
                                       ({"mean_mbps": 10**400}, "mean_mbps"), ({"mean_mbps": True}, "mean_mbps"),
                                       ({"mean_mbps": MAX_MBPS * 2}, "mean_mbps"),
                                       ({"outage_rate": "0.1"}, "outage_rate"), ({"variability": "1"}, "variability"),
                                       ({"correlation": None}, "correlation"), ({"correlation": 1j}, "correlation")])
def test_c9_synthetic_bandwidth_checks_the_type_of_numbers(kw, field):
    with pytest.raises(TraceError, match=rf"^{field} = .*: must be a number in ") as caught:
        synthetic_bandwidth(10, **kw)
    _one_line(caught.value)


@pytest.mark.parametrize("mean", [5e-324, 1e-300, MIN_MBPS / 2])
def test_a_target_mean_below_one_bit_a_second_is_refused(mean):
    # A subnormal target used to be accepted: the factor left float64's normal range, the scaled
    # mean missed the target and every slot carried 0 bytes, silently.
    trace = read_bandwidth_trace(TRACE)
    with pytest.raises(TraceError, match=r"^mbps = .* \(the target mean, Mbit/s\): .*\[1e-06, 1e\+07\]") as caught:
        trace.scaled(mean)
    _one_line(caught.value)
    with pytest.raises(TraceError, match=r"^mean_mbps = .*: must be a number in \[1e-06, "):
        synthetic_bandwidth(10, mean_mbps=mean)
    scaled, factor = trace.scaled(MIN_MBPS)   # the floor itself is a trace with that mean
    assert math.isclose(float(scaled.mbps.mean()), MIN_MBPS, rel_tol=MEAN_RTOL)
    assert math.isclose(float(synthetic_bandwidth(10, mean_mbps=MIN_MBPS).mbps.mean()), MIN_MBPS, rel_tol=MEAN_RTOL)


@pytest.mark.parametrize("seed", [-1, 1.5, "a", True, None, np.int64(-2)])
def test_c10_synthetic_bandwidth_checks_seed(seed):
    with pytest.raises(TraceError, match=r"^seed = .*: must be an integer >= 0$"):
        synthetic_bandwidth(10, seed=seed)


def test_c10_numpy_integer_seed_is_the_same_seed():
    a, b = synthetic_bandwidth(50, seed=3), synthetic_bandwidth(50, seed=np.int64(3))
    np.testing.assert_array_equal(a.mbps, b.mbps)
    assert a.name == b.name == "synthetic-s3"


@pytest.mark.parametrize("outage_s", [3, (1, 2, 3), (1, math.inf), (1, 10**30), None, "12", (2, 1), (0, 3),
                                      (1, MAX_TRACE_SAMPLES + 1)])
def test_c11_synthetic_bandwidth_checks_outage_s(outage_s):
    with pytest.raises(TraceError, match=r"^outage_s = .*: must be a pair \(lo, hi\) of integers"):
        synthetic_bandwidth(10, outage_s=outage_s, outage_rate=0.5)


@pytest.mark.parametrize("outage_s", [(1.5, 2.5), (1, 2.0), (True, 2), (np.float64(1), 3)])
def test_d18_synthetic_bandwidth_refuses_outage_s_that_are_not_integers(outage_s):
    with pytest.raises(TraceError, match=r"^outage_s = .*: must be a pair \(lo, hi\) of integers"):
        synthetic_bandwidth(10, outage_s=outage_s, outage_rate=0.5)


@PROPERTY
@given(seconds=st.integers(1, 400), mean=st.floats(1e-6, MAX_MBPS), variability=st.floats(0, MAX_VARIABILITY),
       outage_rate=st.floats(0, 0.5), lo=st.integers(1, 5), extra=st.integers(0, 5),
       correlation=st.floats(0, 0.999), seed=st.integers(0, 2**63))
def test_synthetic_bandwidth_is_finite_with_the_mean_asked_for(seconds, mean, variability, outage_rate, lo, extra,
                                                               correlation, seed):
    try:
        trace = synthetic_bandwidth(seconds, mean, variability=variability, outage_rate=outage_rate,
                                    outage_s=(lo, lo + extra), correlation=correlation, seed=seed)
    except TraceError as e:  # the one refusal of valid arguments: every second drew an outage
        assert "all outage" in str(e) and outage_rate > 0
        return
    assert trace.mbps.shape == (seconds,)
    assert np.isfinite(trace.mbps).all() and (trace.mbps >= 0).all()
    assert trace.mbps.mean() == pytest.approx(mean, rel=MEAN_RTOL)


def test_synthetic_bandwidth_at_the_largest_variability_and_length_is_finite():
    trace = synthetic_bandwidth(MAX_TRACE_SAMPLES, variability=MAX_VARIABILITY, correlation=0.0, seed=1)
    assert np.isfinite(trace.mbps).all() and trace.mbps.mean() == pytest.approx(11.8, rel=MEAN_RTOL)


# ------------------------------------------------------------------------- synthetic_poses

@pytest.mark.parametrize("kw, match", [
    ({"seconds": 1e12}, r"^seconds = 1000000000000.0: .*MAX_POSE_SECONDS"),
    ({"seconds": -5}, r"^seconds = -5: "),
    ({"seconds": math.nan}, r"^seconds = nan: "),
    ({"seconds": math.inf}, r"^seconds = inf: "),
    ({"seconds": "10"}, r"^seconds = '10': "),
    ({"seconds": 0}, r"^seconds = 0: "),
    ({"seconds": True}, r"^seconds = True: "),
    ({"seed": -1}, r"^seed = -1: must be an integer >= 0$"),
    ({"seed": 2.5}, r"^seed = 2.5: must be an integer >= 0$"),
    ({"rate_hz": 0}, r"^rate_hz = 0: "),
    ({"rate_hz": -30}, r"^rate_hz = -30: "),
    ({"rate_hz": None}, r"^rate_hz = None: "),
    ({"rate_hz": 1e-300}, r"^seconds \* rate_hz = .*MAX_POSE_SAMPLES"),        # rounds to no sample
    ({"seconds": 1e5, "rate_hz": 1e3}, r"^seconds \* rate_hz = .*MAX_POSE_SAMPLES"),  # 1e8 samples
    ({"seconds": 1e5, "rate_hz": 1e308}, r"^seconds \* rate_hz = .* inf samples"),    # the product overflows
    ({"kind": ["walk"]}, r"kind \['walk'\] is not one of"),
])
def test_b3_synthetic_poses_checks_its_arguments(kw, match):
    with pytest.raises(PoseError, match=match) as caught:
        synthetic_poses(**kw)
    _one_line(caught.value)


@PROPERTY
@given(kind=st.sampled_from(["walk", "orbit", "fast_turns"]), seconds=st.floats(0.05, 200),
       rate_hz=st.floats(0.5, 120), seed=st.integers(0, 2**32))
def test_synthetic_poses_has_the_samples_asked_for(kind, seconds, rate_hz, seed):
    n = round(seconds * rate_hz)
    if not 1 <= n <= MAX_POSE_SAMPLES:
        with pytest.raises(PoseError, match="MAX_POSE_SAMPLES"):
            synthetic_poses(kind, seconds=seconds, rate_hz=rate_hz, seed=seed)
        return
    trace = synthetic_poses(kind, seconds=seconds, rate_hz=rate_hz, seed=seed)
    assert len(trace.time_s) == n and np.isfinite(trace.features).all()
    assert (np.diff(trace.time_s) > 0).all()


# ------------------------------------------------------------------------- BandwidthTrace

@pytest.mark.parametrize("call, match", [
    (lambda t: t.scaled("5"), r"^mbps = '5' \(the target mean, Mbit/s\): must be a positive number"),
    (lambda t: t.scaled(None), r"^mbps = None \(the target mean"),
    (lambda t: t.scaled(True), r"^mbps = True \(the target mean"),
    (lambda t: t.scaled(10**400), r"^mbps = 1000.* \(the target mean"),
    (lambda t: t.window(0.5, 2), r"window start = 0.5: must be an integer"),
    (lambda t: t.window(0, 2.0), r"window length = 2.0: must be an integer"),
    (lambda t: t.window(True, 2), r"window start = True: must be an integer"),
    (lambda t: t.window("0", 2), r"window start = '0': must be an integer"),
])
def test_c12_scaled_and_window_check_argument_types(call, match):
    trace = read_bandwidth_trace(TRACE)
    with pytest.raises(TraceError, match=match):
        call(trace)


@pytest.mark.parametrize("kw, match", [
    ({"mbps": np.array([-5.0, math.nan])}, r"^x: mbps\[0\] = -5.0: must be finite and >= 0"),
    ({"mbps": np.array([5.0, math.nan])}, r"^x: mbps\[1\] = nan: must be finite"),
    ({"mbps": [1.0, math.inf]}, r"^x: mbps\[1\] = inf: must be finite"),
    ({"mbps": np.ones((2, 2))}, r"^x: mbps: shape \(2, 2\) must be \[N\] with N >= 1"),
    ({"mbps": np.array([])}, r"^x: mbps: shape \(0,\) must be \[N\] with N >= 1"),
    ({"mbps": ["5"]}, r"^mbps = \['5'\]: must be an array of numbers, got strings"),
    ({"mbps": np.array([True])}, r"^mbps = .*: must be an array of numbers, got bools"),
    ({"mbps": [1.0], "sample_s": 0}, r"^sample_s = 0: must be a positive number"),
    ({"mbps": [1.0], "sample_s": math.nan}, r"^sample_s = nan: "),
    ({"mbps": [1.0], "skipped": -1}, r"^skipped: -1: must be an integer in"),
    ({"mbps": [1.0], "skipped": 1.5}, r"^skipped: 1.5: must be an integer in"),
])
def test_d10_bandwidth_trace_constructor_checks_its_samples(kw, match):
    with pytest.raises(TraceError, match=match):
        BandwidthTrace("x", **kw)


def test_d10_bandwidth_trace_refuses_a_name_that_is_not_a_string():
    with pytest.raises(TraceError, match=r"^name = 5: must be a string"):
        BandwidthTrace(5, np.array([1.0]))


def test_d10_bandwidth_trace_keeps_float_arrays_and_converts_lists():
    f32 = np.array([1.0, 2.0], dtype=np.float32)
    assert BandwidthTrace("x", f32).mbps is f32          # internal callers' arrays are kept as given
    listed = BandwidthTrace("x", [1, 2])
    assert listed.mbps.dtype == np.float64 and listed.scaled(3.0)[0].mbps.tolist() == [2.0, 4.0]


# ------------------------------------------------------------------------- mbps_to_bytes

@pytest.mark.parametrize("mbps, match", [
    ([[1, 2], [3]], r"^mbps = \[\[1, 2\], \[3\]\]: must be an array of numbers \(rows of equal length\)"),
    ([1 + 2j], r"^mbps = \[\(1\+2j\)\]: must be an array of numbers, got complex numbers"),
])
def test_c13_mbps_to_bytes_refuses_ragged_and_complex_input(mbps, match):
    with pytest.raises(TraceError, match=match):
        mbps_to_bytes(mbps)


@pytest.mark.parametrize("mbps, slot_s, match", [
    (["5"], 1.0, r"^mbps = \['5'\]: must be an array of numbers, got strings"),
    ([True, False], 1.0, r"^mbps = \[True, False\]: must be an array of numbers, got bools"),
    (5, 1.0, r"^mbps: shape \(\) must be \[N\]"),
    ([[1, 2], [3, 4]], 1.0, r"^mbps: shape \(2, 2\) must be \[N\]"),
    ([1.0], True, r"^slot_s = True: must be a positive number of seconds"),
    ([1.0], "1", r"^slot_s = '1': must be a positive number of seconds"),
    ([1.0], 10**400, r"^slot_s = 1000.*: must be a positive number of seconds"),
])
def test_d9_mbps_to_bytes_refuses_strings_bools_and_wrong_shapes(mbps, slot_s, match):
    with pytest.raises(TraceError, match=match):
        mbps_to_bytes(mbps, slot_s)


def test_d9_mbps_to_bytes_still_takes_lists_and_integer_arrays():
    assert mbps_to_bytes([8, 0]).tolist() == [1_000_000, 0]
    assert mbps_to_bytes(np.array([8], dtype=np.int32), np.float32(0.5)).tolist() == [500_000]
    assert mbps_to_bytes(np.array([], dtype=np.float64)).tolist() == []


def test_e5_mbps_to_bytes_of_none_says_it_is_not_numbers():
    with pytest.raises(TraceError, match=r"^mbps = None: must be an array of numbers, got NoneType$"):
        mbps_to_bytes(None)


# ------------------------------------------------------------------------- readers' paths

@pytest.mark.parametrize("read, error", [(read_bandwidth_trace, TraceError), (read_pose_log, PoseError),
                                         (read_camera_path, PoseError)])
@pytest.mark.parametrize("path", [None, 3, b"trace.txt", ["a"]])
def test_c15_readers_refuse_a_path_that_is_not_a_path(read, error, path):
    with pytest.raises(error, match=r"^path = .*: must be a file path \(str or os.PathLike\), got "):
        read(path)


@pytest.mark.parametrize("format", [np.array(["lumos", "auto"]), ["lumos"]])
def test_c15_read_bandwidth_trace_refuses_a_format_that_is_not_a_string(format):
    with pytest.raises(TraceError, match=r"^format = .*: must be one of"):
        read_bandwidth_trace(TRACE, format=format)


# ------------------------------------------------------------------------- PoseTrace

def test_c14_pose_trace_takes_lists():
    trace = PoseTrace(time_s=[0, 1], position=[[0, 0, 0]] * 2, rotation_deg=[[0, 0, 0]] * 2)
    assert trace.time_s.dtype == trace.position.dtype == np.float64
    assert trace.rate_hz == 1.0 and trace.features.shape == (2, 6)


@pytest.mark.parametrize("kw, match", [
    ({"time_s": [0, 1], "position": [[0, 0, 0], [0, 0]]}, r"^position = .*: must be an array of numbers \(rows"),
    ({"time_s": ["0", "1"]}, r"^time_s = \['0', '1'\]: must be an array of numbers, got strings"),
    ({"time_s": [0, 1], "rotation_deg": np.zeros((2, 3), dtype=bool)}, r"^rotation_deg = .*got bools"),
])
def test_c14_pose_trace_refuses_arrays_that_are_not_numbers(kw, match):
    arrays = {"time_s": [0.0, 1.0], "position": np.zeros((2, 3)), "rotation_deg": np.zeros((2, 3))} | kw
    with pytest.raises(PoseError, match=match):
        PoseTrace(**arrays)


@pytest.mark.parametrize("time_s, match", [
    ([1.0, 0.0], r"^time_s\[1\] = 0.0: must increase \(previous 1.0\)"),
    ([0.0, 0.5, 0.5], r"^time_s\[2\] = 0.5: must increase \(previous 0.5\)"),
    (np.zeros((0,)), r"^time_s: shape \(0,\) must be \[N\] with N >= 1"),
    (np.zeros((2, 1)), r"^time_s: shape \(2, 1\) must be \[N\]"),
])
def test_d11_pose_trace_time_must_increase(time_s, match):
    n = len(time_s)
    with pytest.raises(PoseError, match=match):
        PoseTrace(time_s=np.asarray(time_s, dtype=np.float64), position=np.zeros((n, 3)),
                  rotation_deg=np.zeros((n, 3)))


def test_d11_pose_trace_refuses_a_bad_skipped_count():
    with pytest.raises(PoseError, match=r"^skipped: -1: must be an integer in"):
        PoseTrace(time_s=[0.0], position=np.zeros((1, 3)), rotation_deg=np.zeros((1, 3)), skipped=-1)


# ------------------------------------------------------------------------- read_camera_path

ROTATION_Z_90 = "0 -1 0 1\n1 0 0 2\n0 0 1 3\n0 0 0 1\n"


@pytest.mark.parametrize("text, match", [
    ("0 0 0 0\n" * 4, r"matrix 0: last row \[0.0, 0.0, 0.0, 0.0\] must be \[0, 0, 0, 1\]"),
    ("1 0 0 0\n0 1 0 0\n0 0 1 0\n5 5 5 5\n", r"matrix 0: last row \[5.0, 5.0, 5.0, 5.0\] must be"),
    (ROTATION_Z_90 + "\n2 0 0 0\n0 2 0 0\n0 0 2 0\n0 0 0 1\n", r"matrix 1: rotation block is not a rotation"),  # scale
    ("-1 0 0 0\n0 1 0 0\n0 0 1 0\n0 0 0 1\n", r"matrix 0: rotation block is not a rotation .*det = -1"),  # mirror
    ("1 0.5 0 0\n0 1 0 0\n0 0 1 0\n0 0 0 1\n", r"matrix 0: rotation block is not a rotation"),  # shear
])
def test_d12_read_camera_path_refuses_matrices_that_are_not_rigid(tmp_path, text, match):
    (tmp_path / "path.txt").write_text(text)
    with pytest.raises(PoseError, match=match):
        read_camera_path(tmp_path / "path.txt")


def test_d12_rigid_camera_paths_still_read(tmp_path):
    (tmp_path / "path.txt").write_text(ROTATION_Z_90 + "\n" + ROTATION_Z_90)
    assert read_camera_path(tmp_path / "path.txt").shape == (2, 4, 4)
    # rotations written to 9 digits (write_camera_path) are within the tolerance
    c, s = math.cos(0.3), math.sin(0.3)
    m = np.array([[c, 0, s, 1], [0, 1, 0, 2], [-s, 0, c, 3], [0, 0, 0, 1]])
    write_camera_path(m[None], tmp_path / "written.txt")
    np.testing.assert_allclose(read_camera_path(tmp_path / "written.txt")[0], m, atol=1e-8)


@pytest.mark.parametrize("text, match", [
    ("1 0 0 0\n0 1 0 0\n0 0 1\n0 0 0 1\n", r"matrix 0: row 2 has 3 entries: expected 4 rows of 4 finite numbers"),
    ("1 0 0 0 0\n0 1 0 0\n0 0 1 0\n0 0 0 1\n", r"matrix 0: row 0 has 5 entries"),
    ("1 0 0 0\n0 1 0 x\n0 0 1 0\n0 0 0 1\n", r"matrix 0: row 1: entries must be numbers"),
    ("1 0 0 0\n0 1 0 nan\n0 0 1 0\n0 0 0 1\n", r"matrix 0: row 1, entry 3 = nan: must be finite"),
    ("1 0 0 0\n0 1 0 0\n0 0 1 0\n", r"matrix 0: expected 4 rows of 4 finite numbers, got 3 rows"),
])
def test_e1_read_camera_path_names_a_short_row_as_short(tmp_path, text, match):
    (tmp_path / "path.txt").write_text(text)
    with pytest.raises(PoseError, match=match) as caught:
        read_camera_path(tmp_path / "path.txt")
    assert isinstance(caught.value, L3gsError)
