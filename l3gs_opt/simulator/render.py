"""Rendering for the simulator: one backend choice and a content-keyed image cache.

Rendering the client view and the reference each slot dominates a simulation's run time. Both
are pure functions of (the splats, the camera), so they are cached by content:

* the **reference** (teacher) images, keyed by the teacher's fingerprint and the camera: every
  run in the process that scores the same teacher from the same path (another method, another
  :class:`~l3gs_opt.simulator.simulation.Simulation`) reuses them, and with a ``directory`` so does every
  later process (one ``.npy`` per image);
* the **client views**, keyed by the bundle scene's fingerprint, the rows shown, which of them
  show their full SH (distill) and the camera: a slot where nothing new arrived and the viewer
  did not move, or another method holding the same splats at the same slot, renders nothing.

Keys are SHA-1 digests of the exact bytes (float arrays bit for bit), so a hit returns the very
image a render would give. Images are stored as float32 (what the renderer computes) and handed
out as float64 in [0, 1].

Renders run with :data:`RENDER_THREADS` torch threads: a 160x120 frame of 12k splats is a few
hundred small tensor ops, too small to split, and on a shared machine every parallel region
waits for a descheduled second thread (measured on the 2-core development machine at load 5:
725-770 ms per render with 2 threads, 90-95 ms with 1).
"""

from __future__ import annotations

import contextlib
import hashlib
import os
import struct
from collections import OrderedDict
from pathlib import Path

import numpy as np
from l3gs_opt.output_files import write_atomic

__all__ = ["RenderCache", "render_backend", "scene_fingerprint", "camera_key", "render_image",
           "REFERENCE_CACHE", "VIEW_CACHE", "RENDER_THREADS"]

#: Torch threads while rendering (None: leave torch's setting alone); see the module docstring.
RENDER_THREADS: int | None = 1


@contextlib.contextmanager
def torch_threads(n: int | None):
    """Run the block with ``n`` torch intra-op threads, then restore the setting (free to switch)."""
    import torch

    before = torch.get_num_threads()
    if n is not None and n != before:
        torch.set_num_threads(n)
    try:
        yield
    finally:
        if torch.get_num_threads() != before:
            torch.set_num_threads(before)


def render_backend() -> str:
    """``numba`` when installed (the compiled compositing kernels), else ``torch``."""
    from l3gs_opt.renderer import _kernels

    return "numba" if _kernels.HAVE_NUMBA else "torch"


def scene_fingerprint(scene, *extra: np.ndarray) -> bytes:
    """SHA-1 of a :class:`~l3gs_opt.scene.splats.SplatScene`'s render inputs (and ``extra`` arrays)."""
    h = hashlib.sha1()
    for a in (scene.means, scene.log_scales, scene.quats, scene.opacity_logits, scene.sh, *extra):
        a = np.ascontiguousarray(a)
        h.update(str((a.dtype.str, a.shape)).encode())
        h.update(a.tobytes())
    return h.digest()


def camera_key(camera) -> bytes:
    """The bytes that determine what ``camera`` sees (pose, intrinsics, size, background)."""
    return (np.ascontiguousarray(camera.world_to_camera, np.float64).tobytes()
            + struct.pack("<2q4d", int(camera.width), int(camera.height), float(camera.fx), float(camera.fy),
                          float(camera.cx), float(camera.cy))
            + np.ascontiguousarray(camera.background, np.float64).tobytes())


def render_image(scene, camera, backend: str | None = None, *, threads: int | None = RENDER_THREADS) -> np.ndarray:
    """``scene`` seen by ``camera``: float64 ``[H, W, 3]`` clipped to [0, 1]; the background for no splats.

    ``backend``: the renderer's compositing backend (default :func:`render_backend`); ``threads``:
    torch threads during the render (see the module docstring).
    """
    from l3gs_opt.renderer.render import render_scene

    if scene is None or scene.num_splats == 0:
        background = np.clip(np.asarray(camera.background, np.float64), 0.0, 1.0)
        return np.broadcast_to(background, (camera.height, camera.width, 3)).copy()
    with torch_threads(threads):
        out = render_scene(scene, camera, backend=backend or render_backend()).image.numpy()
    return np.clip(out.astype(np.float64), 0.0, 1.0)


class RenderCache:
    """Images by key, least recently used dropped past ``max_bytes``; optionally also on disk.

    Parameters
    ----------
    max_bytes : int
        Memory budget of the in-memory part (bytes of the float32 images).
    directory : path, optional
        Also read and write ``DIR/<key>.npy`` (float32); written atomically, so concurrent
        processes may share it.
    """

    def __init__(self, max_bytes: int = 256 << 20, directory: str | os.PathLike | None = None):
        self.max_bytes = int(max_bytes)
        self.directory = None if directory is None else Path(directory)
        self._items: OrderedDict[str, np.ndarray] = OrderedDict()
        self._bytes = 0
        self.hits = 0
        self.misses = 0

    @staticmethod
    def key(*parts: bytes) -> str:
        h = hashlib.sha1()
        for p in parts:
            h.update(struct.pack("<q", len(p)))
            h.update(p)
        return h.hexdigest()

    def get(self, key: str) -> np.ndarray | None:
        """The float64 image stored under ``key`` (memory, then disk), or None."""
        img = self._items.get(key)
        if img is None and self.directory is not None:
            path = self.directory / f"{key}.npy"
            if path.is_file():
                try:
                    img = np.load(path)
                except (OSError, ValueError):   # a file cut off by a killed writer: render again
                    img = None
                if img is not None:
                    self._remember(key, img)
        if img is None:
            self.misses += 1
            return None
        self._items.move_to_end(key)
        self.hits += 1
        return img.astype(np.float64)

    def put(self, key: str, image: np.ndarray) -> None:
        img = np.asarray(image, np.float32)
        self._remember(key, img)
        if self.directory is not None:
            self.directory.mkdir(parents=True, exist_ok=True)
            write_atomic(self.directory / f"{key}.npy", lambda fh: np.save(fh, img))

    def _remember(self, key: str, img: np.ndarray) -> None:
        if key in self._items:
            return
        self._items[key] = img
        self._bytes += img.nbytes
        while self._bytes > self.max_bytes and len(self._items) > 1:
            _, old = self._items.popitem(last=False)
            self._bytes -= old.nbytes

    def clear(self) -> None:
        """Forget the in-memory images (files on disk stay)."""
        self._items.clear()
        self._bytes = 0

    def __len__(self) -> int:
        return len(self._items)


#: Process-wide caches used by every Simulation unless it is given its own.
REFERENCE_CACHE = RenderCache(256 << 20)
VIEW_CACHE = RenderCache(128 << 20)
