"""CLI subcommands for scenes and rendering: ``render``, ``scene make|info|segment|build|convert``.

Wire into the main parser with ``register(subparsers)``; each subcommand sets ``func`` to a
handler ``handler(args) -> int``.  Bad input raises :class:`l3gs_opt.errors.L3gsError`
subclasses (``SceneError``, ``CameraError``), which the main CLI prints as one line (exit 2).
"""

from __future__ import annotations

import argparse
import json
import os
import time
from pathlib import Path

from l3gs_opt.scene.cameras import CameraError
from l3gs_opt.errors import L3gsError

__all__ = ["register", "load_any_cameras", "save_image", "OutputError"]


class OutputError(L3gsError, ValueError):
    """An output path the CLI cannot write (e.g. an image suffix other than .png / .npy)."""


def load_any_cameras(path, *, size=None) -> list:
    """Cameras from a camera JSON, a ``transforms.json`` (has ``frames``) or a COLMAP model folder
    (:func:`l3gs_opt.scene.cameras.load_any_cameras`); ``size`` = ``(width, height)`` in pixels
    is the size of a file without one and rescales the others."""
    from l3gs_opt.scene.cameras import load_any_cameras as load

    width, height = size if size is not None else (None, None)
    return load(path, width=width, height=height)


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
    """``r,g,b`` as three floats; anything else is passed on as given, for the one background check
    to name it in one error line (``--background: ... must be 3 numbers in [0, 1]``)."""
    try:
        return [float(v) for v in text.split(",")]
    except ValueError:
        return text


def _cmd_render(args: argparse.Namespace) -> int:
    import time

    from l3gs_opt.renderer.render import render_scene
    from l3gs_opt.scene.cameras import check_background, parse_image_size
    from l3gs_opt.scene.scene_files import read_scene

    out = Path(args.out)
    if out.suffix.lower() not in (".png", ".npy"):
        raise OutputError(f"--out: {out.name} must end in .png or .npy")
    size = parse_image_size(args.size, field="--size") if args.size is not None else None
    # named as the option, as scene make does, and before the scene is read
    background = check_background(args.background, "--background") if args.background is not None else None
    scene = read_scene(args.scene, ignore_unknown=args.ignore_unknown_properties)
    cams = load_any_cameras(args.camera, size=size)
    # no Python negative indexing: --index -1 silently rendering the last camera hides a typo
    if not 0 <= args.index < len(cams):
        raise CameraError(f"--index: {args.index} out of range ({args.camera} holds {len(cams)} cameras, "
                          f"indices 0..{len(cams) - 1})")
    cam = cams[args.index]
    if background is not None:
        cam = cam.replace(background=background)
    t0 = time.perf_counter()
    result = render_scene(scene, cam, sh_degree=args.sh_degree)
    dt = time.perf_counter() - t0
    save_image(result.image.numpy(), out)
    print(f"wrote {out}: {cam.width}x{cam.height}, {int(result.projection.visible.sum())} of "
          f"{scene.num_splats} splats visible, {dt:.2f} s (load {os.getloadavg()[0]:.2f})")
    return 0


def _cmd_scene_make(args: argparse.Namespace) -> int:
    from l3gs_opt.scene.camera_paths import orbit_path, walk_path
    from l3gs_opt.scene.cameras import check_background, save_cameras
    from l3gs_opt.scene.scene_files import scene_format
    from l3gs_opt.scene.splats import write_ply
    from l3gs_opt.scene.procedural import make_scene

    # only the reference PLY keeps the object ids; another suffix (m.txt) would give a PLY that
    # read_scene and 'scene convert' later refuse by its name
    if scene_format(args.out).extension != ".ply":
        raise OutputError(f"--out: {Path(args.out).name} must end in .ply (scene make writes the reference PLY)")
    # the check render --background uses, also when no camera path is written
    bg = check_background(args.background, "--background") if args.background is not None else (0.0, 0.0, 0.0)
    kw = dict(width=args.width, height=args.height, fov_x_deg=args.fov, background=bg)
    # the camera paths first: a bad size or background fails before any file is written
    paths = [(kind, make(args.views, **kw), out) for kind, make, out in (("orbit", orbit_path, args.orbit),
                                                                         ("walk", walk_path, args.walk)) if out]
    if not paths:   # no path is written: the camera options are still checked, not taken in silence
        orbit_path(args.views, **kw)
    scene = make_scene(args.splats, objects=args.objects, sh_degree=args.sh_degree, seed=args.seed)
    path = write_ply(scene, args.out)
    print(f"wrote {path}: {scene!r}, {path.stat().st_size} bytes")
    for kind, cams, out in paths:
        p = save_cameras(cams, out)
        print(f"wrote {p}: {kind} path, {args.views} cameras {args.width}x{args.height}")
    return 0


def _cmd_scene_info(args: argparse.Namespace) -> int:
    import numpy as np

    from l3gs_opt.scene.scene_files import read_scene
    from l3gs_opt.scene.splats import bytes_per_splat

    scene = read_scene(args.scene, ignore_unknown=args.ignore_unknown_properties)
    info = {"file": str(args.scene), "file_bytes": Path(args.scene).stat().st_size,
            "splats": scene.num_splats, "sh_degree": scene.sh_degree,
            "bytes_per_splat": bytes_per_splat(scene.sh_degree),
            "objects": scene.num_objects, "layers": scene.num_layers,
            "has_normals": scene.normals is not None}
    if scene.num_splats:
        info["bbox_min"] = scene.means.min(0).round(4).tolist()
        info["bbox_max"] = scene.means.max(0).round(4).tolist()
        # the sigmoid as 0.5 (1 + tanh(x / 2)): 1 / (1 + exp(-x)) overflows (a warning) for logits below -709
        logits = scene.opacity_logits.astype(np.float64)
        info["mean_opacity"] = round(float(np.mean(0.5 * (1 + np.tanh(0.5 * logits)))), 4)
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


def _parse_objects(text: str):
    """``auto`` or a whole number; anything else is left to the library's named check."""
    if text == "auto":
        return text
    try:
        return int(text)
    except ValueError:
        return text


def _identity_features(path):
    """Gaussian Grouping's identity encodings when a PLY carries them, else None."""
    if not str(path).lower().endswith(".ply"):
        return None
    from l3gs_opt.scene.splats import read_identity_features

    return read_identity_features(path)


def _cmd_scene_segment(args: argparse.Namespace) -> int:
    from l3gs_opt.scene.scene_files import read_scene, scene_format, write_scene
    from l3gs_opt.scene.segment import object_counts, segment_scene

    scene_format(args.out)   # an unknown output extension fails before the segmentation runs
    scene = read_scene(args.scene, ignore_unknown=args.ignore_unknown_properties)
    features = _identity_features(args.scene)
    t0 = time.perf_counter()
    out = segment_scene(scene, _parse_objects(args.objects), method=args.method, planes=args.planes,
                        background=args.background, seed=args.seed, features=features)
    dt = time.perf_counter() - t0
    path = write_scene(out, args.out)
    how = "k-means on the file's identity encodings" if features is not None else args.method
    print(f"wrote {path}: {out.num_splats} splats in {out.num_objects} objects ({how}, "
          f"{args.planes} planes{', background' if args.background else ''}; {dt:.1f} s), "
          f"splats per object {object_counts(out)}")
    return 0


def _cmd_scene_build(args: argparse.Namespace) -> int:
    from l3gs_opt.pipeline.build import DEFAULT, QUICK, build_bundle
    from l3gs_opt.scene.cameras import parse_image_size

    size = parse_image_size(args.size, field="--size") if args.size is not None else None
    schedule = QUICK if args.quick else DEFAULT
    if args.max_width is not None:
        import dataclasses

        schedule = dataclasses.replace(schedule, max_width=args.max_width)
    teacher = args.teacher
    if args.objects is not None or args.cameras is None:
        from l3gs_opt.scene.scene_files import read_scene

        teacher = read_scene(args.teacher, ignore_unknown=args.ignore_unknown_properties)
    if args.objects is not None:
        from l3gs_opt.scene.segment import object_counts, segment_scene

        t0 = time.perf_counter()
        teacher = segment_scene(teacher, _parse_objects(args.objects), planes=args.planes,
                                background=args.background, seed=args.seed,
                                features=_identity_features(args.teacher))
        print(f"segmented the teacher into {teacher.num_objects} objects in {time.perf_counter() - t0:.1f} s: "
              f"splats per object {object_counts(teacher)}")
    if args.cameras is not None:
        cams = load_any_cameras(args.cameras, size=size)
    else:
        from l3gs_opt.scene.camera_sampling import sample_cameras

        w, h = size or (schedule.max_width, max(1, round(schedule.max_width * 3 / 4)))
        cams = sample_cameras(teacher, args.views, mode=args.camera_mode, width=w, height=h, seed=args.seed)
        print(f"no --cameras: {len(cams)} cameras sampled {args.camera_mode} the scene, {w}x{h}")
    res = build_bundle(teacher, cams, _parse_sizes(args.layers), args.variant, args.out, schedule=schedule,
                       resume=args.resume, show_progress=not args.no_progress, log=print)
    print(f"total {res.total_seconds:.1f} s (load {os.getloadavg()[0]:.2f})")
    return 0


def _cmd_scene_convert(args: argparse.Namespace) -> int:
    from l3gs_opt.scene.scene_files import read_scene, scene_format, write_scene

    fmt_out = scene_format(args.out)   # an unknown output extension fails before the input is read
    t0 = time.perf_counter()
    scene = read_scene(args.scene, ignore_unknown=args.ignore_unknown_properties)
    path = write_scene(scene, args.out)
    size_in, size_out = Path(args.scene).stat().st_size, path.stat().st_size
    n = max(scene.num_splats, 1)
    print(f"wrote {path}: {scene!r} as {fmt_out.description}; {size_in:,} -> {size_out:,} bytes "
          f"({size_in / n:.1f} -> {size_out / n:.1f} bytes a splat), {time.perf_counter() - t0:.2f} s")
    if not fmt_out.keeps_ids and (scene.object_ids is not None or scene.layers is not None):
        print("note: object ids and layers are not kept by this format")
    return 0


def register(subparsers) -> None:
    """Add ``render`` and ``scene`` (``make``, ``info``, ``segment``, ``build``) to an argparse subparsers object."""
    p = subparsers.add_parser("render", help="render a splat scene (.ply) from a camera to .png or .npy")
    p.add_argument("scene", help="scene file (.ply, .compressed.ply, .splat, .spz)")
    p.add_argument("--camera", required=True,
                   help="camera JSON (object or list), NeRF/Blender transforms.json, or COLMAP sparse folder")
    p.add_argument("--out", required=True, help="output image: .png (8-bit) or .npy (float32 HxWx3, unclipped)")
    p.add_argument("--index", type=int, default=0,
                   help="camera index 0..count-1 when the file holds several (default 0)")
    p.add_argument("--size", metavar="WxH", default=None,
                   help="image size in pixels, e.g. 800x800: needed for NeRF-synthetic transforms.json files, "
                        "which have camera_angle_x but no w/h; a camera file with its own size is rescaled "
                        "to it (fx, cx scale with the width, fy, cy with the height; the aspect ratio must "
                        "stay, up to rounding)")
    p.add_argument("--background", type=_parse_rgb, default=None, help="override the background, r,g,b in [0, 1]")
    p.add_argument("--sh-degree", type=int, choices=[0, 1, 2, 3], default=None,
                   help="render with SH degrees up to this only")
    p.add_argument("--ignore-unknown-properties", action="store_true",
                   help="skip unknown PLY vertex properties instead of failing")
    p.set_defaults(func=_cmd_render)

    s = subparsers.add_parser("scene", help="make or inspect splat scenes")
    ssub = s.add_subparsers(dest="scene_command", required=True)
    m = ssub.add_parser("make", help="build a procedural multi-object room scene (+ camera paths)")
    m.add_argument("--out", required=True, help="output PLY file (.ply)")
    m.add_argument("--splats", type=int, default=100_000, help="number of splats (default 100000; 1000..2000000)")
    m.add_argument("--objects", type=int, default=5, help="objects on the floor (1..12, default 5)")
    m.add_argument("--sh-degree", type=int, choices=[0, 1, 2, 3], default=3, help="SH degree (default 3)")
    m.add_argument("--seed", type=int, default=0, help="random seed (default 0)")
    m.add_argument("--orbit", help="also write an orbit camera path (camera JSON list) here")
    m.add_argument("--walk", help="also write a walk-through camera path (camera JSON list) here")
    m.add_argument("--views", type=int, default=36, help="cameras per path (default 36; 1..10000)")
    m.add_argument("--width", type=int, default=800, help="image width of the path cameras (default 800)")
    m.add_argument("--height", type=int, default=600, help="image height of the path cameras (default 600)")
    m.add_argument("--fov", type=float, default=70.0, help="horizontal field of view in degrees (default 70)")
    m.add_argument("--background", type=_parse_rgb, default=None, help="camera background r,g,b (default black)")
    m.set_defaults(func=_cmd_scene_make)
    i = ssub.add_parser("info", help="print a scene's size, SH degree, objects and layers")
    i.add_argument("scene", help="scene file (.ply, .compressed.ply, .splat, .spz)")
    i.add_argument("--json", action="store_true", help="print one JSON object")
    i.add_argument("--ignore-unknown-properties", action="store_true",
                   help="skip unknown PLY vertex properties instead of failing")
    i.set_defaults(func=_cmd_scene_info)
    g = ssub.add_parser("segment", help="give a scene object ids from its splat centres (connected components or "
                                        "k-means, optional floor/wall planes and far background)")
    g.add_argument("scene", help="scene file (.ply, .compressed.ply, .splat, .spz)")
    g.add_argument("--objects", default="auto",
                   help="number of objects, or 'auto' (default): as many as the scene's separate parts (at most 32)")
    g.add_argument("--method", default="components", choices=["components", "kmeans"],
                   help="how the splats left after planes and background are grouped (default components)")
    g.add_argument("--planes", type=int, default=0,
                   help="dominant planes split off first as objects (floor, walls: e.g. 1 or 6; default 0)")
    g.add_argument("--background", action="store_true", help="split the far background off as one object")
    g.add_argument("--out", required=True, help="output PLY file (with object_id)")
    g.add_argument("--seed", type=int, default=0, help="random seed (default 0)")
    g.add_argument("--ignore-unknown-properties", action="store_true",
                   help="skip unknown PLY vertex properties instead of failing")
    g.set_defaults(func=_cmd_scene_segment)
    b = ssub.add_parser("build", help="train a layered / separate / sort / distill / hierarchy bundle from a teacher")
    b.add_argument("teacher", help="teacher scene (.ply, .compressed.ply, .splat, .spz)")
    b.add_argument("--cameras", default=None,
                   help="training cameras: camera JSON list, NeRF/Blender transforms.json or COLMAP folder; "
                        "without it, --views cameras are sampled around the scene (--camera-mode)")
    b.add_argument("--size", default=None, metavar="WxH",
                   help="image size of the cameras (a transforms.json without w/h; sampled cameras)")
    b.add_argument("--views", type=int, default=32, help="sampled cameras when no --cameras (default 32)")
    b.add_argument("--camera-mode", default="outside", choices=["outside", "inside"],
                   help="sampled cameras on a sphere around the scene (objects) or inside it (rooms)")
    b.add_argument("--layers", required=True,
                   help="cumulative sizes in splats, increasing, e.g. 45000,90000,135000,180000")
    b.add_argument("--variant", default="layered", choices=["layered", "separate", "sort", "distill", "hierarchy"],
                   help="default layered")
    b.add_argument("--objects", default=None,
                   help="segment the teacher first: a count or 'auto' (see 'scene segment'); default: keep its ids")
    b.add_argument("--planes", type=int, default=0, help="with --objects: dominant planes split off first")
    b.add_argument("--background", action="store_true", help="with --objects: the far background as one object")
    b.add_argument("--seed", type=int, default=0, help="seed of the segmentation and sampled cameras")
    b.add_argument("--out", required=True, help="bundle directory (manifest.json + chunks/)")
    b.add_argument("--quick", action="store_true", help="small views and short training (demo, CI)")
    b.add_argument("--resume", action="store_true", help="continue an interrupted build from its checkpoints")
    b.add_argument("--max-width", type=int, default=None, help="training view width in pixels (overrides the schedule)")
    b.add_argument("--no-progress", action="store_true", help="no progress bars")
    b.add_argument("--ignore-unknown-properties", action="store_true",
                   help="skip unknown PLY vertex properties instead of failing")
    b.set_defaults(func=_cmd_scene_build)
    c = ssub.add_parser("convert", help="convert a scene between .ply, .compressed.ply, .splat and .spz (by extension)")
    c.add_argument("scene", help="input scene file")
    c.add_argument("out", help="output scene file; its extension picks the format")
    c.add_argument("--ignore-unknown-properties", action="store_true",
                   help="skip unknown PLY vertex properties instead of failing")
    c.set_defaults(func=_cmd_scene_convert)
