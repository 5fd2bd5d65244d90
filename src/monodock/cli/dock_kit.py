"""``monodock dock-kit``: the charger's markers as PDFs to print at exact scale, with where they go on the charger."""

from __future__ import annotations

import argparse
from pathlib import Path

from monodock.cli.options import SubParsers, add_command
from monodock.core.atomic import atomic_directory, check_writable, write_bytes_atomic
from monodock.core.layout import DockLayout
from monodock.errors import InputError
from monodock.report.dock_kit import PAPERS, dock_kit_pdf, misfit

__all__ = ["add_parser", "run"]

PAPER_CHOICES = (*PAPERS, "both")


def add_parser(subparsers: SubParsers) -> None:
    """Add ``dock-kit``."""
    p = add_command(subparsers, "dock-kit", run)
    p.add_argument("--layout", required=True, help="dock layout YAML: the markers to print")
    p.add_argument("--out", required=True, metavar="DIR", help="folder to write (a new one, or replaced with --force)")
    p.add_argument(
        "--paper",
        choices=PAPER_CHOICES,
        default="both",
        help="paper size: a4 (210 x 297 mm), letter (8.5 x 11 in), both of those (the default), or a3 / a2 for a "
        "far-field marker larger than A4 holds",
    )
    p.add_argument("--sheet", action="store_true", help="as many markers per page as fit, not one page each")
    p.add_argument("--force", action="store_true", help="replace an existing DIR")


def run(args: argparse.Namespace) -> int:
    """a printable dock kit: the layout's markers at exact scale and where they go on the charger (PDF)

    Write DIR with dock_kit_a4.pdf and/or dock_kit_letter.pdf (one page per marker, or --sheet, and a placement drawing)
    and layout.yaml. Print at 100 % / actual size and check the 10 cm scale bar."""
    # Every paper is checked to fit before anything is drawn; the folder is then written in one rename.
    check_writable(args.out, force=args.force, inputs=(args.layout,))
    layout = DockLayout.load(args.layout)
    keys = ["a4", "letter"] if args.paper == "both" else [args.paper]
    reasons = {key: misfit(layout, PAPERS[key]) for key in keys}
    for reason in reasons.values():
        if reason is not None:
            # With --paper both, a kit that fits only one paper is refused too, saying which one it fits.
            fits = [k for k, r in reasons.items() if r is None]
            hint = f"; it fits on {PAPERS[fits[0]].name}: pass --paper {fits[0]}" if fits else ""
            raise InputError(reason + hint)
    pdfs = {f"dock_kit_{key}.pdf": dock_kit_pdf(layout, PAPERS[key], sheet=args.sheet) for key in keys}
    with atomic_directory(args.out, force=args.force) as tmp:
        for name, data in pdfs.items():
            write_bytes_atomic(tmp / name, data)
        layout.save(tmp / "layout.yaml")
    out = Path(args.out)
    ids = ", ".join(str(m.id) for m in layout.markers)
    written = ", ".join(str(out / name) for name in [*pdfs, "layout.yaml"])
    print(f"dock kit: {layout.dictionary} markers {ids} -> {written}")
    print("print at 100 % / actual size (no fit-to-page) and check the 10 cm scale bar with a ruler")
    return 0
