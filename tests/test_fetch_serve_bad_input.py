"""Bad input to serve, fetch and bundle export: one line that names the field, exit 2, before any work
(never a traceback, a hang or silent acceptance); servers bind loopback only.

Regression tests, one per bug; a tiny procedural bundle (1000 splats, 16x12 pixels). Nothing here
needs a server except the run that checks a fetch may write into its own previous output.
"""

from __future__ import annotations

import hashlib
import shutil
import socket
import urllib.request
from typing import Optional

import pytest

pytest.importorskip("aiohttp")

from l3gs_opt.delivery.fetch import FETCH_DIR, MAX_RETRY_S, MIN_SLOT_S, FetchError, fetch  # noqa: E402
from l3gs_opt.delivery.server import ServerError, _is_loopback, start_server  # noqa: E402
from l3gs_opt.scene.stream_index import (StreamError, export_stream, load_stream_chunk,  # noqa: E402
                                         read_stream)
from cli_helpers import one_error_line, run_cli, tiny_sort_bundle  # noqa: E402


@pytest.fixture(scope="module")
def world(tmp_path_factory):
    w = tiny_sort_bundle(tmp_path_factory.mktemp("fsbad"), "bundle")
    return {**w, "single": export_stream(w["bundle"], w["root"] / "single", pack="single").parent}


@pytest.fixture
def busy_port():
    """A port listening on 127.0.0.1: a serve that got as far as binding fails at once instead of serving."""
    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        s.listen(1)
        yield s.getsockname()[1]


def _fetch_args(world, out, url="http://127.0.0.1:9") -> list:
    # Port 9 (discard): nothing answers, so any check that comes after the first request would show.
    return ["fetch", url, "--trace", "lumos-throughput-mid-11", "--mbps", "0.5", "--path", world["log"],
            "--width", "16", "--height", "12", "--no-progress", "--slots", "2", "--slot-s", "0.5",
            "--method", "l3gs", "--samples-per-slot", "1", "--retry-s", "1", "--out", out]


def _digests(folder) -> dict:
    return {p.relative_to(folder).as_posix(): hashlib.sha256(p.read_bytes()).hexdigest()
            for p in sorted(folder.rglob("*")) if p.is_file()}


# -- 1: serve --host 0.0.0.0 / :: listened on every interface
def test_loopback_hosts():
    assert all(_is_loopback(h) for h in ("127.0.0.1", "127.0.0.2", "::1", "localhost"))
    assert not any(_is_loopback(h) for h in ("0.0.0.0", "::", "192.168.1.1", "example.com", "127.0.0.1 "))


@pytest.mark.parametrize("host", ["0.0.0.0", "::", "192.168.1.1"])
def test_serve_refuses_a_host_that_is_not_loopback(world, capsys, busy_port, host):
    with pytest.raises(ServerError, match=r"^host: .*only a loopback address"):
        start_server(world["single"], host=host, port=busy_port, timeout_s=2.0)
    line = one_error_line(capsys, "serve", world["single"], "--host", host, "--port", busy_port)
    assert line.startswith(f"error: --host: {host!r}: only a loopback address") and "local viewing" in line, line


# -- 2: fetch --slot-s 1e-300 / --mbps 1e-300 ran and reported nonsense (1e-300 is now below MIN_MBPS; 1e-6 still gives no byte)
def test_fetch_slot_too_short(world, capsys, tmp_path):
    args = _fetch_args(world, tmp_path / "o")
    args[args.index("--slot-s") + 1] = "1e-300"
    line = one_error_line(capsys, *args)
    assert line == f"error: --slot-s: 1e-300: must be at least {MIN_SLOT_S} s (MIN_SLOT_S): a fetch slot is wall-clock " \
                   "time", line
    assert not (tmp_path / "o").exists()


def test_fetch_mbps_giving_no_byte(world, capsys, tmp_path):
    args = _fetch_args(world, tmp_path / "o")
    args[args.index("--mbps") + 1] = "1e-6"
    line = one_error_line(capsys, *args)
    assert line.startswith("error: --mbps: 1e-06 Mbit/s gives 0 bytes in every one of the 2 slots"), line
    assert not (tmp_path / "o" / "index.json").exists()


# -- 3: fetch --retry-s had no upper limit
def test_fetch_retry_has_an_upper_limit(world, capsys, tmp_path):
    args = _fetch_args(world, tmp_path / "o")
    args[args.index("--retry-s") + 1] = "1e12"
    line = one_error_line(capsys, *args)
    assert line == f"error: --retry-s: 1000000000000.0: expected seconds in [0, {MAX_RETRY_S:g}] (MAX_RETRY_S)", line


# -- 4: fetch --out / bundle export --out into a bundle or another export wrote over its files
@pytest.mark.parametrize("kind, what", [("single", "a stream export (index.json)"), ("bundle", "a bundle")])
def test_fetch_refuses_out_holding_a_bundle_or_export(world, capsys, tmp_path, kind, what):
    target = tmp_path / kind
    shutil.copytree(world[kind], target)
    before = _digests(target)
    line = one_error_line(capsys, *_fetch_args(world, target))
    assert line.startswith(f"error: --out: {target} holds {what}"), line
    assert _digests(target) == before


def test_fetch_may_write_into_its_own_previous_output(world, capsys, tmp_path):
    out = tmp_path / "o"
    with start_server(world["single"], host="127.0.0.1", port=0, timeout_s=5.0) as h:
        for _ in range(2):   # the second run overwrites the first's records, as before
            args = _fetch_args(world, out, h.url)
            args[args.index("--slots") + 1] = "1"
            code, _, err = run_cli(capsys, *args)
            assert code == 0, err
    assert (out / FETCH_DIR).is_dir() and (out / "index.json").is_file()


def test_export_refuses_out_holding_another_bundle(world, capsys, tmp_path):
    other = tmp_path / "other"
    shutil.copytree(world["bundle"], other)
    before = _digests(other)
    line = one_error_line(capsys, "bundle", "export", world["bundle"], "--out", other, "--pack", "per-chunk")
    assert line == f"error: --out: {other} holds a bundle (manifest.json): export to a new or empty folder", line
    assert _digests(other) == before


def test_export_may_rewrite_an_export_folder(world, capsys, tmp_path):
    out = tmp_path / "e"
    for pack in ("per-chunk", "single"):
        code, _, err = run_cli(capsys, "bundle", "export", world["bundle"], "--out", out, "--pack", pack)
        assert code == 0, err


# -- 5: --out "" wrote into the current folder
def test_empty_out_is_refused(world, capsys, tmp_path, monkeypatch):
    monkeypatch.chdir(tmp_path)
    for argv in (("bundle", "export", world["bundle"], "--out", ""), _fetch_args(world, "")):
        line = one_error_line(capsys, *argv)
        assert line == "error: --out: empty: name a path ('.' for the current folder)", line
    assert list(tmp_path.iterdir()) == []
    # the library call refuses it too (the command line stops it earlier, for every command)
    with pytest.raises(FetchError, match=r"^out: '' is not a folder name"):
        fetch("http://127.0.0.1:9/", "lumos-throughput-mid-11", None, "l3gs", "")


# -- 6: options that would be ignored (serve --mbps / --trace-format without --trace; fetch --path-rate with a log)
@pytest.mark.parametrize("flag, value, shown", [("--mbps", "5", "5.0"), ("--trace-format", "pensieve", "'pensieve'")])
def test_serve_trace_options_need_a_trace(world, capsys, busy_port, flag, value, shown):
    line = one_error_line(capsys, "serve", world["single"], "--port", busy_port, flag, value)
    assert line == f"error: {flag}: {shown}: needs --trace (without one the server does not pace)", line


@pytest.mark.parametrize("rate", ["nan", "30"])
def test_fetch_path_rate_needs_cameras(world, capsys, tmp_path, rate):
    line = one_error_line(capsys, *_fetch_args(world, tmp_path / "o"), "--path-rate", rate)
    assert line.startswith("error: --path-rate: ") and "only --path-format cameras reads it" in line, line
    assert not (tmp_path / "o").exists()


def _get(url: str, headers: Optional[dict] = None) -> tuple[int, bytes]:
    with urllib.request.urlopen(urllib.request.Request(url, headers=headers or {}), timeout=10) as r:
        return r.status, r.read()


# -- 7: serve started on an export whose chunk bytes fail their sha256 (clients then refused each chunk)
@pytest.mark.parametrize("pack", ["single", "per-chunk"])
def test_serve_refuses_an_export_whose_chunk_fails_its_hash(world, capsys, tmp_path, busy_port, pack):
    out = export_stream(world["bundle"], tmp_path / pack, pack=pack).parent
    index = read_stream(out)
    c = index.chunks[len(index.chunks) // 2]
    data = out / c.file
    raw = bytearray(data.read_bytes())
    raw[c.start] ^= 0xFF                      # one flipped byte: same size, so only the hash can tell
    data.write_bytes(bytes(raw))
    with pytest.raises(StreamError, match=rf"^chunks\[{c.index}\]: sha256 .* \(corrupt or stale data\)"):
        start_server(out, port=0, timeout_s=2.0)
    line = one_error_line(capsys, "serve", out, "--port", busy_port)
    assert line.startswith(f"error: chunks[{c.index}]: sha256 of the {c.bytes} bytes is "), line
    # --no-verify skips the hashing: that serve gets as far as binding the (busy) port
    line = one_error_line(capsys, "serve", out, "--port", busy_port, "--no-verify")
    assert line == f"error: --port: {busy_port}: cannot listen on 127.0.0.1: address already in use", line
    with start_server(out, port=0, verify=False) as server:
        status, got = _get(server.url + "/" + c.file, {"Range": c.range_header})
    assert status == 206 and got == bytes(raw[c.start:c.end])   # served as is, and the client's check refuses it
    with pytest.raises(StreamError, match=r"corrupt or stale"):
        load_stream_chunk(index, c, got)


def test_serve_verifies_a_sound_export_and_takes_only_bool_flags(world):
    with start_server(world["single"], port=0) as server:
        status, _ = _get(server.url + "/index.json")
    assert status == 200
    for name in ("verify", "shape_anonymous"):
        with pytest.raises(ServerError, match=rf"^{name}: 'no': must be True or False"):
            start_server(world["single"], port=0, **{name: "no"})
