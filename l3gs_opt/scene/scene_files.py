"""Scene files by extension: one reader and one writer for every splat format l3gs-opt knows.

* ``.ply``: the reference 3DGS PLY (float32, :mod:`.splats`); lossless; ``4 (14 + 3 K)`` bytes a
  splat (+12 with normals); the only format that keeps object ids, layers and normals.
* ``.compressed.ply``: PlayCanvas compressed PLY (:mod:`.compressed_ply`); lossy;
  ``16 + 3 (K - 1) + 72/256`` bytes a splat.
* ``.splat``: antimatter15 ``.splat`` (:mod:`.splat_format`); lossy, SH degree 0 only; 32 bytes.
* ``.spz``: Niantic SPZ v2/v3 (:mod:`.spz`); lossy; gzip, so the size depends on the data (the
  payload before gzip is ``9 + 1 + 3 + 3 + 4 + 3 (K - 1)`` bytes a splat in v3).

(``K = (sh_degree + 1)^2``; the table as data is :data:`SCENE_FORMATS`.)

``.compressed.ply`` is matched before ``.ply``. A file named just ``.ply`` whose header declares
a ``chunk`` element is a compressed PLY and is read as one; writing ``.ply`` always writes the
float32 layout.

Object ids, layers and normals: only the PLY carries them. Writing a scene with object ids or
layers to a lossy format drops them (the rule is: a lossy format stores what renders, nothing
else); a caller that must keep them writes ``.ply``. :func:`write_scene` says nothing when it
drops them: this docstring and :data:`SCENE_FORMATS` (``keeps_ids``) are the contract.
"""

from __future__ import annotations

import dataclasses
from pathlib import Path
from typing import Callable, Optional

from l3gs_opt.scene.compressed_ply import CHUNK_PROPERTIES, CHUNK_SIZE, is_compressed_ply, \
    read_compressed_ply, write_compressed_ply
from l3gs_opt.scene.splat_format import SPLAT_RECORD_BYTES, read_splat, write_splat
from l3gs_opt.input_files import MAX_BINARY_BYTES, check_regular_file
from l3gs_opt.scene.splats import SceneError, SplatScene, bytes_per_splat, read_ply, write_ply
from l3gs_opt.scene.spz import read_spz, write_spz

__all__ = ["SceneFormat", "SCENE_FORMATS", "scene_format", "read_scene", "write_scene"]


@dataclasses.dataclass(frozen=True)
class SceneFormat:
    """One scene file format.

    Attributes
    ----------
    extension : str
        File name suffix, with the dot (``".compressed.ply"``).
    description : str
    lossy : bool
        Whether a write -> read round trip can change the splats' parameters.
    keeps_ids : bool
        Whether object ids and layers survive a round trip.
    bytes_per_splat : callable or None
        ``f(sh_degree) -> bytes`` per splat of the file (headers and per-chunk data amortised),
        or ``None`` when the size depends on the data (a compressed stream).
    """

    extension: str
    description: str
    lossy: bool
    keeps_ids: bool
    bytes_per_splat: Optional[Callable[[int], float]]


def _compressed_ply_bytes(d: int) -> float:
    return 4 * 4 + 3 * ((d + 1) ** 2 - 1) + 4 * len(CHUNK_PROPERTIES) / CHUNK_SIZE


#: The formats, most specific extension first (the order :func:`scene_format` matches in).
SCENE_FORMATS: tuple[SceneFormat, ...] = (
    SceneFormat(".compressed.ply", "PlayCanvas compressed PLY (11-10-11 bit positions/scales per 256-splat chunk, "
                                   "8-bit colour, 2+30-bit rotation, 8-bit SH)", True, False, _compressed_ply_bytes),
    SceneFormat(".ply", "reference 3DGS PLY, float32 (object ids and layers as extra int32 properties)",
                False, True, lambda d: float(bytes_per_splat(d))),
    SceneFormat(".splat", "antimatter15 .splat (float32 position and scale, 8-bit RGBA and rotation; SH degree 0)",
                True, False, lambda d: float(SPLAT_RECORD_BYTES)),
    SceneFormat(".spz", "Niantic SPZ v2/v3 (gzip of 24-bit positions and 8-bit attributes)", True, False, None),
)


def scene_format(path) -> SceneFormat:
    """The :class:`SceneFormat` of ``path`` by its extension (case-insensitive).

    Raises
    ------
    SceneError
        ``file`` for an extension that is none of :data:`SCENE_FORMATS`, naming them.
    """
    name = Path(path).name.lower()
    for fmt in SCENE_FORMATS:
        if name.endswith(fmt.extension):
            return fmt
    known = ", ".join(f.extension for f in SCENE_FORMATS)
    raise SceneError("file", f"{path}: unknown scene file extension (supported: {known})")


def read_scene(path, *, ignore_unknown: bool = False) -> SplatScene:
    """Read a scene file in any of :data:`SCENE_FORMATS`, chosen by extension.

    A ``.ply`` whose header declares a ``chunk`` element is read as a compressed PLY; a file with
    another extension is read as PLY when it starts with the PLY magic line.

    Parameters
    ----------
    path : str or Path
    ignore_unknown : bool, keyword-only
        Skip unknown PLY properties/elements instead of refusing them (PLY formats only; the
        other formats have no named fields).

    Returns
    -------
    SplatScene

    Raises
    ------
    SceneError
        For an unknown extension (``file``) or anything the format's reader refuses.
    """
    path = check_regular_file(path, lambda f, m: SceneError(f, m), max_bytes=MAX_BINARY_BYTES)
    try:
        ext = scene_format(path).extension
    except SceneError:
        # Another extension: a PLY says so in its first bytes (``scene.bin``, ``teacher.PLY.bak``).
        with open(path, "rb") as fh:
            if fh.read(4) != b"ply\n":
                raise
        ext = ".ply"
    if ext == ".compressed.ply" or (ext == ".ply" and is_compressed_ply(path)):
        return read_compressed_ply(path, ignore_unknown=ignore_unknown)
    if ext == ".ply":
        return read_ply(path, ignore_unknown=ignore_unknown)
    if ext == ".splat":
        return read_splat(path)
    return read_spz(path)


def write_scene(scene: SplatScene, path) -> Path:
    """Write ``scene`` in the format of ``path``'s extension (see :data:`SCENE_FORMATS`).

    Lossy formats drop object ids, layers and normals (module docstring); ``.splat`` also drops
    SH bands above degree 0; ``.compressed.ply`` puts the splats in Morton order.

    Parameters
    ----------
    scene : SplatScene
    path : str or Path
        Destination; parent folders are created.

    Returns
    -------
    Path
        The path written.

    Raises
    ------
    SceneError
        ``file`` for an unknown extension, or what the format's writer refuses (e.g. SPZ
        positions beyond its 24-bit range).
    """
    ext = scene_format(path).extension
    writers = {".compressed.ply": write_compressed_ply, ".ply": write_ply, ".splat": write_splat,
               ".spz": write_spz}
    return writers[ext](scene, path)
