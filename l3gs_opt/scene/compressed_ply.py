"""PlayCanvas compressed PLY (``.compressed.ply``): 16 bytes a splat plus 8-bit SH.

The layout written by PlayCanvas SuperSplat and splat-transform (``write-compressed-ply.ts``,
``compressed-chunk.ts``) and read by the PlayCanvas engine (``decompress-ply.ts``). A binary
little-endian PLY with up to three elements, in this order:

``chunk`` (one row per 256 splats), float32
    ``min_x min_y min_z max_x max_y max_z`` (position bounds), ``min_scale_x .. max_scale_z``
    (bounds of the *log* scales, each clamped to [-20, 20]) and, in newer files,
    ``min_r min_g min_b max_r max_g max_b`` (bounds of the colour ``0.5 + SH_C0 f_dc``). Older
    files have only the first 12; their colour bytes are the colour itself in [0, 1].
``vertex``, uint32 each
    ``packed_position`` and ``packed_scale``: 11-10-11 bits (x in bits 31-21, y 20-11, z 10-0)
    of the value normalised to its chunk's [min, max]; ``packed_rotation``: bits 31-30 the index
    (in ``rot_0..rot_3`` = ``w x y z`` order) of the largest component of the normalised quaternion
    (the quaternion negated if that component is negative), then the other three in index order,
    10 bits each, as ``unorm10(q_i sqrt(2) / 2 + 0.5)``; the largest is decoded as
    ``sqrt(1 - sum of the others' squares)``; ``packed_color``: 8-8-8-8
    ``r g b`` normalised to the chunk's colour bounds, and ``alpha = sigmoid(opacity)``.
``sh`` (only for SH degree > 0), uchar ``f_rest_0 .. f_rest_{3(K-1)-1}``
    The PLY's channel-major ``f_rest`` order; ``byte = clamp(trunc((v / 8 + 0.5) * 256), 0, 255)``,
    decoded as ``(n - 0.5) * 8`` with ``n = 0`` for byte 0, ``1`` for 255 and ``(byte + 0.5) / 256``
    otherwise: a step of 1/32 on [-4, 4].

``unormB(t) = clamp(floor(t (2^B - 1) + 0.5), 0, 2^B - 1)``; a value is normalised as
``(v - min) / (max - min)`` (0 at or below ``min``, 1 at or above ``max``, 0 when
``max - min < 1e-5``) and decoded as ``min (1 - t) + max t``.

Order: the writer sorts the splats in Morton order of their positions before cutting them into
chunks of 256, as splat-transform does (same algorithm: 10 bits per axis over the scene's bounds,
buckets of more than 256 equal codes sorted again inside their own bounds); chunks of nearby
splats have tight bounds, so positions and scales lose less. ``morton=False`` keeps the input
order instead. :func:`morton_order` gives the permutation, so a caller can map splats back.

What is lost: positions and log-scales to 11/10/11 bits of their chunk's range, colour to 8 bits
of the chunk's range, opacity to 8 bits of ``sigmoid`` (alpha bytes 0/255 read as logits of
``ALPHA_EPS``/``1 - ALPHA_EPS``), rotations to 10 bits a component, SH bands to 1/32 with values
clipped to [-4, 4]; object ids, layers and normals are not carried (dropped on write; the PLY
keeps them).
"""

from __future__ import annotations

import math
from pathlib import Path

import numpy as np

from l3gs_opt.input_files import MAX_BINARY_BYTES, check_regular_file, read_bytes
from l3gs_opt.scene.splat_format import SH_C0, alpha_to_logit, sigmoid
from l3gs_opt.scene.splats import SceneError, SplatScene

__all__ = ["CHUNK_SIZE", "CHUNK_PROPERTIES", "VERTEX_PROPERTIES", "morton_order", "write_compressed_ply",
           "read_compressed_ply", "is_compressed_ply"]

#: Splats per chunk row.
CHUNK_SIZE = 256
#: The chunk element's float32 properties (the last six, colour bounds, are absent in older files).
CHUNK_PROPERTIES = ("min_x", "min_y", "min_z", "max_x", "max_y", "max_z",
                    "min_scale_x", "min_scale_y", "min_scale_z", "max_scale_x", "max_scale_y", "max_scale_z",
                    "min_r", "min_g", "min_b", "max_r", "max_g", "max_b")
#: The vertex element's uint32 properties.
VERTEX_PROPERTIES = ("packed_position", "packed_rotation", "packed_scale", "packed_color")
#: Log-scale bounds are clamped to this range (splat-transform: "sometimes values are at infinity").
SCALE_CLAMP = 20.0
#: A chunk range below this normalises every value to 0 (splat-transform's rule).
_MIN_RANGE = 1e-5
_MAX_HEADER = 1 << 16
_TYPES = {"char": "i1", "int8": "i1", "uchar": "u1", "uint8": "u1", "short": "<i2", "int16": "<i2",
          "ushort": "<u2", "uint16": "<u2", "int": "<i4", "int32": "<i4", "uint": "<u4", "uint32": "<u4",
          "float": "<f4", "float32": "<f4", "double": "<f8", "float64": "<f8"}


# ---------------------------------------------------------------------- Morton order
def _part1by2(v: np.ndarray) -> np.ndarray:
    v = v.astype(np.uint32) & 0x3FF
    v = (v ^ (v << 16)) & 0xFF0000FF
    v = (v ^ (v << 8)) & 0x0300F00F
    v = (v ^ (v << 4)) & 0x030C30C3
    v = (v ^ (v << 2)) & 0x09249249
    return v


def _morton_sort(means: np.ndarray, idx: np.ndarray) -> np.ndarray:
    p = means[idx]
    lo, hi = p.min(axis=0), p.max(axis=0)
    span = hi - lo
    if not (span > 0).any():
        return idx
    mul = np.where(span > 0, 1024.0 / np.where(span > 0, span, 1.0), 0.0)
    cell = np.minimum(1023.0, (p - lo) * mul).astype(np.uint32)
    code = (_part1by2(cell[:, 2]) << 2) + (_part1by2(cell[:, 1]) << 1) + _part1by2(cell[:, 0])
    order = np.argsort(code, kind="stable")
    idx, code = idx[order], code[order]
    # Buckets of more than one chunk share a code: sort them again inside their own bounds.
    starts = np.flatnonzero(np.r_[True, code[1:] != code[:-1]])
    ends = np.r_[starts[1:], code.size]
    for s, e in zip(starts, ends):
        if e - s > CHUNK_SIZE:
            idx[s:e] = _morton_sort(means, idx[s:e])
    return idx


def morton_order(means) -> np.ndarray:
    """The permutation that puts splats in Morton (Z-order) of their positions, as splat-transform's
    ``sortMortonOrder``: 10 bits per axis over the bounding box, stable among equal codes, buckets
    of more than :data:`CHUNK_SIZE` equal codes sorted again within their own box.

    Parameters
    ----------
    means : array_like, shape [N, 3]

    Returns
    -------
    ndarray, shape [N], int64
        ``means[order]`` is in Morton order.
    """
    means = np.asarray(means, np.float64)
    idx = np.arange(means.shape[0], dtype=np.int64)
    return _morton_sort(means, idx) if idx.size else idx


# ---------------------------------------------------------------------- writing
def _unorm(t: np.ndarray, bits: int) -> np.ndarray:
    top = (1 << bits) - 1
    return np.clip(np.floor(t * top + 0.5), 0, top).astype(np.uint32)


def _normalise(v: np.ndarray, lo: np.ndarray, hi: np.ndarray) -> np.ndarray:
    """splat-transform's ``normalize`` on [C, 256, ...] values with [C, 1, ...] bounds."""
    rng = hi - lo
    with np.errstate(divide="ignore", invalid="ignore"):
        t = np.where(rng < _MIN_RANGE, 0.0, (v - lo) / np.where(rng == 0, 1.0, rng))
    t = np.where(v >= hi, 1.0, t)
    return np.where(v <= lo, 0.0, t)


def _pack_111011(t: np.ndarray) -> np.ndarray:
    return (_unorm(t[..., 0], 11) << 21) | (_unorm(t[..., 1], 10) << 11) | _unorm(t[..., 2], 11)


def _pack_rotation(quats: np.ndarray) -> np.ndarray:
    q = quats.astype(np.float64)
    q = q / np.linalg.norm(q, axis=1, keepdims=True)
    largest = np.argmax(np.abs(q), axis=1)  # first of equals, as the reference's reduce
    rows = np.arange(q.shape[0])
    q = np.where((q[rows, largest] < 0)[:, None], -q, q)
    out = largest.astype(np.uint32)
    norm = math.sqrt(2.0) * 0.5
    for i in range(4):
        code = _unorm(q[:, i] * norm + 0.5, 10)
        keep = largest != i
        out = np.where(keep, (out << 10) | code, out)
    return out.astype(np.uint32)


def _header(num_chunks: int, n: int, rest: int) -> bytes:
    lines = ["ply", "format binary_little_endian 1.0", "comment Generated by l3gs-opt (PlayCanvas compressed PLY)",
             f"element chunk {num_chunks}", *[f"property float {p}" for p in CHUNK_PROPERTIES],
             f"element vertex {n}", *[f"property uint {p}" for p in VERTEX_PROPERTIES]]
    if rest:
        lines += [f"element sh {n}", *[f"property uchar f_rest_{i}" for i in range(rest)]]
    return ("\n".join(lines + ["end_header"]) + "\n").encode("ascii")


def write_compressed_ply(scene: SplatScene, path, *, morton: bool = True) -> Path:
    """Write ``scene`` as a PlayCanvas compressed PLY (layout and losses in the module docstring).

    Parameters
    ----------
    scene : SplatScene
    path : str or Path
        Destination (conventionally ``*.compressed.ply``); parent folders are created.
    morton : bool, keyword-only
        Sort the splats in :func:`morton_order` first (the reference writers do); ``False`` keeps
        the input order (larger chunk bounds, so more loss, unless the input is already sorted).

    Returns
    -------
    Path
        The path written.
    """
    path = Path(path)
    n = scene.num_splats
    if morton and n:
        scene = scene.subset(morton_order(scene.means))
    num_chunks = -(-n // CHUNK_SIZE)
    pad = num_chunks * CHUNK_SIZE - n
    # The last chunk is filled with copies of its last splat (as the reference): the bounds stay.
    take = np.r_[np.arange(n), np.full(pad, n - 1)] if n else np.zeros(0, np.int64)

    def chunked(a: np.ndarray) -> np.ndarray:
        a = np.asarray(a)[take]
        return a.reshape((num_chunks, CHUNK_SIZE) + a.shape[1:])

    pos = chunked(scene.means).astype(np.float64)
    logs = chunked(scene.log_scales).astype(np.float64)
    # The colour is rounded to float32 before its bounds are taken, as the reference stores it.
    col = chunked((scene.sh[:, 0, :].astype(np.float64) * SH_C0 + 0.5).astype(np.float32)).astype(np.float64)
    p_lo, p_hi = pos.min(axis=1, keepdims=True), pos.max(axis=1, keepdims=True)
    s_lo = np.clip(logs.min(axis=1, keepdims=True), -SCALE_CLAMP, SCALE_CLAMP)
    s_hi = np.clip(logs.max(axis=1, keepdims=True), -SCALE_CLAMP, SCALE_CLAMP)
    c_lo, c_hi = col.min(axis=1, keepdims=True), col.max(axis=1, keepdims=True)
    chunk = np.concatenate([p_lo, p_hi, s_lo, s_hi, c_lo, c_hi], axis=2)[:, 0, :].astype("<f4")

    colour = _normalise(col, c_lo, c_hi)
    alpha = sigmoid(chunked(scene.opacity_logits))
    vertex = np.empty((num_chunks, CHUNK_SIZE, 4), "<u4")
    vertex[..., 0] = _pack_111011(_normalise(pos, p_lo, p_hi))
    vertex[..., 1] = _pack_rotation(chunked(scene.quats).reshape(-1, 4)).reshape(num_chunks, CHUNK_SIZE)
    vertex[..., 2] = _pack_111011(_normalise(logs, s_lo, s_hi))
    vertex[..., 3] = ((_unorm(colour[..., 0], 8) << 24) | (_unorm(colour[..., 1], 8) << 16)
                      | (_unorm(colour[..., 2], 8) << 8) | _unorm(alpha, 8))
    vertex = vertex.reshape(-1, 4)[:n]

    k = scene.sh.shape[1]
    rest = np.ascontiguousarray(scene.sh[:, 1:, :].transpose(0, 2, 1)).reshape(n, 3 * (k - 1)).astype(np.float64)
    sh = np.clip(np.trunc((rest / 8.0 + 0.5) * 256.0), 0, 255).astype(np.uint8)

    path.parent.mkdir(parents=True, exist_ok=True)
    with open(path, "wb") as fh:
        fh.write(_header(num_chunks, n, sh.shape[1]))
        fh.write(chunk.tobytes())
        fh.write(vertex.tobytes())
        fh.write(sh.tobytes())
    return path


# ---------------------------------------------------------------------- reading
def _parse_header(data: bytes, path) -> tuple[list[tuple[str, int, list[tuple[str, str]]]], int]:
    """Elements ``(name, count, [(property, dtype)])`` and the offset of the body."""
    end = data.find(b"end_header", 0, _MAX_HEADER)
    if not data.startswith(b"ply") or end < 0:
        raise SceneError("file", f"{path}: not a PLY file (no 'ply' ... 'end_header' header in the first "
                                 f"{_MAX_HEADER:,} bytes)")
    newline = data.find(b"\n", end)
    if newline < 0:
        raise SceneError("file", f"{path}: truncated after 'end_header'")
    elements: list[tuple[str, int, list[tuple[str, str]]]] = []
    fmt = None
    for no, raw in enumerate(data[:end].decode("ascii", "replace").splitlines()[1:], start=2):
        tok = raw.split()
        if not tok or tok[0] in ("comment", "obj_info"):
            continue
        if tok[0] == "format":
            fmt = tok[1] if len(tok) > 1 else ""
        elif tok[0] == "element" and len(tok) == 3 and tok[2].isdigit():
            elements.append((tok[1], int(tok[2]), []))
        elif tok[0] == "property" and len(tok) == 3 and elements:
            if tok[1] not in _TYPES:
                raise SceneError(tok[2], f"{path}: header line {no}: unknown PLY type {tok[1]!r}")
            elements[-1][2].append((tok[2], _TYPES[tok[1]]))
        elif tok[0] == "property" and len(tok) >= 2 and tok[1] == "list":
            raise SceneError(tok[-1], f"{path}: header line {no}: list properties are not part of a compressed PLY")
        else:
            raise SceneError("file", f"{path}: header line {no}: cannot parse {raw.strip()[:60]!r}")
    if fmt != "binary_little_endian":
        raise SceneError("file", f"{path}: format {fmt!r}: a compressed PLY is binary_little_endian")
    return elements, newline + 1


def is_compressed_ply(path) -> bool:
    """Whether the PLY header of ``path`` declares a ``chunk`` element (a compressed PLY).

    Reads at most the first 64 KiB; a file that is not a readable PLY header gives ``False``.
    """
    path = check_regular_file(path, lambda f, m: SceneError(f, m), max_bytes=MAX_BINARY_BYTES)
    with open(path, "rb") as fh:
        head = fh.read(_MAX_HEADER)
    end = head.find(b"end_header")
    if not head.startswith(b"ply") or end < 0:
        return False
    return any(line.split()[:2] == ["element", "chunk"]
               for line in head[:end].decode("ascii", "replace").splitlines())


def _unpack_unorm(v: np.ndarray, bits: int) -> np.ndarray:
    top = (1 << bits) - 1
    return (v & top).astype(np.float64) / top


def _lerp(lo: np.ndarray, hi: np.ndarray, t: np.ndarray) -> np.ndarray:
    return lo * (1.0 - t) + hi * t


def _unpack_rotation(v: np.ndarray) -> np.ndarray:
    norm = 1.0 / (math.sqrt(2.0) * 0.5)
    a = (_unpack_unorm(v >> 20, 10) - 0.5) * norm
    b = (_unpack_unorm(v >> 10, 10) - 0.5) * norm
    c = (_unpack_unorm(v, 10) - 0.5) * norm
    m = np.sqrt(np.maximum(0.0, 1.0 - (a * a + b * b + c * c)))
    which = (v >> 30).astype(np.int64)
    q = np.empty((v.size, 4))
    for w in range(4):
        others = [a, b, c]
        others.insert(w, m)
        sel = which == w
        q[sel] = np.stack([o[sel] for o in others], axis=1)
    return q


def read_compressed_ply(path, *, ignore_unknown: bool = False) -> SplatScene:
    """Read a PlayCanvas compressed PLY into a :class:`SplatScene` (decoding in the module docstring).

    Parameters
    ----------
    path : str or Path
    ignore_unknown : bool, keyword-only
        Skip elements and properties that are not part of the format instead of refusing them.

    Returns
    -------
    SplatScene
        Splats in file order; SH degree from the ``sh`` element (0 without it); no object ids,
        layers or normals.

    Raises
    ------
    SceneError
        ``file`` for a missing, non-regular or oversized file, a header that does not parse, an
        ASCII PLY or a body shorter than the header claims; ``chunk``/``sh`` for a row count that
        does not match ``vertex``; the property's name for a missing property, a wrong type, an
        unknown property (unless ``ignore_unknown``) or a non-finite chunk bound (with its row).
    """
    data = read_bytes(path, lambda f, m: SceneError(f, m), max_bytes=MAX_BINARY_BYTES)
    elements, offset = _parse_header(data, path)
    arrays: dict[str, np.ndarray] = {}
    for name, count, props in elements:
        dt = np.dtype([(p, t) for p, t in props])
        size = count * dt.itemsize
        if offset + size > len(data):
            raise SceneError("file", f"{path}: header claims {count:,} '{name}' rows of {dt.itemsize} bytes, but only "
                                     f"{len(data) - offset:,} bytes are left (truncated)")
        if name in arrays:
            raise SceneError(name, f"{path}: element declared twice")
        if name in ("chunk", "vertex", "sh"):
            arrays[name] = np.frombuffer(data, dt, count, offset)
        elif not ignore_unknown:
            raise SceneError(name, f"{path}: unknown element (a compressed PLY has chunk, vertex, sh; pass "
                                   f"ignore_unknown=True to skip it)")
        offset += size
    for name in ("chunk", "vertex"):
        if name not in arrays:
            raise SceneError(name, f"{path}: no '{name}' element: not a compressed PLY")
    chunk, vertex = arrays["chunk"], arrays["vertex"]
    n = len(vertex)

    def check(elem: str, rec: np.ndarray, expected: tuple[str, ...], kind: str, required: tuple[str, ...]) -> None:
        names = rec.dtype.names or ()
        for p in required:
            if p not in names:
                raise SceneError(p, f"{path}: missing '{elem}' property")
        for p in names:
            if p in expected:
                if rec.dtype[p] != np.dtype(kind):
                    raise SceneError(p, f"{path}: '{elem}' property of type {rec.dtype[p]}, must be {np.dtype(kind)}")
            elif not ignore_unknown:
                raise SceneError(p, f"{path}: unknown '{elem}' property (pass ignore_unknown=True to skip it)")

    check("chunk", chunk, CHUNK_PROPERTIES, "<f4", CHUNK_PROPERTIES[:12])
    has_colour = all(p in (chunk.dtype.names or ()) for p in CHUNK_PROPERTIES[12:])
    check("vertex", vertex, VERTEX_PROPERTIES, "<u4", VERTEX_PROPERTIES)
    want = -(-n // CHUNK_SIZE)
    if len(chunk) != want:
        raise SceneError("chunk", f"{path}: {len(chunk):,} rows for {n:,} splats, must be "
                                  f"ceil(N / {CHUNK_SIZE}) = {want:,}")
    if "sh" in arrays and len(arrays["sh"]) != n:
        raise SceneError("sh", f"{path}: {len(arrays['sh']):,} rows, must equal the {n:,} vertex rows")
    # after the counts: a wrong count also leaves bytes over, and the count is the better message
    if offset != len(data) and not ignore_unknown:
        raise SceneError("file", f"{path}: {len(data) - offset:,} bytes after the last element")
    for p in CHUNK_PROPERTIES[:18 if has_colour else 12]:
        bad = ~np.isfinite(chunk[p])
        if bad.any():
            raise SceneError(p, f"{path}: {chunk[p][bad][0]} is not finite", (int(np.argmax(bad)),))

    ci = np.arange(n) // CHUNK_SIZE
    bound = lambda p: chunk[p].astype(np.float64)[ci]  # noqa: E731

    def lerp3(packed: np.ndarray, lo: tuple[str, ...], hi: tuple[str, ...]) -> np.ndarray:
        t = (_unpack_unorm(packed >> 21, 11), _unpack_unorm(packed >> 11, 10), _unpack_unorm(packed, 11))
        return np.stack([_lerp(bound(a), bound(b), tj) for a, b, tj in zip(lo, hi, t)], axis=1)

    means = lerp3(vertex["packed_position"], CHUNK_PROPERTIES[0:3], CHUNK_PROPERTIES[3:6])
    log_scales = lerp3(vertex["packed_scale"], CHUNK_PROPERTIES[6:9], CHUNK_PROPERTIES[9:12])
    quats = _unpack_rotation(vertex["packed_rotation"])
    pc = vertex["packed_color"]
    bytes_ = [_unpack_unorm(pc >> s, 8) for s in (24, 16, 8, 0)]
    if has_colour:
        colour = np.stack([_lerp(bound(CHUNK_PROPERTIES[12 + c]), bound(CHUNK_PROPERTIES[15 + c]), bytes_[c])
                           for c in range(3)], axis=1)
    else:
        colour = np.stack(bytes_[:3], axis=1)
    dc = (colour - 0.5) / SH_C0

    sh = dc[:, None, :]
    if "sh" in arrays:
        rec = arrays["sh"]
        m = sum(1 for p in rec.dtype.names or () if p.startswith("f_rest_"))
        if m not in (9, 24, 45):
            raise SceneError("sh", f"{path}: {m} f_rest properties, must be 9, 24 or 45 (SH degree 1-3)")
        names = tuple(f"f_rest_{i}" for i in range(m))
        check("sh", rec, names, "u1", names)
        raw = np.stack([rec[p] for p in names], axis=1).astype(np.float64)
        nrm = np.where(raw == 0, 0.0, np.where(raw == 255, 1.0, (raw + 0.5) / 256.0))
        rest = ((nrm - 0.5) * 8.0).reshape(n, 3, m // 3).transpose(0, 2, 1)
        sh = np.concatenate([sh, rest], axis=1)
    return SplatScene(means=means, log_scales=log_scales, quats=quats,
                      opacity_logits=alpha_to_logit(bytes_[3]), sh=sh)
