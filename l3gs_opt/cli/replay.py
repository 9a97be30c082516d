"""CLI subcommand ``replay``: an HTML page of a simulated run (``l3gs-opt replay RUN --out PAGE``).

Wire into the main parser with ``register(subparsers)``. The page is
:func:`l3gs_opt.delivery.replay.write_replay`'s; bad input raises
:class:`l3gs_opt.errors.L3gsError` subclasses, which the main CLI prints as one line (exit 2).
"""

from __future__ import annotations

import argparse

__all__ = ["register"]


def _cmd_replay(args: argparse.Namespace) -> int:
    from l3gs_opt.delivery.replay import write_replay

    path = write_replay(args.run_dir, args.out)
    print(f"wrote {path} (open it in a browser; it needs no network)")
    return 0


def register(subparsers) -> None:
    """Add ``replay`` to an argparse subparsers object."""
    p = subparsers.add_parser("replay", help="an HTML page of a simulated run: the client's view beside the "
                                             "reference per second, SSIM, bytes and the chunks that arrived")
    p.add_argument("run_dir", help="a simulate --out folder (slots.jsonl; views/ with simulate --save-views)")
    p.add_argument("--out", required=True,
                   help="the page's folder: index.html and the pictures it shows (may be RUN_DIR itself)")
    p.set_defaults(func=_cmd_replay)
