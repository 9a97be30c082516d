"""Streamable bundles: byte ranges tile the data, hashes and decodes match the bundle's chunks,
boxes hold the splats, a Range-fetch client rebuilds the bundle's scenes bit for bit, malformed
indexes give named errors, and the ``bundle export|info`` commands."""

from __future__ import annotations

import argparse
import dataclasses
import hashlib
import json
import re

import numpy as np
import pytest
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st

from l3gs_opt.errors import L3gsError
from l3gs_opt.scene.bundle import read_bundle, split_layers, write_bundle
from l3gs_opt.scene.stream_index import (DEFAULT_ALIGNMENT, PACKS, StreamError, export_stream,
                                         load_stream_chunk, read_chunk_bytes, read_stream, stream_bundle,
                                         verify_stream)
from renderer_helpers import random_scene

_KEYS = ("means", "log_scales", "quats", "opacity_logits", "sh", "object_ids", "layers")
_RANGE = re.compile(r"^bytes=(\d+)-(\d+)$")


def _same(a, b):
    for k in _KEYS:
        x, y = getattr(a, k), getattr(b, k)
        assert (x is None) == (y is None), k
        if x is not None:
            assert x.dtype == y.dtype and x.tobytes() == y.tobytes(), k


def _by_object(scene):
    """Rows grouped by object id (stable): the order chunks store them in."""
    return scene.subset(np.argsort(scene.object_ids, kind="stable")) if scene.object_ids is not None else scene


def _make(kind, root):
    """A tiny bundle of each variant; returns (path, the level scenes written)."""
    path = root / kind
    if kind == "layered":
        s = random_scene(60, sh_degree=2, seed=1, object_ids=True, layers=3)
        levels = split_layers(s.subset(np.argsort(s.layers, kind="stable")))
        write_bundle(path, levels, variant="layered", build={"note": "test"})
    elif kind == "sort":  # unsegmented, SH degree 0
        s = random_scene(20, sh_degree=0, seed=2)
        levels = [s.subset(np.arange(8)), s.subset(np.arange(8, 20))]
        write_bundle(path, levels, variant="sort")
    elif kind == "distill":
        s = random_scene(30, sh_degree=1, seed=4, object_ids=True)
        levels = [s.subset(np.arange(10)), s.subset(np.arange(10, 30))]
        write_bundle(path, levels, variant="distill",
                     compact_sh=[np.asarray(lv.sh[:, :1]) * 0.5 for lv in levels])
    else:  # hierarchy
        v0 = random_scene(10, sh_degree=0, seed=5, object_ids=True)
        v1 = random_scene(25, sh_degree=0, seed=6, object_ids=True)
        par = np.array([np.flatnonzero(v0.object_ids == j)[0] if (v0.object_ids == j).any() else -1
                        for j in v1.object_ids])
        levels = [v0, v1]
        write_bundle(path, levels, variant="hierarchy", parents=[None, par])
    return path, levels


VARIANTS = ("layered", "sort", "distill", "hierarchy")


@pytest.fixture(scope="module")
def exports(tmp_path_factory):
    """Every variant exported in both packs: {(variant, pack): (bundle path, index)}."""
    root = tmp_path_factory.mktemp("stream")
    out = {}
    for kind in VARIANTS:
        path, _ = _make(kind, root)
        for pack in PACKS:
            out[kind, pack] = path, read_stream(export_stream(path, root / f"{kind}-{pack}", pack=pack))
    return out


@pytest.mark.parametrize("pack", PACKS)
@pytest.mark.parametrize("kind", VARIANTS)
def test_round_trip_bit_for_bit(tmp_path, kind, pack):
    path, levels = _make(kind, tmp_path)
    idx = read_stream(export_stream(path, tmp_path / "out", pack=pack))
    src, got = read_bundle(path), stream_bundle(idx)
    for lvl in range(len(levels)):
        _same(got.scene(lvl), src.scene(lvl))
        _same(got.level_scene(lvl), src.level_scene(lvl))
        if kind != "distill":  # independent of both readers: the scenes written
            _same(got.level_scene(lvl), _by_object(levels[lvl]))
    if kind == "distill":
        for lvl in range(len(levels)):
            _same(got.level_scene(lvl, sh_form="compact"), src.level_scene(lvl, sh_form="compact"))
    if kind == "hierarchy":
        for j in src.manifest["objects"]:
            assert got.parents(1, j).tolist() == src.parents(1, j).tolist()
    # the index restates the manifest: only where the chunks live differs
    want = dict(src.manifest, chunks=[{k: v for k, v in c.items() if k not in ("file", "offset")}
                                      for c in src.manifest["chunks"]])
    have = dict(got.manifest, chunks=[{k: v for k, v in c.items() if k not in ("file", "offset")}
                                      for c in got.manifest["chunks"]])
    assert have == want
    assert idx.count == sum(lv.num_splats for lv in levels)


@pytest.mark.parametrize("kind", VARIANTS)
def test_single_pack_ranges_tile_the_file(exports, kind):
    _, idx = exports[kind, "single"]
    data = (idx.path / "chunks.bin").read_bytes()
    spans = sorted((c.start, c.end) for c in idx.chunks)
    pos = 0
    for start, end in spans:
        assert start == pos + (-pos % DEFAULT_ALIGNMENT)  # next aligned byte: no overlap, no gap beyond padding
        assert start % DEFAULT_ALIGNMENT == 0
        assert data[pos:start] == b"\0" * (start - pos)  # the padding is zeros
        pos = end
    assert pos == len(data)  # nothing after the last chunk
    assert sum(c.bytes for c in idx.chunks) == idx.total_bytes == sum(lv.bytes for lv in idx.levels)


@pytest.mark.parametrize("kind", VARIANTS)
def test_per_chunk_pack_one_whole_file_each(exports, kind):
    path, idx = exports[kind, "per-chunk"]
    assert len(idx.filenames) == len(idx.chunks) == len(set(c.file for c in idx.chunks))
    for c in idx.chunks:
        assert (c.start, c.end) == (0, c.bytes) and (idx.path / c.file).stat().st_size == c.bytes
    names = lambda folder: sorted(p.name for p in folder.iterdir())  # noqa: E731
    assert names(idx.path / "chunks") == names(path / "chunks")  # the bundle's file names


@pytest.mark.parametrize("pack", PACKS)
@pytest.mark.parametrize("kind", VARIANTS)
def test_range_fetch_is_enough(exports, kind, pack):
    """A client holding only index.json and a server answering Range requests on the data files."""
    path, idx = exports[kind, pack]
    served = {name: (idx.path / name).read_bytes() for name in idx.filenames}
    requests = []

    def fetch(chunk):  # what an HTTP server does with "Range: bytes=a-b" (inclusive end)
        a, b = map(int, _RANGE.match(chunk.range_header).groups())
        requests.append((chunk.file, chunk.range_header))
        return served[chunk.file][a:b + 1]

    src = read_bundle(path)
    for i, c in enumerate(idx.chunks):
        want = (path / src.manifest["chunks"][i]["file"]).read_bytes()  # the bundle's own chunk file
        assert hashlib.sha256(want).hexdigest() == c.sha256
        rec = load_stream_chunk(idx, c, fetch(c))
        assert rec.tobytes() == want and rec.dtype == src.chunk(i).dtype and len(rec) == c.splats
        assert read_chunk_bytes(idx, i) == want
    got = stream_bundle(idx, fetch=fetch)
    requests.clear()
    top = len(idx.levels) - 1
    _same(got.scene(top), src.scene(top))
    # a layered scene needs every chunk (each once per level); a separate one only its version's
    need = {(c.file, c.range_header) for c in idx.chunks if idx.representation == "layered" or c.level == top}
    assert set(requests) == need


@pytest.mark.parametrize("kind", VARIANTS)
def test_bounds_hold_the_splats(exports, kind):
    path, idx = exports[kind, "single"]
    src = read_bundle(path)
    for c in idx.chunks:
        scene = src.level_scene(c.level, sh_form="compact" if kind == "distill" else "full")
        rows = scene.object_ids == c.object if scene.object_ids is not None else np.ones(scene.num_splats, bool)
        means = scene.means[rows].astype(np.float64)
        assert len(means) == c.splats
        # exact box of the centres: its faces are the extreme centres
        assert c.bound.min == tuple(means.min(0)) and c.bound.max == tuple(means.max(0))
        # conservative box: the 3-sigma ellipsoid's axis tips (rotated by each splat's quaternion)
        q = scene.quats[rows].astype(np.float64)
        w, x, y, z = (q / np.linalg.norm(q, axis=1, keepdims=True)).T
        rot = np.stack([np.stack([1 - 2 * (y * y + z * z), 2 * (x * y - w * z), 2 * (x * z + w * y)], 1),
                        np.stack([2 * (x * y + w * z), 1 - 2 * (x * x + z * z), 2 * (y * z - w * x)], 1),
                        np.stack([2 * (x * z - w * y), 2 * (y * z + w * x), 1 - 2 * (x * x + y * y)], 1)], 1)
        sig = np.exp(scene.log_scales[rows].astype(np.float64))
        for axis in range(3):
            for sign in (-1, 1):
                tips = means + sign * 3 * sig[:, axis:axis + 1] * rot[:, :, axis]
                assert c.bound_3sigma.contains(tips)
        assert c.bound_3sigma.encloses(c.bound)
    for o in idx.objects:
        mine = [c for c in idx.chunks if c.object == o.id]
        assert all(o.bound.encloses(c.bound) and o.bound_3sigma.encloses(c.bound_3sigma) for c in mine)
        assert list(o.bytes) == [sum(c.bytes for c in mine if c.level == lv.level) for lv in idx.levels]


def test_empty_chunk_has_no_range(tmp_path):
    path, levels = _make("layered", tmp_path)
    m = json.loads((path / "manifest.json").read_text())
    obj, lvl = max(m["objects"]) + 1, 1  # an object with no splats (read_bundle accepts it)
    m["objects"].append(obj)
    (path / "chunks" / "empty.bin").write_bytes(b"")
    m["chunks"].append(dict(m["chunks"][0], object=obj, level=lvl, splats=0, bytes=0, file="chunks/empty.bin"))
    (path / "manifest.json").write_text(json.dumps(m))
    for pack in PACKS:
        idx = read_stream(export_stream(path, tmp_path / pack, pack=pack))
        c = idx.chunks[-1]
        assert c.splats == 0 and c.range_header is None and c.bound is None
        assert c.sha256 == hashlib.sha256(b"").hexdigest()
        assert load_stream_chunk(idx, c, b"").shape == (0,)
        for lv in range(3):
            _same(stream_bundle(idx).scene(lv), read_bundle(path).scene(lv))


def test_re_export_replaces_the_old_one(tmp_path):
    path, _ = _make("layered", tmp_path)
    out = tmp_path / "out"
    export_stream(path, out, pack="per-chunk")
    export_stream(path, out, pack="single", alignment=4096)
    assert not list((out / "chunks").glob("*.bin"))
    idx = read_stream(out)
    assert idx.alignment == 4096 and all(c.start % 4096 == 0 for c in idx.chunks)
    export_stream(path, out, pack="per-chunk")
    assert not (out / "chunks.bin").exists() and read_stream(out).pack == "per-chunk"
    assert verify_stream(read_stream(out)) == read_stream(out).total_bytes


def test_export_argument_errors(tmp_path):
    path, _ = _make("sort", tmp_path)
    with pytest.raises(StreamError, match="pack: 'zip' must be one of single, per-chunk"):
        export_stream(path, tmp_path / "o", pack="zip")
    for bad in (0, 3, 48, 1 << 17, True, 64.0):
        with pytest.raises(StreamError, match=r"alignment: .* must be a power of two in \[4, 65536\]"):
            export_stream(path, tmp_path / "o", alignment=bad)
    with pytest.raises(StreamError, match="is the bundle folder itself"):
        export_stream(path, path, pack="per-chunk")
    (tmp_path / "f").write_text("x")
    with pytest.raises(StreamError, match="out: .* is a file"):
        export_stream(path, tmp_path / "f")
    assert (path / "chunks").is_dir() and read_bundle(path)  # the bundle is untouched


# ---------------------------------------------------------------------- malformed indexes
@pytest.fixture()
def stream(tmp_path):
    path, _ = _make("layered", tmp_path)
    out = tmp_path / "out"
    export_stream(path, out)
    return out


def _edit(out, change):
    index = json.loads((out / "index.json").read_text())
    change(index)
    (out / "index.json").write_text(json.dumps(index))


def _move(c, start):
    c.update(start=start, end=start + c["bytes"], range=f"bytes={start}-{start + c['bytes'] - 1}")


MALFORMED = [
    (lambda m: m.update(schema="l3gs-opt/stream@2"), r"^schema: 'l3gs-opt/stream@2' must be 'l3gs-opt/stream@1'$"),
    (lambda m: m.update(extra=1), r"^extra: unknown index key$"),
    (lambda m: m.pop("alignment"), r"^alignment: missing index key$"),
    (lambda m: m["chunks"][1].update(colour=1), r"^chunks\[1\]: unknown chunk key 'colour'$"),
    (lambda m: _move(m["chunks"][1], m["chunks"][0]["start"] + 64), r"^chunks\[1\]: bytes \[64, \d+\) of chunks.bin "
                                                                      r"overlap those of chunk 0 \[0, \d+\)$"),
    (lambda m: m["chunks"][2].update(end=m["chunks"][2]["end"] + 4),
     r"^chunks\[2\]: range \[start \d+, end \d+\) holds \d+ bytes, not bytes \d+$"),
    (lambda m: _move(m["chunks"][3], m["chunks"][3]["start"] + 4), r"^chunks\[3\]: start \d+ is not a multiple of "
                                                                     r"the alignment 64$"),
    (lambda m: m["chunks"][0].update(range="bytes=0-999"), r"^chunks\[0\]: range 'bytes=0-999' must be 'bytes=0-\d+'"),
    (lambda m: m["chunks"][4].update(sha256="ABC"), r"^chunks\[4\]: sha256 'ABC' must be 64 lower-case hex digits$"),
    (lambda m: m["chunks"][0].update(bytes=m["chunks"][0]["bytes"] + 152),
     r"^chunks\[0\]: bytes \d+ != splats \d+ x 152$"),
    (lambda m: m["chunks"][0]["bound"].update(min=[9.0, 9.0, 9.0]), r"^chunks\[0\]: bound: min \[9.0, 9.0, 9.0\] "
                                                                       r"exceeds max"),
    (lambda m: m["chunks"][0]["bound_3sigma"].update(max=m["chunks"][0]["bound"]["min"]),
     r"^chunks\[0\]: bound_3sigma must enclose bound$"),
    (lambda m: m["chunks"][5].update(bound=None), r"^chunks\[5\]: bound and bound_3sigma must be null for an empty "
                                                  r"chunk and only there$"),
    (lambda m: m["chunks"][0].update(object=99), r"^chunks\[0\]: object 99 is not in 'objects'$"),
    (lambda m: m["chunks"][0].update(level=-1), r"^chunks\[0\]: level -1 must be a whole number >= 0$"),
    (lambda m: m["chunks"][1].update(level=m["chunks"][0]["level"], object=m["chunks"][0]["object"]),
     r"^chunks\[1\]: object \d+, level \d+, full: also chunk 0$"),
    (lambda m: m.update(filenames=["../chunks.bin"]), r"^filenames\[0\]: '../chunks.bin' resolves outside"),
    (lambda m: m["records"]["full"].update(bytes=150), r"^records.full: bytes 150 must be 152"),
    (lambda m: m["records"]["full"]["fields"].reverse(), r"^records.full: fields must be the full records"),
    (lambda m: m["levels"][1].update(splats=m["levels"][1]["splats"] + 1), r"^levels\[1\]: cumulative_splats"),
    (lambda m: m["objects"][0].update(bytes=[0, 0, 0]), r"^objects\[0\]: bytes \[0, 0, 0\] must be"),
    (lambda m: m["objects"][1]["bound"].update(max=[1e9, 1e9, 1e9]), r"^objects\[1\]: bound and bound_3sigma must be "
                                                                       r"the union of its chunks' boxes$"),
    (lambda m: m.update(count=1), r"^count: 1 != 60 \(the levels' splats\)$"),
    # regressions found by the fuzz test below (each was a ValueError/OverflowError/TypeError, not a StreamError)
    (lambda m: m.update(filenames=["chunks\0.bin"]), r"^filenames\[0\]: 'chunks\\x00.bin' must be a relative path"),
    (lambda m: m["chunks"][0]["bound"].update(min=[10**400, 0, 0]), r"^chunks\[0\]: bound.min \[1000.* must be 3 "
                                                                     r"finite numbers$"),
    (lambda m: m["chunks"][0].update(sh_form=["full"]), r"^chunks\[0\]: sh_form \['full'\] must be one of full$"),
    (lambda m: m.update(representation="separate"), r"^representation: 'separate' must be 'layered'"),
]


@pytest.mark.parametrize("change, message", MALFORMED)
def test_malformed_index_named_error(stream, change, message):
    _edit(stream, change)
    with pytest.raises(StreamError, match=message):
        read_stream(stream)


def test_range_past_end_of_file(stream):
    data = (stream / "chunks.bin").read_bytes()
    last = max(read_stream(stream).chunks, key=lambda c: c.end)
    (stream / "chunks.bin").write_bytes(data[:-10])
    with pytest.raises(StreamError, match=rf"^chunks\[{last.index}\]: end {last.end} is past the end of "
                                          rf"chunks.bin \({len(data) - 10} bytes\)$"):
        read_stream(stream)
    idx = read_stream(stream, check_files=False)  # the index alone is fine; reading the chunk is not
    with pytest.raises(StreamError, match=rf"^chunks\[{last.index}\]: chunks.bin: \d+ bytes at \d+, expected "
                                          rf"{last.bytes} \(file cut short\)$"):
        read_chunk_bytes(idx, last)
    (stream / "chunks.bin").unlink()
    with pytest.raises(StreamError, match=r"^filenames\[0\]: .*chunks.bin: no such file$"):
        read_stream(stream)


def test_hash_mismatch(stream):
    idx = read_stream(stream)
    c = idx.chunks[3]
    data = bytearray((stream / "chunks.bin").read_bytes())
    data[c.start + 5] ^= 0x01  # one bit of one float
    (stream / "chunks.bin").write_bytes(bytes(data))
    idx = read_stream(stream)  # sizes still agree
    with pytest.raises(StreamError, match=r"^chunks\[3\]: sha256 of the \d+ bytes is [0-9a-f]{64}, the index says "
                                          + c.sha256):
        verify_stream(idx)
    with pytest.raises(StreamError, match=r"^chunks\[3\]: sha256"):
        stream_bundle(idx).scene(len(idx.levels) - 1)
    with pytest.raises(StreamError, match=rf"^chunks\[3\]: {c.bytes - 1} bytes given, expected {c.bytes}"):
        load_stream_chunk(idx, 3, bytes(data[c.start:c.end - 1]))
    with pytest.raises(StreamError, match=r"^chunk: 99 must be a StreamChunk or a chunk number"):
        load_stream_chunk(idx, 99, b"")
    other = dataclasses.replace(c, sha256="0" * 64)
    with pytest.raises(StreamError, match=r"^chunk\[3\]: 3: not a chunk of this index"):
        load_stream_chunk(idx, other, b"")


def _json_values():
    return st.recursive(st.none() | st.booleans() | st.integers(-3, 10**6) | st.integers(-10**400, 10**400)
                        | st.floats(allow_nan=False)
                        | st.text(max_size=8), lambda kids: st.lists(kids, max_size=3)
                        | st.dictionaries(st.text(max_size=6), kids, max_size=3), max_leaves=6)


@settings(max_examples=150, deadline=None, derandomize=True,
          suppress_health_check=[HealthCheck.function_scoped_fixture, HealthCheck.too_slow])
@given(data=st.data())
def test_mutated_index_valid_or_named_error(tmp_path_factory, data):
    """Any one value of a valid index replaced (or a key dropped): a StreamIndex or a StreamError."""
    base = tmp_path_factory.getbasetemp() / "fuzz-stream"
    if not (base / "out" / "index.json").exists():
        path, _ = _make("distill", base)
        export_stream(path, base / "out")
    text = (base / "out" / "index.json").read_text()
    index = json.loads(text)
    # walk down to a random container, then replace or drop one of its entries
    node = index
    for _ in range(data.draw(st.integers(0, 4))):
        kids = list(node.items()) if isinstance(node, dict) else list(enumerate(node))
        kids = [(k, v) for k, v in kids if isinstance(v, (dict, list)) and v]
        if not kids:
            break
        node = data.draw(st.sampled_from(kids))[1]
    keys = list(node) if isinstance(node, dict) else list(range(len(node)))
    key = data.draw(st.sampled_from(keys))
    if isinstance(node, dict) and data.draw(st.booleans()):
        del node[key]
    else:
        node[key] = data.draw(_json_values())
    (base / "out" / "index.json").write_text(json.dumps(index))
    try:
        read_stream(base / "out")
    except StreamError:
        pass
    finally:
        (base / "out" / "index.json").write_text(text)


# ---------------------------------------------------------------------- CLI
def _parser():
    from l3gs_opt.cli.bundle import register

    parser = argparse.ArgumentParser(prog="l3gs-opt")
    register(parser.add_subparsers(dest="command", required=True))
    return parser


def test_cli_export_and_info(tmp_path, capsys):
    path, _ = _make("distill", tmp_path)
    out = tmp_path / "web"
    args = _parser().parse_args(["bundle", "export", str(path), "--out", str(out), "--pack", "per-chunk"])
    assert args.func(args) == 0
    line = capsys.readouterr().out.strip()
    idx = read_stream(out)
    assert line == (f"wrote {out / 'index.json'}: {len(idx.chunks)} chunks, {idx.total_bytes} bytes in "
                    f"{len(idx.chunks)} file(s) (per-chunk, alignment 64 bytes)")
    args = _parser().parse_args(["bundle", "info", str(out), "--json", "--verify"])
    assert args.func(args) == 0
    info = json.loads(capsys.readouterr().out)
    src = read_bundle(path).manifest
    assert info["variant"] == "distill" and info["chunks"] == len(src["chunks"])
    assert info["bytes"] == info["verified_bytes"] == sum(c["bytes"] for c in src["chunks"]) == info["file_bytes"]
    assert info["bytes_per_splat"] == src["bytes_per_splat"] == {"compact": 56, "sh_upgrade": 48}
    assert info["splats_per_level"] == [lv["splats"] for lv in src["levels"]]
    args = _parser().parse_args(["bundle", "info", str(out / "index.json")])
    assert args.func(args) == 0 and "pack: per-chunk" in capsys.readouterr().out


def test_cli_errors_are_library_errors(tmp_path):
    """The main CLI prints an L3gsError as one line with exit 2: the handlers raise nothing else."""
    path, _ = _make("sort", tmp_path)
    parser = _parser()
    args = parser.parse_args(["bundle", "export", str(path), "--out", str(tmp_path / "o"), "--align", "100"])
    with pytest.raises(L3gsError, match="alignment: 100 must be a power of two"):
        args.func(args)
    args = parser.parse_args(["bundle", "info", str(tmp_path / "nowhere")])
    with pytest.raises(L3gsError, match=r"^index: .*nowhere: no such file$"):
        args.func(args)
    args = parser.parse_args(["bundle", "export", str(tmp_path / "nowhere"), "--out", str(tmp_path / "o")])
    with pytest.raises(L3gsError, match="manifest"):
        args.func(args)
    with pytest.raises(SystemExit) as exc:  # argparse's own usage error: exit 2
        parser.parse_args(["bundle", "export", str(path), "--out", "o", "--pack", "zip"])
    assert exc.value.code == 2
    assert not (tmp_path / "o" / "index.json").exists()  # nothing half-written by the failed exports


def test_export_refuses_what_the_index_cannot_say(tmp_path):
    path, _ = _make("sort", tmp_path)
    mp = path / "manifest.json"
    good = mp.read_text()
    m = json.loads(good)
    m["chunks"].append(dict(m["chunks"][0]))  # read_bundle accepts a repeated chunk; the index could not tell
    mp.write_text(json.dumps(m))
    with pytest.raises(StreamError, match=r"^chunks\[2\]: object 0, level 0, full: also chunk 0$"):
        export_stream(path, tmp_path / "o")
    m = json.loads(good)
    raw = bytearray((path / m["chunks"][1]["file"]).read_bytes())
    raw[0:4] = np.float32(np.inf).tobytes()  # x of record 0
    (path / m["chunks"][1]["file"]).write_bytes(bytes(raw))
    mp.write_text(good)
    with pytest.raises(StreamError, match=r"^chunks\[1\]: record 0: x = inf is not finite$"):
        export_stream(path, tmp_path / "o")
    assert not (tmp_path / "o" / "index.json").exists()
