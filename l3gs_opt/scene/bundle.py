"""Deliverable bundles: a directory of splat chunks and a schema-versioned JSON manifest.

Layout::

    BUNDLE/manifest.json
    BUNDLE/chunks/o{object}_l{level}_{sh_form}.bin

A **chunk** is the unit a scheduler sends: the splats of one object in one layer (layered
representations) or one version (separate representations), in one SH form.  Each ``.bin`` is
a headerless array of little-endian records whose fields are listed in the manifest (the
reference 3DGS PLY properties, in PLY order, without normals), so its ``bytes`` are exactly
``splats x record bytes``.  Object ids and layer numbers are not stored per splat: the chunk
says which object and level it holds.

Bytes per splat (float32 fields; ``K = (D + 1)^2`` SH coefficients per channel):

=================  ========================================================  =====================
SH form            fields                                                     bytes (D = 0/1/2/3)
=================  ========================================================  =====================
``full``           x y z, f_dc_0..2, f_rest_0..3(K-1)-1, opacity,           56 / 92 / 152 / 236
                   scale_0..2, rot_0..3
``compact``        as ``full`` at the compact degree (``distill``)            56 / 92 / 152 / 236
``sh_upgrade``     f_dc_0..2, f_rest_* only (``distill``: replaces the       12 / 48 / 108 / 192
                   compact SH of the same splats, same row order)
``hierarchy``      adds ``parent`` (int32, 4 bytes): row of the parent in    +4
                   the same object's previous version, -1 if none
=================  ========================================================  =====================

Only what the scene needs is kept: SH bands above the highest band with a non-zero
coefficient are dropped (``sh_degree`` in the manifest), and an unsegmented scene has a single
object ``0``.

Manifest (``schema = "l3gs-opt/bundle@1"``; unknown keys are an error):

``variant`` (layered / separate / sort / distill / hierarchy), ``representation`` (layered:
level ``l`` adds splats on top of levels ``< l``; separate: level ``l`` is a standalone
version), ``segmented``, ``sh_degree``, ``compact_sh_degree`` (distill, else null),
``levels`` (per level: ``splats`` in that level and ``cumulative_splats``), ``objects`` (ids),
``bytes_per_splat`` (per SH form present), ``chunks`` (per chunk: ``object``, ``level``,
``sh_form``, ``sh_degree``, ``splats``, ``bytes``, ``file``, ``offset`` (bytes), ``fields``
(``[name, dtype]`` pairs)), ``build`` (free-form provenance: teacher, sizes, timings).

Reading checks the manifest before any chunk is read: strict JSON, every key's type and range
(counts and offsets whole numbers >= 0, levels and objects that exist, the record fields of the
chunk's SH form), and every chunk ``file`` a regular file *inside* the bundle folder (after
resolving ``..`` and symbolic links) holding ``offset + bytes`` bytes.
"""

from __future__ import annotations

import dataclasses
import json
from pathlib import Path
from typing import Optional, Sequence

import numpy as np

from l3gs_opt.errors import L3gsError
from l3gs_opt.input_files import check_regular_file, read_json
from l3gs_opt.scene.splats import SceneError, SplatScene, bytes_per_splat, ply_property

__all__ = ["BUNDLE_SCHEMA", "VARIANTS", "REPRESENTATION", "SH_FORMS", "BundleError", "Bundle",
           "effective_sh_degree", "record_fields", "write_bundle", "read_bundle", "split_layers"]

BUNDLE_SCHEMA = "l3gs-opt/bundle@1"
VARIANTS = ("layered", "separate", "sort", "distill", "hierarchy")
#: Representation of each variant (the scheduler's Problem I/III vs II/IV).
REPRESENTATION = {"layered": "layered", "sort": "layered", "distill": "layered",
                  "separate": "separate", "hierarchy": "separate"}
SH_FORMS = ("full", "compact", "sh_upgrade")
_MANIFEST_KEYS = {"schema", "variant", "representation", "segmented", "sh_degree", "compact_sh_degree",
                  "levels", "objects", "bytes_per_splat", "chunks", "build"}
_CHUNK_KEYS = {"object", "level", "sh_form", "sh_degree", "splats", "bytes", "file", "offset", "fields"}
_GEOM = ("x", "y", "z")
_TAIL = ("opacity", "scale_0", "scale_1", "scale_2", "rot_0", "rot_1", "rot_2", "rot_3")


class BundleError(L3gsError, ValueError):
    """A bundle (or the data given to write one) is malformed; names the field and index."""

    def __init__(self, field: str, message: str, index: Optional[int] = None):
        self.field = field
        self.index = index
        super().__init__(f"{field}{'' if index is None else f'[{index}]'}: {message}")


def effective_sh_degree(sh: np.ndarray) -> int:
    """Highest SH degree with a non-zero coefficient in ``sh`` [N, K, 3] (0 if only DC is used)."""
    sh = np.asarray(sh)
    for deg in (3, 2, 1):
        lo, hi = deg * deg, (deg + 1) ** 2
        if sh.shape[1] >= hi and np.any(sh[:, lo:hi] != 0):
            return deg
    return 0


def _sh_names(degree: int) -> list[str]:
    k = (degree + 1) ** 2
    return ["f_dc_0", "f_dc_1", "f_dc_2"] + [f"f_rest_{i}" for i in range(3 * (k - 1))]


def record_fields(sh_form: str, sh_degree: int, *, parent: bool = False) -> list[tuple[str, str]]:
    """``[(name, dtype)]`` of one record of a chunk (see the module docstring)."""
    if sh_form == "sh_upgrade":
        names = _sh_names(sh_degree)
    else:
        names = list(_GEOM) + _sh_names(sh_degree) + list(_TAIL)
    fields = [(n, "<f4") for n in names]
    if parent:
        fields.append(("parent", "<i4"))
    return fields


def _records(scene: SplatScene, rows: np.ndarray, sh_form: str, degree: int,
             parent: Optional[np.ndarray]) -> np.ndarray:
    dt = np.dtype(record_fields(sh_form, degree, parent=parent is not None))
    rec = np.zeros(len(rows), dtype=dt)
    k = (degree + 1) ** 2
    sh = scene.sh[rows][:, :k]
    for c in range(3):
        rec[f"f_dc_{c}"] = sh[:, 0, c]
    rest = np.ascontiguousarray(sh[:, 1:, :].transpose(0, 2, 1)).reshape(len(rows), 3 * (k - 1))  # PLY: channel-major
    for i in range(rest.shape[1]):
        rec[f"f_rest_{i}"] = rest[:, i]
    if sh_form != "sh_upgrade":
        for i, n in enumerate(_GEOM):
            rec[n] = scene.means[rows, i]
        rec["opacity"] = scene.opacity_logits[rows]
        for i in range(3):
            rec[f"scale_{i}"] = scene.log_scales[rows, i]
        for i in range(4):
            rec[f"rot_{i}"] = scene.quats[rows, i]
    if parent is not None:
        rec["parent"] = parent
    return rec


def _sh_from_records(rec: np.ndarray, degree: int) -> np.ndarray:
    n, k = len(rec), (degree + 1) ** 2
    dc = np.stack([rec[f"f_dc_{c}"] for c in range(3)], 1)
    rest = np.stack([rec[f"f_rest_{i}"] for i in range(3 * (k - 1))], 1) if k > 1 else np.zeros((n, 0), np.float32)
    return np.concatenate([dc[:, None, :], rest.reshape(n, 3, k - 1).transpose(0, 2, 1)], axis=1)


def _check_levels(levels: Sequence[SplatScene], representation: str) -> None:
    if len(levels) == 0:
        raise BundleError("levels", "at least one level is needed")
    seg = [s.object_ids is not None for s in levels]
    for i, s in enumerate(levels):
        if not isinstance(s, SplatScene):
            raise BundleError("levels", f"{type(s).__name__} is not a SplatScene", i)
        if s.num_splats == 0 and representation == "separate":
            raise BundleError("levels", "a version with no splats", i)
        if seg[i] != seg[0]:
            raise BundleError("levels", "mixes segmented and unsegmented scenes", i)
        if s.sh.shape[1] != levels[0].sh.shape[1]:
            raise BundleError("levels", f"SH degree {s.sh_degree} differs from level 0's {levels[0].sh_degree}", i)


def write_bundle(path, levels: Sequence[SplatScene], *, variant: str,
                 compact_sh: Optional[Sequence[np.ndarray]] = None,
                 parents: Optional[Sequence[np.ndarray]] = None, build: Optional[dict] = None) -> Path:
    """Write a bundle.

    Parameters
    ----------
    path : str or Path
        Bundle directory (created; an existing ``manifest.json`` there is replaced).
    levels : sequence of SplatScene
        Layered variants: the splats *added* by each layer; separate variants: each whole version.
        Object ids (when present) select each splat's chunk.
    variant : str, keyword-only
        One of :data:`VARIANTS`.
    compact_sh : sequence of ndarray [n_l, k, 3], keyword-only
        ``distill`` only: compact coefficients of each level's splats (row-aligned with ``levels``).
    parents : sequence of ndarray [n_l], int, keyword-only
        ``hierarchy`` only: per splat of version ``l >= 1``, the row (within ``levels[l-1]``) of its
        parent, which must belong to the same object (-1: none); ``parents[0]`` is ignored.
    build : dict, keyword-only
        Provenance stored as ``manifest["build"]`` (JSON-serialisable).

    Returns
    -------
    Path
        The manifest path.

    Raises
    ------
    BundleError
        On an unknown variant, missing/extra distill or hierarchy data, or inconsistent levels.
    """
    if variant not in VARIANTS:
        raise BundleError("variant", f"{variant!r} must be one of {', '.join(VARIANTS)}")
    rep = REPRESENTATION[variant]
    _check_levels(levels, rep)
    if (compact_sh is not None) != (variant == "distill"):
        raise BundleError("compact_sh", "is required for variant 'distill' and only there")
    if (parents is not None) != (variant == "hierarchy"):
        raise BundleError("parents", "is required for variant 'hierarchy' and only there")
    segmented = levels[0].object_ids is not None
    deg = max(effective_sh_degree(s.sh) for s in levels)
    ids_of = [np.zeros(s.num_splats, np.int64) if not segmented else s.object_ids.astype(np.int64) for s in levels]
    objects = sorted(set(np.concatenate(ids_of).tolist())) if segmented else [0]
    cdeg = None
    if compact_sh is not None:
        if len(compact_sh) != len(levels):
            raise BundleError("compact_sh", f"{len(compact_sh)} arrays for {len(levels)} levels")
        cdeg = {1: 0, 4: 1, 9: 2, 16: 3}.get(np.asarray(compact_sh[0]).shape[1])
        for i, c in enumerate(compact_sh):
            c = np.asarray(c)
            if c.ndim != 3 or c.shape[0] != levels[i].num_splats or c.shape[2] != 3 or cdeg is None \
                    or c.shape[1] != (cdeg + 1) ** 2:
                raise BundleError("compact_sh", f"shape {c.shape} must be [{levels[i].num_splats}, k, 3]", i)
        if cdeg >= deg:
            raise BundleError("compact_sh", f"compact degree {cdeg} must be below the scene's used degree {deg}")
    if parents is not None:
        if len(parents) != len(levels):
            raise BundleError("parents", f"{len(parents)} arrays for {len(levels)} versions")
        for i in range(1, len(levels)):
            p = np.asarray(parents[i])
            if p.shape != (levels[i].num_splats,):
                raise BundleError("parents", f"shape {p.shape} must be [{levels[i].num_splats}]", i)
            if p.size and (p.min() < -1 or p.max() >= levels[i - 1].num_splats):
                raise BundleError("parents", f"entries must be -1 or rows of version {i - 1}", i)
            ok = p >= 0
            if np.any(ids_of[i - 1][p[ok]] != ids_of[i][ok]):
                raise BundleError("parents", "a parent belongs to another object", i)
    root = Path(path)
    (root / "chunks").mkdir(parents=True, exist_ok=True)
    for old in (root / "chunks").glob("*.bin"):  # a rewrite must not leave chunks of an earlier bundle
        old.unlink()
    chunks = []
    for lvl, scene in enumerate(levels):
        ids = ids_of[lvl]
        prev_local = _local_rows(ids_of[lvl - 1], objects) if variant == "hierarchy" and lvl > 0 else None
        for j in objects:
            rows = np.flatnonzero(ids == j)
            if rows.size == 0:
                continue  # an object absent from this level: no chunk (nothing to send)
            if variant == "distill":
                cs = dataclasses.replace(scene.subset(rows), sh=np.asarray(compact_sh[lvl])[rows])
                forms = [("compact", cs, np.arange(rows.size), cdeg, None), ("sh_upgrade", scene, rows, deg, None)]
            else:
                par = None
                if variant == "hierarchy":
                    par = np.full(rows.size, -1, np.int32)
                    if prev_local is not None:
                        p = np.asarray(parents[lvl])[rows]
                        par[p >= 0] = prev_local[p[p >= 0]]  # global row of version l-1 -> row in its chunk
                forms = [("full", scene, rows, deg, par)]
            for form, src, r, d, par in forms:
                rec = _records(src, r, form, d, par)
                rel = f"chunks/o{j}_l{lvl}_{form}.bin"
                (root / rel).write_bytes(rec.tobytes())
                chunks.append({"object": int(j), "level": lvl, "sh_form": form, "sh_degree": int(d),
                               "splats": int(rows.size), "bytes": int(rec.nbytes), "file": rel, "offset": 0,
                               "fields": [list(f) for f in record_fields(form, d, parent=par is not None)]})
    cum = np.cumsum([s.num_splats for s in levels])
    level_info = [{"level": i, "splats": int(s.num_splats),
                   "cumulative_splats": int(cum[i]) if rep == "layered" else int(s.num_splats)}
                  for i, s in enumerate(levels)]
    if variant == "distill":
        bps = {"compact": bytes_per_splat(cdeg), "sh_upgrade": 12 * (deg + 1) ** 2}
    else:
        bps = {"full": bytes_per_splat(deg) + (4 if variant == "hierarchy" else 0)}
    manifest = {"schema": BUNDLE_SCHEMA, "variant": variant, "representation": rep, "segmented": segmented,
                "sh_degree": deg, "compact_sh_degree": cdeg, "levels": level_info, "objects": objects,
                "bytes_per_splat": bps, "chunks": chunks, "build": build or {}}
    out = root / "manifest.json"
    out.write_text(json.dumps(manifest, indent=1))
    return out


def split_layers(scene: SplatScene) -> list[SplatScene]:
    """The per-layer splat sets of a layered scene (rows tagged ``layers == l``), layer tags dropped."""
    tags = np.zeros(scene.num_splats, np.int32) if scene.layers is None else scene.layers
    return [dataclasses.replace(scene.subset(np.flatnonzero(tags == lvl)), layers=None)
            for lvl in range(scene.num_layers)]


def _local_rows(ids: np.ndarray, objects) -> np.ndarray:
    """Row of each splat inside its object's chunk."""
    local = np.zeros(ids.size, np.int64)
    for j in objects:
        rows = np.flatnonzero(ids == j)
        local[rows] = np.arange(rows.size)
    return local


def _concat(parts: Sequence[SplatScene]) -> SplatScene:
    """Splats of ``parts`` stacked in order (object ids kept when all have them; layers dropped)."""
    cat = lambda k: np.concatenate([getattr(p, k) for p in parts])  # noqa: E731
    ids = cat("object_ids") if all(p.object_ids is not None for p in parts) else None
    return SplatScene(means=cat("means"), log_scales=cat("log_scales"), quats=cat("quats"),
                      opacity_logits=cat("opacity_logits"), sh=cat("sh"), object_ids=ids)


@dataclasses.dataclass(frozen=True)
class Bundle:
    """A bundle read from disk: its manifest and accessors for chunks and assembled scenes."""

    path: Path
    manifest: dict

    @property
    def variant(self) -> str:
        return self.manifest["variant"]

    @property
    def num_levels(self) -> int:
        return len(self.manifest["levels"])

    def chunk(self, index: int) -> np.ndarray:
        """The records of chunk ``index`` (structured array; fields as in the manifest)."""
        c = self.manifest["chunks"][index]
        dt = np.dtype([tuple(f) for f in c["fields"]])
        path = check_regular_file(self.path / c["file"], lambda f, m: BundleError(f, m, index), field="chunks")
        with open(path, "rb") as fh:
            fh.seek(c["offset"])
            raw = fh.read(c["bytes"])
        if len(raw) != c["bytes"]:
            raise BundleError("chunks", f"{c['file']}: shorter than offset + bytes", index)
        return np.frombuffer(raw, dtype=dt, count=c["splats"])

    def _find(self, obj: int, level: int, form: str) -> Optional[int]:
        for i, c in enumerate(self.manifest["chunks"]):
            if (c["object"], c["level"], c["sh_form"]) == (obj, level, form):
                return i
        return None

    def level_scene(self, level: int, *, sh_form: str = "full") -> SplatScene:
        """The splats stored for ``level`` alone (a layer's additions or a whole version).

        ``sh_form="compact"`` (distill) gives the compact form; ``"full"`` the full form (for
        distill: the compact chunk's geometry with the ``sh_upgrade`` chunk's SH).
        """
        m = self.manifest
        if not 0 <= level < self.num_levels:
            raise BundleError("level", f"{level} must be in [0, {self.num_levels})")
        if sh_form not in ("full", "compact"):
            raise BundleError("sh_form", f"{sh_form!r} must be 'full' or 'compact'")
        if sh_form == "compact" and m["variant"] != "distill":
            raise BundleError("sh_form", "'compact' exists only in distill bundles")
        geo_form = "compact" if m["variant"] == "distill" else "full"
        parts = []
        for j in m["objects"]:
            gi = self._find(j, level, geo_form)
            if gi is None:
                continue
            rec = self.chunk(gi)
            sh = _sh_from_records(rec, m["chunks"][gi]["sh_degree"])
            if m["variant"] == "distill" and sh_form == "full":
                ui = self._find(j, level, "sh_upgrade")
                if ui is None or m["chunks"][ui]["splats"] != len(rec):
                    raise BundleError("chunks", f"object {j}, level {level}: no sh_upgrade chunk of "
                                                f"{len(rec)} splats beside the compact one", gi)
                sh = _sh_from_records(self.chunk(ui), m["sh_degree"])
            col = lambda names: np.stack([rec[n] for n in names], 1)  # noqa: E731
            try:
                parts.append(SplatScene(means=col(_GEOM), log_scales=col(("scale_0", "scale_1", "scale_2")),
                                        quats=col(("rot_0", "rot_1", "rot_2", "rot_3")),
                                        opacity_logits=np.array(rec["opacity"]), sh=sh,
                                        object_ids=np.full(len(rec), j, np.int32) if m["segmented"] else None))
            except SceneError as exc:  # a corrupt chunk: name it, its record and field
                where = str(exc)
                if exc.index:
                    field, row = ply_property(exc.field, exc.index, sh.shape[1])
                    where = f"record {row[0]}: {field}: {where.split(': ', 1)[1]}"
                raise BundleError("chunks", f"{m['chunks'][gi]['file']}: {where}", gi) from None
        if not parts:
            raise BundleError("level", f"{level}: no chunks")
        return _concat(parts)

    def scene(self, level: int, *, sh_form: str = "full") -> SplatScene:
        """The scene a client holds at ``level``: layers ``0..level`` stacked (tagged with
        ``layers``) for layered bundles, version ``level`` for separate ones."""
        if self.manifest["representation"] == "separate":
            return self.level_scene(level, sh_form=sh_form)
        parts = [self.level_scene(i, sh_form=sh_form) for i in range(level + 1)]
        layers = np.concatenate([np.full(p.num_splats, i, np.int32) for i, p in enumerate(parts)])
        return dataclasses.replace(_concat(parts), layers=layers)

    def parents(self, level: int, obj: int) -> np.ndarray:
        """``hierarchy``: parent rows (in version ``level - 1`` of object ``obj``) of that chunk's splats."""
        if self.variant != "hierarchy":
            raise BundleError("variant", f"{self.variant!r} bundles have no parents")
        i = self._find(obj, level, "full")
        if i is None:
            raise BundleError("chunks", f"no chunk for object {obj}, level {level}")
        return np.array(self.chunk(i)["parent"])


def _bundle_error(field: str, message: str) -> BundleError:
    return BundleError(field, message)


def _whole(value, minimum: int = 0) -> bool:
    return isinstance(value, int) and not isinstance(value, bool) and value >= minimum


def read_bundle(path) -> Bundle:
    """Read and check a bundle's manifest (schema, keys, types, chunk sizes against the files).

    Raises
    ------
    BundleError
        On a missing or non-regular manifest, strict-JSON faults, wrong schema, an unknown or
        missing key, a value of the wrong type or range, a chunk whose ``bytes`` disagree with
        ``splats x record size`` or with the file, or a chunk file outside the bundle folder.
    """
    root = Path(path)
    m = read_json(root / "manifest.json", _bundle_error, field="manifest")
    if not isinstance(m, dict) or m.get("schema") != BUNDLE_SCHEMA:
        raise BundleError("schema", f"{m.get('schema') if isinstance(m, dict) else m!r} must be {BUNDLE_SCHEMA!r}")
    unknown = sorted(set(m) - _MANIFEST_KEYS)
    if unknown:
        raise BundleError(unknown[0], "unknown manifest key")
    missing = sorted(_MANIFEST_KEYS - set(m))
    if missing:
        raise BundleError(missing[0], "missing manifest key")
    _check_manifest_values(m)
    inside = root.resolve()
    hierarchy = m["variant"] == "hierarchy"
    forms = ("compact", "sh_upgrade") if m["variant"] == "distill" else ("full",)
    for i, c in enumerate(m["chunks"]):
        if not isinstance(c, dict):
            raise BundleError("chunks", f"{c!r} must be an object", i)
        bad = sorted(set(c) ^ _CHUNK_KEYS)
        if bad:
            raise BundleError("chunks", f"key {bad[0]!r} unknown or missing", i)
        for key in ("splats", "bytes", "offset", "object", "level", "sh_degree"):
            if not _whole(c[key]):
                raise BundleError("chunks", f"{key} {c[key]!r} must be a whole number >= 0", i)
        if c["object"] not in m["objects"]:
            raise BundleError("chunks", f"object {c['object']!r} is not in 'objects'", i)
        if c["level"] >= len(m["levels"]):
            raise BundleError("chunks", f"level {c['level']} must be below {len(m['levels'])} (the levels)", i)
        if c["sh_form"] not in forms or c["sh_degree"] > 3:
            raise BundleError("chunks", f"sh_form {c['sh_form']!r} / sh_degree {c['sh_degree']!r}: must be one of "
                                        f"{', '.join(forms)} (variant {m['variant']!r}) and 0..3", i)
        expected = [list(f) for f in record_fields(c["sh_form"], c["sh_degree"], parent=hierarchy)]
        if c["fields"] != expected:
            raise BundleError("chunks", f"fields must be the {c['sh_form']} records of SH degree {c['sh_degree']} "
                                        f"(see record_fields)", i)
        size = np.dtype([tuple(f) for f in expected]).itemsize
        if c["bytes"] != c["splats"] * size:
            raise BundleError("chunks", f"bytes {c['bytes']} != splats {c['splats']} x {size}", i)
        if not isinstance(c["file"], str) or not c["file"]:
            raise BundleError("chunks", f"file {c['file']!r} must be a path inside the bundle", i)
        f = (root / c["file"]).resolve()
        if not f.is_relative_to(inside):
            raise BundleError("chunks", f"file {c['file']!r} resolves to {f}, outside the bundle folder {inside}", i)
        f = check_regular_file(f, lambda field, message: BundleError(field, message, i), field="chunks")
        if f.stat().st_size < c["offset"] + c["bytes"]:
            raise BundleError("chunks", f"{c['file']}: missing or shorter than offset + bytes", i)
    return Bundle(path=root, manifest=m)


def _check_manifest_values(m: dict) -> None:
    """Types and ranges of the manifest's top-level values (the chunks are checked by the caller)."""
    if m["variant"] not in VARIANTS:
        raise BundleError("variant", f"{m['variant']!r} must be one of {', '.join(VARIANTS)}")
    if m["representation"] != REPRESENTATION[m["variant"]]:
        raise BundleError("representation", f"{m['representation']!r} must be "
                                            f"{REPRESENTATION[m['variant']]!r} for variant {m['variant']!r}")
    if not isinstance(m["segmented"], bool):
        raise BundleError("segmented", f"{m['segmented']!r} must be true or false")
    if not (_whole(m["sh_degree"]) and m["sh_degree"] <= 3):
        raise BundleError("sh_degree", f"{m['sh_degree']!r} must be 0..3")
    for key in ("levels", "objects", "chunks"):
        if not isinstance(m[key], list) or (key != "chunks" and not m[key]):
            raise BundleError(key, f"must be a{' non-empty' if key != 'chunks' else ''} list")
    for i, lv in enumerate(m["levels"]):
        if not isinstance(lv, dict):
            raise BundleError("levels", f"{lv!r} must be an object", i)
    for i, obj in enumerate(m["objects"]):
        if not _whole(obj):
            raise BundleError("objects", f"{obj!r} must be a whole number >= 0", i)
    if len(set(m["objects"])) != len(m["objects"]):
        raise BundleError("objects", "ids must be distinct")
    if not isinstance(m["build"], dict):
        raise BundleError("build", f"{type(m['build']).__name__} must be an object")
