"""Splat utilities: what a splat (and a chunk of splats) is worth to the viewer, by name.

One interface serves every place a utility is computed (instances from scenes, the simulator,
experiments, the CLI's ``--utility NAME``): a :class:`SplatUtility` prepares a scene once
(camera-independent work) and then gives, for a set of predicted viewpoints, a value per splat
(the mean over the viewpoints) and a value per chunk (a set of splat rows; by default the sum of
its splats' values). Values are float64 and never negative; each utility states its ``unit``.
Values of two utilities are not comparable, and neither are sums over slots across utilities.

Built-ins (:func:`utility_names`):

``eq1``
    The paper's Eq. 1: closeness x projected area x opacity
    (:mod:`l3gs_opt.pipeline.splat_utility`); occlusion-blind. Unit ``eq1`` (pixels per world unit).
``visibility``
    Each splat's share of the rendered picture of the full scene: its alpha-compositing weight
    summed over the pixels (:mod:`l3gs_opt.renderer.weights`), occlusion included. Counted on a
    picture ``scale`` times the camera's size and reported in the camera's pixels.
``visibility-prefix``
    ``visibility`` in the picture a layer arrives into: a splat is not dimmed by its own object's
    higher layers (in the full scene an object's base layer lies partly under its own detail, so
    ``visibility`` undervalues it). Held-free.
``visibility-held``
    Held-aware: a splat not held is valued by its weight if it were added alone to what the
    viewer holds (only held splats in front of it dim it), so a coarse splat that fills a hole is
    worth more than fine detail behind held ones. Held splats keep their weight among the held.
``coverage``
    ``visibility-held`` with each pixel weighted by how far the held picture is from the full one
    there (mean absolute RGB difference, in [0, 1]): splats that fill empty or wrong pixels.
    Unit: pixels x colour error. Two more renders per viewpoint.
``counterfactual``
    Reference, slow (one render per chunk and viewpoint): a chunk's value is the measured SSIM
    gain of the held picture when the chunk alone is added (against the full scene's picture),
    floored at 0. Its per-splat values (the order inside a chunk) are ``visibility-held``'s.

A user's utility (a :class:`SplatUtility` subclass or instance, or a plain function
``f(scene, camera) -> values [N]``) is added with :func:`register_utility` and is then accepted
wherever a name is; or named ``MODULE:ATTR`` (e.g. on the command line), which imports
``MODULE`` and registers its ``ATTR`` under that name on first use.
"""

from __future__ import annotations

import threading
from typing import Any, Callable, Sequence

import numpy as np

from l3gs_opt.errors import L3gsError
from l3gs_opt.scene.cameras import Camera
from l3gs_opt.scene.splats import SplatScene

__all__ = ["UtilityNameError", "SplatUtility", "Eq1Utility", "VisibilityUtility", "CoverageUtility",
           "CounterfactualUtility", "PrefixVisibilityUtility", "register_utility", "get_utility", "utility_names", "DEFAULT_UTILITY",
           "scaled_camera", "chunk_gains", "tabulate", "ScenePictures"]

#: The utility used when none is named (the paper's Eq. 1; see benchmarks/results for how the others compare).
DEFAULT_UTILITY = "eq1"
#: Default size of the picture the picture-based utilities count on, as a fraction of the camera's.
DEFAULT_SCALE = 0.5


class UtilityNameError(L3gsError, ValueError):
    """An unknown utility name, or a registration that is not a utility."""


def scaled_camera(camera: Camera, scale: float) -> Camera:
    """``camera`` with its picture ``scale`` times as wide and high (at least 1 pixel; the field of
    view and pose unchanged)."""
    if scale == 1.0:
        return camera
    w = max(1, int(round(camera.width * scale)))
    h = max(1, int(round(camera.height * scale)))
    sx, sy = w / camera.width, h / camera.height
    return camera.replace(width=w, height=h, fx=camera.fx * sx, fy=camera.fy * sy, cx=camera.cx * sx,
                          cy=camera.cy * sy)


def _check_held(held: np.ndarray | None, n: int) -> np.ndarray | None:
    if held is None:
        return None
    out = np.asarray(held)
    if out.dtype != np.bool_ or out.shape != (n,):
        raise ValueError(f"held: a boolean mask of {n} splats expected, got {out.dtype} {out.shape}")
    return out


class SplatUtility:
    """A splat utility (subclass it, or register a plain function).

    Attributes
    ----------
    name : str
        Its registered name (part of every record's identity).
    unit : str
        What its values count.
    held_aware : bool
        Its values depend on what the viewer holds (``held``); callers recompute them when that
        changes.
    """

    name: str = ""
    unit: str = ""
    held_aware: bool = False

    def prepare(self, scene: SplatScene) -> Any:
        """Camera-independent preparation of ``scene`` (cached by callers; default: the scene)."""
        return scene

    def splat_values(self, prepared: Any, cameras: Sequence[Camera], *, held: np.ndarray | None = None) -> np.ndarray:
        """Mean value of each splat over ``cameras`` (float64 [N], >= 0). Every utility defines it."""
        raise NotImplementedError(f"utility {self.name or type(self).__name__!r}: define splat_values")

    def chunk_values(self, prepared: Any, cameras: Sequence[Camera], chunks: Sequence[np.ndarray], *,
                     held: np.ndarray | None = None) -> np.ndarray:
        """Value of each chunk (rows of the scene) over ``cameras`` (float64 [K]): by default the sum
        of its splats' values."""
        v = self.splat_values(prepared, cameras, held=held)
        return np.array([float(v[np.asarray(rows, dtype=np.int64)].sum()) for rows in chunks])

    def describe(self) -> dict:
        """Name, unit and options, as records store them."""
        return {"name": self.name, "unit": self.unit}


class Eq1Utility(SplatUtility):
    """The paper's Eq. 1 (see :func:`l3gs_opt.pipeline.splat_utility.splat_utility`)."""

    name, unit = "eq1", "eq1"

    def __init__(self, area: str = "square"):
        self.area = area

    def prepare(self, scene: SplatScene) -> Any:
        from l3gs_opt.pipeline.splat_utility import UtilityScene

        return UtilityScene.from_scene(scene)

    def splat_values(self, prepared: Any, cameras: Sequence[Camera], *, held: np.ndarray | None = None) -> np.ndarray:
        from l3gs_opt.pipeline.splat_utility import splat_utility

        if not len(cameras):
            return np.zeros(prepared.num_splats)
        return np.mean([splat_utility(prepared, c, area=self.area) for c in cameras], axis=0)

    def describe(self) -> dict:
        return {**super().describe(), "area": self.area}


class VisibilityUtility(SplatUtility):
    """Blending weight summed over the picture; ``held_aware=True`` is ``visibility-held``.
    Subclasses name themselves with ``kind``."""

    unit = "pixels"
    kind = ""

    def __init__(self, *, scale: float = DEFAULT_SCALE, held_aware: bool = False):
        if not 0.0 < float(scale) <= 1.0:
            raise UtilityNameError(f"scale = {scale!r}: must be in (0, 1]")
        self.scale = float(scale)
        self.held_aware = bool(held_aware) or type(self).held_aware
        self.name = self.kind or ("visibility-held" if self.held_aware else "visibility")

    def prepare(self, scene: SplatScene) -> Any:
        from l3gs_opt.renderer.weights import WeightScene

        return WeightScene.from_scene(scene)

    def _weights(self, prepared: Any, camera: Camera, held: np.ndarray | None,
                 pixel_weight: np.ndarray | None = None) -> np.ndarray:
        from l3gs_opt.renderer.weights import scene_weights

        small = scaled_camera(camera, self.scale)
        w = scene_weights(prepared, small, held=held, pixel_weight=pixel_weight)
        # In the camera's pixels, whatever picture they were counted on.
        return w * ((camera.width * camera.height) / (small.width * small.height))

    def splat_values(self, prepared: Any, cameras: Sequence[Camera], *, held: np.ndarray | None = None) -> np.ndarray:
        held = _check_held(held, prepared.num_splats) if self.held_aware else None
        if not len(cameras):
            return np.zeros(prepared.num_splats)
        return np.mean([self._weights(prepared, c, held) for c in cameras], axis=0)

    def describe(self) -> dict:
        return {**super().describe(), "scale": self.scale}


class PrefixVisibilityUtility(VisibilityUtility):
    """``visibility`` in the picture a layer arrives into: a splat is dimmed by every splat in front
    except its own object's higher layers (which arrive after it). Held-free; layered scenes
    (without object or layer labels it is ``visibility``)."""

    kind = "visibility-prefix"

    def prepare(self, scene: SplatScene) -> Any:
        n = scene.num_splats
        obj = np.zeros(n, np.int64) if scene.object_ids is None else np.unique(scene.object_ids, return_inverse=True)[1]
        lay = np.zeros(n, np.int64) if scene.layers is None else np.asarray(scene.layers, np.int64)
        return super().prepare(scene), (obj.astype(np.int64), lay)

    def splat_values(self, prepared: Any, cameras: Sequence[Camera], *, held: np.ndarray | None = None) -> np.ndarray:
        from l3gs_opt.renderer.weights import scene_weights

        weights, labels = prepared
        out = []
        for c in cameras:
            small = scaled_camera(c, self.scale)
            w = scene_weights(weights, small, prefix=labels)
            out.append(w * ((c.width * c.height) / (small.width * small.height)))
        return np.mean(out, axis=0) if out else np.zeros(weights.num_splats)


class ScenePictures:
    """A scene and renders of it (clipped to [0, 1], float64), the full scene's cached per camera
    (it repeats across slots and chunks); ``weights``: the scene prepared for
    :func:`~l3gs_opt.renderer.weights.scene_weights` (or None)."""

    def __init__(self, scene: SplatScene, weights: Any = None):
        self.scene, self.weights = scene, weights
        self._full: dict[bytes, np.ndarray] = {}
        self._lock = threading.Lock()

    @property
    def num_splats(self) -> int:
        return int(self.scene.num_splats)

    def render(self, camera: Camera, rows: np.ndarray | None = None) -> np.ndarray:
        from l3gs_opt.renderer import render_scene

        if rows is None:
            key = np.ascontiguousarray(camera.world_to_camera).tobytes() + bytes(f"{camera.width}x{camera.height}", "ascii")
            with self._lock:
                if key in self._full:
                    return self._full[key]
            image = np.clip(render_scene(self.scene, camera).image.numpy().astype(np.float64), 0.0, 1.0)
            with self._lock:
                self._full[key] = image
            return image
        if rows.size == 0:
            return np.broadcast_to(np.asarray(camera.background, dtype=np.float64),
                                   (camera.height, camera.width, 3)).copy()
        return np.clip(render_scene(self.scene.subset(rows), camera).image.numpy().astype(np.float64), 0.0, 1.0)


class _PictureUtility(VisibilityUtility):
    """A held-aware utility that also renders the scene: prepared as :class:`ScenePictures`."""

    held_aware = True

    def prepare(self, scene: SplatScene) -> Any:
        return ScenePictures(scene, super().prepare(scene))


class CoverageUtility(_PictureUtility):
    """``visibility-held`` weighted per pixel by the held picture's colour error."""

    unit = "pixels x colour error"
    kind = "coverage"

    def splat_values(self, prepared: Any, cameras: Sequence[Camera], *, held: np.ndarray | None = None) -> np.ndarray:
        held = _check_held(held, prepared.num_splats)
        if not len(cameras):
            return np.zeros(prepared.num_splats)
        rows = np.arange(prepared.num_splats) if held is None else np.flatnonzero(held)
        out = []
        for c in cameras:
            small = scaled_camera(c, self.scale)
            error = np.abs(prepared.render(small) - prepared.render(small, rows)).mean(axis=2)
            out.append(self._weights(prepared.weights, c, held, error))
        return np.mean(out, axis=0)


class CounterfactualUtility(_PictureUtility):
    """Measured SSIM gain of adding each chunk alone to what is held (reference; slow)."""

    unit = "SSIM"
    kind = "counterfactual"

    def splat_values(self, prepared: Any, cameras: Sequence[Camera], *, held: np.ndarray | None = None) -> np.ndarray:
        return super().splat_values(prepared.weights, cameras, held=held)

    def chunk_values(self, prepared: Any, cameras: Sequence[Camera], chunks: Sequence[np.ndarray], *,
                     held: np.ndarray | None = None) -> np.ndarray:
        gains = chunk_gains(prepared, cameras, chunks, held=held, scale=self.scale)
        return np.maximum(gains["ssim"], 0.0)


def chunk_gains(prepared: ScenePictures, cameras: Sequence[Camera], chunks: Sequence[np.ndarray], *,
                held: np.ndarray | None = None, scale: float = DEFAULT_SCALE) -> dict[str, np.ndarray]:
    """Measured gain of adding each chunk alone to the held splats, averaged over ``cameras``:
    ``ssim`` and ``psnr`` (dB, None-free: a picture equal to the reference counts as 100 dB) of
    the held picture plus the chunk against the full scene's, minus those of the held picture.
    Pictures at ``scale`` times the camera's size."""
    from l3gs_opt.renderer.metrics import psnr, ssim

    n = prepared.num_splats
    held = np.zeros(n, dtype=bool) if held is None else _check_held(held, n)
    base_rows = np.flatnonzero(held)
    out = {"ssim": np.zeros(len(chunks)), "psnr": np.zeros(len(chunks))}
    if not len(cameras):
        return out

    def score(image: np.ndarray, ref: np.ndarray) -> tuple[float, float]:
        p = psnr(image, ref)
        return float(ssim(image, ref)), 100.0 if p is None or not np.isfinite(p) else min(float(p), 100.0)

    for c in cameras:
        small = scaled_camera(c, scale)
        ref = prepared.render(small)
        s0, p0 = score(prepared.render(small, base_rows), ref)
        for k, rows in enumerate(chunks):
            add = np.setdiff1d(np.asarray(rows, dtype=np.int64), base_rows)
            if add.size == 0:
                continue
            s1, p1 = score(prepared.render(small, np.union1d(base_rows, add)), ref)
            out["ssim"][k] += (s1 - s0) / len(cameras)
            out["psnr"][k] += (p1 - p0) / len(cameras)
    return out


class _FunctionUtility(SplatUtility):
    """A user's function ``f(scene, camera) -> values [N]``, averaged over the cameras."""

    def __init__(self, name: str, fn: Callable[[SplatScene, Camera], np.ndarray], unit: str):
        self.name, self.fn, self.unit = name, fn, unit

    def splat_values(self, prepared: Any, cameras: Sequence[Camera], *, held: np.ndarray | None = None) -> np.ndarray:
        n = len(prepared.means)
        if not len(cameras):
            return np.zeros(n)
        vals = []
        for c in cameras:
            try:
                v = np.asarray(self.fn(prepared, c), dtype=np.float64)
            except Exception as exc:  # noqa: BLE001 -- any failure of user code: one line naming it, not a traceback
                text = str(exc).splitlines()[0] if str(exc) else ""
                raise UtilityNameError(f"utility: {self.name!r} could not be called as a utility f(scene, camera): "
                                       f"{type(exc).__name__}: {text}") from exc
            if v.shape != (n,) or not np.all(np.isfinite(v)) or np.any(v < 0):
                raise UtilityNameError(f"utility: {self.name!r} returned {v.shape} values; expected {n} finite values >= 0")
            vals.append(v)
        return np.mean(vals, axis=0)


_REGISTRY: dict[str, Callable[[], SplatUtility]] = {
    "eq1": Eq1Utility,
    "visibility": VisibilityUtility,
    "visibility-held": lambda: VisibilityUtility(held_aware=True),
    "visibility-prefix": PrefixVisibilityUtility,
    "coverage": CoverageUtility,
    "counterfactual": CounterfactualUtility,
}


def utility_names() -> list[str]:
    """Every registered utility name (built-ins first)."""
    return list(_REGISTRY)


def register_utility(name: str, utility: Any, *, unit: str = "user", replace: bool = False) -> None:
    """Make ``utility`` available by ``name``: a :class:`SplatUtility` instance or subclass, or a
    function ``f(scene, camera) -> values [N]`` (float64, >= 0).

    Raises
    ------
    UtilityNameError
        An empty name, a name taken (unless ``replace``), or something that is not a utility.
    """
    if not isinstance(name, str) or not name or ":" in name:
        raise UtilityNameError(f"utility name {name!r}: must be a non-empty string without ':'")
    if name in _REGISTRY and not replace:
        raise UtilityNameError(f"utility {name!r} is already registered (replace=True to replace it)")
    _REGISTRY[name] = _factory(name, utility, unit)


def _factory(name: str, utility: Any, unit: str) -> Callable[[], SplatUtility]:
    """A maker of ``utility`` (an instance, a subclass or a function) named ``name``."""
    if isinstance(utility, SplatUtility):
        utility.name = name
        return lambda: utility
    if isinstance(utility, type) and issubclass(utility, SplatUtility):
        def factory() -> SplatUtility:
            made = utility()
            made.name = name
            return made

        return factory
    if callable(utility) and not isinstance(utility, type):
        return lambda: _FunctionUtility(name, utility, unit)
    raise UtilityNameError(f"utility {name!r}: {type(utility).__name__} is not a SplatUtility or a function")


def get_utility(utility: "str | SplatUtility") -> SplatUtility:
    """The utility of a name (or the utility itself).

    Raises
    ------
    UtilityNameError
        Unknown name.
    """
    if isinstance(utility, SplatUtility):
        return utility
    if isinstance(utility, str) and ":" in utility and utility not in _REGISTRY:
        _import_utility(utility)
    if not isinstance(utility, str) or utility not in _REGISTRY:
        raise UtilityNameError(f"utility {utility!r} is not one of {', '.join(_REGISTRY)} (or MODULE:NAME)")
    return _REGISTRY[utility]()


def _import_utility(spec: str) -> None:
    """Register ``MODULE:ATTR`` under that name (the module imported, its attribute a utility)."""
    import importlib

    module, _, attr = spec.partition(":")
    try:
        obj = getattr(importlib.import_module(module), attr)
    except (ImportError, AttributeError, ValueError) as exc:
        raise UtilityNameError(f"utility {spec!r}: cannot import {attr!r} from {module!r} ({exc})") from None
    _REGISTRY[spec] = _factory(spec, obj, "user")


def tabulate(utility: "str | SplatUtility", scene: SplatScene, positions: np.ndarray, *, yaw_steps: int = 36,
             pitches_deg: tuple[float, ...] = (-45.0, -30.0, -15.0, 0.0, 15.0, 30.0), up_axis: int = 2,
             width: int = 800, height: int = 600, fov_deg: float = 70.0, progress: bool = False):
    """A :class:`~l3gs_opt.pipeline.splat_utility.UtilityTable` of any held-free utility: per
    (object, layer) of ``scene``'s labels, its value from every grid viewpoint (the grid of
    :func:`~l3gs_opt.pipeline.splat_utility.build_utility_table`, which ``eq1`` uses: compiled,
    both cores). Other utilities cost one ``splat_values`` call per viewpoint.

    Raises
    ------
    UtilityNameError
        A held-aware utility (its values depend on what is held: there is no one table).
    """
    import scipy.sparse as sp
    from tqdm import tqdm

    from l3gs_opt.pipeline.splat_utility import UtilityTable, _labels, build_utility_table

    u = get_utility(utility)
    grid = dict(yaw_steps=yaw_steps, pitches_deg=pitches_deg, up_axis=up_axis, width=width, height=height,
                fov_deg=fov_deg, progress=progress)
    if isinstance(u, Eq1Utility):
        return build_utility_table(scene, positions, area=u.area, **grid)
    if u.held_aware:
        raise UtilityNameError(f"utility {u.name!r} depends on what is held: it cannot be tabulated")
    # The grid and its cameras, checked as for Eq. 1: the Eq. 1 table of no splats (no work).
    shell = build_utility_table(scene.subset(np.zeros(0, dtype=np.int64)), positions, **{**grid, "progress": False})
    obj, lay, J, L = _labels(scene)
    bins = obj * max(L, 1) + lay
    table = UtilityTable(shell.positions, shell.yaw_steps, shell.pitches_deg, sp.csr_matrix((0, J * L)), (J, L),
                         up_axis, shell.intrinsics)
    prep = u.prepare(scene)
    O = len(table.orientations)
    blocks = []
    for p in tqdm(range(len(table.positions)), desc=f"{u.name} table", disable=not progress):
        rows = [np.bincount(bins, weights=u.splat_values(prep, [table.camera(p, o)]), minlength=J * L)
                for o in range(O)]
        blocks.append(sp.csr_matrix(np.array(rows)))
    return UtilityTable(table.positions, table.yaw_steps, table.pitches_deg, sp.vstack(blocks, format="csr"), (J, L),
                        up_axis, table.intrinsics)
