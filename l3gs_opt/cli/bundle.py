"""CLI subcommands for streamable bundles: ``bundle export``, ``bundle tables`` and ``bundle info``.

Wire into the main parser with ``register(subparsers)``; each subcommand sets ``func`` to a
handler ``handler(args) -> int``. Bad input raises :class:`l3gs_opt.errors.L3gsError` subclasses
(``BundleError``, ``StreamError``), which the main CLI prints as one line (exit 2).
"""

from __future__ import annotations

import argparse

__all__ = ["register", "stream_summary"]


def _cmd_bundle_export(args: argparse.Namespace) -> int:
    from pathlib import Path

    from l3gs_opt.scene.stream_index import StreamError, export_stream, read_stream

    # Re-exporting into an export folder rewrites it (intended); a bundle's folder would lose its chunk files.
    if (Path(args.out) / "manifest.json").exists() and Path(args.out).resolve() != Path(args.bundle).resolve():
        raise StreamError("--out", f"{args.out} holds a bundle (manifest.json): export to a new or empty folder")
    path = export_stream(args.bundle, args.out, pack=args.pack, alignment=args.align)
    index = read_stream(path)  # what a client will read: checked before we say "wrote"
    print(f"wrote {path}: {len(index.chunks)} chunks, {index.total_bytes} bytes in {len(index.filenames)} "
          f"file(s) ({index.pack}, alignment {index.alignment} bytes)")
    return 0


def _numbers(text: str, field: str, kind=float) -> list:
    from l3gs_opt.delivery.tables import TablesError

    try:
        return [kind(x) for x in text.split(",")]
    except ValueError:
        raise TablesError(field, f"{text!r}: expected comma-separated {'integers' if kind is int else 'numbers'}") \
            from None


def _cmd_bundle_tables(args: argparse.Namespace) -> int:
    from l3gs_opt.delivery.tables import TablesError, export_tables

    counts = _numbers(args.grid, "--grid", int)
    if len(counts) != 3:
        raise TablesError("--grid", f"{args.grid!r}: expected NX,NY,NZ")
    path = export_tables(args.stream, utility=args.utility, views=args.views.split(","), counts=counts,
                         margin=args.margin, yaw_steps=args.yaw_steps, pitches_deg=_numbers(args.pitches, "--pitches"),
                         up=args.up, width=args.width, height=args.height, fov_deg=args.fov,
                         progress=not args.no_progress)
    from l3gs_opt.delivery.tables import read_tables

    for e in read_tables(path):
        print(f"wrote {path.parent / e['file']}: {e['utility']} / {e['view']}, {e['bytes']} bytes")
    return 0


def stream_summary(index) -> dict:
    """What ``bundle info`` prints about a :class:`~l3gs_opt.scene.stream_index.StreamIndex`
    (bytes are chunk bytes; ``file_bytes`` include the padding between chunks)."""
    return {"index": str(index.path / "index.json"), "variant": index.variant,
            "representation": index.representation, "segmented": index.segmented, "sh_degree": index.sh_degree,
            "compact_sh_degree": index.compact_sh_degree, "pack": index.pack, "alignment": index.alignment,
            "splats": index.count, "levels": len(index.levels), "objects": len(index.objects),
            "chunks": len(index.chunks), "bytes": index.total_bytes,
            "file_bytes": sum((index.path / f).stat().st_size for f in index.filenames),
            "files": len(index.filenames),
            "bytes_per_splat": {r.sh_form: r.bytes for r in index.records},
            "splats_per_level": [lv.splats for lv in index.levels],
            "bytes_per_level": [lv.bytes for lv in index.levels],
            "bytes_per_object_level": {o.id: list(o.bytes) for o in index.objects}}


def _cmd_bundle_info(args: argparse.Namespace) -> int:
    from l3gs_opt.scene.stream_index import read_stream, verify_stream

    index = read_stream(args.stream)
    info = stream_summary(index)
    if args.verify:
        verify_stream(index)
        info["verified_bytes"] = index.total_bytes
    if args.json:
        from l3gs_opt.jsonout import dumps

        print(dumps(info, where="info"))
    else:
        for k, v in info.items():
            print(f"{k}: {v}")
    return 0


def register(subparsers) -> None:
    """Add ``bundle`` (``export``, ``info``) to an argparse subparsers object."""
    from l3gs_opt.scene.stream_index import DEFAULT_ALIGNMENT, PACKS

    b = subparsers.add_parser("bundle", help="export bundles for HTTP Range streaming and inspect the exports")
    bsub = b.add_subparsers(dest="bundle_command", required=True)
    e = bsub.add_parser("export", help="write index.json + chunk data a web client fetches by HTTP Range")
    e.add_argument("bundle", metavar="BUNDLE", help="bundle directory (manifest.json + chunks/)")
    e.add_argument("--out", required=True, metavar="DIR", help="output folder (index.json + chunks.bin or chunks/)")
    e.add_argument("--pack", default="single", choices=list(PACKS),
                   help="single: all chunks in chunks.bin (default); per-chunk: one file per chunk")
    e.add_argument("--align", type=int, default=DEFAULT_ALIGNMENT, metavar="BYTES",
                   help=f"chunk start alignment in chunks.bin, a power of two (default {DEFAULT_ALIGNMENT})")
    e.set_defaults(func=_cmd_bundle_export)
    t = bsub.add_parser("tables", help="precompute utility tables a client values chunks by before it holds any "
                                       "(served with the export; fetch --catalogue tables)")
    t.add_argument("stream", metavar="STREAM_DIR", help="export folder (index.json)")
    t.add_argument("--utility", default="eq1", help="a held-free splat utility (eq1, visibility, ...)")
    t.add_argument("--views", default="object", help="comma-separated: object (per-object methods), scene")
    t.add_argument("--grid", default="5,5,2", metavar="NX,NY,NZ", help="positions per axis over the scene's box")
    t.add_argument("--margin", type=float, default=0.5, help="box widened by this times its extent per side")
    t.add_argument("--yaw-steps", type=int, default=12)
    t.add_argument("--pitches", default="-20,0,20", metavar="DEG,...")
    t.add_argument("--up", default="z", choices=["x", "y", "z"])
    t.add_argument("--width", type=int, default=160, help="the client's image width (pixels)")
    t.add_argument("--height", type=int, default=120)
    t.add_argument("--fov", type=float, default=70.0, help="the client's horizontal field of view (degrees)")
    t.add_argument("--no-progress", action="store_true")
    t.set_defaults(func=_cmd_bundle_tables)
    i = bsub.add_parser("info", help="check a stream export's index and summarise it")
    i.add_argument("stream", metavar="STREAM_DIR", help="export folder (or its index.json)")
    i.add_argument("--verify", action="store_true", help="also hash every chunk against the index")
    i.add_argument("--json", action="store_true", help="print one JSON object")
    i.set_defaults(func=_cmd_bundle_info)
