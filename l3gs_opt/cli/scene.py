"""CLI subcommands for scenes and rendering: ``render``, ``scene make|info|segment|build``.

Wire into the main parser with ``register(subparsers)``; each subcommand sets ``func`` to a
handler ``handler(args) -> int``.  Bad input raises :class:`l3gs_opt.errors.L3gsError`
subclasses (``SceneError``, ``CameraError``), which the main CLI prints as one line (exit 2).
"""

from __future__ import annotations

import argparse
import json
import os
from pathlib import Path

from l3gs_opt.scene.cameras import CameraError
from l3gs_opt.errors import L3gsError

__all__ = ["register", "load_any_cameras", "save_image", "OutputError"]


class OutputError(L3gsError, ValueError):
    """An output path the CLI cannot write (e.g. an image suffix other than .png / .npy)."""


def load_any_cameras(path) -> list:
    """Cameras from a camera JSON, a ``transforms.json`` (has ``frames``) or a COLMAP model folder
    (:func:`l3gs_opt.scene.cameras.load_any_cameras`)."""
    from l3gs_opt.scene.cameras import load_any_cameras as load

    return load(path)


def save_image(image, path) -> Path:
    """Save an [H, W, 3] render: ``.npy`` float32 as rendered, ``.png`` clipped to [0, 1] and
    rounded to 8 bits."""
    import numpy as np

    path = Path(path)
    a = np.asarray(image, dtype=np.float32)
    path.parent.mkdir(parents=True, exist_ok=True)
    suffix = path.suffix.lower()
    if suffix == ".npy":
        np.save(path, a)
    elif suffix == ".png":
        from PIL import Image

        Image.fromarray((np.clip(a, 0.0, 1.0) * 255.0 + 0.5).astype(np.uint8)).save(path)
    else:
        raise OutputError(f"--out: {path.name} must end in .png or .npy")
    return path


def _parse_rgb(text: str):
    """``r,g,b`` as three floats; anything else is passed on as given, for the camera's own check to
    name it in one error line (``background: ... must be 3 numbers in [0, 1]``)."""
    try:
        return [float(v) for v in text.split(",")]
    except ValueError:
        return text


def _cmd_render(args: argparse.Namespace) -> int:
    import time

    from l3gs_opt.renderer.render import render_scene
    from l3gs_opt.scene.splats import read_ply

    out = Path(args.out)
    if out.suffix.lower() not in (".png", ".npy"):
        raise OutputError(f"--out: {out.name} must end in .png or .npy")
    scene = read_ply(args.scene, ignore_unknown=args.ignore_unknown_properties)
    cams = load_any_cameras(args.camera)
    if not -len(cams) <= args.index < len(cams):
        raise CameraError(f"--index: {args.index} out of range ({args.camera} holds {len(cams)} cameras)")
    cam = cams[args.index]
    if args.background is not None:
        cam = cam.replace(background=args.background)
    t0 = time.perf_counter()
    result = render_scene(scene, cam, sh_degree=args.sh_degree)
    dt = time.perf_counter() - t0
    save_image(result.image.numpy(), out)
    print(f"wrote {out}: {cam.width}x{cam.height}, {int(result.projection.visible.sum())} of "
          f"{scene.num_splats} splats visible, {dt:.2f} s (load {os.getloadavg()[0]:.2f})")
    return 0


def _cmd_scene_make(args: argparse.Namespace) -> int:
    from l3gs_opt.scene.camera_paths import orbit_path, walk_path
    from l3gs_opt.scene.cameras import save_cameras
    from l3gs_opt.scene.splats import write_ply
    from l3gs_opt.scene.procedural import make_scene

    bg = args.background if args.background is not None else (0.0, 0.0, 0.0)
    kw = dict(width=args.width, height=args.height, fov_x_deg=args.fov, background=bg)
    # the camera paths first: a bad size or background fails before any file is written
    paths = [(kind, make(args.views, **kw), out) for kind, make, out in (("orbit", orbit_path, args.orbit),
                                                                         ("walk", walk_path, args.walk)) if out]
    scene = make_scene(args.splats, objects=args.objects, sh_degree=args.sh_degree, seed=args.seed)
    path = write_ply(scene, args.out)
    print(f"wrote {path}: {scene!r}, {path.stat().st_size} bytes")
    for kind, cams, out in paths:
        p = save_cameras(cams, out)
        print(f"wrote {p}: {kind} path, {args.views} cameras {args.width}x{args.height}")
    return 0


def _cmd_scene_info(args: argparse.Namespace) -> int:
    import numpy as np

    from l3gs_opt.scene.splats import bytes_per_splat, read_ply

    scene = read_ply(args.scene, ignore_unknown=args.ignore_unknown_properties)
    info = {"file": str(args.scene), "file_bytes": Path(args.scene).stat().st_size,
            "splats": scene.num_splats, "sh_degree": scene.sh_degree,
            "bytes_per_splat": bytes_per_splat(scene.sh_degree),
            "objects": scene.num_objects, "layers": scene.num_layers,
            "has_normals": scene.normals is not None}
    if scene.num_splats:
        info["bbox_min"] = scene.means.min(0).round(4).tolist()
        info["bbox_max"] = scene.means.max(0).round(4).tolist()
        info["mean_opacity"] = round(float(np.mean(1 / (1 + np.exp(-scene.opacity_logits.astype(np.float64))))), 4)
        info["median_scale"] = round(float(np.median(np.exp(scene.log_scales.max(1).astype(np.float64)))), 5)
    if scene.object_ids is not None:
        ids, counts = np.unique(scene.object_ids, return_counts=True)
        info["splats_per_object"] = {int(i): int(c) for i, c in zip(ids, counts)}
    if scene.layers is not None:
        ids, counts = np.unique(scene.layers, return_counts=True)
        info["splats_per_layer"] = {int(i): int(c) for i, c in zip(ids, counts)}
    if args.json:
        print(json.dumps(info))
    else:
        for k, v in info.items():
            print(f"{k}: {v}")
    return 0


def _parse_sizes(text: str) -> list:
    """``45000,90000`` -> ``[45000, 90000]``; entries that are not integers are kept as text so that
    the library's size check names the field and index."""
    out = []
    for part in text.split(","):
        part = part.strip()
        try:
            out.append(int(part))
        except ValueError:
            try:
                out.append(float(part))
            except ValueError:
                out.append(part)
    return out


def _cmd_scene_segment(args: argparse.Namespace) -> int:
    import numpy as np

    from l3gs_opt.scene.splats import read_ply, write_ply
    from l3gs_opt.scene.segment import segment_scene

    scene = read_ply(args.scene, ignore_unknown=args.ignore_unknown_properties)
    out = segment_scene(scene, args.objects, seed=args.seed)
    path = write_ply(out, args.out)
    counts = np.bincount(out.object_ids, minlength=args.objects).tolist()
    print(f"wrote {path}: {out.num_splats} splats in {args.objects} objects (k-means on the means), "
          f"splats per object {counts}")
    return 0


def _cmd_scene_build(args: argparse.Namespace) -> int:
    from l3gs_opt.pipeline.build import DEFAULT, QUICK, build_bundle

    cams = load_any_cameras(args.cameras)
    schedule = QUICK if args.quick else DEFAULT
    if args.max_width is not None:
        import dataclasses

        schedule = dataclasses.replace(schedule, max_width=args.max_width)
    res = build_bundle(args.teacher, cams, _parse_sizes(args.layers), args.variant, args.out, schedule=schedule,
                       resume=args.resume, show_progress=not args.no_progress, log=print)
    print(f"total {res.total_seconds:.1f} s (load {os.getloadavg()[0]:.2f})")
    return 0


def register(subparsers) -> None:
    """Add ``render`` and ``scene`` (``make``, ``info``, ``segment``, ``build``) to an argparse subparsers object."""
    p = subparsers.add_parser("render", help="render a splat scene (.ply) from a camera to .png or .npy")
    p.add_argument("scene", help="scene PLY file (reference 3DGS layout)")
    p.add_argument("--camera", required=True,
                   help="camera JSON (object or list), NeRF/Blender transforms.json, or COLMAP sparse folder")
    p.add_argument("--out", required=True, help="output image: .png (8-bit) or .npy (float32 HxWx3, unclipped)")
    p.add_argument("--index", type=int, default=0, help="camera index when the file holds several (default 0)")
    p.add_argument("--background", type=_parse_rgb, default=None, help="override the background, r,g,b in [0, 1]")
    p.add_argument("--sh-degree", type=int, choices=[0, 1, 2, 3], default=None,
                   help="render with SH degrees up to this only")
    p.add_argument("--ignore-unknown-properties", action="store_true",
                   help="skip unknown PLY vertex properties instead of failing")
    p.set_defaults(func=_cmd_render)

    s = subparsers.add_parser("scene", help="make or inspect splat scenes")
    ssub = s.add_subparsers(dest="scene_command", required=True)
    m = ssub.add_parser("make", help="build a procedural multi-object room scene (+ camera paths)")
    m.add_argument("--out", required=True, help="output PLY file")
    m.add_argument("--splats", type=int, default=100_000, help="number of splats (default 100000; 1000..2000000)")
    m.add_argument("--objects", type=int, default=5, help="objects on the floor (1..12, default 5)")
    m.add_argument("--sh-degree", type=int, choices=[0, 1, 2, 3], default=3, help="SH degree (default 3)")
    m.add_argument("--seed", type=int, default=0, help="random seed (default 0)")
    m.add_argument("--orbit", help="also write an orbit camera path (camera JSON list) here")
    m.add_argument("--walk", help="also write a walk-through camera path (camera JSON list) here")
    m.add_argument("--views", type=int, default=36, help="cameras per path (default 36)")
    m.add_argument("--width", type=int, default=800, help="image width of the path cameras (default 800)")
    m.add_argument("--height", type=int, default=600, help="image height of the path cameras (default 600)")
    m.add_argument("--fov", type=float, default=70.0, help="horizontal field of view in degrees (default 70)")
    m.add_argument("--background", type=_parse_rgb, default=None, help="camera background r,g,b (default black)")
    m.set_defaults(func=_cmd_scene_make)
    i = ssub.add_parser("info", help="print a scene's size, SH degree, objects and layers")
    i.add_argument("scene", help="scene PLY file")
    i.add_argument("--json", action="store_true", help="print one JSON object")
    i.add_argument("--ignore-unknown-properties", action="store_true",
                   help="skip unknown PLY vertex properties instead of failing")
    i.set_defaults(func=_cmd_scene_info)
    g = ssub.add_parser("segment", help="assign object ids to a scene by k-means on the splat centres (scipy)")
    g.add_argument("scene", help="scene PLY file")
    g.add_argument("--objects", type=int, required=True, help="number of objects (clusters)")
    g.add_argument("--out", required=True, help="output PLY file (with object_id)")
    g.add_argument("--seed", type=int, default=0, help="random seed (default 0)")
    g.add_argument("--ignore-unknown-properties", action="store_true",
                   help="skip unknown PLY vertex properties instead of failing")
    g.set_defaults(func=_cmd_scene_segment)
    b = ssub.add_parser("build", help="train a layered / separate / sort / distill / hierarchy bundle from a teacher")
    b.add_argument("teacher", help="teacher scene PLY (reference 3DGS layout)")
    b.add_argument("--cameras", required=True,
                   help="training cameras: camera JSON list, NeRF/Blender transforms.json or COLMAP folder")
    b.add_argument("--layers", required=True,
                   help="cumulative sizes in splats, increasing, e.g. 45000,90000,135000,180000")
    b.add_argument("--variant", required=True, choices=["layered", "separate", "sort", "distill", "hierarchy"])
    b.add_argument("--out", required=True, help="bundle directory (manifest.json + chunks/)")
    b.add_argument("--quick", action="store_true", help="small views and short training (demo, CI)")
    b.add_argument("--resume", action="store_true", help="continue an interrupted build from its checkpoints")
    b.add_argument("--max-width", type=int, default=None, help="training view width in pixels (overrides the schedule)")
    b.add_argument("--no-progress", action="store_true", help="no progress bars")
    b.set_defaults(func=_cmd_scene_build)
