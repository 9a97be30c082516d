"""Streamable bundles: one small JSON index and chunk data that a web client fetches by HTTP Range.

Layout (``export_stream``)::

    OUT/index.json                              # schema "l3gs-opt/stream@1"
    OUT/chunks.bin                              # pack="single": every chunk, one file
    OUT/chunks/o{object}_l{level}_{sh_form}.bin # pack="per-chunk": one file per chunk

A client reads ``index.json`` once and then knows, for every chunk of the bundle, what it holds
(object, level, SH form, splats), where it is (``filenames[file]``, bytes ``[start, end)`` and the
``Range: bytes=start-(end-1)`` header that fetches exactly those bytes), how to check it
(``sha256`` of those bytes) and how to decode it (``records[sh_form].fields``: the chunk is a
headerless array of little-endian records, as in the bundle; see :mod:`l3gs_opt.scene.bundle`).
The chunk bytes are copied from the bundle unchanged: a stream holds the bundle's records bit for
bit, and :func:`stream_bundle` reads a stream export back as a :class:`~l3gs_opt.scene.bundle.Bundle`.

Length (~900 lines): most of it is the reader's validation, which checks every field and every
cross-reference of an index a server or another tool may have written (ranges, alignment, files
inside the folder, hashes, boxes, totals), each error naming the field and index.

Vocabulary follows PlayCanvas's streamed-SOG ``lod-meta.json`` (splat-transform) where it fits:
``filenames`` (data files, paths relative to the index, referred to by integer ``file``),
``count`` (splats in all levels), ``bound`` ``{min, max}`` per node, and ``offset``/``count`` per
entry become ``start``/``end``/``splats`` here. One difference: PlayCanvas's LOD 0 is the *most*
detailed level, while level 0 here is the base layer (layered) or smallest version (separate).

Index keys (unknown or missing keys are an error, as for the bundle manifest)
------------------------------------------------------------------------------
``schema``, ``variant``, ``representation``, ``segmented``, ``sh_degree``, ``compact_sh_degree``
    As in the bundle manifest.
``pack`` (``single`` / ``per-chunk``), ``alignment`` (bytes; every ``start`` is a multiple of it)
``count``
    Splats stored in all levels (bytes are per level and per object below).
``levels``
    Per level: ``level``, ``splats``, ``cumulative_splats``, ``bytes`` (all chunks of the level).
``records``
    Per SH form: ``sh_degree``, ``bytes`` (per splat) and ``fields`` (``[name, dtype]`` pairs, in
    record order), enough to decode a chunk; ``bytes_per_splat`` repeats the sizes (manifest key).
``filenames``
    Data files, relative to the index's folder.
``objects``
    Per object: ``id``, ``bound`` and ``bound_3sigma`` over its chunks, ``splats`` and ``bytes``
    per level (lists of length ``len(levels)``), ``chunks`` (indices into ``chunks``).
``chunks``
    Per chunk, in the bundle manifest's order: ``object``, ``level``, ``sh_form``, ``sh_degree``,
    ``splats``, ``bytes``, ``file`` (index into ``filenames``), ``start``, ``end`` (bytes,
    ``end - start == bytes``), ``range`` (the HTTP Range header value, inclusive end; ``null``
    for an empty chunk, which is never fetched), ``sha256`` (hex digest of the chunk's bytes),
    ``bound`` and ``bound_3sigma`` (``null`` for an empty chunk).
``build``
    The bundle's free-form provenance, copied.

Bounding boxes
--------------
``bound`` is the exact axis-aligned box of the splat centres (float32 values written exactly).
``bound_3sigma`` is conservative: each centre grown by ``3 max(exp(scale_i))`` on every axis, a
cube that holds the splat's 3-sigma ellipsoid whatever its rotation (PlayCanvas grows by the
rotated 1-sigma box instead; 3 sigma is where a splat's alpha falls below 1/90 of its peak, the
usual cut-off of splat rasterisers). An ``sh_upgrade`` chunk (distill) holds no geometry: its
boxes are those of the ``compact`` chunk of the same object and level, whose rows it upgrades.

Alignment
---------
In a ``single`` pack each chunk starts at a multiple of ``alignment`` (default
:data:`DEFAULT_ALIGNMENT` = 64 bytes; zero padding between chunks, none after the last). A Range
response is its own buffer, so the client needs no alignment for fetched chunks; it matters when
the whole file is fetched (or memory-mapped) and each chunk is viewed in place: 64 is a multiple
of the 4-byte fields (``Float32Array``/``Int32Array`` views need it) and of a CPU cache line, and
costs under 64 bytes per chunk (768 bytes for the 24 chunks of a 100k-splat, 23.6 MB bundle). A
4096-byte page alignment would only help a server that memory-maps pages or uses direct I/O, at
up to 4 KiB per chunk (38.7 kB for the same bundle; as much as a whole small chunk of a segmented
scene); WebGPU storage-buffer bindings want 256 (``alignment=256``).
"""

from __future__ import annotations

import dataclasses
import hashlib
import json
import math
import re
from pathlib import Path
from typing import Callable, Optional, Sequence, Union

import numpy as np

from l3gs_opt.errors import L3gsError
from l3gs_opt.input_files import check_regular_file, key_name, read_json
from l3gs_opt.output_files import write_atomic
from l3gs_opt.scene.bundle import BUNDLE_SCHEMA, REPRESENTATION, VARIANTS, Bundle, read_bundle, record_fields

__all__ = ["STREAM_SCHEMA", "PACKS", "DEFAULT_ALIGNMENT", "MAX_ALIGNMENT", "INDEX_NAME", "StreamError",
           "Bound", "RecordLayout", "StreamLevel", "StreamObject", "StreamChunk", "StreamIndex",
           "export_stream", "check_streamable", "read_stream", "read_chunk_bytes", "load_stream_chunk",
           "verify_stream", "stream_bundle"]

STREAM_SCHEMA = "l3gs-opt/stream@1"
PACKS = ("single", "per-chunk")
INDEX_NAME = "index.json"
SINGLE_FILE = "chunks.bin"
#: Default chunk alignment in a single pack (bytes); see "Alignment" in the module docstring.
DEFAULT_ALIGNMENT = 64
#: Largest alignment accepted (bytes): a 64 KiB block is beyond any page or buffer rule in use.
MAX_ALIGNMENT = 1 << 16
#: Sigmas the conservative box grows by (see "Bounding boxes").
BOUND_SIGMAS = 3.0

_INDEX_KEYS = {"schema", "variant", "representation", "segmented", "sh_degree", "compact_sh_degree", "pack",
               "alignment", "count", "levels", "records", "bytes_per_splat", "filenames", "objects", "chunks",
               "build"}
_LEVEL_KEYS = {"level", "splats", "cumulative_splats", "bytes"}
_RECORD_KEYS = {"sh_degree", "bytes", "fields"}
_OBJECT_KEYS = {"id", "bound", "bound_3sigma", "splats", "bytes", "chunks"}
_CHUNK_KEYS = {"object", "level", "sh_form", "sh_degree", "splats", "bytes", "file", "start", "end", "range",
               "sha256", "bound", "bound_3sigma"}
_BOUND_KEYS = {"min", "max"}
_SHA256 = re.compile(r"^[0-9a-f]{64}$")


class StreamError(L3gsError, ValueError):
    """A stream index (or its data, or an export request) is malformed; names the field and index."""

    def __init__(self, field: str, message: str, index: Optional[int] = None):
        self.field = field
        self.index = index
        super().__init__(f"{field}{'' if index is None else f'[{index}]'}: {message}")


# ---------------------------------------------------------------------- data types
@dataclasses.dataclass(frozen=True)
class Bound:
    """An axis-aligned box ``[min, max]`` (world units, per axis x, y, z)."""

    min: tuple[float, float, float]
    max: tuple[float, float, float]

    def contains(self, points: np.ndarray) -> bool:
        """Whether every point of ``points`` [N, 3] lies in the box (faces included)."""
        p = np.asarray(points, dtype=np.float64).reshape(-1, 3)
        return bool(np.all(p >= np.asarray(self.min)) and np.all(p <= np.asarray(self.max)))

    def encloses(self, other: "Bound") -> bool:
        """Whether ``other`` lies inside this box."""
        return all(a <= b for a, b in zip(self.min, other.min)) and all(a >= b for a, b in zip(self.max, other.max))

    def union(self, other: "Bound") -> "Bound":
        return Bound(tuple(map(min, self.min, other.min)), tuple(map(max, self.max, other.max)))

    def to_dict(self) -> dict:
        return {"min": list(self.min), "max": list(self.max)}


@dataclasses.dataclass(frozen=True)
class RecordLayout:
    """The record of one SH form: ``fields`` ``((name, dtype), ...)``, ``bytes`` per splat."""

    sh_form: str
    sh_degree: int
    bytes: int
    fields: tuple[tuple[str, str], ...]

    @property
    def dtype(self) -> np.dtype:
        """NumPy structured dtype of one record (little-endian, packed)."""
        return np.dtype(list(self.fields))


@dataclasses.dataclass(frozen=True)
class StreamLevel:
    """One level: ``splats`` in it, ``cumulative_splats`` held after it, ``bytes`` of its chunks."""

    level: int
    splats: int
    cumulative_splats: int
    bytes: int


@dataclasses.dataclass(frozen=True)
class StreamObject:
    """One object: boxes over its chunks, ``splats`` and ``bytes`` per level, its chunk indices."""

    id: int
    bound: Optional[Bound]
    bound_3sigma: Optional[Bound]
    splats: tuple[int, ...]
    bytes: tuple[int, ...]
    chunks: tuple[int, ...]


@dataclasses.dataclass(frozen=True)
class StreamChunk:
    """One chunk: what it holds and the bytes ``[start, end)`` of ``file`` (a path relative to the
    index's folder) that hold it; ``bound`` / ``bound_3sigma`` are ``None`` for an empty chunk."""

    index: int
    object: int
    level: int
    sh_form: str
    sh_degree: int
    splats: int
    bytes: int
    file: str
    start: int
    end: int
    sha256: str
    bound: Optional[Bound]
    bound_3sigma: Optional[Bound]

    @property
    def range_header(self) -> Optional[str]:
        """The HTTP ``Range`` header value fetching exactly this chunk (``None`` if it is empty)."""
        return _range_header(self.start, self.end)


@dataclasses.dataclass(frozen=True)
class StreamIndex:
    """A checked stream index (see the module docstring for each field); ``path`` is its folder."""

    path: Path
    variant: str
    representation: str
    segmented: bool
    sh_degree: int
    compact_sh_degree: Optional[int]
    pack: str
    alignment: int
    count: int
    levels: tuple[StreamLevel, ...]
    records: tuple[RecordLayout, ...]
    filenames: tuple[str, ...]
    objects: tuple[StreamObject, ...]
    chunks: tuple[StreamChunk, ...]
    build: str  # the provenance as JSON text: keeps the dataclass immutable

    def record(self, sh_form: str) -> RecordLayout:
        """The record layout of ``sh_form``."""
        for r in self.records:
            if r.sh_form == sh_form:
                return r
        raise StreamError("sh_form", f"{sh_form!r} is not in this stream (forms: "
                                     f"{', '.join(r.sh_form for r in self.records)})")

    @property
    def total_bytes(self) -> int:
        """Bytes of all chunks (padding excluded)."""
        return sum(c.bytes for c in self.chunks)

    def file_path(self, chunk: Union["StreamChunk", int]) -> Path:
        """Local path of the data file holding ``chunk``."""
        return self.path / _chunk_of(self, chunk).file

    def bundle_manifest(self) -> dict:
        """The bundle manifest this stream was exported from, chunks pointing into the stream's
        files (``file`` and ``offset`` = ``start``): :func:`l3gs_opt.scene.bundle.read_bundle`'s
        contract, readable by :class:`~l3gs_opt.scene.bundle.Bundle`."""
        hierarchy = self.variant == "hierarchy"
        return {"schema": BUNDLE_SCHEMA, "variant": self.variant, "representation": self.representation,
                "segmented": self.segmented, "sh_degree": self.sh_degree, "compact_sh_degree": self.compact_sh_degree,
                "levels": [{"level": lv.level, "splats": lv.splats, "cumulative_splats": lv.cumulative_splats}
                           for lv in self.levels],
                "objects": [o.id for o in self.objects],
                "bytes_per_splat": {r.sh_form: r.bytes for r in self.records},
                "chunks": [{"object": c.object, "level": c.level, "sh_form": c.sh_form, "sh_degree": c.sh_degree,
                            "splats": c.splats, "bytes": c.bytes, "file": c.file, "offset": c.start,
                            "fields": [list(f) for f in record_fields(c.sh_form, c.sh_degree, parent=hierarchy)]}
                           for c in self.chunks],
                "build": json.loads(self.build)}


def _range_header(start: int, end: int) -> Optional[str]:
    return None if end <= start else f"bytes={start}-{end - 1}"


def _chunk_of(index: StreamIndex, chunk: Union[StreamChunk, int]) -> StreamChunk:
    if isinstance(chunk, StreamChunk):
        if not (0 <= chunk.index < len(index.chunks)) or index.chunks[chunk.index] != chunk:
            raise StreamError("chunk", f"{chunk.index}: not a chunk of this index", chunk.index)
        return chunk
    if isinstance(chunk, bool) or not isinstance(chunk, (int, np.integer)) or not 0 <= chunk < len(index.chunks):
        raise StreamError("chunk", f"{chunk!r} must be a StreamChunk or a chunk number in [0, {len(index.chunks)})")
    return index.chunks[int(chunk)]


# ---------------------------------------------------------------------- export
def _bounds(rec: np.ndarray, where: int) -> tuple[Optional[Bound], Optional[Bound]]:
    """Exact centre box and conservative 3-sigma box of a chunk's records (``None`` when empty)."""
    if len(rec) == 0:
        return None, None
    for name in ("x", "y", "z", "scale_0", "scale_1", "scale_2"):
        bad = ~np.isfinite(rec[name])
        if bad.any():
            row = int(np.argmax(bad))
            raise StreamError("chunks", f"record {row}: {name} = {rec[name][row]} is not finite", where)
    means = np.stack([rec[n] for n in ("x", "y", "z")], 1).astype(np.float64)
    with np.errstate(over="ignore"):
        grow = BOUND_SIGMAS * np.exp(np.max(np.stack([rec[f"scale_{i}"] for i in range(3)], 1).astype(np.float64), 1))
    lo, hi = means - grow[:, None], means + grow[:, None]
    if not (np.all(np.isfinite(lo)) and np.all(np.isfinite(hi))):
        row = int(np.argmax(~np.isfinite(lo).all(1) | ~np.isfinite(hi).all(1)))
        raise StreamError("chunks", f"record {row}: a scale so large that its {BOUND_SIGMAS:g}-sigma box is not "
                                    f"finite", where)
    exact = Bound(tuple(float(v) for v in means.min(0)), tuple(float(v) for v in means.max(0)))
    wide = Bound(tuple(float(v) for v in lo.min(0)), tuple(float(v) for v in hi.max(0)))
    return exact, wide


def _check_export_args(bundle: Path, out: Path, pack: str, alignment: int) -> None:
    if pack not in PACKS:
        raise StreamError("pack", f"{pack!r} must be one of {', '.join(PACKS)}")
    if isinstance(alignment, bool) or not isinstance(alignment, (int, np.integer)) \
            or not 4 <= alignment <= MAX_ALIGNMENT or alignment & (alignment - 1):
        raise StreamError("alignment", f"{alignment!r} must be a power of two in [4, {MAX_ALIGNMENT}] bytes")
    if out.exists() and not out.is_dir():
        raise StreamError("out", f"{out} is a file: expected a folder")
    if out.resolve() == bundle.resolve():
        raise StreamError("out", f"{out} is the bundle folder itself: export to another folder")


def export_stream(bundle_dir, out_dir, *, pack: str = "single", alignment: int = DEFAULT_ALIGNMENT) -> Path:
    """Export a bundle as a streamable index and chunk data files.

    Parameters
    ----------
    bundle_dir : str or Path
        A bundle (``manifest.json`` + ``chunks/``), read and checked with
        :func:`l3gs_opt.scene.bundle.read_bundle`.
    out_dir : str or Path
        Output folder (created; not the bundle folder). An earlier export there is replaced:
        stale ``chunks/*.bin`` are removed, and ``index.json`` is written last, so that a server
        never serves an index whose data is not yet complete.
    pack : {"single", "per-chunk"}, keyword-only
        ``single``: every chunk in ``chunks.bin``, each starting at a multiple of ``alignment``;
        ``per-chunk``: one file per chunk (``chunks/o{object}_l{level}_{sh_form}.bin``).
    alignment : int, keyword-only
        Bytes; a power of two in [4, :data:`MAX_ALIGNMENT`] (see "Alignment" in the module docstring).

    Returns
    -------
    Path
        The index path ``out_dir/index.json``.

    Raises
    ------
    StreamError
        On a bad ``pack``/``alignment``/``out_dir``, an SH form whose chunks disagree on the
        record layout, a non-finite centre or scale, or an ``sh_upgrade`` chunk without its
        ``compact`` chunk.
    l3gs_opt.scene.bundle.BundleError
        On a malformed bundle.

    Example
    -------
    >>> export_stream("bundle", "web", pack="single")          # doctest: +SKIP
    PosixPath('web/index.json')
    """
    bundle_dir, out = Path(bundle_dir), Path(out_dir)
    _check_export_args(bundle_dir, out, pack, alignment)
    b = read_bundle(bundle_dir)
    m = b.manifest
    records = check_streamable(m)
    out.mkdir(parents=True, exist_ok=True)
    if (out / INDEX_NAME).is_file():  # first: no moment where an old index points at missing data
        (out / INDEX_NAME).unlink()
    if (out / "chunks").is_dir():
        for old in (out / "chunks").glob("*.bin"):  # a rewrite must not leave chunks of an earlier export
            old.unlink()
    if (out / SINGLE_FILE).is_file():
        (out / SINGLE_FILE).unlink()
    boxes = _chunk_bounds(b)
    chunks: list[dict] = []

    def entry(i: int, data: bytes, file: int, start: int) -> dict:
        c = m["chunks"][i]
        exact, wide = boxes[i]
        return {"object": c["object"], "level": c["level"], "sh_form": c["sh_form"], "sh_degree": c["sh_degree"],
                "splats": c["splats"], "bytes": c["bytes"], "file": file, "start": start, "end": start + len(data),
                "range": _range_header(start, start + len(data)), "sha256": hashlib.sha256(data).hexdigest(),
                "bound": None if exact is None else exact.to_dict(),
                "bound_3sigma": None if wide is None else wide.to_dict()}

    if pack == "single":
        filenames = [SINGLE_FILE]

        def write_single(fh) -> None:
            pos = 0
            for i in range(len(m["chunks"])):  # one chunk in memory at a time
                data = b.chunk(i).tobytes()
                pad = -pos % alignment
                fh.write(b"\0" * pad)
                chunks.append(entry(i, data, 0, pos + pad))
                fh.write(data)
                pos += pad + len(data)

        write_atomic(out / SINGLE_FILE, write_single)
    else:
        (out / "chunks").mkdir(exist_ok=True)
        filenames = [f"chunks/o{c['object']}_l{c['level']}_{c['sh_form']}.bin" for c in m["chunks"]]
        for i in range(len(m["chunks"])):
            data = b.chunk(i).tobytes()
            write_atomic(out / filenames[i], data)
            chunks.append(entry(i, data, i, 0))
    index = _index_dict(m, records, pack, alignment, filenames, chunks)
    path = out / INDEX_NAME
    write_atomic(path, _dumps_index(index))
    return path


def _dumps_index(index: dict) -> str:
    """The index as JSON, one line per level, record, object and chunk: small, and a diff shows
    which chunk changed."""
    dump = lambda v: json.dumps(v, allow_nan=False)  # noqa: E731
    lines = []
    for key, value in index.items():
        if isinstance(value, list) and value and all(isinstance(v, dict) for v in value):
            body = ",\n".join(f"  {dump(v)}" for v in value)
            lines.append(f" {dump(key)}: [\n{body}\n ]")
        elif key == "records":
            body = ",\n".join(f"  {dump(k)}: {dump(v)}" for k, v in value.items())
            lines.append(f" {dump(key)}: {{\n{body}\n }}")
        else:
            lines.append(f" {dump(key)}: {dump(value)}")
    return "{\n" + ",\n".join(lines) + "\n}\n"


def _chunk_bounds(b: Bundle) -> list[tuple[Optional[Bound], Optional[Bound]]]:
    """Boxes of every chunk; an sh_upgrade chunk takes those of the compact chunk of its splats."""
    m = b.manifest
    geo: dict[tuple[int, int], tuple] = {}
    for i, c in enumerate(m["chunks"]):
        if c["sh_form"] != "sh_upgrade":
            geo[(c["object"], c["level"])] = (c["splats"], _bounds(b.chunk(i), i))
    out = []
    for i, c in enumerate(m["chunks"]):
        key = (c["object"], c["level"])
        if key not in geo or geo[key][0] != c["splats"]:
            raise StreamError("chunks", f"sh_upgrade chunk of object {key[0]}, level {key[1]}: no compact chunk "
                                        f"of {c['splats']} splats holds its splats' geometry", i)
        out.append(geo[key][1])
    return out


def check_streamable(m: dict) -> dict[str, RecordLayout]:
    """What a bundle's manifest ``m`` must meet beyond :func:`~l3gs_opt.scene.bundle.read_bundle`'s
    checks to be exported (and so delivered): no two chunks of one (object, level, SH form), one
    record layout per SH form, and each level's counts consistent (``cumulative_splats`` the running
    sum). Returns the record layouts.

    Raises
    ------
    StreamError
        Naming the field and index (``chunks[20]``, ``levels[1]``).
    """
    records = _export_records(m)
    # The index's own level check; the levels' bytes are not known yet and not part of it.
    _read_levels({"representation": m["representation"], "levels": [{**lv, "bytes": 0} for lv in m["levels"]]})
    return records


def _export_records(m: dict) -> dict[str, RecordLayout]:
    """One record layout per SH form (a bundle whose chunks of one form disagree cannot be indexed so),
    after checking that no two chunks hold the same object, level and form."""
    hierarchy = m["variant"] == "hierarchy"
    out: dict[str, RecordLayout] = {}
    seen: dict[tuple, int] = {}
    for i, c in enumerate(m["chunks"]):
        key = (c["object"], c["level"], c["sh_form"])
        if seen.setdefault(key, i) != i:  # read_bundle lets it pass; a client could not tell them apart
            raise StreamError("chunks", f"object {key[0]}, level {key[1]}, {key[2]}: also chunk {seen[key]}", i)
        fields = tuple(tuple(f) for f in record_fields(c["sh_form"], c["sh_degree"], parent=hierarchy))
        lay = RecordLayout(c["sh_form"], c["sh_degree"], np.dtype(list(fields)).itemsize, fields)
        if out.setdefault(c["sh_form"], lay) != lay:
            raise StreamError("chunks", f"sh_degree {c['sh_degree']} differs from that of the first "
                                        f"{c['sh_form']} chunk ({out[c['sh_form']].sh_degree}): one record "
                                        f"layout per SH form", i)
    for form, size in m["bytes_per_splat"].items():
        if form in out and out[form].bytes != size:
            raise StreamError("bytes_per_splat", f"{form}: {size!r} != the record's {out[form].bytes} bytes")
    return out


def _index_dict(m: dict, records: dict[str, RecordLayout], pack: str, alignment: int, filenames: list[str],
                chunks: list[dict]) -> dict:
    nl = len(m["levels"])
    geo_forms = ("compact",) if m["variant"] == "distill" else ("full",)
    objects = []
    for j in m["objects"]:
        mine = [i for i, c in enumerate(chunks) if c["object"] == j]
        boxes = [(Bound(**chunks[i]["bound"]), Bound(**chunks[i]["bound_3sigma"])) for i in mine
                 if chunks[i]["bound"] is not None]
        exact = wide = None
        for e, w in boxes:
            exact, wide = (e, w) if exact is None else (exact.union(e), wide.union(w))
        objects.append({"id": j, "bound": None if exact is None else exact.to_dict(),
                        "bound_3sigma": None if wide is None else wide.to_dict(),
                        "splats": [sum(chunks[i]["splats"] for i in mine if chunks[i]["level"] == lv
                                       and chunks[i]["sh_form"] in geo_forms) for lv in range(nl)],
                        "bytes": [sum(chunks[i]["bytes"] for i in mine if chunks[i]["level"] == lv)
                                  for lv in range(nl)],
                        "chunks": mine})
    levels = [{"level": lv["level"], "splats": lv["splats"], "cumulative_splats": lv["cumulative_splats"],
               "bytes": sum(c["bytes"] for c in chunks if c["level"] == k)} for k, lv in enumerate(m["levels"])]
    return {"schema": STREAM_SCHEMA, "variant": m["variant"], "representation": m["representation"],
            "segmented": m["segmented"], "sh_degree": m["sh_degree"], "compact_sh_degree": m["compact_sh_degree"],
            "pack": pack, "alignment": int(alignment), "count": sum(lv["splats"] for lv in m["levels"]),
            "levels": levels,
            "records": {f: {"sh_degree": r.sh_degree, "bytes": r.bytes, "fields": [list(x) for x in r.fields]}
                        for f, r in records.items()},
            "bytes_per_splat": {f: r.bytes for f, r in records.items()},
            "filenames": filenames, "objects": objects, "chunks": chunks, "build": m["build"]}


# ---------------------------------------------------------------------- reading
def _whole(value, minimum: int = 0) -> bool:
    return isinstance(value, int) and not isinstance(value, bool) and value >= minimum


def _keys(obj, keys: set, field: str, index: Optional[int] = None, what: str = "object") -> None:
    if not isinstance(obj, dict):
        raise StreamError(field, f"{_short(obj)} must be a JSON object", index)
    unknown = sorted(set(obj) - keys, key=str)
    if unknown:
        raise StreamError(field, f"unknown {what} key {key_name(unknown[0])!r}", index)
    missing = sorted(keys - set(obj))
    if missing:
        raise StreamError(field, f"missing {what} key {missing[0]!r}", index)


def _short(value) -> str:
    text = repr(value)
    return text if len(text) <= 40 else text[:37] + "..."


def _counts(obj: dict, names: Sequence[str], field: str, index: Optional[int]) -> None:
    for k in names:
        if not _whole(obj[k]):
            raise StreamError(field, f"{k} {_short(obj[k])} must be a whole number >= 0", index)


def _finite(x) -> bool:
    """A JSON number that is a finite float (an integer too large for a float is not)."""
    if isinstance(x, bool) or not isinstance(x, (int, float)):
        return False
    try:
        return math.isfinite(float(x))
    except OverflowError:
        return False


def _bound(value, field: str, index: Optional[int], key: str) -> Optional[Bound]:
    if value is None:
        return None
    _keys(value, _BOUND_KEYS, field, index, what=f"{key}")
    corners = []
    for k in ("min", "max"):
        v = value[k]
        if not (isinstance(v, list) and len(v) == 3 and all(_finite(x) for x in v)):
            raise StreamError(field, f"{key}.{k} {_short(v)} must be 3 finite numbers", index)
        corners.append(tuple(float(x) for x in v))
    if any(a > b for a, b in zip(*corners)):
        raise StreamError(field, f"{key}: min {list(corners[0])} exceeds max {list(corners[1])}", index)
    return Bound(*corners)


def read_stream(path, *, check_files: bool = True) -> StreamIndex:
    """Read and check a stream index (a folder holding ``index.json``, or the index file itself).

    Every key's type and range is checked, and every cross-reference: records are the bundle's
    layouts for the variant, each chunk's ``bytes == splats x record bytes`` and
    ``end - start == bytes``, ``start`` a multiple of ``alignment``, ``range`` the header of
    ``[start, end)``, no two chunks of one file overlapping, the boxes (``bound`` inside
    ``bound_3sigma``, objects' boxes the union of their chunks'), splat and byte totals per level
    and object, data files inside the index's folder (after resolving ``..`` and links).

    Parameters
    ----------
    path : str or Path
    check_files : bool, keyword-only
        Also check that each data file is a regular file reaching every range's end (default;
        off for an index whose data sits elsewhere, e.g. behind a URL). Hashes are checked when a
        chunk is decoded (:func:`load_stream_chunk`) or by :func:`verify_stream`.

    Returns
    -------
    StreamIndex

    Raises
    ------
    StreamError
        Naming the JSON field and the entry's index, e.g. ``chunks[3]: end 1200 is past the end
        of chunks.bin (1100 bytes)``.
    """
    path = Path(path)
    if path.is_dir():
        path = path / INDEX_NAME
    m = read_json(path, lambda f, msg: StreamError(f, msg), field="index")
    if not isinstance(m, dict) or m.get("schema") != STREAM_SCHEMA:
        got = m.get("schema") if isinstance(m, dict) else m
        raise StreamError("schema", f"{_short(got)} must be {STREAM_SCHEMA!r}")
    unknown = sorted(set(m) - _INDEX_KEYS)
    if unknown:
        raise StreamError(key_name(unknown[0]), "unknown index key")
    missing = sorted(_INDEX_KEYS - set(m))
    if missing:
        raise StreamError(missing[0], "missing index key")
    root = path.parent
    head = _read_head(m)
    records = _read_records(m, head)
    levels = _read_levels(m)
    filenames = _read_filenames(m, root)
    chunks = _read_chunks(m, head, records, levels, filenames)
    objects = _read_objects(m, chunks, len(levels))
    _check_totals(m, head, levels, chunks)
    index = StreamIndex(path=root, variant=head["variant"], representation=head["representation"],
                        segmented=head["segmented"], sh_degree=head["sh_degree"],
                        compact_sh_degree=head["compact_sh_degree"], pack=head["pack"], alignment=head["alignment"],
                        count=head["count"], levels=levels, records=tuple(records.values()),
                        filenames=tuple(filenames), objects=objects, chunks=chunks,
                        build=json.dumps(m["build"], sort_keys=True))
    if check_files:
        _check_files(index)
    return index


def _read_head(m: dict) -> dict:
    if m["variant"] not in VARIANTS:
        raise StreamError("variant", f"{_short(m['variant'])} must be one of {', '.join(VARIANTS)}")
    if m["representation"] != REPRESENTATION[m["variant"]]:
        raise StreamError("representation", f"{_short(m['representation'])} must be "
                                            f"{REPRESENTATION[m['variant']]!r} for variant {m['variant']!r}")
    if not isinstance(m["segmented"], bool):
        raise StreamError("segmented", f"{_short(m['segmented'])} must be true or false")
    if not (_whole(m["sh_degree"]) and m["sh_degree"] <= 3):
        raise StreamError("sh_degree", f"{_short(m['sh_degree'])} must be 0..3")
    cdeg = m["compact_sh_degree"]
    if m["variant"] == "distill":
        if not (_whole(cdeg) and cdeg < m["sh_degree"]):
            raise StreamError("compact_sh_degree", f"{_short(cdeg)} must be a degree below sh_degree "
                                                   f"{m['sh_degree']} (variant 'distill')")
    elif cdeg is not None:
        raise StreamError("compact_sh_degree", f"{_short(cdeg)} must be null for variant {m['variant']!r}")
    if m["pack"] not in PACKS:
        raise StreamError("pack", f"{_short(m['pack'])} must be one of {', '.join(PACKS)}")
    a = m["alignment"]
    if not (_whole(a, 4) and a <= MAX_ALIGNMENT and not a & (a - 1)):
        raise StreamError("alignment", f"{_short(a)} must be a power of two in [4, {MAX_ALIGNMENT}] bytes")
    if not _whole(m["count"]):
        raise StreamError("count", f"{_short(m['count'])} must be a whole number >= 0")
    for key in ("levels", "objects", "filenames", "chunks"):
        if not isinstance(m[key], list) or (key != "chunks" and not m[key]):
            raise StreamError(key, f"must be a{' non-empty' if key != 'chunks' else ''} list")
    if not isinstance(m["build"], dict):
        raise StreamError("build", f"{type(m['build']).__name__} must be an object")
    return {k: m[k] for k in ("variant", "representation", "segmented", "sh_degree", "compact_sh_degree", "pack",
                              "alignment", "count")}


def _read_records(m: dict, head: dict) -> dict[str, RecordLayout]:
    forms = {"full": head["sh_degree"]} if head["variant"] != "distill" else \
        {"compact": head["compact_sh_degree"], "sh_upgrade": head["sh_degree"]}
    hierarchy = head["variant"] == "hierarchy"
    recs = m["records"]
    if not isinstance(recs, dict) or set(recs) != set(forms):
        got = sorted(recs) if isinstance(recs, dict) else _short(recs)
        raise StreamError("records", f"{got} must hold the SH forms {sorted(forms)} (variant {head['variant']!r})")
    out = {}
    for form, deg in forms.items():
        r = recs[form]
        _keys(r, _RECORD_KEYS, f"records.{form}", what="record")
        fields = record_fields(form, deg, parent=hierarchy)
        if r["sh_degree"] != deg:
            raise StreamError(f"records.{form}", f"sh_degree {_short(r['sh_degree'])} must be {deg}")
        if r["fields"] != [list(f) for f in fields]:
            raise StreamError(f"records.{form}", f"fields must be the {form} records of SH degree {deg} "
                                                 f"(see l3gs_opt.scene.bundle.record_fields)")
        size = np.dtype(fields).itemsize
        if r["bytes"] != size:
            raise StreamError(f"records.{form}", f"bytes {_short(r['bytes'])} must be {size} (the fields' size)")
        out[form] = RecordLayout(form, deg, size, tuple(tuple(f) for f in fields))
    want = {f: r.bytes for f, r in out.items()}
    if m["bytes_per_splat"] != want:
        raise StreamError("bytes_per_splat", f"{_short(m['bytes_per_splat'])} must be {want} (the records' sizes)")
    return out


def _read_levels(m: dict) -> tuple[StreamLevel, ...]:
    out = []
    for k, lv in enumerate(m["levels"]):
        _keys(lv, _LEVEL_KEYS, "levels", k, what="level")
        _counts(lv, ("level", "splats", "cumulative_splats", "bytes"), "levels", k)
        if lv["level"] != k:
            raise StreamError("levels", f"level {lv['level']} must be {k} (its position)", k)
        out.append(StreamLevel(k, lv["splats"], lv["cumulative_splats"], lv["bytes"]))
    layered = m["representation"] == "layered"
    total = 0
    for lv in out:
        total += lv.splats
        want = total if layered else lv.splats
        if lv.cumulative_splats != want:
            raise StreamError("levels", f"cumulative_splats {lv.cumulative_splats} must be {want} "
                                        f"({m['representation']} representation)", lv.level)
    return tuple(out)


def _read_filenames(m: dict, root: Path) -> list[str]:
    inside = root.resolve()
    names = m["filenames"]
    for i, name in enumerate(names):
        if not isinstance(name, str) or not name or name.startswith(("/", "\\")) or "\0" in name:
            raise StreamError("filenames", f"{_short(name)} must be a relative path inside the index's folder", i)
        if not (root / name).resolve().is_relative_to(inside):
            raise StreamError("filenames", f"{_short(name)} resolves outside the index's folder {inside}", i)
        if names.index(name) != i:
            raise StreamError("filenames", f"{_short(name)} appears twice", i)
    if m["pack"] == "single" and len(names) != 1:
        raise StreamError("filenames", f"{len(names)} files: a single pack has exactly one")
    return list(names)


def _read_chunks(m: dict, head: dict, records: dict[str, RecordLayout], levels: tuple,
                 filenames: list[str]) -> tuple[StreamChunk, ...]:
    objects = [o.get("id") if isinstance(o, dict) else None for o in m["objects"]]
    out = []
    seen: dict[tuple, int] = {}
    for i, c in enumerate(m["chunks"]):
        _keys(c, _CHUNK_KEYS, "chunks", i, what="chunk")
        _counts(c, ("object", "level", "sh_degree", "splats", "bytes", "file", "start", "end"), "chunks", i)
        if c["object"] not in objects:
            raise StreamError("chunks", f"object {c['object']} is not in 'objects'", i)
        if c["level"] >= len(levels):
            raise StreamError("chunks", f"level {c['level']} must be below {len(levels)} (the levels)", i)
        if not isinstance(c["sh_form"], str) or c["sh_form"] not in records:
            raise StreamError("chunks", f"sh_form {_short(c['sh_form'])} must be one of {', '.join(records)}", i)
        lay = records[c["sh_form"]]
        if c["sh_degree"] != lay.sh_degree:
            raise StreamError("chunks", f"sh_degree {c['sh_degree']} must be {lay.sh_degree} "
                                        f"(records.{c['sh_form']})", i)
        key = (c["object"], c["level"], c["sh_form"])
        if key in seen:
            raise StreamError("chunks", f"object {key[0]}, level {key[1]}, {key[2]}: also chunk {seen[key]}", i)
        seen[key] = i
        if c["bytes"] != c["splats"] * lay.bytes:
            raise StreamError("chunks", f"bytes {c['bytes']} != splats {c['splats']} x {lay.bytes}", i)
        if c["file"] >= len(filenames):
            raise StreamError("chunks", f"file {c['file']} must be below {len(filenames)} (the filenames)", i)
        if c["end"] - c["start"] != c["bytes"]:
            raise StreamError("chunks", f"range [start {c['start']}, end {c['end']}) holds {c['end'] - c['start']} "
                                        f"bytes, not bytes {c['bytes']}", i)
        if c["start"] % head["alignment"]:
            raise StreamError("chunks", f"start {c['start']} is not a multiple of the alignment "
                                        f"{head['alignment']}", i)
        if c["range"] != _range_header(c["start"], c["end"]):
            raise StreamError("chunks", f"range {_short(c['range'])} must be "
                                        f"{_range_header(c['start'], c['end'])!r} (the bytes [start, end))", i)
        if not isinstance(c["sha256"], str) or not _SHA256.match(c["sha256"]):
            raise StreamError("chunks", f"sha256 {_short(c['sha256'])} must be 64 lower-case hex digits", i)
        exact = _bound(c["bound"], "chunks", i, "bound")
        wide = _bound(c["bound_3sigma"], "chunks", i, "bound_3sigma")
        if (exact is None) != (c["splats"] == 0) or (wide is None) != (exact is None):
            raise StreamError("chunks", "bound and bound_3sigma must be null for an empty chunk and only there", i)
        if exact is not None and not wide.encloses(exact):
            raise StreamError("chunks", "bound_3sigma must enclose bound", i)
        out.append(StreamChunk(i, c["object"], c["level"], c["sh_form"], c["sh_degree"], c["splats"], c["bytes"],
                               filenames[c["file"]], c["start"], c["end"], c["sha256"], exact, wide))
    _check_overlaps(out)
    if m["pack"] == "per-chunk":
        used = sorted(m["chunks"][c.index]["file"] for c in out)
        if used != list(range(len(filenames))):
            raise StreamError("filenames", f"{len(filenames)} files for {len(out)} chunks: a per-chunk pack has "
                                           f"one file per chunk")
    for c in out:
        if c.sh_form == "sh_upgrade":
            g = seen.get((c.object, c.level, "compact"))
            if g is None or out[g].splats != c.splats or out[g].bound != c.bound \
                    or out[g].bound_3sigma != c.bound_3sigma:
                raise StreamError("chunks", "an sh_upgrade chunk needs a compact chunk of the same object, level, "
                                            "splats and bounds", c.index)
    return tuple(out)


def _check_overlaps(chunks: Sequence[StreamChunk]) -> None:
    by_file: dict[str, list[StreamChunk]] = {}
    for c in chunks:
        if c.bytes:
            by_file.setdefault(c.file, []).append(c)
    for group in by_file.values():
        group.sort(key=lambda c: c.start)
        for a, b in zip(group, group[1:]):
            if b.start < a.end:
                raise StreamError("chunks", f"bytes [{b.start}, {b.end}) of {b.file} overlap those of chunk "
                                            f"{a.index} [{a.start}, {a.end})", b.index)


def _read_objects(m: dict, chunks: tuple[StreamChunk, ...], nl: int) -> tuple[StreamObject, ...]:
    geo = ("compact",) if m["variant"] == "distill" else ("full",)
    out = []
    ids = []
    for k, o in enumerate(m["objects"]):
        _keys(o, _OBJECT_KEYS, "objects", k, what="object")
        if not _whole(o["id"]):
            raise StreamError("objects", f"id {_short(o['id'])} must be a whole number >= 0", k)
        if o["id"] in ids:
            raise StreamError("objects", f"id {o['id']} appears twice", k)
        ids.append(o["id"])
        mine = [c for c in chunks if c.object == o["id"]]
        if o["chunks"] != [c.index for c in mine]:
            raise StreamError("objects", f"chunks {_short(o['chunks'])} must be {[c.index for c in mine]} "
                                         f"(the chunks of object {o['id']})", k)
        for key, want in (("splats", [sum(c.splats for c in mine if c.level == lv and c.sh_form in geo)
                                      for lv in range(nl)]),
                          ("bytes", [sum(c.bytes for c in mine if c.level == lv) for lv in range(nl)])):
            if o[key] != want:
                raise StreamError("objects", f"{key} {_short(o[key])} must be {_short(want)} (its chunks' "
                                             f"{key} per level)", k)
        exact = _bound(o["bound"], "objects", k, "bound")
        wide = _bound(o["bound_3sigma"], "objects", k, "bound_3sigma")
        want_e = want_w = None
        for c in mine:
            if c.bound is not None:
                want_e = c.bound if want_e is None else want_e.union(c.bound)
                want_w = c.bound_3sigma if want_w is None else want_w.union(c.bound_3sigma)
        if exact != want_e or wide != want_w:
            raise StreamError("objects", "bound and bound_3sigma must be the union of its chunks' boxes", k)
        out.append(StreamObject(o["id"], exact, wide, tuple(o["splats"]), tuple(o["bytes"]),
                                tuple(o["chunks"])))
    return tuple(out)


def _check_totals(m: dict, head: dict, levels: tuple[StreamLevel, ...], chunks: tuple[StreamChunk, ...]) -> None:
    geo = ("compact",) if head["variant"] == "distill" else ("full",)
    for lv in levels:
        splats = sum(c.splats for c in chunks if c.level == lv.level and c.sh_form in geo)
        if splats != lv.splats:
            raise StreamError("levels", f"splats {lv.splats} != {splats} in its chunks", lv.level)
        size = sum(c.bytes for c in chunks if c.level == lv.level)
        if size != lv.bytes:
            raise StreamError("levels", f"bytes {lv.bytes} != {size} in its chunks", lv.level)
    if head["count"] != sum(lv.splats for lv in levels):
        raise StreamError("count", f"{head['count']} != {sum(lv.splats for lv in levels)} (the levels' splats)")


def _check_files(index: StreamIndex) -> None:
    ends: dict[str, tuple[int, int]] = {}
    for c in index.chunks:
        if c.file not in ends or c.end > ends[c.file][0]:
            ends[c.file] = (c.end, c.index)
    for k, name in enumerate(index.filenames):
        f = check_regular_file(index.path / name, lambda field, msg: StreamError(field, msg, k), field="filenames")
        size = f.stat().st_size
        end, i = ends.get(name, (0, None))
        if end > size:
            raise StreamError("chunks", f"end {end} is past the end of {name} ({size} bytes)", i)


# ---------------------------------------------------------------------- chunks
def read_chunk_bytes(index: StreamIndex, chunk: Union[StreamChunk, int]) -> bytes:
    """The bytes ``[start, end)`` of a chunk from the local data file (what a Range request returns)."""
    c = _chunk_of(index, chunk)
    path = check_regular_file(index.path / c.file, lambda f, msg: StreamError(f, msg, c.index), field="chunks")
    with open(path, "rb") as fh:
        fh.seek(c.start)
        data = fh.read(c.bytes)
    if len(data) != c.bytes:
        raise StreamError("chunks", f"{c.file}: {len(data)} bytes at {c.start}, expected {c.bytes} (file cut short)",
                          c.index)
    return data


def load_stream_chunk(index: StreamIndex, chunk: Union[StreamChunk, int], data: bytes) -> np.ndarray:
    """Decode a chunk's bytes (e.g. the body of its Range response) into its records.

    Parameters
    ----------
    index : StreamIndex
    chunk : StreamChunk or int
        The chunk (or its number in ``index.chunks``).
    data : bytes-like
        Exactly the chunk's bytes ``[start, end)``.

    Returns
    -------
    ndarray, shape [splats], structured (``index.record(chunk.sh_form).dtype``), read-only
        One record per splat, fields as in the bundle (``x y z f_dc_* f_rest_* opacity
        scale_* rot_*``, ``parent`` for hierarchy, SH only for ``sh_upgrade``).

    Raises
    ------
    StreamError
        If ``data`` is not ``bytes`` long or its SHA-256 is not the index's.
    """
    c = _chunk_of(index, chunk)
    data = bytes(data)
    if len(data) != c.bytes:
        raise StreamError("chunks", f"{len(data)} bytes given, expected {c.bytes} (splats {c.splats} x "
                                    f"{index.record(c.sh_form).bytes})", c.index)
    digest = hashlib.sha256(data).hexdigest()
    if digest != c.sha256:
        raise StreamError("chunks", f"sha256 of the {len(data)} bytes is {digest}, the index says {c.sha256} "
                                    f"(corrupt or stale data)", c.index)
    return np.frombuffer(data, dtype=index.record(c.sh_form).dtype, count=c.splats)


def verify_stream(index: StreamIndex) -> int:
    """Hash every chunk's bytes against the index; returns the bytes checked.

    Raises
    ------
    StreamError
        On the first chunk whose bytes are missing or whose hash differs.
    """
    for c in index.chunks:
        load_stream_chunk(index, c, read_chunk_bytes(index, c))
    return index.total_bytes


@dataclasses.dataclass(frozen=True)
class _StreamBundle(Bundle):
    """A :class:`Bundle` whose chunks come from a stream: fetched, size- and hash-checked, decoded."""

    index: Optional[StreamIndex] = None
    fetch: Optional[Callable[[StreamChunk], bytes]] = None

    def chunk(self, index: int) -> np.ndarray:
        c = self.index.chunks[index]
        return load_stream_chunk(self.index, c, self.fetch(c))


def stream_bundle(index: StreamIndex, *, fetch: Optional[Callable[[StreamChunk], bytes]] = None) -> Bundle:
    """The bundle a stream export holds, as a :class:`~l3gs_opt.scene.bundle.Bundle`.

    ``stream_bundle(read_stream(out)).scene(level)`` equals ``read_bundle(src).scene(level)`` bit
    for bit (and so ``level_scene`` and ``parents``): the chunk bytes are the bundle's, decoded by
    the bundle's own reader. Each chunk is fetched when it is needed, then checked against its
    size and hash.

    Parameters
    ----------
    index : StreamIndex
    fetch : callable ``(StreamChunk) -> bytes``, keyword-only
        Returns a chunk's bytes ``[start, end)`` (an HTTP client would send ``chunk.range_header``);
        default: read them from the local data file (:func:`read_chunk_bytes`).
    """
    if fetch is None:
        fetch = lambda c: read_chunk_bytes(index, c)  # noqa: E731
    return _StreamBundle(path=index.path, manifest=index.bundle_manifest(), index=index, fetch=fetch)
