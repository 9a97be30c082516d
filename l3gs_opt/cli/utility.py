"""CLI subcommand ``utility``: list the splat utilities, and check how well each predicts the picture.

``l3gs-opt utility list`` names the registered utilities; ``l3gs-opt utility check BUNDLE --path P``
runs :func:`l3gs_opt.pipeline.fidelity.utility_fidelity` and writes ``fidelity.json`` and
``fidelity.png`` (rank correlation per utility, and the time per viewpoint) into ``--out``.
"""

from __future__ import annotations

import argparse
from pathlib import Path

__all__ = ["register", "plot_fidelity"]


def plot_fidelity(report, path: Path) -> Path:
    """Bars of each utility's mean Spearman correlation with the measured SSIM gain (per sample,
    per byte, pooled), and its milliseconds per viewpoint."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt
    import numpy as np

    names = report.utilities
    keys = (("spearman_ssim", "per sample"), ("spearman_ssim_per_byte", "per sample, per byte"),
            ("spearman_ssim_pooled", "pooled over samples"))
    fig, (ax, bx) = plt.subplots(1, 2, figsize=(10, 3.6), gridspec_kw={"width_ratios": [3, 1.4]})
    x = np.arange(len(names))
    w = 0.8 / len(keys)
    for i, (k, label) in enumerate(keys):
        vals = [report.correlations[n].get(k) for n in names]
        ax.bar(x + (i - 1) * w, [np.nan if v is None else v for v in vals], w, label=label)
    size = report.setup.get("spearman_ssim_chunk_size")
    if size is not None:
        ax.axhline(size, color="grey", linestyle="--", linewidth=1, label=f"chunk size alone ({size:.2f})")
    ax.set_xticks(x, names, rotation=15)
    ax.set_ylim(-0.2, 1.3)
    ax.set_ylabel("Spearman rank correlation")
    ax.set_title(f"utility vs measured SSIM gain of adding a chunk ({report.setup['candidates']} candidates)",
                 fontsize=9)
    ax.legend(fontsize=7, loc="upper center", ncol=2)
    ms = [1e3 * report.seconds_per_viewpoint[n] for n in names]
    bx.barh(names, ms, color="tab:purple")
    bx.set_xscale("log")
    bx.set_xlabel(f"ms per viewpoint ({report.setup['splats']} splats)")
    fig.tight_layout()
    fig.savefig(path, dpi=120)
    plt.close(fig)
    return path


def _cmd_check(args: argparse.Namespace) -> int:
    from tqdm import tqdm

    from l3gs_opt.jsonout import dumps
    from l3gs_opt.pipeline.fidelity import utility_fidelity

    names = [n.strip() for n in args.utilities.split(",") if n.strip()]
    twice = [n for i, n in enumerate(names) if n in names[:i]]
    if twice:   # each would be measured twice and shown as two rows
        from l3gs_opt.pipeline.fidelity import FidelityError

        raise FidelityError(f"--utilities: {twice[0]!r} is named twice")
    out = Path(args.out)
    if out.exists() and not out.is_dir():
        from l3gs_opt.pipeline.fidelity import FidelityError

        raise FidelityError(f"--out {out}: is a file, not a folder")
    bar = None   # made at the first sample: an argument refused before it leaves one error line, no bar

    def progress(i: int, n: int) -> None:
        nonlocal bar
        if bar is None:
            bar = tqdm(desc="fidelity", unit="sample", total=n, disable=args.no_progress)
        bar.update(i - bar.n)

    report = utility_fidelity(args.bundle, args.path, utilities=names, samples=args.samples, slots=args.slots,
                              samples_per_slot=args.samples_per_slot, width=args.width, height=args.height,
                              fov_deg=args.fov, seed=args.seed, up=args.up, progress=progress)
    if bar is not None:
        bar.close()
    out.mkdir(parents=True, exist_ok=True)
    (out / "fidelity.json").write_text(dumps(report.to_dict(), indent=1, where="fidelity") + "\n")
    plot = plot_fidelity(report, out / "fidelity.png")
    if args.json:
        print(dumps({"correlations": report.correlations, "seconds_per_viewpoint": report.seconds_per_viewpoint,
                     "setup": report.setup}, where="fidelity"))
        return 0
    print(f"{report.setup['candidates']} candidate chunks over {report.setup['samples']} samples "
          f"({report.setup['splats']} splats, {args.width}x{args.height}); chunk size alone: Spearman "
          f"{report.setup['spearman_ssim_chunk_size']:.2f}")
    print(f"  {'utility':<18} {'Spearman':>8} {'Kendall':>8} {'per byte':>8} {'pooled':>8} {'ms/view':>8}")
    fmt = lambda v: "    -   " if v is None else f"{v:8.3f}"  # noqa: E731
    for n in report.utilities:
        c = report.correlations[n]
        print(f"  {n:<18} {fmt(c['spearman_ssim'])} {fmt(c['kendall_ssim'])} {fmt(c['spearman_ssim_per_byte'])} "
              f"{fmt(c['spearman_ssim_pooled'])} {1e3 * report.seconds_per_viewpoint[n]:8.1f}")
    print(f"  wrote {out / 'fidelity.json'}, {plot}")
    return 0


def _cmd_list(args: argparse.Namespace) -> int:
    from l3gs_opt.pipeline.utilities import get_utility, utility_names

    for n in utility_names():
        u = get_utility(n)
        print(f"{n:<18} unit: {u.unit}{' (held-aware)' if u.held_aware else ''}")
    return 0


def register(subparsers) -> None:
    """Add ``utility list`` and ``utility check`` to an argparse subparsers object."""
    p = subparsers.add_parser("utility", help="splat utilities: list them, check how well they predict the picture")
    sub = p.add_subparsers(dest="action", required=True)
    sub.add_parser("list", help="the registered utilities").set_defaults(func=_cmd_list)
    c = sub.add_parser("check", help="rank correlation of each utility with the measured SSIM/PSNR gain of "
                                     "adding a chunk; fidelity.json and fidelity.png")
    c.add_argument("bundle", help="a layered bundle directory")
    c.add_argument("--path", required=True, help="headset pose log, camera JSON list or camera path file")
    c.add_argument("--utilities", default="eq1,visibility,visibility-held,coverage",
                   help="comma-separated utility names (default: eq1,visibility,visibility-held,coverage)")
    c.add_argument("--samples", type=int, default=8, help="sampled (slot, held state) pairs (default 8)")
    c.add_argument("--slots", type=int, default=30, help="slots of the path the samples are spread over")
    c.add_argument("--samples-per-slot", type=int, default=1, help="viewpoints per sample")
    c.add_argument("--width", type=int, default=128)
    c.add_argument("--height", type=int, default=96)
    c.add_argument("--fov", type=float, default=70.0, help="horizontal field of view, degrees")
    c.add_argument("--seed", type=int, default=0, help="seed of the held states")
    c.add_argument("--up", default="z", choices=["y", "z"], help="the scene's up axis (pose logs are y up)")
    c.add_argument("--out", default="fidelity-out", help="folder for fidelity.json and fidelity.png")
    c.add_argument("--json", action="store_true", help="print the correlations and timings as one JSON object")
    c.add_argument("--no-progress", action="store_true")
    c.set_defaults(func=_cmd_check)
