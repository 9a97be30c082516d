"""Splat scenes: the immutable :class:`SplatScene` and PLY I/O in the reference 3DGS layout.

The PLY layout is the one written by the reference 3DGS implementation (Kerbl et al. 2023)
and read by most viewers: one ``vertex`` element with the float32 properties

``x y z [nx ny nz] f_dc_0 f_dc_1 f_dc_2 [f_rest_0 ... f_rest_{3(K-1)-1}] opacity
scale_0 scale_1 scale_2 rot_0 rot_1 rot_2 rot_3``

with ``K = (sh_degree + 1) ** 2`` SH coefficients per colour channel.  ``f_rest_*`` is stored
channel-major (all red coefficients 1..K-1, then green, then blue), ``opacity`` is a logit,
``scale_*`` are natural logs of the standard deviations (world units) and ``rot_*`` is a
quaternion ``(w, x, y, z)`` (not necessarily normalised).  l3gs-opt adds two optional int32
properties: ``object_id`` (segmented scenes) and ``layer`` (layered scenes, 0 = base layer).

Writing keeps only what the scene has: no normals unless the scene carries them, no
``f_rest_*`` for SH degree 0, no ``object_id`` for an unsegmented scene, no ``layer`` for a
single-layer scene.  Reading then writing a file written here is bit-exact.

Reading is bounded: only regular files of at most :data:`l3gs_opt.input_files.MAX_BINARY_BYTES`,
and a header whose element counts the file cannot hold is refused before anything is allocated.
Every error names the PLY property and the vertex row (``x[0]: 1e+300 does not fit in float32``),
never an internal array.
"""

from __future__ import annotations

import dataclasses
import math
import re
from pathlib import Path
from typing import NamedTuple, Optional

import numpy as np

from l3gs_opt.checks import check_count
from l3gs_opt.checks import check_seed as shared_check_seed
from l3gs_opt.errors import L3gsError
from l3gs_opt.input_files import MAX_BINARY_BYTES, check_regular_file

__all__ = ["SceneError", "SplatScene", "read_ply", "write_ply", "read_identity_features", "sh_degree_from_coeffs",
           "bytes_per_splat", "MIN_QUAT_NORM", "MAX_ABS_MEAN", "MAX_LOG_SCALE", "ply_property", "check_seed",
           "check_sh_degree"]

#: Smallest quaternion norm: the renderer normalises in float32, where the squares of smaller
#: components underflow (a norm of 1e-25 renders a wrong rotation).
MIN_QUAT_NORM = 1e-15
#: Longest PLY header read (bytes); the reference layout's is ~1.5 kB.
_MAX_PLY_HEADER = 1 << 20
_PLY_SIZES = {"char": 1, "int8": 1, "uchar": 1, "uint8": 1, "short": 2, "int16": 2, "ushort": 2, "uint16": 2,
              "int": 4, "int32": 4, "uint": 4, "uint32": 4, "float": 4, "float32": 4, "double": 8, "float64": 8}
_FLOAT32_MAX = float(np.finfo(np.float32).max)
#: Largest |coordinate| of a splat centre (world units). Positions are float32 and so is what is
#: computed from them: the camera transform sums three products, ``scene info`` rounds the bounding
#: box by multiplying by 1e4 (inf above 3.4e34), a squared distance between two splats, 3 (2 M)^2,
#: overflows above M = 5.3e18. 1e18 keeps all of these finite; real scenes span at most ~1e4 units.
MAX_ABS_MEAN = 1e18
#: Largest log-scale (natural log of a standard deviation, world units): a splat's covariance holds
#: exp(2 s) in float32, which overflows above s = ln(float32 max) / 2 = 44.36. No lower bound: a
#: very negative s underflows to a point splat, which the renderer's 0.3 px dilation still draws
#: (trained files go down to about -25).
MAX_LOG_SCALE = 0.5 * math.log(_FLOAT32_MAX)

_BASE_PROPS = ("x", "y", "z", "f_dc_0", "f_dc_1", "f_dc_2", "opacity",
               "scale_0", "scale_1", "scale_2", "rot_0", "rot_1", "rot_2", "rot_3")
_NORMAL_PROPS = ("nx", "ny", "nz")
#: Per-splat object id properties read as ``object_ids`` (ours first; the others are what
#: segmentation tools write). A file may carry one of them; written back as ``object_id``.
OBJECT_ID_PROPS = ("object_id", "obj_id", "instance_id", "segment_id")
_REST_RE = re.compile(r"^f_rest_(\d+)$")
#: Gaussian Grouping's per-splat identity encoding (``obj_dc_0..K-1``): not ids, but features
#: whose clusters are the objects (``l3gs_opt.scene.segment.segment_scene(features=...)``).
_IDENTITY_RE = re.compile(r"^obj_dc_(\d+)$")


class SceneError(L3gsError, ValueError):
    """A splat scene or scene file is malformed (bad shape, NaN, missing/unknown PLY property).

    Attributes
    ----------
    field : str
        The field or PLY property at fault (``"means"``, ``"f_rest_7"``, ``"file"``, ...).
    index : tuple of int or None
        The index inside that field when one entry is at fault.
    """

    def __init__(self, field: str, message: str, index: tuple[int, ...] | None = None):
        self.field = field
        self.index = tuple(int(i) for i in index) if index is not None else None
        where = field + "".join(f"[{i}]" for i in self.index or ())
        # "seed = -1: must be ..." (as InstanceError) reads better than "seed: = -1: ..."
        sep = " " if message.startswith("= ") else ": "
        super().__init__(f"{where}{sep}{message}")


def check_seed(seed, field: str = "seed") -> int:
    """``seed`` as an int after checking it is a whole number >= 0 (:func:`l3gs_opt.checks.check_seed`).

    Raises
    ------
    SceneError
        ``seed = -1: must be an integer >= 0`` (the wording of ``instance synth``).
    """
    return shared_check_seed(seed, field=field, error=SceneError)


def check_sh_degree(degree, field: str = "sh_degree") -> int:
    """``degree`` as an int after checking it is an integer 0..3 (not a bool: ``True`` is no degree,
    and not a float: ``1.0`` would fail later as an array size).

    Raises
    ------
    SceneError
        ``sh_degree: 4: must be an integer in [0, 3]``.
    """
    return check_count(field, degree, low=0, high=3, error=SceneError)


def sh_degree_from_coeffs(k: int) -> int:
    """Return the SH degree ``d`` with ``(d + 1) ** 2 == k`` (``k`` in {1, 4, 9, 16}).

    Raises
    ------
    SceneError
        If ``k`` is not the coefficient count of degree 0..3.
    """
    for d in range(4):
        if (d + 1) ** 2 == k:
            return d
    raise SceneError("sh", f"{k} coefficients per channel: must be 1, 4, 9 or 16 (SH degree 0-3)")


def bytes_per_splat(sh_degree: int) -> int:
    """Bytes per splat in the reference float32 PLY layout without normals.

    ``3`` (mean) + ``3 (d+1)^2`` (SH) + ``1`` (opacity) + ``3`` (scale) + ``4`` (rotation)
    float32 values: 56 bytes at degree 0, 236 bytes at degree 3 (the reference file adds
    12 bytes of zero normals).
    """
    return 4 * (3 + 3 * (int(sh_degree) + 1) ** 2 + 1 + 3 + 4)


def _float32_array(field: str, value) -> np.ndarray:
    """``value`` as a contiguous float32 array; ragged rows and anything but real numbers (strings,
    complex, bools, objects) are refused by name rather than parsed or cast (``"1"`` would become 1.0)."""
    try:
        raw = np.asarray(value)
    except (TypeError, ValueError):   # numpy's "inhomogeneous shape" for ragged rows
        raise SceneError(field, "must be an array of numbers with rows of equal length") from None
    if raw.dtype.kind not in "fiu":
        raise SceneError(field, f"dtype {raw.dtype}: must hold real numbers")
    return np.ascontiguousarray(raw, dtype=np.float32)


def _check_finite(field: str, a: np.ndarray) -> None:
    bad = ~np.isfinite(a)
    if bad.any():
        idx = tuple(int(i) for i in np.argwhere(bad)[0])
        raise SceneError(field, f"{a[idx]} is not finite", idx)


def _check_float32_range(means: np.ndarray, log_scales: np.ndarray) -> None:
    """Refuse finite values whose float32 arithmetic overflows (:data:`MAX_ABS_MEAN`,
    :data:`MAX_LOG_SCALE`): they would render or report as inf, not fail."""
    for field, a, bad, rule in (
            ("means", means, np.abs(means) > MAX_ABS_MEAN,
             f"|position| must be <= {MAX_ABS_MEAN:g} world units (MAX_ABS_MEAN): float32 arithmetic on it overflows"),
            ("log_scales", log_scales, log_scales > MAX_LOG_SCALE,
             f"must be <= {MAX_LOG_SCALE:.2f} (MAX_LOG_SCALE): exp(2 scale), the variance, overflows float32")):
        if bad.any():
            idx = tuple(int(i) for i in np.argwhere(bad)[0])
            raise SceneError(field, f"{float(a[idx]):g}: {rule}", idx)


@dataclasses.dataclass(frozen=True, eq=False)
class SplatScene:
    """An immutable, validated set of 3D Gaussian splats (reference 3DGS parameterisation).

    Parameters
    ----------
    means : ndarray, shape [N, 3], float32
        Splat centres in world units.
    log_scales : ndarray, shape [N, 3], float32
        Natural log of the per-axis standard deviations (world units).
    quats : ndarray, shape [N, 4], float32
        Rotation quaternions ``(w, x, y, z)``; normalised when rendering, must be non-zero.
    opacity_logits : ndarray, shape [N], float32
        Opacity before the sigmoid.
    sh : ndarray, shape [N, K, 3], float32
        Spherical-harmonic colour coefficients, ``K = (sh_degree + 1) ** 2``; coefficient 0 is
        the DC term (``f_dc_*`` in the PLY).
    object_ids : ndarray, shape [N], int32, optional
        Object of each splat (segmented scenes); ``None`` for an unsegmented scene.
    layers : ndarray, shape [N], int32, optional
        Layer of each splat, 0 = base layer; ``None`` for a single-layer scene.  An array whose
        entries are all 0 is stored as ``None`` (one layer).
    normals : ndarray, shape [N, 3], float32, optional
        Normals carried by some PLY files (unused by rendering); kept for a bit-exact round trip.

    Raises
    ------
    SceneError
        On a wrong shape or ragged rows, values that are not real numbers (strings, complex,
        bools), a non-finite value, a position beyond :data:`MAX_ABS_MEAN` or a
        log-scale above :data:`MAX_LOG_SCALE` (float32 overflow), a zero quaternion or a negative
        id/layer; the message names the field and the index.
    """

    means: np.ndarray
    log_scales: np.ndarray
    quats: np.ndarray
    opacity_logits: np.ndarray
    sh: np.ndarray
    object_ids: Optional[np.ndarray] = None
    layers: Optional[np.ndarray] = None
    normals: Optional[np.ndarray] = None

    def __post_init__(self) -> None:
        set_ = lambda k, v: object.__setattr__(self, k, v)  # noqa: E731
        means = _float32_array("means", self.means)
        if means.ndim != 2 or means.shape[1] != 3:
            raise SceneError("means", f"shape {means.shape}: must be [N, 3]")
        n = means.shape[0]
        shapes = {"log_scales": (n, 3), "quats": (n, 4), "opacity_logits": (n,)}
        arrays = {"means": means}
        for name, shape in shapes.items():
            a = _float32_array(name, getattr(self, name))
            if a.shape != shape:
                raise SceneError(name, f"shape {a.shape}: must be {list(shape)} (N = {n})")
            arrays[name] = a
        sh = _float32_array("sh", self.sh)
        if sh.ndim != 3 or sh.shape[0] != n or sh.shape[2] != 3:
            raise SceneError("sh", f"shape {sh.shape}: must be [N, K, 3] (N = {n})")
        sh_degree_from_coeffs(sh.shape[1])
        arrays["sh"] = sh
        if self.normals is not None:
            nrm = _float32_array("normals", self.normals)
            if nrm.shape != (n, 3):
                raise SceneError("normals", f"shape {nrm.shape}: must be [N, 3] (N = {n})")
            arrays["normals"] = nrm
        for name, a in arrays.items():
            _check_finite(name, a)
            a.setflags(write=False)
            set_(name, a)
        _check_float32_range(self.means, self.log_scales)
        qn = np.linalg.norm(self.quats.astype(np.float64), axis=1)
        if n and (qn == 0).any():
            raise SceneError("quats", "zero quaternion", (int(np.argmin(qn)),))
        if n and (qn < MIN_QUAT_NORM).any():
            i = int(np.argmin(qn))
            raise SceneError("quats", f"norm {qn[i]:.3g} is below {MIN_QUAT_NORM:g} (MIN_QUAT_NORM): too close to zero "
                                      f"to normalise in float32", (i,))
        for name in ("object_ids", "layers"):
            v = getattr(self, name)
            if v is None:
                continue
            try:
                raw = np.asarray(v)
            except (TypeError, ValueError):   # ragged rows
                raise SceneError(name, "must be an array of integers [N]") from None
            if raw.shape != (n,):
                raise SceneError(name, f"shape {raw.shape}: must be [N] (N = {n})")
            if raw.dtype.kind == "f":
                if not np.all(np.isfinite(raw)) or np.any(raw != np.round(raw)):
                    i = int(np.argmax(~np.isfinite(raw) | (raw != np.round(raw))))
                    raise SceneError(name, f"{raw[i]} is not an integer", (i,))
            elif raw.dtype.kind not in "iub":
                raise SceneError(name, f"dtype {raw.dtype}: must be integer")
            # Range first, on the values as given: a cast to int64 first would wrap 1e20 or a
            # uint64 above 2^63 into a negative number and blame the sign.
            for i, bad, rule in (() if not n else
                                 ((int(np.argmin(raw)), raw.min() < 0, "must be >= 0"),
                                  (int(np.argmax(raw)), raw.max() > np.iinfo(np.int32).max, "must fit in int32"))):
                if bad:
                    shown = f"{raw[i]:g}" if raw.dtype.kind == "f" else f"{raw[i]}"
                    raise SceneError(name, f"{shown}: {rule}", (i,))
            a = np.ascontiguousarray(raw, dtype=np.int32)
            if name == "layers" and not a.any():
                set_(name, None)
                continue
            a.setflags(write=False)
            set_(name, a)

    # ------------------------------------------------------------------ properties
    @property
    def num_splats(self) -> int:
        """Number of splats ``N``."""
        return int(self.means.shape[0])

    def __len__(self) -> int:
        return self.num_splats

    @property
    def sh_degree(self) -> int:
        """SH degree 0..3 of the colour coefficients."""
        return sh_degree_from_coeffs(self.sh.shape[1])

    @property
    def num_objects(self) -> int:
        """Number of distinct object ids (1 for an unsegmented scene)."""
        return 1 if self.object_ids is None else int(np.unique(self.object_ids).size)

    @property
    def num_layers(self) -> int:
        """``max(layer) + 1`` (1 for a single-layer scene)."""
        return 1 if self.layers is None else int(self.layers.max()) + 1

    def subset(self, index) -> "SplatScene":
        """Return the scene restricted to ``index``: a boolean mask [N], integer row indices in
        ``[0, N)`` (in the order given, repeats allowed) or a slice.

        Raises
        ------
        SceneError
            On a mask of the wrong length, a row outside ``[0, N)`` or an index of another type.
        """
        if not isinstance(index, slice):
            index = self._rows(index)
        pick = lambda a: None if a is None else np.asarray(a)[index]  # noqa: E731
        return SplatScene(means=self.means[index], log_scales=self.log_scales[index],
                          quats=self.quats[index], opacity_logits=self.opacity_logits[index],
                          sh=self.sh[index], object_ids=pick(self.object_ids),
                          layers=pick(self.layers), normals=pick(self.normals))

    def _rows(self, index) -> np.ndarray:
        """``index`` of :meth:`subset` as a boolean mask [N] or int64 rows, each in ``[0, N)``: numpy
        would wrap a negative row to the end and fail on a row past it with a bare IndexError."""
        n = self.num_splats
        try:
            a = np.asarray(index)
        except (TypeError, ValueError):
            a = np.asarray(None)
        if a.dtype.kind == "b":
            if a.shape != (n,):
                raise SceneError("index", f"boolean mask of shape {a.shape}: must be [N] (N = {n})")
            return a
        if a.ndim != 1 or (a.dtype.kind not in "iu" and a.size):
            shown = repr(index) if a.size <= 8 else f"{a.dtype} array of shape {a.shape}"
            raise SceneError("index", f"{shown}: must be a boolean mask [N], integer rows [k] or a slice")
        a = a.astype(np.int64)
        bad = (a < 0) | (a >= n)
        if bad.any():
            i = int(np.argmax(bad))
            raise SceneError("index", f"{a[i]} is not a row of the scene (rows 0..{n - 1})" if n else
                             f"{a[i]} is not a row of the scene (it has none)", (i,))
        return a

    def with_sh_degree(self, degree: int) -> "SplatScene":
        """Return the scene truncated (or zero-padded) to SH degree ``degree`` (0..3)."""
        degree = check_sh_degree(degree)
        k = (degree + 1) ** 2
        sh = np.zeros((self.num_splats, k, 3), np.float32)
        m = min(k, self.sh.shape[1])
        sh[:, :m] = self.sh[:, :m]
        return dataclasses.replace(self, sh=sh)

    def __repr__(self) -> str:
        return (f"SplatScene(N={self.num_splats}, sh_degree={self.sh_degree}, "
                f"objects={self.num_objects}, layers={self.num_layers})")


# ---------------------------------------------------------------------- PLY I/O
def _ply_dtype(scene: SplatScene) -> list[tuple[str, str]]:
    names = ["x", "y", "z"]
    if scene.normals is not None:
        names += list(_NORMAL_PROPS)
    names += ["f_dc_0", "f_dc_1", "f_dc_2"]
    names += [f"f_rest_{i}" for i in range(3 * (scene.sh.shape[1] - 1))]
    names += ["opacity", "scale_0", "scale_1", "scale_2", "rot_0", "rot_1", "rot_2", "rot_3"]
    dt = [(n, "<f4") for n in names]
    if scene.object_ids is not None:
        dt.append(("object_id", "<i4"))
    if scene.layers is not None:
        dt.append(("layer", "<i4"))
    return dt


def write_ply(scene: SplatScene, path, *, text: bool = False) -> Path:
    """Write ``scene`` as a PLY file in the reference 3DGS layout (binary little-endian).

    Parameters
    ----------
    scene : SplatScene
    path : str or Path
        Destination; parent folders are created.
    text : bool, keyword-only
        Write ASCII PLY instead (large and slow; for debugging).

    Returns
    -------
    Path
        The path written.
    """
    from plyfile import PlyData, PlyElement

    path = Path(path)
    path.parent.mkdir(parents=True, exist_ok=True)
    n = scene.num_splats
    rec = np.empty(n, dtype=_ply_dtype(scene))
    rec["x"], rec["y"], rec["z"] = scene.means.T
    if scene.normals is not None:
        rec["nx"], rec["ny"], rec["nz"] = scene.normals.T
    for c in range(3):
        rec[f"f_dc_{c}"] = scene.sh[:, 0, c]
    rest = np.ascontiguousarray(scene.sh[:, 1:, :].transpose(0, 2, 1)).reshape(n, -1)
    for i in range(rest.shape[1]):
        rec[f"f_rest_{i}"] = rest[:, i]
    rec["opacity"] = scene.opacity_logits
    for i in range(3):
        rec[f"scale_{i}"] = scene.log_scales[:, i]
    for i in range(4):
        rec[f"rot_{i}"] = scene.quats[:, i]
    if scene.object_ids is not None:
        rec["object_id"] = scene.object_ids
    if scene.layers is not None:
        rec["layer"] = scene.layers
    PlyData([PlyElement.describe(rec, "vertex")], text=text).write(str(path))
    return path


def read_ply(path, *, ignore_unknown: bool = False) -> SplatScene:
    """Read a 3DGS PLY file (reference layout, with or without normals) into a :class:`SplatScene`.

    Parameters
    ----------
    path : str or Path
    ignore_unknown : bool, keyword-only
        Unknown ``vertex`` properties (e.g. ``red``/``green``/``blue`` from other tools) are an
        error by default, so that a misspelt property never silently drops data; set this to
        skip them instead.

    Returns
    -------
    SplatScene

    Raises
    ------
    SceneError
        If the file is missing, not a PLY, truncated or corrupt, lacks a required property,
        has an unknown one (unless ``ignore_unknown``), only some of ``nx ny nz``, text after the
        rows an ASCII header declares, a gap in ``f_rest_*``, a coefficient
        count that is not SH degree 0-3, a non-finite value, or a value whose float32 arithmetic
        overflows (``x y z`` beyond :data:`MAX_ABS_MEAN`, ``scale_*`` above :data:`MAX_LOG_SCALE`).
    """
    path = check_regular_file(path, lambda f, m: SceneError(f, m), max_bytes=MAX_BINARY_BYTES)
    header = _check_ply_header(path)
    table = _VertexTable.mapped(path, header) if header is not None else None
    if table is None:
        table = _VertexTable.parsed(path)
    names, n = table.names, table.n
    missing = [p for p in _BASE_PROPS if p not in names]
    if missing:
        raise SceneError(missing[0], f"{path}: missing vertex property (found {', '.join(names)})")
    rest_idx = sorted(int(m.group(1)) for m in (_REST_RE.match(p) for p in names) if m)
    if rest_idx != list(range(len(rest_idx))):
        gap = next(i for i in range(len(rest_idx) + 1) if i not in rest_idx)
        raise SceneError(f"f_rest_{gap}", f"{path}: missing (f_rest_* must be numbered 0..M-1)")
    if len(rest_idx) % 3:
        raise SceneError("f_rest", f"{path}: {len(rest_idx)} properties, must be a multiple of 3")
    k = 1 + len(rest_idx) // 3
    sh_degree_from_coeffs(k)
    id_props = [p for p in OBJECT_ID_PROPS if p in names]
    if len(id_props) > 1:
        raise SceneError(id_props[1], f"{path}: a second object id property beside {id_props[0]!r}: which one is meant?")
    known = set(_BASE_PROPS) | set(_NORMAL_PROPS) | set(OBJECT_ID_PROPS) | {"layer"} | {f"f_rest_{i}" for i in rest_idx} \
        | {p for p in names if _IDENTITY_RE.match(p)}   # identity encodings: read_identity_features
    unknown = [p for p in names if p not in known]
    if unknown and not ignore_unknown:
        raise SceneError(unknown[0], f"{path}: unknown vertex property (pass ignore_unknown=True / "
                                     f"--ignore-unknown-properties to skip it)")
    has_normals = all(p in names for p in _NORMAL_PROPS)
    if not has_normals and any(p in names for p in _NORMAL_PROPS):   # half a normal would be dropped unsaid
        lacking = [p for p in _NORMAL_PROPS if p not in names]
        raise SceneError(lacking[0], f"{path}: missing beside {', '.join(p for p in _NORMAL_PROPS if p in names)} "
                                     f"(normals need all of nx, ny, nz)")
    groups = {"means": ("x", "y", "z"), "log_scales": ("scale_0", "scale_1", "scale_2"),
              "quats": ("rot_0", "rot_1", "rot_2", "rot_3"), "opacity": ("opacity",),
              # [N, K, 3] order: f_rest_* is channel-major in the file
              "sh": [f"f_dc_{c}" if j == 0 else f"f_rest_{c * (k - 1) + j - 1}" for j in range(k) for c in range(3)]}
    if has_normals:
        groups["normals"] = _NORMAL_PROPS
    # Ids as one column [N] in the file's own type, float or int (some tools write every property
    # as float): SplatScene then judges the values (``layer[0]: 1.5 is not an integer``).
    if id_props:
        groups["object_ids"] = id_props[0]
    if "layer" in names:
        groups["layers"] = "layer"
    got = dict(zip(groups, table.gather(groups.values())))
    means, sh = got["means"], got["sh"].reshape(n, k, 3)
    kwargs = {key: got[key] for key in ("normals", "object_ids", "layers") if key in got}
    try:
        return SplatScene(means=means, log_scales=got["log_scales"], quats=got["quats"],
                          opacity_logits=got["opacity"][:, 0], sh=sh, **kwargs)
    except SceneError as exc:  # name the PLY property, not the internal array
        if exc.field not in _SCENE_FIELDS or not exc.index:
            raise
        field, index = ply_property(exc.field, exc.index, k)
        if exc.field == "object_ids":   # the file's own name for the ids (obj_id, segment_id, ...)
            field = id_props[0]
        message = str(exc).split(": ", 1)[1]
        raise SceneError(field, f"{path}: {message}", index) from None


def read_identity_features(path) -> Optional[np.ndarray]:
    """The identity encodings a Gaussian Grouping PLY carries (``obj_dc_0..K-1``), as float32
    ``[N, K]``, or ``None`` when the file has none. :func:`read_ply` skips them (they are not part of
    a :class:`SplatScene`); segmentation clusters them into objects.

    Raises
    ------
    SceneError
        As :func:`read_ply` for an unreadable file, and for a gap in ``obj_dc_*``.
    """
    path = check_regular_file(path, lambda f, m: SceneError(f, m), max_bytes=MAX_BINARY_BYTES)
    header = _check_ply_header(path)
    table = (_VertexTable.mapped(path, header) if header is not None else None) or _VertexTable.parsed(path)
    idx = sorted(int(m.group(1)) for m in (_IDENTITY_RE.match(p) for p in table.names) if m)
    if not idx:
        return None
    if idx != list(range(len(idx))):
        gap = next(i for i in range(len(idx) + 1) if i not in idx)
        raise SceneError(f"obj_dc_{gap}", f"{path}: missing (obj_dc_* must be numbered 0..K-1)")
    (features,) = table.gather([[f"obj_dc_{i}" for i in idx]])
    bad = ~np.isfinite(features)
    if bad.any():
        row, col = np.argwhere(bad)[0]
        raise SceneError(f"obj_dc_{col}", f"{path}: {features[row, col]} is not finite", (int(row),))
    return features


_SCENE_FIELDS = {"means": ("x", "y", "z"), "log_scales": ("scale_0", "scale_1", "scale_2"),
                 "quats": None, "opacity_logits": ("opacity",), "sh": None, "normals": _NORMAL_PROPS,
                 "object_ids": ("object_id",), "layers": ("layer",)}


def ply_property(field: str, index: tuple[int, ...], coeffs: int) -> tuple[str, tuple[int, ...]]:
    """The PLY property and vertex row of entry ``index`` of a :class:`SplatScene` array ``field``
    (``("means", (5, 1))`` -> ``("y", (5,))``; ``coeffs`` = SH coefficients per channel)."""
    row = (index[0],)
    if field == "quats":
        return ("rot_0..3" if len(index) == 1 else f"rot_{index[1]}"), row
    if field == "sh":
        if len(index) < 3:
            return "f_dc_0..2", row
        k, c = index[1], index[2]
        return (f"f_dc_{c}" if k == 0 else f"f_rest_{c * (coeffs - 1) + k - 1}"), row
    names = _SCENE_FIELDS[field]
    return names[index[1] if len(index) > 1 else 0], row


class _PlyHeader(NamedTuple):
    """What :func:`_check_ply_header` parsed: ``format``, ``elements`` as ``(name, count,
    [(property, type or None for a list)])``, and ``body`` (byte offset of the data)."""

    format: str
    elements: list
    body: int


def _check_ply_header(path: Path) -> Optional[_PlyHeader]:
    """Refuse a header whose element counts the file cannot hold (before anything allocates them).

    Each element takes at least its scalar sizes (binary) or two characters per property (ASCII).
    Returns the parsed header, or ``None`` for a header that does not parse: plyfile then names
    the fault.
    """
    with open(path, "rb") as fh:
        head = fh.read(_MAX_PLY_HEADER)
    end = head.find(b"end_header")
    if end < 0:
        if len(head) == _MAX_PLY_HEADER:
            raise SceneError("file", f"{path}: no 'end_header' in the first {_MAX_PLY_HEADER:,} bytes")
        return None
    newline = head.find(b"\n", end)
    start = newline + 1 if newline >= 0 else len(head)
    body = path.stat().st_size - start
    fmt = ""
    parsed = True
    elements: list[list] = []
    for line in head[:end].decode("ascii", "replace").splitlines():
        tok = line.split()
        if len(tok) >= 2 and tok[0] == "format":
            fmt = tok[1]
        elif len(tok) == 3 and tok[0] == "element" and tok[2].isdigit():
            elements.append([tok[1], int(tok[2]), 0, []])
        elif len(tok) >= 3 and tok[0] == "property" and elements:
            kind = tok[2] if tok[1] == "list" else tok[1]
            size = _PLY_SIZES.get(kind, 1)
            parsed &= kind in _PLY_SIZES
            elements[-1][2] += 2 if fmt == "ascii" else size
            elements[-1][3].append((tok[-1], None if tok[1] == "list" else tok[1]))
        elif tok and tok[0] not in ("ply", "comment", "obj_info"):
            parsed = False
    for name, count, least, props in elements:
        if count * max(least, 1) > body:
            if fmt == "ascii":   # a text body is rows of values, not bytes
                raise SceneError("file", f"{path}: header claims {count:,} '{name}' elements (rows of {len(props)} "
                                         f"values), more than the {body:,} characters of text after the header can "
                                         f"hold (each value takes at least 2: a digit and a separator)")
            raise SceneError("file", f"{path}: header claims {count:,} '{name}' elements, more than the "
                                     f"{body:,} bytes after the header can hold")
        body -= count * max(least, 1)
    if not parsed:
        return None
    return _PlyHeader(fmt, [(e[0], e[1], e[3]) for e in elements], start)


def _check_no_extra_rows(path: Path, rows: int) -> None:
    """Refuse text after the ``rows`` rows an ASCII header declares: plyfile reads that many lines and
    ignores the rest, so an ``element vertex`` count that is too small would drop splats unsaid.
    Lines are read as plyfile reads them (ASCII text, universal newlines), one at a time."""
    import io

    with open(path, "rb") as fh:
        head = fh.read(_MAX_PLY_HEADER)
        end = head.find(b"end_header")
        newline = head.find(b"\n", end)
        if end < 0 or newline < 0:
            return
        fh.seek(newline + 1)
        text = io.TextIOWrapper(fh, "ascii", errors="replace")
        for k, line in enumerate(text):
            if k >= rows and line.strip():
                raise SceneError("file", f"{path}: text after the {rows:,} rows the header declares (line {k + 1} "
                                         f"of the body): is the header's element count too small?")


#: Rows :meth:`_VertexTable.gather` reads at a time (16 MiB at the reference layout's 248 bytes).
_GATHER_ROWS = 1 << 16
_PLY_NUMPY = {"char": "i1", "int8": "i1", "uchar": "u1", "uint8": "u1", "short": "i2", "int16": "i2",
              "ushort": "u2", "uint16": "u2", "int": "i4", "int32": "i4", "uint": "u4", "uint32": "u4",
              "float": "f4", "float32": "f4", "double": "f8", "float64": "f8"}


class _VertexTable:
    """The ``vertex`` element's columns, by property name.

    :meth:`mapped` handles a binary file whose first element is ``vertex`` with scalar properties
    only (every 3DGS writer's layout): no per-splat Python; when every property is 4 bytes (the
    reference layout, ids included), :meth:`gather` reads the rows once, in blocks of
    :data:`_GATHER_ROWS`, and copies each requested group of columns out of each block, so memory
    holds the result plus one block (not the file as well).  Anything else goes through plyfile
    (:meth:`parsed`), which also names the faults of malformed files.
    """

    def __init__(self, names: list, n: int, getter, words: Optional[tuple] = None):
        self.names, self.n = names, n
        self._get, self._words = getter, words

    @classmethod
    def mapped(cls, path: Path, header: _PlyHeader) -> Optional["_VertexTable"]:
        if header.format not in ("binary_little_endian", "binary_big_endian") or not header.elements:
            return None
        name, n, props = header.elements[0]
        if name != "vertex" or any(t is None for _, t in props) or len({p for p, _ in props}) != len(props):
            return None
        order = "<" if header.format == "binary_little_endian" else ">"
        dtype = np.dtype([(p, order + _PLY_NUMPY[t]) for p, t in props])
        if n == 0:
            data = np.zeros(0, dtype)
        else:
            # A plain view of the map: gathers from it are ndarrays, not memmaps.
            data = np.asarray(np.memmap(path, dtype=dtype, mode="r", offset=header.body, shape=(n,)))
        words = None
        if dtype.itemsize == 4 * len(props):   # every property 4 bytes: rows are words
            words = (path, header.body, order, {p: (i, _PLY_NUMPY[t]) for i, (p, t) in enumerate(props)})
        return cls([p for p, _ in props], n, lambda p: data[p], words)

    @classmethod
    def parsed(cls, path: Path) -> "_VertexTable":
        from plyfile import PlyData

        try:
            ply = PlyData.read(str(path))
        except Exception as exc:  # plyfile raises several types on bad input
            raise SceneError("file", f"{path}: not a readable PLY file ({type(exc).__name__}: {exc})") from None
        try:
            vertex = ply["vertex"]
        except KeyError:
            raise SceneError("file", f"{path}: no 'vertex' element") from None
        try:
            data = vertex.data
            names = list(data.dtype.names or ())
            n = len(data)
        except Exception as exc:
            raise SceneError("file", f"{path}: corrupt vertex data ({exc})") from None
        if ply.text:
            _check_no_extra_rows(path, sum(e.count for e in ply.elements))
        return cls(names, n, lambda p: data[p])

    def gather(self, groups) -> list:
        """Each group of property names as one array: float32 ``[N, k]`` for a group of floats,
        the file's integer type ``[N]`` for a group of one integer property, and the file's type
        ``[N]``, float or integer, for a group given as one name (a ``str``)."""
        single = [isinstance(g, str) for g in groups]
        groups = [[g] if one else list(g) for g, one in zip(groups, single)]
        if self._words is None or not self.n:
            return [self.column(g[0], limit=not one) if one or self._kind(g[0]) != "f" else self.block(g)
                    for g, one in zip(groups, single)]
        path, body, order, where = self._words
        width = len(where)
        outs = [np.empty((self.n, len(g)), order + "u4") for g in groups]
        index = [[where[p][0] for p in g] for g in groups]
        with open(path, "rb") as fh:
            fh.seek(body)
            for start in range(0, self.n, _GATHER_ROWS):
                m = min(_GATHER_ROWS, self.n - start)
                raw = fh.read(4 * width * m)
                if len(raw) != 4 * width * m:  # the header check makes this unreachable but for a race
                    raise SceneError("file", f"{path}: ends inside vertex row {start + len(raw) // (4 * width)}")
                rows = np.frombuffer(raw, order + "u4").reshape(m, width)
                for out, ix in zip(outs, index):
                    out[start:start + m] = rows[:, ix]
        result = []
        for g, out, one in zip(groups, outs, single):
            if not out.dtype.isnative:
                out = out.byteswap().view(out.dtype.newbyteorder("="))
            kind = where[g[0]][1]
            result.append(out.view(kind)[:, 0] if one or kind[0] != "f" else out.view(np.float32))
        return result

    def _kind(self, name: str) -> str:
        return np.asarray(self._get(name)[:0]).dtype.kind

    def column(self, name: str, *, limit: bool = True) -> np.ndarray:
        """One property as an array [N] in its file type; with ``limit``, a float that does not fit
        float32 is refused (ids, read without it, are judged by SplatScene's int32 range instead)."""
        a = np.asarray(self._get(name))
        if a.dtype.kind not in "fiu":
            raise SceneError(name, f"dtype {a.dtype} is not numeric")
        if limit and a.dtype.kind == "f" and a.dtype.itemsize > 4:
            # Refused before the cast to float32 makes it inf (non-finite values are named by SplatScene).
            big = np.abs(a) > _FLOAT32_MAX
            if big.any():
                i = int(np.argmax(big))
                raise SceneError(name, f"{float(a[i])!r} does not fit in float32 (|value| <= {_FLOAT32_MAX:.4g})", (i,))
        return a

    def block(self, names) -> np.ndarray:
        """Properties ``names`` as one float32 array [N, len(names)] (column by column)."""
        names = list(names)
        if not self.n:
            return np.zeros((0, len(names)), np.float32)
        return np.stack([self.column(p).astype(np.float32) for p in names], axis=1)