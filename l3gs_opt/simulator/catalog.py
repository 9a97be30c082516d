"""What a simulated client can request: a bundle's splats grouped into units (:class:`Catalog`).

Views (``build_catalog(bundle, view)``):

* ``object`` -- one unit per (object, level), the bundle's chunks (an unsegmented bundle has one
  object); a ``distill`` layer is one unit of compact + SH-upgrade bytes (a splat usable with
  full SH once both parts arrived);
* ``scene`` -- one unit per level, the objects merged (whole-scene layers or versions);
* ``distill`` -- a ``distill`` bundle's chunks as they are stored: per (object, layer) a
  ``compact`` unit (geometry and compact SH) and an ``sh_upgrade`` unit (the full SH of the
  same splats);
* ``hierarchy`` -- the ``object`` units of a separate bundle, scheduled in the item form
  (each object's versions one replacement group).

Unit ``k = (j * L + l) * F + f`` is form ``f`` of object ``j`` at level ``l`` (``F = 1`` except
in the ``distill`` view, where ``f = 0`` is compact and ``f = 1`` the SH upgrade).
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from l3gs_opt.simulator.config import SimulationError

__all__ = ["CATALOG_VIEWS", "Catalog", "build_catalog", "compact_sh", "upgrade_fraction"]

CATALOG_VIEWS = ("object", "scene", "distill", "hierarchy")


@dataclass(frozen=True, eq=False)
class Catalog:
    """What a method can request: the bundle's splats grouped into units of one view.

    Attributes
    ----------
    view : {"object", "scene", "distill", "hierarchy"}
    representation : {"layered", "separate"}
    rows : list of int arrays, K of them
        Rows of ``scene`` in each unit, in the bundle's order (``scene`` view: objects of a level
        interleaved in proportion, which keeps a ``sort`` bundle's global-significance order as
        far as the per-object chunks allow). The forms of one (object, level) share their rows.
    unit_of_row : int array [N]
        The (object, level) cell ``j * L + l`` of each row of ``scene`` (the unit when ``F = 1``).
    splats, bytes_per_splat, bytes : int arrays [K]
        Splats, bytes per splat and bytes (= splats x bytes per splat) of each unit; an empty
        unit has 0 of each.
    shape : (J, L)
    forms : tuple of str
        The unit forms per (object, level): ``("full",)``, or ``("compact", "sh_upgrade")``.
    file_rows : list of int arrays, K of them, or None
        Rows of each unit in the order its chunks' records sit in the files (chunks in the
        bundle's order, each chunk's records in order): what a client fetching the unit's chunks
        one after the other by HTTP Range receives (``SimConfig.splat_order="stored"``). None: ``rows``.
    """

    view: str
    representation: str
    rows: list
    unit_of_row: np.ndarray
    splats: np.ndarray
    bytes_per_splat: np.ndarray
    bytes: np.ndarray
    shape: tuple[int, int]
    forms: tuple[str, ...] = ("full",)
    file_rows: list | None = None

    def stored_rows(self, k: int) -> np.ndarray:
        """Rows of unit ``k`` in file order (see ``file_rows``)."""
        return self.rows[k] if self.file_rows is None else self.file_rows[k]

    @property
    def units(self) -> int:
        return len(self.rows)

    @property
    def grid(self) -> tuple[int, ...]:
        """Shape of per-unit arrays seen by a scheduler: ``(J, L)``, or ``(J, L, F)`` with forms."""
        return self.shape if len(self.forms) == 1 else (*self.shape, len(self.forms))

    @property
    def cost(self) -> np.ndarray:
        """Bytes per unit (shape :attr:`grid`); an empty unit costs 1 byte (instances want > 0)."""
        return np.maximum(self.bytes, 1).reshape(self.grid)

    @property
    def empty(self) -> np.ndarray:
        return (self.splats == 0).reshape(self.grid)

    def label(self, k: int) -> tuple[int, ...]:
        """``(j, l)``, or ``(j, l, f)`` with forms, of unit ``k``."""
        return tuple(int(v) for v in np.unravel_index(int(k), self.grid))

    def unit(self, label) -> int:
        """Inverse of :meth:`label`."""
        return int(np.ravel_multi_index(tuple(int(v) for v in label), self.grid))

    def top_units(self) -> np.ndarray:
        """Units of the largest model: every unit (layered) or the last level's (separate)."""
        J, L = self.shape
        if self.representation == "layered":
            return np.arange(self.units)
        return np.arange(J) * L + (L - 1)


def _base_scene(bundle):
    """All splats the bundle can deliver (full SH), with per-row object ids (manifest ids) and levels."""
    from l3gs_opt.scene.bundle import _concat

    L = bundle.num_levels
    segmented = bundle.manifest["segmented"]
    if bundle.manifest["representation"] == "layered":
        scene = bundle.scene(L - 1)
        level = np.zeros(scene.num_splats, np.int64) if scene.layers is None else scene.layers.astype(np.int64)
    else:
        parts = [bundle.level_scene(l) for l in range(L)]
        scene = _concat(parts)
        level = np.concatenate([np.full(p.num_splats, l, np.int64) for l, p in enumerate(parts)])
    obj = scene.object_ids.astype(np.int64) if segmented and scene.object_ids is not None \
        else np.zeros(scene.num_splats, np.int64)
    return scene, obj, level


def compact_sh(bundle, full_k: int) -> np.ndarray:
    """``distill``: the compact SH of every row of :func:`_base_scene` ``[N, full_k, 3]``, zero-padded
    above the compact degree (zero coefficients evaluate like the lower degree)."""
    sh = bundle.scene(bundle.num_levels - 1, sh_form="compact").sh
    out = np.zeros((sh.shape[0], full_k, 3), np.float32)
    out[:, :sh.shape[1]] = sh
    return out


def upgrade_fraction(full: np.ndarray, compact: np.ndarray, how, compact_k: int) -> np.ndarray:
    """Per splat, the share ``f`` of its utility the SH upgrade brings (see ``SimConfig.sh_upgrade_utility``).

    Parameters
    ----------
    full, compact : float arrays [N, K, 3]
        Full SH and zero-padded compact SH.
    how : {"residual", "bands"} or float
    compact_k : int
        Coefficients per channel of the compact degree (``bands``: the ones below count as held).

    Returns
    -------
    float array [N] in [0, 1]
        A splat whose SH is all zero gets 0 (nothing to upgrade).
    """
    if not isinstance(how, str):
        return np.full(full.shape[0], float(how))
    full = np.asarray(full, np.float64)
    total = np.square(full).sum(axis=(1, 2))
    if how == "residual":
        part = np.square(full - np.asarray(compact, np.float64)).sum(axis=(1, 2))
    else:
        part = np.square(full[:, compact_k:]).sum(axis=(1, 2))
    with np.errstate(invalid="ignore", divide="ignore"):
        f = np.where(total > 0, part / np.where(total > 0, total, 1.0), 0.0)
    # A poor compact fit can miss more than the whole energy; its upgrade is then worth the whole splat.
    return np.clip(f, 0.0, 1.0)


def _chunk_records(bundle) -> dict:
    """``(object id, level, sh_form) -> (splats, bytes)`` of the manifest's chunks."""
    return {(c["object"], c["level"], c["sh_form"]): (int(c["splats"]), int(c["bytes"]))
            for c in bundle.manifest["chunks"]}


def _bytes_per_splat(chunks: dict, forms) -> dict:
    """``(object id, level) -> bytes per splat`` of the given SH forms together (geometry splat count)."""
    sums: dict = {}
    splats: dict = {}
    for (o, lv, form), (n, b) in chunks.items():
        if form not in forms:
            continue
        sums[(o, lv)] = sums.get((o, lv), 0) + b
        if form != "sh_upgrade" or (o, lv) not in splats:
            splats[(o, lv)] = n
    out = {}
    for key, total in sums.items():
        n = splats.get(key, 0)
        if n <= 0 or total % n:
            raise SimulationError("chunks", f"object {key[0]} level {key[1]}: {total} bytes do not split into "
                                            f"{n} splats")
        out[key] = total // n
    return out


def build_catalog(bundle, view: str = "object", *, base=None) -> Catalog:
    """The units of ``bundle`` seen by ``view`` (see the module docstring).

    ``base`` (the ``(scene, object ids, levels)`` of :func:`_base_scene`) avoids reading the
    chunks again.

    Raises
    ------
    SimulationError
        An unknown view; ``distill`` on a bundle not built as distill, ``hierarchy`` on a
        layered bundle; chunks of one unit with different record sizes.
    """
    if view not in CATALOG_VIEWS:
        raise SimulationError("view", f"{view!r} is not one of {', '.join(CATALOG_VIEWS)}")
    m = bundle.manifest
    if view == "distill" and m["variant"] != "distill":
        raise SimulationError("view", f"'distill' needs a bundle built as variant distill, not {m['variant']!r}")
    if view == "hierarchy" and m["representation"] != "separate":
        raise SimulationError("view", f"'hierarchy' needs a separate bundle (variant hierarchy or separate), "
                                      f"not {m['variant']!r}")
    scene, obj, level = base if base is not None else _base_scene(bundle)
    objects = list(m["objects"]) if m["segmented"] else [0]
    index = {o: j for j, o in enumerate(objects)}
    L = bundle.num_levels
    J = 1 if view == "scene" else len(objects)
    if view != "scene":
        j_of_row = np.array([index[o] for o in obj.tolist()], np.int64)
    else:
        j_of_row = np.zeros(len(obj), np.int64)
    cell = j_of_row * L + level
    chunks = _chunk_records(bundle)
    forms = ("compact", "sh_upgrade") if view == "distill" else ("full",)
    stored = {f for (_, _, f) in chunks}
    per_form = [_bytes_per_splat(chunks, (f,)) for f in forms] if view == "distill" \
        else [_bytes_per_splat(chunks, stored)]
    F = len(forms)
    K = J * L * F
    rows, file_rows, splats, bps = [], [], np.zeros(K, np.int64), np.zeros(K, np.int64)
    for c in range(J * L):
        r = np.flatnonzero(cell == c)
        in_files = r   # the base scene is the chunks' records concatenated in the bundle's order
        if view == "scene" and r.size:
            # Interleave the objects of the level in proportion (rank within object / object size).
            key = np.zeros(r.size)
            for o in np.unique(obj[r]):
                sel = obj[r] == o
                key[sel] = (np.arange(sel.sum()) + 0.5) / sel.sum()
            r = r[np.argsort(key, kind="stable")]
        for f in range(F):
            k = c * F + f
            rows.append(r)
            file_rows.append(in_files)
            splats[k] = r.size
            if r.size:
                members = {per_form[f].get((int(o), int(level[r[0]])), None) for o in np.unique(obj[r])}
                if None in members or len(members) != 1:
                    raise SimulationError("chunks", f"unit {k}: its chunks have different record sizes "
                                                    f"{sorted(members, key=str)} and cannot be merged into one stream")
                bps[k] = members.pop()
    return Catalog(view=view, representation=m["representation"], rows=rows, unit_of_row=cell,
                   splats=splats, bytes_per_splat=bps, bytes=splats * bps, shape=(J, L), forms=forms,
                   file_rows=file_rows)
