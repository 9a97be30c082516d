"""Real delivery over HTTP on loopback: the server's Range/ETag/refusal semantics against the file's
bytes, trace pacing against the trace, many clients and a client that leaves mid-body, and a fetch
run whose requests equal the simulator's given the same measured bytes."""

from __future__ import annotations

import asyncio
import dataclasses
import hashlib
import json
import socket
import time

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

aiohttp = pytest.importorskip("aiohttp")

from l3gs_opt.delivery.fetch import FetchError, fetch, unit_chunks  # noqa: E402
from l3gs_opt.delivery.server import ByteRange, ServerError, parse_range, start_server  # noqa: E402
from l3gs_opt.delivery.shaping import ShapingError, TraceShaper  # noqa: E402
from l3gs_opt.scene.bundle import write_bundle  # noqa: E402
from l3gs_opt.scene.procedural import make_scene  # noqa: E402
from l3gs_opt.scene.stream_index import export_stream, read_stream, stream_bundle  # noqa: E402
from l3gs_opt.traces.poses import synthetic_poses, write_pose_log  # noqa: E402

TIMEOUT = aiohttp.ClientTimeout(total=10)
SIZES = (300, 600, 1200)


@pytest.fixture(scope="module")
def world(tmp_path_factory):
    """A 1200-splat ``sort`` bundle of 3 objects (3 levels), exported in one file and per chunk."""
    root = tmp_path_factory.mktemp("delivery")
    teacher = make_scene(1500, objects=3, sh_degree=1, seed=0)
    order = np.random.default_rng(0).permutation(teacher.num_splats)
    bounds = (0, *SIZES)
    write_bundle(root / "bundle", [teacher.subset(order[bounds[i]:bounds[i + 1]]) for i in range(len(SIZES))],
                 variant="sort")
    single = export_stream(root / "bundle", root / "single", pack="single").parent
    per = export_stream(root / "bundle", root / "per", pack="per-chunk").parent
    log = write_pose_log(synthetic_poses("orbit", seconds=6, rate_hz=30, seed=0), root / "viewer.log")
    return {"root": root, "single": single, "per": per, "log": log, "teacher": teacher}


@pytest.fixture(scope="module")
def server(world):
    with start_server(world["single"]) as handle:
        yield handle


def _request(url, *, method="GET", headers=None, raw_path=None):
    """(status, headers, body) of one request; ``raw_path`` is sent as it is (no normalisation)."""
    async def go():
        async with aiohttp.ClientSession(timeout=TIMEOUT) as s:
            target = aiohttp.client.URL(url + raw_path, encoded=True) if raw_path is not None else url
            async with s.request(method, target, headers=headers or {}) as r:
                return r.status, r.headers.copy(), await r.read()
    return asyncio.run(go())


def _raw(handle, request_line: bytes) -> bytes:
    """The status line of a hand-written HTTP/1.1 request (paths no client library would send)."""
    with socket.create_connection((handle.host, handle.port), timeout=5) as s:
        s.sendall(request_line + b"\r\nHost: x\r\nConnection: close\r\n\r\n")
        data = b""
        while not data.endswith(b"\r\n\r\n") and b"\r\n" not in data[:200]:
            part = s.recv(4096)
            if not part:
                break
            data += part
    return data.split(b"\r\n", 1)[0]


# ---------------------------------------------------------------------- Range parsing
@pytest.mark.parametrize("header, size, want", [
    ("bytes=0-9", 100, ByteRange(0, 10, 100)),
    ("bytes=90-200", 100, ByteRange(90, 100, 100)),     # end clipped
    ("bytes=95-", 100, ByteRange(95, 100, 100)),
    ("bytes=-10", 100, ByteRange(90, 100, 100)),
    ("bytes=-1000", 100, ByteRange(0, 100, 100)),       # suffix longer than the file: all of it
    ("BYTES = 1 - 2", 100, ByteRange(1, 3, 100)),       # unit is case-insensitive, spaces allowed
    ("bytes=100-", 100, "unsatisfiable"),
    ("bytes=100-200", 100, "unsatisfiable"),
    ("bytes=-0", 100, "unsatisfiable"),
    ("bytes=0-0", 0, "unsatisfiable"),
    ("bytes=5-4", 100, None),                           # last < first: invalid, ignored
    ("bytes=0-1,5-6", 100, None),                       # several ranges: whole file
    ("items=0-1", 100, None), ("bytes=", 100, None), ("bytes=-", 100, None), ("bytes=a-b", 100, None),
    (None, 100, None),
])
def test_parse_range_cases(header, size, want):
    assert parse_range(header, size) == want


@settings(max_examples=200, deadline=None)
@given(st.text(max_size=40), st.integers(0, 10**6))
def test_parse_range_never_raises_and_stays_inside(header, size):
    r = parse_range(header, size)
    assert r is None or r == "unsatisfiable" or (0 <= r.start < r.end <= size)


@settings(max_examples=200, deadline=None)
@given(st.integers(0, 2000), st.integers(0, 2000), st.integers(1, 1500))
def test_parse_range_selects_the_slice(a, b, size):
    """Against Python slicing: ``bytes=a-b`` is ``data[a:b+1]`` when a <= b and a < size."""
    data = bytes(range(256)) * 6
    data = data[:size]
    r = parse_range(f"bytes={a}-{b}", size)
    if a > b:
        assert r is None
    elif a >= size:
        assert r == "unsatisfiable"
    else:
        assert data[r.start:r.end] == data[a:b + 1]


# ---------------------------------------------------------------------- server semantics
def test_whole_file_range_head_and_etag(world, server):
    body = (world["single"] / "chunks.bin").read_bytes()
    status, h, got = _request(server.url + "/chunks.bin")
    assert status == 200 and got == body and h["Accept-Ranges"] == "bytes"
    assert h["ETag"] == f'"sha256:{hashlib.sha256(body).hexdigest()[:32]}"'
    status, h2, got = _request(server.url + "/chunks.bin", headers={"Range": "bytes=10-99"})
    assert status == 206 and got == body[10:100] and h2["Content-Range"] == f"bytes 10-99/{len(body)}"
    status, _, got = _request(server.url + "/chunks.bin", headers={"Range": "bytes=-7"})
    assert status == 206 and got == body[-7:]
    status, _, got = _request(server.url + "/chunks.bin", headers={"Range": f"bytes={len(body) - 3}-"})
    assert status == 206 and got == body[-3:]
    status, h3, got = _request(server.url + "/chunks.bin", method="HEAD", headers={"Range": "bytes=0-1"})
    assert status == 200 and got == b"" and int(h3["Content-Length"]) == len(body)   # HEAD ignores Range
    status, h4, _ = _request(server.url + "/index.json")
    assert status == 200 and h4["Content-Type"].startswith("application/json")


def test_every_chunk_by_its_index_range(world, server):
    """The index's own ``range`` headers fetch bytes whose SHA-256 is the index's."""
    index = read_stream(world["single"])
    for c in index.chunks:
        if c.bytes:
            status, _, got = _request(f"{server.url}/{c.file}", headers={"Range": c.range_header})
            assert status == 206 and hashlib.sha256(got).hexdigest() == c.sha256


def test_unsatisfiable_malformed_and_multi_range(world, server):
    size = (world["single"] / "chunks.bin").stat().st_size
    for bad in (f"bytes={size}-", "bytes=-0", f"bytes={size + 5}-{size + 9}"):
        status, h, _ = _request(server.url + "/chunks.bin", headers={"Range": bad})
        assert status == 416 and h["Content-Range"] == f"bytes */{size}", bad
    for ignored in ("bytes=9-3", "pages=1-2", "bytes=x", "bytes=0-1,4-5", "bytes=" + "9" * 40 + "-"):
        status, _, got = _request(server.url + "/chunks.bin", headers={"Range": ignored})
        assert status == 200 and len(got) == size, ignored


def test_if_none_match_and_if_range(world, server):
    _, h, _ = _request(server.url + "/chunks.bin")
    etag = h["ETag"]
    for inm in (etag, f'W/{etag}', f'"other", {etag}', "*"):
        status, h2, got = _request(server.url + "/chunks.bin", headers={"If-None-Match": inm})
        assert status == 304 and got == b"" and h2["ETag"] == etag, inm
    status, _, _ = _request(server.url + "/chunks.bin", headers={"If-None-Match": '"other"'})
    assert status == 200
    status, _, got = _request(server.url + "/chunks.bin", headers={"Range": "bytes=0-3", "If-Range": etag})
    assert status == 206 and len(got) == 4
    status, _, got = _request(server.url + "/chunks.bin", headers={"Range": "bytes=0-3", "If-Range": '"stale"'})
    assert status == 200 and len(got) > 4


def test_etag_follows_the_content(tmp_path, world):
    """A rewritten file gets the ETag of its new bytes (same size, so size+mtime alone could miss it)."""
    import shutil

    folder = tmp_path / "copy"
    shutil.copytree(world["single"], folder)
    with start_server(folder) as h:
        _, first, body = _request(h.url + "/chunks.bin")
        flipped = bytes([body[0] ^ 1]) + body[1:]
        (folder / "chunks.bin").write_bytes(flipped)
        _, second, got = _request(h.url + "/chunks.bin")
    assert got == flipped and second["ETag"] != first["ETag"]
    assert second["ETag"] == f'"sha256:{hashlib.sha256(flipped).hexdigest()[:32]}"'


def test_paths_outside_the_export_are_404(world, server, tmp_path):
    secret = world["root"] / "secret.txt"
    secret.write_text("secret")
    (world["single"] / "link_out").symlink_to(secret)
    (world["single"] / "dir_out").symlink_to(world["root"], target_is_directory=True)
    try:
        for path in ("/../secret.txt", "/%2e%2e/secret.txt", "/%2E%2E%2Fsecret.txt", "/..%2fsecret.txt",
                     "//etc/passwd", "/" + str(secret), "/link_out", "/dir_out/secret.txt", "/", "/chunks.bin/",
                     "/./index.json", "/index.json%00", "/nothere.bin", "/%ZZ"):
            status, _, body = _request(server.url, raw_path=path)
            assert status == 404 and b"secret" not in body and b"Traceback" not in body, path
        for line in (b"GET ../secret.txt HTTP/1.1", b"GET /../../secret.txt HTTP/1.1",
                     b"GET " + str(secret).encode() + b" HTTP/1.1", b"GET http://x/../secret.txt HTTP/1.1"):
            status = _raw(server, line)
            assert status.split()[1] in (b"400", b"404"), (line, status)
        status, h, _ = _request(server.url + "/index.json", method="POST")
        assert status == 405 and "GET" in h.get("Allow", "")
    finally:
        (world["single"] / "link_out").unlink()
        (world["single"] / "dir_out").unlink()


def test_per_chunk_pack_and_bad_folders(world, tmp_path):
    index = read_stream(world["per"])
    with start_server(world["per"]) as h:
        c = next(c for c in index.chunks if c.bytes)
        status, _, got = _request(f"{h.url}/{c.file}")
        assert status == 200 and hashlib.sha256(got).hexdigest() == c.sha256
    with pytest.raises(ServerError, match="folder"):
        start_server(tmp_path / "missing")
    with pytest.raises(ServerError, match="port"):
        start_server(world["per"], port=70000)
    with pytest.raises(ShapingError, match="bytes_per_slot"):
        start_server(world["per"], trace=[0, 0])


def test_client_leaving_mid_body_does_not_break_the_server(world, caplog):
    """A slow-paced body is abandoned after its first bytes; the server goes on answering and logs
    no error (no traceback)."""
    caplog.set_level("DEBUG")
    with start_server(world["single"], trace=[20_000] * 20) as h:
        for _ in range(3):
            with socket.create_connection((h.host, h.port), timeout=5) as s:
                s.sendall(b"GET /chunks.bin HTTP/1.1\r\nHost: x\r\n\r\n")
                assert s.recv(4096).startswith(b"HTTP/1.1 200")
            # closed mid-body (the file is ~100 kB, paced at 20 kB/s)
        status, _, got = _request(h.url + "/chunks.bin", headers={"Range": "bytes=0-99", "X-L3gs-Client": "x"})
        assert status == 206 and len(got) == 100
        time.sleep(0.3)   # let the abandoned responses notice
    assert "client left" in caplog.text    # the abandoned bodies took the quiet path
    assert not [r for r in caplog.records if r.levelname in ("ERROR", "CRITICAL") or r.exc_info], caplog.text


def test_many_concurrent_clients(world):
    """40 clients at once, each the whole file: all bytes right, within a bounded time."""
    body = (world["single"] / "chunks.bin").read_bytes()
    n = 40

    async def go(url):
        async with aiohttp.ClientSession(timeout=TIMEOUT, connector=aiohttp.TCPConnector(limit=n)) as s:
            async def one(i):
                rng = f"bytes={i}-{len(body) - 1}"
                async with s.get(url + "/chunks.bin", headers={"Range": rng}) as r:
                    return r.status, await r.read()
            return await asyncio.gather(*(one(i) for i in range(n)))

    with start_server(world["single"]) as h:
        t0 = time.monotonic()
        results = asyncio.run(asyncio.wait_for(go(h.url), 20))
        elapsed = time.monotonic() - t0
    assert all(s == 206 and got == body[i:] for i, (s, got) in enumerate(results))
    assert elapsed < 10


def test_many_paced_sessions_each_get_the_trace(world):
    """20 named sessions at once: each is its own link, paced to the whole trace (not a shared
    bottleneck), within 5 % + one burst over its first second."""
    n, rate = 20, 30_000

    async def go(url):
        async with aiohttp.ClientSession(timeout=TIMEOUT, connector=aiohttp.TCPConnector(limit=n)) as s:
            async def one(i):
                got = 0
                async with s.get(url + "/chunks.bin", headers={"X-L3gs-Client": f"s{i}"}) as r:
                    t0 = time.monotonic()
                    async for data in r.content.iter_any():
                        if time.monotonic() - t0 >= 1.0:
                            break
                        got += len(data)
                return got
            return await asyncio.gather(*(one(i) for i in range(n)))

    shaper = TraceShaper([rate] * 3, burst_bytes=2048)
    with start_server(world["single"], trace=shaper) as h:
        got = asyncio.run(asyncio.wait_for(go(h.url), 10))
    assert all(abs(g - rate) <= 0.05 * rate + 2048 for g in got), got


# ---------------------------------------------------------------------- shaping
def test_shaper_curve_and_inverse():
    sh = TraceShaper([1000, 0, 500], slot_s=1.0, burst_bytes=100)
    assert sh.cumulative_bytes(0.5) == 500 and sh.cumulative_bytes(2.0) == 1000
    assert sh.cumulative_bytes(3.5) == 1500 + 500                      # the trace repeats
    for amount in (1, 999, 1000, 1001, 1499, 1500, 1501, 4000):
        t = sh.time_for_bytes(amount)
        assert sh.cumulative_bytes(t) == pytest.approx(amount)
        assert sh.cumulative_bytes(t - 1e-6) < amount
    with pytest.raises(ShapingError, match=r"bytes_per_slot\[1\]"):
        TraceShaper([10, -1])
    with pytest.raises(ShapingError, match="slot_s"):
        TraceShaper([10], slot_s=0)


def test_bucket_with_a_fake_clock():
    """Hand-computed waits: 1000 B/s, burst 100, the bucket empty at the start."""
    now = [0.0]
    sh = TraceShaper([1000, 1000], burst_bytes=100, clock=lambda: now[0])
    b = sh.session("a")
    assert b.reserve(100) == pytest.approx(0.1)
    assert b.reserve(100) == pytest.approx(0.2)                       # queued behind the first debt
    now[0] = 0.15
    assert b.reserve(50) == pytest.approx(0.1)                        # debt 200 - 150 + 50 at 1000 B/s
    now[0] = 10.0                                                       # long idle: at most one burst saved
    assert b.reserve(100) == 0.0 and b.reserve(1) == pytest.approx(0.001)
    assert sh.session("b").reserve(100) == pytest.approx(0.1)         # sessions are independent
    now[0] = 10.5
    late = sh.session("c", start_slot=1)                                # a resumed client: slot 1's rate
    assert late.reserve(500) == pytest.approx(0.5)


def test_session_age_lines_the_trace_up_with_the_client():
    """A session started 0.5 s ago on the client's clock: its slot boundaries are the client's
    (slot 1's rate from 0.5 s after creation), and the half second before is gone but for a burst."""
    from l3gs_opt.delivery.server import _age

    now = [100.0]
    sh = TraceShaper([1000, 3000], burst_bytes=100, clock=lambda: now[0])
    b = sh.session("a", age_s=0.5)
    assert b.reserve(100) == 0.0                                        # one burst saved, not 500 bytes
    assert b.reserve(400) == pytest.approx(0.4)                         # 400 more at 1000 B/s
    now[0] = 100.5                                                      # the client's slot 1 starts now
    # The debt of 400 is repaid by 1.0 s, one burst (100) saved: 200 of the 300 wait, at 3000 B/s.
    assert b.piece_bytes() == 100 and b.reserve(300) == pytest.approx(200 / 3000)
    with pytest.raises(ShapingError, match="age_s"):
        sh.session("b", age_s=-1.0)
    assert [_age(v) for v in (None, "0.25", "-1", "nan", "1e9", "x" * 20, "oops")] == [0.0, 0.25, 0, 0, 0, 0, 0]


def test_piece_follows_the_current_slot_rate():
    """10 ms of the current slot's rate, clamped to [MIN_PIECE_BYTES, burst]; the trace repeats and a
    resumed session counts from its start slot."""
    from l3gs_opt.delivery.shaping import MIN_PIECE_BYTES

    now = [0.0]
    sh = TraceShaper([1_000_000, 50_000, 1_000], clock=lambda: now[0])
    assert sh.burst_bytes == 10_000
    b = sh.session("a")
    assert b.piece_bytes() == 10_000                                   # 10 ms of 1 MB/s
    now[0] = 1.5
    assert b.piece_bytes() == 500                                      # 10 ms of 50 kB/s
    now[0] = 2.5
    assert b.piece_bytes() == MIN_PIECE_BYTES                          # 10 B would be a write per 10 B
    now[0] = 3.2
    assert b.piece_bytes() == 10_000                                   # the trace repeats
    assert sh.session("r", start_slot=1).piece_bytes() == 500          # slot 1 for a resumed client


def test_shaping_accuracy_over_three_seconds(world):
    """Bytes received per second on loopback follow a 3 s trace.

    Tolerance: the burst (2 KiB here, so that it stays small beside a 20 kB second) can land one side of a second's boundary, and the reader's
    second boundaries are off the server's by the request's latency (~1 ms, 0.1 % of a second);
    so each second is within 5 % of the trace plus one burst (the bucket starts empty, so the first
    second holds no extra burst).
    """
    trace = [50_000, 20_000, 35_000]
    index = read_stream(world["single"])
    size = (world["single"] / "chunks.bin").stat().st_size
    assert size > sum(trace)   # the body outlasts the trace

    async def go(url):
        per_s = [0, 0, 0]
        async with aiohttp.ClientSession(timeout=aiohttp.ClientTimeout(total=10)) as s:
            async with s.get(url + "/chunks.bin", headers={"X-L3gs-Client": "acc"}) as r:
                t0 = time.monotonic()
                async for data in r.content.iter_any():
                    i = int(time.monotonic() - t0)
                    if i >= 3:
                        break
                    per_s[i] += len(data)
        return per_s

    shaper = TraceShaper(trace, burst_bytes=2048)
    with start_server(world["single"], trace=shaper) as h:
        per_s = asyncio.run(asyncio.wait_for(go(h.url), 10))
    burst = shaper.burst_bytes
    for i in (0, 1, 2):
        assert abs(per_s[i] - trace[i]) <= 0.05 * trace[i] + burst, (per_s, trace)
    assert abs(sum(per_s) - sum(trace)) <= 0.05 * sum(trace) + burst, (per_s, trace)
    assert index.total_bytes > 0


# ---------------------------------------------------------------------- fetch
def test_unit_chunks_cover_the_catalogue(world):
    from l3gs_opt.simulator.catalog import build_catalog

    index = read_stream(world["single"])
    bundle = stream_bundle(index)
    for view in ("object", "scene"):
        cat = build_catalog(bundle, view)
        units = unit_chunks(index, cat)
        assert [sum(c.bytes for c in u) for u in units] == [int(b) for b in cat.bytes]
        assert sorted(c.index for u in units for c in u) == [c.index for c in index.chunks if c.bytes]


@pytest.mark.parametrize("carry, last_chunk", [("started", "whole"), ("head", "whole"), ("started", "prefix")])
def test_fetch_matches_simulate_given_the_same_bytes(world, tmp_path, carry, last_chunk):
    """A 3-slot fetch over a paced loopback link, then the simulator driven by the bytes the fetch
    measured: the same requests, completions and in-flight units in every slot (under either rule
    for what a cut keeps on the wire, and with the per-slot plan that counts a last chunk's first
    splats, which arrive in the file's order)."""
    from l3gs_opt.simulator.client import Client, drive
    from l3gs_opt.simulator.simulation import SimConfig, Simulation

    trace_file = tmp_path / "trace.txt"
    trace_file.write_text("\n".join(["0.48", "0.24", "0.4"]) + "\n")     # Mbit/s: 60, 30, 50 kB per s
    config = SimConfig(width=32, height=24, samples_per_slot=1, carry=carry, last_chunk=last_chunk)
    out = tmp_path / "out"
    with start_server(world["single"], trace=str(trace_file), shape_anonymous=False) as h:
        result = fetch(h.url, str(trace_file), world["log"], "l3gs", out, slots=3, config=config)
    recs = [json.loads(line) for line in (out / "slots.jsonl").read_text().splitlines()]
    assert [r["slot"] for r in recs] == [0, 1, 2] and result.summary["slots"] == 3
    measured = [r["fetch"]["bytes_received"] for r in recs]
    assert [r["bytes_share"] for r in recs] == measured
    assert sum(measured) > 0
    # Pacing seen through the whole client: at most the trace's bytes per slot, 5 % + one burst
    # (the catalogue fetch was not paced: it carried no session name). A cut that came late (the
    # client's draw ran long on a loaded machine) also counts what the server sent meanwhile, at
    # most the fastest slot's rate for that long: such a slot failed this bound once, not the pacing.
    for got, want, rec in zip(measured, (60_000, 30_000, 50_000), recs):
        assert got <= want * 1.05 + 2048 + rec["fetch"]["cut_late_s"] * 60_000, (got, want, rec["fetch"])
    sim = Simulation(stream_bundle(read_stream(world["single"])), world["log"], [60_000, 30_000, 50_000],
                     config=dataclasses.replace(config, splat_order="stored"))   # as fetch receives chunks
    client = Client(sim, sim.spec("l3gs"))
    drive([client], measured)
    for mine, theirs in zip(recs, client.records):
        for key in ("requests", "completed", "in_flight", "bytes_delivered", "predicted_bytes"):
            assert mine[key] == theirs[key], (mine["slot"], key)
    # Received bytes are the chunks' bytes (their prefixes for chunks still in flight).
    index = read_stream(world["single"])
    for c in index.chunks:
        part = out / "fetched" / f"c{c.index}.bin"
        if part.exists():
            data = part.read_bytes()
            whole = (world["single"] / "chunks.bin").read_bytes()[c.start:c.end]
            assert whole.startswith(data)


def test_fetch_errors(world, tmp_path):
    with pytest.raises(FetchError, match="url"):
        fetch("ftp://x", "lumos-throughput-mid-11", world["log"], "l3gs", tmp_path, slots=1)
    with pytest.raises(FetchError, match="resume"):
        fetch("http://127.0.0.1:9", "lumos-throughput-mid-11", world["log"], "l3gs", None, slots=1, resume=True)
    with socket.socket() as s:       # a port nobody listens on
        s.bind(("127.0.0.1", 0))
        port = s.getsockname()[1]
    with pytest.raises(FetchError, match="url"):
        fetch(f"http://127.0.0.1:{port}", "lumos-throughput-mid-11", world["log"], "l3gs", tmp_path, slots=1)
    from l3gs_opt.simulator.simulation import SimConfig

    with pytest.raises(FetchError, match="^last_chunk: 'prefix' counts a chunk's first splats: the 'tables'"):
        fetch(f"http://127.0.0.1:{port}", "lumos-throughput-mid-11", world["log"], "l3gs", tmp_path, slots=1,
              catalogue="tables", config=SimConfig(last_chunk="prefix"))


def test_fetch_resumes_the_unit_in_flight(world, tmp_path, monkeypatch):
    """Interrupted after slot 0 with a unit in flight, a resumed fetch replays slot 0, reloads its
    bytes, asks the server for the rest of that unit from where it stopped and ends with the
    same records keys as an uninterrupted run; every completed chunk's bytes pass the index's hash."""
    from l3gs_opt.delivery import fetch as fetch_module
    from l3gs_opt.simulator.simulation import SimConfig

    trace = [40_000] * 4
    config = SimConfig(width=32, height=24, samples_per_slot=1)
    out = tmp_path / "out"
    real_end = fetch_module._FetchClient.end_slot

    def end_then_stop(self, *, defer=False):
        # Stop after the first slot with a unit in flight (a cut can fall between two units: then
        # after slot 2 whatever it holds; on this bundle and trace slot 0 or 2 has one).
        record = real_end(self)
        if record["in_flight"] or record["slot"] == 2:
            raise KeyboardInterrupt
        return (lambda: record) if defer else record

    trace_file = tmp_path / "trace.txt"
    trace_file.write_text("0.32\n" * 4)          # 40 kB per 1 s slot
    with start_server(world["single"], trace=trace, shape_anonymous=False) as h:
        monkeypatch.setattr(fetch_module._FetchClient, "end_slot", end_then_stop)
        with pytest.raises(KeyboardInterrupt):
            fetch(h.url, str(trace_file), world["log"], "l3gs", out, slots=4, config=config)
        monkeypatch.setattr(fetch_module._FetchClient, "end_slot", real_end)
        first = [json.loads(line) for line in (out / "slots.jsonl").read_text().splitlines()]
        result = fetch(h.url, str(trace_file), world["log"], "l3gs", out, slots=4, config=config, resume=True)
    recs = [json.loads(line) for line in (out / "slots.jsonl").read_text().splitlines()]
    t = len(first)
    assert [r["slot"] for r in recs] == [0, 1, 2, 3] and recs[:t] == first
    assert result.summary["resumed_slots"] == t
    assert len({r["run_id"] for r in recs}) == 1
    if first[-1]["in_flight"]:   # it went on first, from where it stopped (checked inside fetch too)
        carried = first[-1]["in_flight"][0][:2]
        assert recs[t]["completed"][:1] == [carried] or recs[t]["in_flight"][0][:2] == carried
    index = read_stream(world["single"])
    body = (world["single"] / "chunks.bin").read_bytes()
    for c in index.chunks:
        part = out / "fetched" / f"c{c.index}.bin"
        if part.exists():
            assert body[c.start:c.end].startswith(part.read_bytes())


def _free_port() -> int:
    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        return s.getsockname()[1]


def test_fetch_survives_a_server_restart(world, tmp_path):
    """The server stops mid-chunk and comes back 1.5 s later on the same port: the client retries,
    resumes the chunk from the first byte it lacks (the received bytes are the file's, hash-checked
    when a chunk completes) and finishes every slot; the slots of the outage record the retries."""
    import threading

    from l3gs_opt.simulator.simulation import SimConfig

    trace_file = tmp_path / "trace.txt"
    trace_file.write_text("0.24\n" * 6)          # 30 kB per 1 s slot: every chunk spans slots
    config = SimConfig(width=32, height=24, samples_per_slot=1)
    port, out = _free_port(), tmp_path / "out"
    first = start_server(world["single"], port=port, trace=str(trace_file), shape_anonymous=False)
    restarted = []

    def bounce():
        time.sleep(2.3)                           # slot 2 of the run: a transfer is in flight
        first.stop()
        time.sleep(1.5)
        restarted.append(start_server(world["single"], port=port, trace=str(trace_file), shape_anonymous=False))

    bouncer = threading.Thread(target=bounce)
    bouncer.start()
    try:
        result = fetch(first.url, str(trace_file), world["log"], "l3gs", out, slots=6, config=config)
    finally:
        bouncer.join()
        first.stop()
        for h in restarted:
            h.stop()
    recs = [json.loads(line) for line in (out / "slots.jsonl").read_text().splitlines()]
    assert [r["slot"] for r in recs] == list(range(6)) and result.summary["slots"] == 6
    assert sum(r["fetch"]["retries"] for r in recs) > 0
    got = [r["fetch"]["bytes_received"] for r in recs]
    assert got[5] > 0 and min(got[2:4]) < 30_000 * 0.8      # the outage cost bytes, the end received again
    body = (world["single"] / "chunks.bin").read_bytes()
    for c in read_stream(world["single"]).chunks:
        part = out / "fetched" / f"c{c.index}.bin"
        if part.exists():
            assert body[c.start:c.end].startswith(part.read_bytes())


def test_fetch_gives_up_on_a_server_that_stays_away(world, tmp_path):
    """With a 1 s retry window and the server gone for good, the fetch fails with one named error
    (no hang, no traceback) within the slot it was in plus the window."""
    from l3gs_opt.simulator.simulation import SimConfig

    trace_file = tmp_path / "trace.txt"
    trace_file.write_text("0.24\n" * 6)
    config = SimConfig(width=32, height=24, samples_per_slot=1)
    port = _free_port()
    handle = start_server(world["single"], port=port, trace=str(trace_file), shape_anonymous=False)
    import threading

    stopper = threading.Timer(1.5, handle.stop)
    stopper.start()
    t0 = time.monotonic()
    try:
        with pytest.raises(FetchError, match=r"chunks\[\d+\]: .*no byte for 1 s of retries"):
            fetch(handle.url, str(trace_file), world["log"], "l3gs", tmp_path / "out", slots=6, config=config,
                  retry_s=1.0)
    finally:
        stopper.join()
        handle.stop()
    assert time.monotonic() - t0 < 8.0


def test_cli_fetch_json(world, tmp_path, capsys):
    import argparse

    from l3gs_opt.cli.fetch import register

    parser = argparse.ArgumentParser()
    register(parser.add_subparsers())
    trace_file = tmp_path / "trace.txt"
    trace_file.write_text("0.8\n0.8\n")
    with start_server(world["single"], trace=str(trace_file), shape_anonymous=False) as h:
        args = parser.parse_args(["fetch", h.url, "--trace", str(trace_file), "--path", str(world["log"]),
                                  "--method", "l3gs", "--out", str(tmp_path / "o"), "--slots", "2", "--width", "32",
                                  "--height", "24", "--samples-per-slot", "1", "--json", "--no-progress"])
        assert args.func(args) == 0
    summary = json.loads(capsys.readouterr().out)
    assert summary["slots"] == 2 and summary["url"] == h.url
    assert summary["bytes_delivered"] <= 2 * 100_000 * 1.05 + 2048
