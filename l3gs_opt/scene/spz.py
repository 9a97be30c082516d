"""Niantic SPZ files (``.spz``), versions 2 and 3: gzip, fixed point and 8-bit attributes.

Written against the published layout (nianticlabs/spz ``src/cc/load-spz.cc``, ``splat-types.h``).
No PyPI package was sound to depend on: ``spz`` 0.0.1 is a Rust source distribution that does not
build without crates.io, and ``gsply`` (a third-party numba/C++ library) skips SPZ's coordinate
conversion.

Layout (after gunzip; all little-endian)
----------------------------------------
16-byte header: ``uint32 magic = 0x5053474e`` ("NGSP"), ``uint32 version`` (2 or 3),
``uint32 numPoints``, ``uint8 shDegree`` (0-3 here), ``uint8 fractionalBits``, ``uint8 flags``
(0x1 antialiased, 0x2 extensions follow the header), ``uint8 reserved``; then, attribute by
attribute for all points:

=========  ===================  ============================================================
section    bytes per point      encoding
=========  ===================  ============================================================
positions  9                    3 x signed 24-bit ``round(p * 2^fractionalBits)``
alphas     1                    ``round(255 sigmoid(opacity))``
colours    3                    ``round(f_dc * 0.15 * 255 + 127.5)`` (the DC coefficient)
scales     3                    ``round((log_scale + 10) * 16)``
rotations  3 (v2) or 4 (v3)     v2: ``round(127.5 q + 127.5)`` of ``x y z`` with ``w >= 0``;
                                v3: "smallest three" in 32 bits: bits 31-30 the index of the
                                largest of ``x y z w``, then per other component (in index
                                order) a sign bit and 9 bits of ``|q_i| / sqrt(1/2) * 511``
SH         3 (K - 1)            coefficient-major, colour inner; ``round(128 v) + 128`` rounded
                                to a bucket of 8 (degree-1 bands, 5 bits) or 16 (higher, 4
                                bits), decoded as ``(byte - 128) / 128``
=========  ===================  ============================================================

Every ``round`` is to nearest (half away from zero) then clipped to [0, 255].

Coordinates: SPZ stores RUB axes (x right, y up, z back); the 3DGS PLY convention, used by
:class:`SplatScene`, is RDF (x right, y down, z forward). Like the Niantic library's
``saveSpz(..., from=RDF)`` / ``loadSpz(..., to=RDF)``, the writer converts RDF -> RUB and the
reader RUB -> RDF: ``y`` and ``z`` of positions change sign, so do the ``y`` and ``z`` components
of the quaternions, and each SH coefficient is multiplied by the sign its basis function takes
under ``(x, y, z) -> (x, -y, -z)`` (:data:`SH_FLIP_RDF_RUB`). A file written here opens upright in
the Niantic viewers, and a Niantic file reads here in the PLY's frame.

Writer choices: version 3 by default (``version=2`` for old readers), 12 fractional bits (the
library's choice, 1/4096 world unit) unless a coordinate does not fit in 24 bits, in which case
fewer fractional bits are used (readers take them from the header); no flags. What is lost:
positions to ``2^-fractionalBits``, opacity, colour, log-scales (steps of 1/16 on [-10, 5.94])
and SH to 8 bits or fewer; object ids, layers and normals are not carried (dropped on write; the
PLY keeps them).

Reader limits: at most :data:`MAX_SPZ_POINTS` points (the library's own limit), SH degree 0-3,
versions 2 and 3 (version 1's float16 positions were never released; version 4's zstd
container and files with extensions (flag 0x2) are refused by name). The antialiased flag is
accepted and dropped (:class:`SplatScene` has no mip-splatting switch). The gzip stream is
decompressed only up to the size the header implies, so a gzip bomb is refused, not unpacked.
"""

from __future__ import annotations

import gzip
import math
import struct
import zlib
from pathlib import Path

import numpy as np

from l3gs_opt.input_files import MAX_BINARY_BYTES, read_bytes
from l3gs_opt.scene.splat_format import alpha_to_logit, sigmoid
from l3gs_opt.scene.splats import SceneError, SplatScene

__all__ = ["SPZ_MAGIC", "SPZ_VERSIONS", "MAX_SPZ_POINTS", "SPZ_COLOR_SCALE", "SH_FLIP_RDF_RUB",
           "write_spz", "read_spz", "spz_payload_bytes"]

#: ``"NGSP"`` read as a little-endian uint32.
SPZ_MAGIC = 0x5053474E
#: Versions read and written here.
SPZ_VERSIONS = (2, 3)
#: Most points a file may declare (the Niantic loader's ``maxPointsToRead``).
MAX_SPZ_POINTS = 10_000_000
#: The DC colour scale: ``0.15`` rather than ``SH_C0`` so that colours a little outside [0, 1] fit.
SPZ_COLOR_SCALE = 0.15
#: Sign of SH coefficients 1..15 (bands 1-3, PLY order) under RDF <-> RUB, ``(x, y, z) -> (x, -y, -z)``:
#: the Niantic library's ``flipSh`` with ``x = 1, y = z = -1``.
SH_FLIP_RDF_RUB = np.array([-1, -1, 1, -1, 1, 1, -1, 1, -1, 1, -1, -1, 1, -1, 1], np.float64)
#: Degree-1 SH bytes are kept to 5 bits, higher bands to 4 (the library's defaults).
_SH1_BUCKET, _SH_REST_BUCKET = 8, 16
_FLIP_P = np.array([1.0, -1.0, -1.0])
_FLAG_ANTIALIASED, _FLAG_EXTENSIONS = 0x1, 0x2
_HEADER = struct.Struct("<IIIBBBB")
_SQRT1_2 = math.sqrt(0.5)
_INT24 = 1 << 23


def _round(x: np.ndarray) -> np.ndarray:
    """C's ``std::round`` (half away from zero) in float64."""
    x = np.asarray(x, np.float64)
    return np.sign(x) * np.floor(np.abs(x) + 0.5)


def _to_u8(x: np.ndarray) -> np.ndarray:
    return np.clip(_round(x), 0, 255).astype(np.uint8)


def spz_payload_bytes(num_points: int, sh_degree: int, version: int = 3) -> int:
    """Bytes of the uncompressed payload (header included) of an SPZ file: what gzip then shrinks.

    ``16 + N (9 + 1 + 3 + 3 + r + 3 (K - 1))`` with ``r`` = 3 (v2) or 4 (v3), ``K = (d + 1)^2``.
    """
    rot = 4 if version >= 3 else 3
    return _HEADER.size + num_points * (9 + 1 + 3 + 3 + rot + 3 * ((sh_degree + 1) ** 2 - 1))


# ---------------------------------------------------------------------- writing
def _pack_smallest_three(q: np.ndarray) -> np.ndarray:
    """v3 rotations: [N, 4] unit quaternions ``x y z w`` -> [N] uint32."""
    largest = np.argmax(np.abs(q), axis=1)
    rows = np.arange(q.shape[0])
    negate = q[rows, largest] < 0
    comp = largest.astype(np.uint64)
    for i in range(4):
        neg = ((q[:, i] < 0) ^ negate).astype(np.uint64)
        mag = np.minimum(np.floor(511.0 * (np.abs(q[:, i]) / _SQRT1_2) + 0.5), 511).astype(np.uint64)
        comp = np.where(largest != i, (comp << 10) | (neg << 9) | mag, comp)
    return comp.astype(np.uint32)


def _quantise_sh(v: np.ndarray, bucket: int) -> np.ndarray:
    q = _round(v * 128.0) + 128.0
    q = np.floor((q + bucket // 2) / bucket) * bucket
    return np.clip(q, 0, 255).astype(np.uint8)


def write_spz(scene: SplatScene, path, *, version: int = 3) -> Path:
    """Write ``scene`` (PLY/RDF axes) as a gzip-compressed SPZ file (RUB axes; see the module docstring).

    Parameters
    ----------
    scene : SplatScene
    path : str or Path
        Destination; parent folders are created.
    version : {2, 3}, keyword-only
        3 (default) stores rotations as "smallest three" in 4 bytes; 2 as ``x y z`` in 3 bytes.

    Returns
    -------
    Path
        The path written.

    Raises
    ------
    SceneError
        ``version`` not 2 or 3; ``num_splats`` above :data:`MAX_SPZ_POINTS`; ``means`` with a
        coordinate of magnitude ``2^23`` or more (no fixed-point width fits it).
    """
    if version not in SPZ_VERSIONS or isinstance(version, bool):
        raise SceneError("version", f"{version!r}: must be 2 or 3")
    n = scene.num_splats
    if n > MAX_SPZ_POINTS:
        raise SceneError("num_splats", f"{n:,}: an SPZ file holds at most {MAX_SPZ_POINTS:,} points")
    pos = scene.means.astype(np.float64) * _FLIP_P
    reach = float(np.abs(pos).max()) if n else 0.0
    bits = 12
    while bits > 0 and _round(reach * (1 << bits)) >= _INT24:
        bits -= 1
    if _round(reach * (1 << bits)) >= _INT24:
        i, j = np.unravel_index(int(np.argmax(np.abs(pos))), pos.shape)
        raise SceneError("means", f"{scene.means[i, j]}: beyond the 24-bit fixed point of SPZ (|p| < {_INT24:,})",
                         (i, j))
    fixed = _round(pos * (1 << bits)).astype(np.int64).reshape(-1) & 0xFFFFFF
    positions = np.stack([fixed & 0xFF, (fixed >> 8) & 0xFF, fixed >> 16], axis=1).astype(np.uint8)

    q = scene.quats.astype(np.float64)
    q = q / np.linalg.norm(q, axis=1, keepdims=True)
    q = np.stack([q[:, 1], -q[:, 2], -q[:, 3], q[:, 0]], axis=1)  # (w, x, y, z) RDF -> (x, y, z, w) RUB
    if version >= 3:
        rotations = np.ascontiguousarray(_pack_smallest_three(q).astype("<u4")).view(np.uint8)
    else:
        q = np.where(q[:, 3:4] < 0, -q, q)
        rotations = _to_u8(q[:, :3] * 127.5 + 127.5)

    k = scene.sh.shape[1]
    rest = scene.sh[:, 1:, :].astype(np.float64) * SH_FLIP_RDF_RUB[: k - 1, None]
    sh = np.empty(rest.shape, np.uint8)
    sh[:, :3] = _quantise_sh(rest[:, :3], _SH1_BUCKET)
    sh[:, 3:] = _quantise_sh(rest[:, 3:], _SH_REST_BUCKET)

    body = b"".join([
        _HEADER.pack(SPZ_MAGIC, version, n, scene.sh_degree, bits, 0, 0),
        positions.tobytes(),
        _to_u8(sigmoid(scene.opacity_logits) * 255.0).tobytes(),
        _to_u8(scene.sh[:, 0, :].astype(np.float64) * (SPZ_COLOR_SCALE * 255.0) + 127.5).tobytes(),
        _to_u8((scene.log_scales.astype(np.float64) + 10.0) * 16.0).tobytes(),
        np.ascontiguousarray(rotations).tobytes(),
        sh.tobytes(),
    ])
    path = Path(path)
    path.parent.mkdir(parents=True, exist_ok=True)
    path.write_bytes(gzip.compress(body, compresslevel=6, mtime=0))
    return path


# ---------------------------------------------------------------------- reading
def _gunzip(data: bytes, path, limit: int) -> bytes:
    """The first ``limit + 1`` bytes (at most) of the gzip stream ``data``: one more than the caller
    expects, so that a longer payload is seen without unpacking all of it."""
    d = zlib.decompressobj(16 + zlib.MAX_WBITS)
    try:
        out = d.decompress(data, limit + 1)
    except zlib.error as exc:
        raise SceneError("file", f"{path}: not a readable gzip stream ({exc})") from None
    return out


def _unpack_smallest_three(comp: np.ndarray) -> np.ndarray:
    comp = comp.astype(np.uint64)
    largest = (comp >> 30).astype(np.int64)
    q = np.zeros((comp.size, 4))
    for i in range(3, -1, -1):
        here = largest != i
        mag = (comp & 511).astype(np.float64)
        neg = ((comp >> 9) & 1).astype(bool)
        val = _SQRT1_2 * mag / 511.0
        q[:, i] = np.where(here, np.where(neg, -val, val), 0.0)
        comp = np.where(here, comp >> 10, comp)
    rows = np.arange(comp.size)
    q[rows, largest] = np.sqrt(np.maximum(0.0, 1.0 - (q ** 2).sum(axis=1)))
    return q


def read_spz(path) -> SplatScene:
    """Read an SPZ file (version 2 or 3) into a :class:`SplatScene` in PLY (RDF) axes.

    Parameters
    ----------
    path : str or Path

    Returns
    -------
    SplatScene
        Splats in file order, SH degree from the header, no object ids, layers or normals.

    Raises
    ------
    SceneError
        ``file`` for a missing, non-regular, oversized or non-gzip file, a version-4 (zstd)
        container, or a payload shorter or longer than the header implies (truncated);
        ``magic``, ``version``, ``numPoints``, ``shDegree``, ``fractionalBits`` or ``flags``
        for a header field out of range.
    """
    raw = read_bytes(path, lambda f, m: SceneError(f, m), max_bytes=MAX_BINARY_BYTES)
    if raw[:4] == b"NGSP":
        raise SceneError("file", f"{path}: an SPZ version-4 (zstd) container: only gzip SPZ versions 2 and 3 "
                                 f"are read")
    head = _gunzip(raw, path, _HEADER.size - 1)
    if len(head) < _HEADER.size:
        raise SceneError("file", f"{path}: {len(head)} bytes after gunzip, shorter than the {_HEADER.size}-byte "
                                 f"header (truncated)")
    magic, version, n, degree, bits, flags, _ = _HEADER.unpack(head[:_HEADER.size])
    if magic != SPZ_MAGIC:
        raise SceneError("magic", f"{path}: {magic:#010x}, must be {SPZ_MAGIC:#010x} ('NGSP'): not an SPZ file")
    if version not in SPZ_VERSIONS:
        raise SceneError("version", f"{path}: {version}, only versions 2 and 3 are read")
    if n > MAX_SPZ_POINTS:
        raise SceneError("numPoints", f"{path}: {n:,}, more than {MAX_SPZ_POINTS:,} (MAX_SPZ_POINTS)")
    if degree > 3:
        raise SceneError("shDegree", f"{path}: {degree}, must be 0-3")
    if bits > 23:
        raise SceneError("fractionalBits", f"{path}: {bits}, must be 0-23 for 24-bit positions")
    if flags & _FLAG_EXTENSIONS:
        raise SceneError("flags", f"{path}: {flags:#04x} has extensions (0x2), which are not read")
    if flags & ~(_FLAG_ANTIALIASED | _FLAG_EXTENSIONS):
        raise SceneError("flags", f"{path}: {flags:#04x} has unknown bits")
    size = spz_payload_bytes(n, degree, version)
    body = _gunzip(raw, path, size)
    if len(body) != size:
        raise SceneError("file", f"{path}: {len(body):,}{'+' if len(body) > size else ''} bytes after gunzip, the "
                                 f"header ({n:,} points, SH degree {degree}, version {version}) implies {size:,}"
                                 f"{' (truncated)' if len(body) < size else ''}")
    k = (degree + 1) ** 2
    rot_bytes = 4 if version >= 3 else 3
    off = _HEADER.size
    sections = {}
    for name, width in (("positions", 9), ("alphas", 1), ("colors", 3), ("scales", 3),
                        ("rotations", rot_bytes), ("sh", 3 * (k - 1))):
        sections[name] = np.frombuffer(body, np.uint8, n * width, off).reshape(n, width)
        off += n * width

    p = sections["positions"].reshape(n, 3, 3).astype(np.int64)
    fixed = p[..., 0] | (p[..., 1] << 8) | (p[..., 2] << 16)
    fixed = np.where(fixed & 0x800000, fixed - (1 << 24), fixed)
    means = fixed.astype(np.float64) / (1 << bits) * _FLIP_P

    if version >= 3:
        q = _unpack_smallest_three(np.ascontiguousarray(sections["rotations"]).view("<u4").reshape(n))
    else:
        xyz = sections["rotations"].astype(np.float64) / 127.5 - 1.0
        w = np.sqrt(np.maximum(0.0, 1.0 - (xyz ** 2).sum(axis=1)))
        q = np.concatenate([xyz, w[:, None]], axis=1)
    quats = np.stack([q[:, 3], q[:, 0], -q[:, 1], -q[:, 2]], axis=1)  # (x, y, z, w) RUB -> (w, x, y, z) RDF

    dc = (sections["colors"].astype(np.float64) / 255.0 - 0.5) / SPZ_COLOR_SCALE
    rest = (sections["sh"].reshape(n, k - 1, 3).astype(np.float64) - 128.0) / 128.0
    rest = rest * SH_FLIP_RDF_RUB[: k - 1, None]
    return SplatScene(means=means, log_scales=sections["scales"].astype(np.float64) / 16.0 - 10.0, quats=quats,
                      opacity_logits=alpha_to_logit(sections["alphas"][:, 0].astype(np.float64) / 255.0),
                      sh=np.concatenate([dc[:, None, :], rest], axis=1))
