"""Property-based fuzzing of the trace, pose-log and PLY readers (issue 19).

Each reader gets bytes mutated from a valid file (bytes flipped, inserted, deleted, duplicated,
the file cut short) and content generated from the format's own pieces (numbers of every kind,
separators, headers with any counts and types). The answer must be either a valid object or the
reader's own error type (an :class:`~l3gs_opt.errors.L3gsError`) -- never another exception,
never a warning on an error, and on success no warning but the documented count of skipped lines.
Every example runs under a hypothesis deadline and a wall-clock alarm, so a hang fails the test.
"""

from __future__ import annotations

import math
import re
import signal
import warnings
from contextlib import contextmanager

import numpy as np
import pytest
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st

from l3gs_opt.errors import L3gsError
from l3gs_opt.traces.poses import (MAX_ANGLE_DEG, MAX_POSITION_M, PoseError, PoseTrace, read_pose_log, synthetic_poses,
                            write_pose_log)
from l3gs_opt.scene.splats import MIN_QUAT_NORM, SceneError, SplatScene, read_ply, write_ply
from l3gs_opt.traces.bandwidth import MAX_MBPS, BandwidthTrace, TraceError, bundled_traces, read_bandwidth_trace
from renderer_helpers import random_scene

#: Seconds one example may take before it counts as a hang (the slowest valid read here is ~50 ms).
HANG_S = 20
FUZZ = settings(max_examples=120, deadline=5000, derandomize=True,
                suppress_health_check=[HealthCheck.too_slow, HealthCheck.function_scoped_fixture])
SKIPPED = re.compile(r"skipped \d+ line\(s\) that are not (numbers|pose samples)$")


class Hang(Exception):
    """Raised by the alarm: the reader did not return in HANG_S seconds."""


@contextmanager
def alarm(seconds: float):
    def fire(signum, frame):
        raise Hang(f"no answer in {seconds} s")

    old = signal.signal(signal.SIGALRM, fire)
    signal.setitimer(signal.ITIMER_REAL, seconds)
    try:
        yield
    finally:
        signal.setitimer(signal.ITIMER_REAL, 0)
        signal.signal(signal.SIGALRM, old)


def read_or_own_error(reader, path, error_type):
    """``reader(path)`` -> (object or None, the error or None); fails on any other outcome."""
    with warnings.catch_warnings(record=True) as caught, alarm(HANG_S):
        warnings.simplefilter("always")
        try:
            value, error = reader(path), None
        except error_type as exc:
            value, error = None, exc
    assert error is None or (isinstance(error, L3gsError) and str(error)), error
    messages = [str(w.message) for w in caught]
    if error is not None:
        assert not messages, f"warning before the error: {messages}"
    else:
        assert all(w.category is UserWarning and SKIPPED.search(str(w.message)) for w in caught), messages
    return value, error


# ----------------------------------------------------------------------------------- strategies
@st.composite
def mutated(draw, seed: bytes) -> bytes:
    """``seed`` with 1-4 random edits."""
    data = bytearray(seed)
    for _ in range(draw(st.integers(1, 4))):
        kind = draw(st.sampled_from(["flip", "insert", "delete", "truncate", "duplicate", "replace"]))
        at = draw(st.integers(0, max(len(data) - 1, 0)))
        if kind == "flip" and data:
            data[at] ^= 1 << draw(st.integers(0, 7))
        elif kind == "insert":
            data[at:at] = draw(st.binary(min_size=1, max_size=16))
        elif kind == "delete":
            del data[at:at + draw(st.integers(1, 64))]
        elif kind == "truncate":
            del data[at:]
        elif kind == "duplicate":
            data[at:at] = data[at:at + draw(st.integers(1, 256))]
        elif kind == "replace" and data:  # an ASCII token the parsers care about
            token = draw(st.sampled_from([b"nan", b"inf", b"-1", b"1e308", b"1e999", b",", b"\n", b"\r", b" ", b"0",
                                          b"\x00", b"9" * 30, b"element vertex 99999999999\n", b"double", b"list"]))
            data[at:at + len(token)] = token
    return bytes(data)


NUMBER_TEXT = st.one_of(
    st.floats(allow_nan=True, allow_infinity=True).map(repr),
    st.integers(-10**30, 10**30).map(str),
    st.sampled_from(["nan", "inf", "-inf", "1e308", "1e999", "-0", "0x10", "1_0", "", " ", "abc", "5e-324"]),
)


# ----------------------------------------------------------------------------------- traces
def check_trace(trace: BandwidthTrace) -> None:
    x = trace.mbps
    assert x.ndim == 1 and len(x) >= 1 and trace.sample_s == 1.0
    assert np.all(np.isfinite(x)) and np.all(x >= 0) and np.all(x <= MAX_MBPS * (1 + 1e-12))


@pytest.fixture(scope="module")
def folder(tmp_path_factory):
    return tmp_path_factory.mktemp("fuzz")


TRACE_SEED = b"".join(bundled_traces()["lumos-throughput-mid-11"].read_bytes().splitlines(keepends=True)[:40])
CSV_SEED = b"time_s,mbps\n" + b"".join(f"{k / 10:.1f},{(k * 7) % 13 + 0.5}\n".encode() for k in range(40))


@FUZZ
@given(data=st.one_of(mutated(TRACE_SEED), mutated(CSV_SEED)))
def test_fuzz_trace_reader_mutated(folder, data):
    path = folder / "t.txt"
    path.write_bytes(data)
    trace, _ = read_or_own_error(read_bandwidth_trace, path, TraceError)
    if trace is not None:
        check_trace(trace)


@FUZZ
@given(lines=st.lists(st.one_of(NUMBER_TEXT, st.tuples(NUMBER_TEXT, NUMBER_TEXT).map(",".join),
                                st.text(max_size=20)), max_size=30),
       newline=st.sampled_from(["\n", "\r\n", "\r"]))
def test_fuzz_trace_reader_generated(folder, lines, newline):
    path = folder / "g.csv"
    path.write_text(newline.join(lines), encoding="utf-8", errors="surrogatepass")
    trace, _ = read_or_own_error(read_bandwidth_trace, path, TraceError)
    if trace is not None:
        check_trace(trace)


# ----------------------------------------------------------------------------------- pose logs
def check_poses(trace: PoseTrace) -> None:
    n = len(trace.time_s)
    assert n >= 1 and trace.time_s[0] == 0 and np.all(np.diff(trace.time_s) > 0)
    assert np.all(np.abs(trace.position) <= MAX_POSITION_M) and np.all(np.abs(trace.rotation_deg) <= MAX_ANGLE_DEG)


@pytest.fixture(scope="module")
def pose_seed(tmp_path_factory):
    path = tmp_path_factory.mktemp("seed") / "log.txt"
    write_pose_log(synthetic_poses("walk", seconds=2, rate_hz=5, seed=1), path)
    return path.read_bytes()


POSE_LINE = ("{stamp}, Head Position: ({0}, {1}, {2}), Head Rotation: ({3}, {4}, {5}), "
             "Left Controller Position: (0.00, 0.00, 0.00)")
STAMP = st.one_of(st.datetimes().map(lambda d: d.strftime("%Y-%m-%d %H:%M:%S")),
                  st.sampled_from(["2024-13-40 25:61:61", "0000-01-01 00:00:00", "9999-12-31 23:59:59.999999"]))


@pytest.mark.parametrize("position, rotation, field", [
    ("nan, 1.5, 0.0", "0, 0, 0", r"Head Position\[0\] = nan"),
    ("0.1, -inf, 0.0", "0, 0, 0", r"Head Position\[1\] = -inf"),
    ("0.1, 1.5, 0.0", "10, Infinity, 0", r"Head Rotation\[1\] = inf"),
])
def test_a_non_finite_pose_is_refused_by_line_not_skipped(tmp_path, position, rotation, field):
    # Regression: the number pattern did not match nan/inf, so such a line was skipped with a warning.
    good = POSE_LINE.format(0.1, 1.5, 0.0, 10, 0, 0, stamp="2024-06-20 16:13:20")
    bad = POSE_LINE.format(*position.split(", "), *rotation.split(", "), stamp="2024-06-20 16:13:21")
    path = tmp_path / "p.log"
    path.write_text("\n".join([good, good, bad, good]) + "\n")
    with pytest.raises(PoseError, match=rf"p\.log: line 3: {field}: must be finite"):
        read_pose_log(path)


@FUZZ
@given(data=st.data())
def test_fuzz_pose_log_reader_mutated(folder, pose_seed, data):
    path = folder / "p.log"
    path.write_bytes(data.draw(mutated(pose_seed)))
    trace, _ = read_or_own_error(read_pose_log, path, PoseError)
    if trace is not None:
        check_poses(trace)


@FUZZ
@given(lines=st.lists(st.one_of(st.builds(lambda s, v: POSE_LINE.format(*v, stamp=s), STAMP,
                                          st.lists(NUMBER_TEXT.filter(lambda t: re.fullmatch(r"-?\d.*", t) is not None)
                                                   | st.floats(-1e9, 1e9).map(lambda f: f"{f:.3f}"),
                                                   min_size=6, max_size=6)),
                                st.text(max_size=40)), max_size=20))
def test_fuzz_pose_log_reader_generated(folder, lines):
    path = folder / "g.log"
    path.write_text("\n".join(lines), encoding="utf-8", errors="surrogatepass")
    trace, _ = read_or_own_error(read_pose_log, path, PoseError)
    if trace is not None:
        check_poses(trace)


# ----------------------------------------------------------------------------------- PLY
def check_scene(scene: SplatScene) -> None:
    for name in ("means", "log_scales", "quats", "opacity_logits", "sh"):
        a = getattr(scene, name)
        assert a.dtype == np.float32 and np.all(np.isfinite(a))
    if scene.num_splats:
        assert np.linalg.norm(scene.quats.astype(np.float64), axis=1).min() >= MIN_QUAT_NORM


@pytest.fixture(scope="module")
def ply_seeds(tmp_path_factory):
    root = tmp_path_factory.mktemp("plyseed")
    scene = random_scene(4, sh_degree=1, seed=5, object_ids=True)
    return [write_ply(scene, root / "b.ply").read_bytes(), write_ply(scene, root / "a.ply", text=True).read_bytes()]


@FUZZ
@given(data=st.data())
def test_fuzz_ply_reader_mutated(folder, ply_seeds, data):
    path = folder / "m.ply"
    path.write_bytes(data.draw(mutated(data.draw(st.sampled_from(ply_seeds)))))
    scene, _ = read_or_own_error(read_ply, path, SceneError)
    if scene is not None:
        check_scene(scene)


PLY_TYPES = ["char", "uchar", "short", "ushort", "int", "uint", "float", "double", "int8", "float64", "bogus"]
PLY_NAMES = ["x", "y", "z", "f_dc_0", "f_dc_1", "f_dc_2", "opacity", "scale_0", "scale_1", "scale_2",
             "rot_0", "rot_1", "rot_2", "rot_3", "f_rest_0", "object_id", "layer", "nx", "red"]


@FUZZ
@given(fmt=st.sampled_from(["ascii", "binary_little_endian", "binary_big_endian", "bogus"]),
       count=st.one_of(st.integers(0, 5), st.integers(0, 10**15)),
       props=st.lists(st.tuples(st.sampled_from(PLY_TYPES), st.sampled_from(PLY_NAMES), st.booleans()), max_size=18),
       body=st.one_of(st.binary(max_size=300),
                      st.lists(NUMBER_TEXT, max_size=60).map(lambda v: (" ".join(v) + "\n").encode())))
def test_fuzz_ply_reader_generated(folder, fmt, count, props, body):
    header = ["ply", f"format {fmt} 1.0", f"element vertex {count}"]
    header += [f"property list uchar {t} {n}" if is_list else f"property {t} {n}" for t, n, is_list in props]
    path = folder / "g.ply"
    path.write_bytes(("\n".join(header) + "\nend_header\n").encode() + body)
    scene, _ = read_or_own_error(read_ply, path, SceneError)
    if scene is not None:
        check_scene(scene)
        assert scene.num_splats == count and math.isfinite(float(scene.means.sum()))
