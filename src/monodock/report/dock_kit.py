"""The dock kit: the charger's markers as a vector PDF at exact physical scale, and a drawing of where they go.

One page per marker (or, with ``sheet``, as many markers per page as fit): the marker centred in its white quiet
zone, a dashed cut line with ticks on the marker's centre lines, a label, and a 10 cm scale bar to check the
printer's scale with a ruler. A last page draws the charger's face from the front at a stated reduced scale, with
the distances between the marker centres and their heights above the floor.

The page is one axes spanning the whole figure in millimetres, and the figure is exactly the paper's size, so a
length of 100 in data coordinates prints as 100 mm. A marker's black cells are one path (its horizontal runs as
rectangles of one orientation), filled once: a renderer's anti-aliasing leaves no hairline between adjacent cells.
"""

from __future__ import annotations

import textwrap
from collections.abc import Iterable
from dataclasses import dataclass
from io import BytesIO

import numpy as np
from matplotlib.axes import Axes
from matplotlib.backends.backend_pdf import PdfPages
from matplotlib.figure import Figure
from matplotlib.patches import PathPatch, Rectangle
from matplotlib.path import Path as MplPath
from numpy.typing import NDArray

from monodock.core.layout import DockLayout, MarkerSpec
from monodock.errors import InputError

__all__ = ["MARGIN_MM", "PAPERS", "SCALE_BAR_MM", "Paper", "check_fits", "dock_kit_pdf", "marker_path", "misfit"]

MM_PER_INCH = 25.4
PT_MM = MM_PER_INCH / 72.0  # one typographic point in millimetres

# Kept blank on every side of the page: most printers cannot print closer to the edge.
MARGIN_MM = 10.0
SCALE_BAR_MM = 100.0
# The white kept around a marker inside its cut line: one cell, and never less than this (a small marker's cell
# is narrower than a cut with scissors is straight).
MIN_QUIET_MM = 5.0
# Between the quiet zone and the cut line: a band for the centre-line ticks and the "top" mark.
BAND_MM = 4.0
# The bands of a marker's page above and below its card: the label, and the scale bar with its caption.
HEADER_MM = 24.0
FOOTER_MM = 24.0
SHEET_HEADER_MM = 16.0
SHEET_LABEL_MM = 13.0  # its two lines, clear of the card's top tick
SHEET_GAP_MM = 8.0  # between cards: their ticks stay apart
# How far the centre-line ticks reach outside the cut line.
TICK_OUT_MM = 3.0
# The placement drawing's scales, largest first: 1:1, 1:2, 1:2.5, ...
SCALES = (1.0, 2.0, 2.5, 4.0, 5.0, 10.0, 20.0, 25.0, 50.0, 100.0, 200.0)


@dataclass(frozen=True)
class Paper:
    """A paper size: its name as printed and its width and height (portrait), millimetres."""

    name: str
    width_mm: float
    height_mm: float

    @property
    def printable(self) -> tuple[float, float]:
        """Width and height inside the margins, millimetres."""
        return self.width_mm - 2 * MARGIN_MM, self.height_mm - 2 * MARGIN_MM

    @property
    def card_box(self) -> tuple[float, float]:
        """The largest card (a marker with its quiet zone) a page holds beside its label and scale bar, and with
        its ticks inside the margins, mm."""
        w, h = self.printable
        return w - 2 * TICK_OUT_MM, h - HEADER_MM - FOOTER_MM


# A4 and Letter for the papers' markers; A3 and A2 (a print shop's) for a far-field marker up to ~20 and ~29 cm.
PAPERS = {
    "a4": Paper("A4", 210.0, 297.0),
    "letter": Paper("Letter", 215.9, 279.4),
    "a3": Paper("A3", 297.0, 420.0),
    "a2": Paper("A2", 420.0, 594.0),
}


def _mm(metres: float) -> float:
    return metres * 1000.0


def _side_mm(layout: DockLayout, m: MarkerSpec) -> float:
    return _mm(layout.side(m.role))


def _quiet_mm(layout: DockLayout, m: MarkerSpec) -> float:
    """The white between the marker's black border and its cut line: one cell, at least MIN_QUIET_MM."""
    return max(_side_mm(layout, m) / layout.modules, MIN_QUIET_MM)


def _card_mm(layout: DockLayout, m: MarkerSpec) -> float:
    """The side of a marker's card: the marker, its quiet zone and the band of marks, cut line to cut line."""
    return _side_mm(layout, m) + 2 * (_quiet_mm(layout, m) + BAND_MM)


def misfit(layout: DockLayout, paper: Paper) -> str | None:
    """Why the layout's markers cannot be printed on ``paper`` (the first that does not fit), or None."""
    box_w, box_h = paper.card_box
    for m in layout.markers:
        card = _card_mm(layout, m)
        if card > box_w or card > box_h:
            pw, ph = paper.printable
            return (
                f"marker {m.role} (id {m.id}) is {_side_mm(layout, m):.1f} mm a side, {card:.1f} mm with its white "
                f"margin: it does not fit on {paper.name} paper, whose printable area is {pw:g} x {ph:g} mm inside "
                f"{MARGIN_MM:g} mm margins ({box_w:g} x {box_h:g} mm of it beside the label and scale bar)"
            )
    return None


def check_fits(layout: DockLayout, paper: Paper) -> None:
    """Raise InputError (one line) when a marker does not fit on the paper's printable area."""
    reason = misfit(layout, paper)
    if reason is not None:
        raise InputError(reason)


def dock_kit_pdf(layout: DockLayout, paper: Paper, *, sheet: bool = False) -> bytes:
    """The dock kit for one paper as PDF bytes: one page per marker (``sheet``: as few pages as hold them all),
    then the placement drawing. The same layout and paper give the same bytes.

    Raises:
        InputError: a marker does not fit on the paper (``misfit``).
    """
    check_fits(layout, paper)
    ids = ", ".join(str(m.id) for m in layout.markers)
    sides = ", ".join(f"{_side_mm(layout, m):.1f}" for m in layout.markers)
    metadata = {
        "Title": f"monodock dock kit: {layout.dictionary} markers {ids} ({paper.name})",
        "Subject": f"ArUco markers of {sides} mm and where they go on the charger; print at 100 % / actual size",
        "Keywords": f"ArUco, {layout.dictionary}, dock, charger, monodock",
        "Creator": "monodock dock-kit",
        "CreationDate": None,  # the same layout gives the same bytes
    }
    buf = BytesIO()
    with PdfPages(buf, metadata=metadata) as pdf:
        groups = (
            _sheets(layout, paper) if sheet else [[(m, _single_card_origin(layout, m, paper))] for m in layout.markers]
        )
        for group in groups:
            fig, ax = _page(paper)
            if sheet:
                _sheet_header(ax, layout, paper)
            else:
                _marker_header(ax, layout, group[0][0], paper)
            for m, (x, y) in group:
                _card(ax, layout, m, x, y)
                if sheet:
                    _sheet_label(ax, layout, m, x, y + _card_mm(layout, m))
            _scale_bar(ax)
            pdf.savefig(fig)
        fig, ax = _page(paper)
        _placement(ax, layout, paper)
        _scale_bar(ax)
        pdf.savefig(fig)
    return buf.getvalue()


# --- pages -----------------------------------------------------------------------------------------------------


def _page(paper: Paper) -> tuple[Figure, Axes]:
    """A figure of exactly the paper's size, one axes over all of it in millimetres (origin bottom left)."""
    fig = Figure(figsize=(paper.width_mm / MM_PER_INCH, paper.height_mm / MM_PER_INCH), dpi=72)
    fig.patch.set_facecolor("white")
    ax = fig.add_axes((0.0, 0.0, 1.0, 1.0))
    ax.set_xlim(0.0, paper.width_mm)
    ax.set_ylim(0.0, paper.height_mm)
    ax.set_axis_off()
    return fig, ax


def _lines(ax: Axes, x: float, top: float, lines: Iterable[tuple[str, float, bool]], *, ha: str = "left") -> float:
    """Lines of text (text, size in pt, bold) from ``top`` down; returns the y below the last."""
    y = top
    for text, size, bold in lines:
        ax.text(x, y, text, fontsize=size, fontweight="bold" if bold else "normal", ha=ha, va="top")
        y -= size * PT_MM * 1.45
    return y


def _name(m: MarkerSpec) -> str:
    """A marker as the kit names it: the papers' number and role ("2 · center"), or another marker's own name."""
    return f"{m.number} · {m.role}" if m.number is not None else m.role


def _title(m: MarkerSpec) -> str:
    where = " (over the docking point)" if m.role == "center" and m.y == 0.0 else ""
    return f"Marker {_name(m)}{where} · id {m.id}"


def _marker_header(ax: Axes, layout: DockLayout, m: MarkerSpec, paper: Paper) -> None:
    side = _side_mm(layout, m)
    n = layout.modules
    _lines(
        ax,
        MARGIN_MM,
        paper.height_mm - MARGIN_MM,
        [
            (_title(m), 14.0, True),
            (
                f"{layout.dictionary} · side {side:.1f} mm (outer black border) · {n} × {n} cells of {side / n:.2f} mm",
                9.0,
                False,
            ),
            ("Print at 100 % / actual size, no fit-to-page. Cut along the dashed line.", 9.0, True),
        ],
    )


def _sheet_header(ax: Axes, layout: DockLayout, paper: Paper) -> None:
    _lines(
        ax,
        MARGIN_MM,
        paper.height_mm - MARGIN_MM,
        [
            (f"monodock dock kit · {layout.dictionary} · {paper.name}", 12.0, True),
            ("Print at 100 % / actual size, no fit-to-page. Cut along the dashed lines.", 9.0, True),
        ],
    )


def _sheet_label(ax: Axes, layout: DockLayout, m: MarkerSpec, x: float, top: float) -> None:
    """A marker's label above its card on a sheet: number, role, id; dictionary and side."""
    _lines(
        ax,
        x,
        top + SHEET_LABEL_MM - 1.0,
        [
            (f"{_name(m)} · id {m.id}", 9.0, True),
            (f"{layout.dictionary} · {_side_mm(layout, m):.1f} mm", 7.0, False),
        ],
    )


def _text_width_mm(text: str, size_pt: float) -> float:
    """A generous estimate of a line's width (DejaVu Sans averages well under 0.62 em a character)."""
    return len(text) * size_pt * 0.62 * PT_MM


def _single_card_origin(layout: DockLayout, m: MarkerSpec, paper: Paper) -> tuple[float, float]:
    """Where a marker's card (its lower left corner) goes on a page of its own: centred between the bands."""
    card = _card_mm(layout, m)
    bottom = MARGIN_MM + FOOTER_MM
    top = paper.height_mm - MARGIN_MM - HEADER_MM
    return (paper.width_mm - card) / 2, bottom + (top - bottom - card) / 2


def _sheets(layout: DockLayout, paper: Paper) -> list[list[tuple[MarkerSpec, tuple[float, float]]]]:
    """The markers packed onto as few pages as hold them: rows left to right, top to bottom, in role order."""
    left = MARGIN_MM + TICK_OUT_MM
    right = paper.width_mm - MARGIN_MM - TICK_OUT_MM
    top = paper.height_mm - MARGIN_MM - SHEET_HEADER_MM
    bottom = MARGIN_MM + FOOTER_MM
    pages: list[list[tuple[MarkerSpec, tuple[float, float]]]] = [[]]
    x, row_top, row_h = left, top, 0.0
    for m in layout.markers:
        card = _card_mm(layout, m)
        label = max(
            _text_width_mm(f"{_name(m)} · id {m.id}", 9.0),
            _text_width_mm(f"{layout.dictionary} · {_side_mm(layout, m):.1f} mm", 7.0),
        )
        w, h = max(card, label), card + SHEET_LABEL_MM
        if x > left and x + w > right:  # a new row
            x, row_top, row_h = left, row_top - row_h - SHEET_GAP_MM, 0.0
        if pages[-1] and row_top - h < bottom:  # a new page
            pages.append([])
            x, row_top, row_h = left, top, 0.0
        pages[-1].append((m, (x, row_top - h)))
        x += w + SHEET_GAP_MM
        row_h = max(row_h, h)
    return pages


# --- drawing ---------------------------------------------------------------------------------------------------


def _rectangles(rects: Iterable[tuple[float, float, float, float]]) -> MplPath:
    """Rectangles (x0, y0, x1, y1) as one path, each counter-clockwise: filled once (non-zero rule), those that
    touch leave no seam between them, as separate fills would under a renderer's anti-aliasing."""
    vertices: list[tuple[float, float]] = []
    codes: list[np.uint8] = []
    for x0, y0, x1, y1 in rects:
        vertices += [(x0, y0), (x1, y0), (x1, y1), (x0, y1), (x0, y0)]
        codes += [MplPath.MOVETO, MplPath.LINETO, MplPath.LINETO, MplPath.LINETO, MplPath.CLOSEPOLY]
    return MplPath(np.array(vertices), np.array(codes, dtype=np.uint8))


def marker_path(bits: NDArray[np.uint8], x: float, y: float, cell: float) -> MplPath:
    """A marker's black cells as one path: each horizontal run of black cells in a row one rectangle.

    Args:
        bits: the cells, 0 black, 1 white, row 0 at the top, shape (n, n).
        x, y: the marker's lower left corner, millimetres (y up).
        cell: a cell's side, millimetres.
    """
    n = bits.shape[0]
    rects = []
    for r in range(n):
        y1 = y + (n - r) * cell
        black = np.r_[False, bits[r] == 0, False].astype(np.int8)
        edges = np.flatnonzero(np.diff(black))
        rects += [(x + c0 * cell, y1 - cell, x + c1 * cell, y1) for c0, c1 in zip(edges[::2], edges[1::2], strict=True)]
    return _rectangles(rects)


def _marker(ax: Axes, layout: DockLayout, m: MarkerSpec, x: float, y: float, side: float, colour: str) -> None:
    path = marker_path(layout.marker_bits(m.id), x, y, side / layout.modules)
    ax.add_patch(PathPatch(path, facecolor=colour, edgecolor="none", linewidth=0.0))


def _card(ax: Axes, layout: DockLayout, m: MarkerSpec, x: float, y: float) -> None:
    """A marker at full size with its quiet zone, dashed cut line and centre-line ticks; (x, y) its lower left."""
    side = _side_mm(layout, m)
    inset = _quiet_mm(layout, m) + BAND_MM
    card = side + 2 * inset
    _marker(ax, layout, m, x + inset, y + inset, side, "black")
    ax.add_patch(Rectangle((x, y), card, card, fill=False, edgecolor="black", linewidth=0.5, linestyle=(0, (8, 6))))
    # Ticks across the cut line on the marker's centre lines: what is left of them after cutting lines the card
    # up with the charger's marks. Inside only as far as the band, so that the quiet zone stays white.
    inside, outside = BAND_MM - 1.0, TICK_OUT_MM
    cx, cy = x + card / 2, y + card / 2
    ticks = [
        ((cx, cx), (y + card - inside, y + card + outside)),
        ((cx, cx), (y - outside, y + inside)),
        ((x - outside, x + inside), (cy, cy)),
        ((x + card - inside, x + card + outside), (cy, cy)),
    ]
    for xs, ys in ticks:
        ax.plot(xs, ys, color="black", linewidth=0.6, solid_capstyle="butt")
    # Which way up: a marker turned on the charger is another marker's corner order.
    ax.text(x + 1.0, y + card - 0.8, "top ▲", fontsize=5.5, color="0.55", ha="left", va="top")


def _scale_bar(ax: Axes) -> None:
    """The 10 cm scale bar at the page's lower left: a solid black bar of exactly 100 mm with 1 cm ticks."""
    x, y, height = MARGIN_MM, MARGIN_MM + 8.0, 3.5
    # The bar and its ticks (within the bar's 100 mm: the end ticks inside its ends) as one path, one fill.
    tick_w = 0.3
    rects = [(x, y, x + SCALE_BAR_MM, y + height)]
    for cm in range(11):
        tall = 3.0 if cm % 5 == 0 else 2.0
        tx = min(max(x + 10.0 * cm - tick_w / 2, x), x + SCALE_BAR_MM - tick_w)
        rects.append((tx, y + height - 0.5, tx + tick_w, y + height + tall))
        ax.text(x + 10.0 * cm, y + height + 3.6, str(cm), fontsize=6.0, ha="center", va="bottom")
    ax.add_patch(PathPatch(_rectangles(rects), facecolor="black", edgecolor="none", linewidth=0.0))
    ax.text(x + SCALE_BAR_MM + 2.5, y + height + 3.6, "cm", fontsize=6.0, ha="left", va="bottom")
    ax.text(x, y - 1.5, "10 cm scale bar", fontsize=7.0, fontweight="bold", ha="left", va="top")
    _lines(
        ax,
        x + SCALE_BAR_MM + 10.0,
        y + height + 2.0,
        [
            ("Check the bar with a ruler: it must measure exactly 100 mm.", 7.0, False),
            ("If it does not, the printer scaled the page:", 7.0, False),
            ("print again at 100 % / actual size, no fit-to-page.", 7.0, False),
        ],
    )


# --- the placement drawing -------------------------------------------------------------------------------------


def _dimension(ax: Axes, a: tuple[float, float], b: tuple[float, float]) -> None:
    ax.annotate(
        "",
        xy=b,
        xytext=a,
        arrowprops={
            "arrowstyle": "<|-|>",
            "mutation_scale": 5,
            "shrinkA": 0,
            "shrinkB": 0,
            "facecolor": "black",
            "edgecolor": "black",
            "linewidth": 0.5,
        },
    )


def _placement_notes(layout: DockLayout, denominator: float) -> list[str]:
    sides = ", ".join(f"{m.role} {_side_mm(layout, m):.1f} mm" for m in layout.markers)
    centre = layout.marker("center")
    notes = [
        f"Seen from the front, as the robot sees the charger (the robot's left is the page's left), drawn at "
        f"1:{denominator:g}. The numbers are the dimensions: measure them on the charger, not on the drawing.",
        "Dimensions in mm: the horizontal distances between marker centres, and each centre's height above the floor.",
        f"Marker 2 (center, id {centre.id}) sits over the docking point: its vertical centre line is the charging "
        "contacts' centre line."
        if centre.y == 0.0
        else f"The docking point (the charging contacts' centre line) is {abs(_mm(centre.y)):.1f} mm to the "
        f"{'right' if centre.y > 0 else 'left'} of marker 2's (center, id {centre.id}) centre line.",
        "Mount the markers flat on the charger's face, upright (the card's 'top' up) and square to the floor, "
        "all in one plane.",
        f"{layout.dictionary}; sides (outer black border): {sides}.",
    ]
    for m in layout.markers[3:]:  # beyond the papers' three: no dimension line of their own, so said here
        side = "left" if m.y > centre.y else "right"
        notes.append(
            f"{m.role} (id {m.id}): its centre {abs(_mm(m.y - centre.y)):.1f} mm to the {side} of marker 2's centre "
            f"line, {_mm(m.z):.1f} mm above the floor."
        )
    off = [m.role for m in layout.markers if m.tilted]
    if off:
        notes.append(
            f"Note: this layout puts {', '.join(off)} off the face or tilted (x, roll, pitch, yaw); the drawing "
            "shows the centres' y and z only: mount those markers as the layout gives them."
        )
    return notes


def _placement(ax: Axes, layout: DockLayout, paper: Paper) -> None:
    """The charger's face from the front at a reduced scale: markers, centre distances, heights, docking point."""
    # Real millimetres, the page's x = -y (the robot's left is the page's left), z up.
    cx = {m.role: -_mm(m.y) for m in layout.markers}
    cz = {m.role: _mm(m.z) for m in layout.markers}
    half = {m.role: _side_mm(layout, m) / 2 for m in layout.markers}
    x_lo = min(cx[r] - half[r] for r in cx)
    x_hi = max(cx[r] + half[r] for r in cx)
    z_lo = min(0.0, *(cz[r] - half[r] for r in cz))
    z_hi = max(0.0, *(cz[r] + half[r] for r in cz))

    # Above the drawing: two tiers of dimensions and the docking point's label; below it: the markers' labels.
    above, below = 25.0, 13.0
    width = paper.width_mm - 2 * MARGIN_MM - 30.0
    wrap = int((paper.width_mm - 2 * MARGIN_MM) / (8.0 * 0.57 * PT_MM))
    probe = [line for note in _placement_notes(layout, 2.5) for line in textwrap.wrap(note, wrap)]
    header = 14.0 * PT_MM * 1.45 + len(probe) * 8.0 * PT_MM * 1.45 + 10.0
    region_top = paper.height_mm - MARGIN_MM - header
    region_bottom = MARGIN_MM + FOOTER_MM
    height = region_top - region_bottom - above - below
    denominator = next((d for d in SCALES if (x_hi - x_lo) / d <= width and (z_hi - z_lo) / d <= height), SCALES[-1])
    k = 1.0 / denominator

    lines = [("Where the markers go: the charger's face from the front", 14.0, True)]
    lines += [
        (line, 8.0, False) for note in _placement_notes(layout, denominator) for line in textwrap.wrap(note, wrap)
    ]
    _lines(ax, MARGIN_MM, paper.height_mm - MARGIN_MM, lines)

    ox = paper.width_mm / 2 - (x_lo + x_hi) / 2 * k
    block = above + (z_hi - z_lo) * k + below
    floor = region_top - (height + above + below - block) / 2 - above - z_hi * k
    px = {r: ox + cx[r] * k for r in cx}
    pz = {r: floor + cz[r] * k for r in cz}
    top = max(pz[r] + half[r] * k for r in pz)

    # The floor, hatched below.
    f0, f1 = ox + x_lo * k - 12.0, ox + x_hi * k + 12.0
    ax.plot([f0, f1], [floor, floor], color="black", linewidth=1.0)
    hx = np.arange(f0 + 1.5, f1, 3.0)
    nan = np.full_like(hx, np.nan)
    hatch_x = np.column_stack([hx, hx - 1.5, nan]).ravel()
    hatch_y = np.column_stack([np.full_like(hx, floor), np.full_like(hx, floor - 1.5), nan]).ravel()
    ax.plot(hatch_x, hatch_y, color="black", linewidth=0.4)
    ax.text(f1, floor + 1.0, "floor", fontsize=7.0, ha="right", va="bottom")

    for m in layout.markers:
        r, h = m.role, half[m.role] * k
        _marker(ax, layout, m, px[r] - h, pz[r] - h, 2 * h, "0.78")
        ax.add_patch(Rectangle((px[r] - h, pz[r] - h), 2 * h, 2 * h, fill=False, edgecolor="black", linewidth=0.6))
        ax.plot([px[r]], [pz[r]], marker="+", color="black", markersize=6, markeredgewidth=0.6)
        # Its centre's height above the floor, along its vertical centre line.
        _dimension(ax, (px[r], floor), (px[r], pz[r]))
        gap = pz[r] - h - floor
        mid = floor + gap / 2 if gap > 16.0 else (floor + pz[r]) / 2
        ax.text(
            px[r] + 1.0,
            mid,
            f"{cz[r]:.1f} mm",
            fontsize=7.0,
            rotation=90,
            ha="left",
            va="center",
            bbox={"facecolor": "white", "edgecolor": "none", "pad": 0.6},
        )
        low = min(floor, pz[r] - h)
        _lines(ax, px[r], low - 4.0, [(_name(m), 7.0, True), (f"id {m.id}", 7.0, False)], ha="center")

    # The horizontal distances between centres: left-center and center-right, then left-right above them.
    tier1, tier2 = top + 7.0, top + 15.0
    for r, tier in (("left", tier2), ("right", tier2), ("center", tier1)):
        ax.plot([px[r], px[r]], [pz[r] + half[r] * k + 1.0, tier + 1.5], color="black", linewidth=0.3)
    for a, b, tier in (("left", "center", tier1), ("center", "right", tier1), ("left", "right", tier2)):
        _dimension(ax, (px[a], tier), (px[b], tier))
        ax.text(
            (px[a] + px[b]) / 2,
            tier + 0.6,
            f"{abs(cx[a] - cx[b]):.1f} mm",
            fontsize=7.0,
            ha="center",
            va="bottom",
            bbox={"facecolor": "white", "edgecolor": "none", "pad": 0.4},
        )

    # The docking point: on the floor below marker 2; its vertical line is the charging contacts' centre line.
    dock_x = ox
    ax.plot([dock_x, dock_x], [floor - 3.0, tier2 + 6.0], color="black", linewidth=0.5, linestyle=(0, (10, 3, 2, 3)))
    ax.plot([dock_x], [floor - 1.6], marker="^", color="black", markersize=5)
    ax.text(
        dock_x,
        tier2 + 6.5,
        "docking point: the charging contacts' centre line",
        fontsize=7.0,
        ha="center",
        va="bottom",
    )
    ax.text(
        paper.width_mm - MARGIN_MM,
        region_bottom + 2.0,
        f"scale 1:{denominator:g} · dimensions in mm",
        fontsize=7.0,
        ha="right",
        va="bottom",
    )
