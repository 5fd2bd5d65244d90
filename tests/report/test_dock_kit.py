"""The dock kit (report.dock_kit) rendered to pixels as a printer would: every marker decodes to its id and
measures its layout's side, the scale bar measures 100 mm, the pages are the paper's size, and the placement
drawing puts the markers where the layout says, at the scale it states."""

from __future__ import annotations

import re
from pathlib import Path

import cv2
import numpy as np
import pypdfium2 as pdfium
import pytest
import yaml
from numpy.typing import NDArray

from monodock.core.layout import DockLayout, MarkerSpec
from monodock.core.settings import from_mapping, to_mapping
from monodock.errors import InputError
from monodock.report.dock_kit import PAPERS, SCALE_BAR_MM, check_fits, dock_kit_pdf, misfit

ROOT = Path(__file__).resolve().parents[2]
DPI = 600
PX_PER_MM = DPI / 25.4
PT_MM = 25.4 / 72
PAGE_PT = {"a4": (595.28, 841.89), "letter": (612.0, 792.0), "a3": (841.89, 1190.55)}
TOLERANCE_MM = 0.1
COARSE = 4  # detection's downsampling


def wide_layout(**sizes: float) -> DockLayout:
    """The benchmarks' second dock (DICT_5X5_100, 12 cm, ids 40-42), with per-marker printed sides."""
    data = yaml.safe_load((ROOT / "bench" / "setups" / "wide" / "layout.yaml").read_text())
    for role, size in sizes.items():
        data["markers"][role]["size"] = size
    return from_mapping(DockLayout, data, "wide")


WIDE = wide_layout(left=0.118, right=0.125)
# Today's dock with an 18 cm far-field marker above it (issue 28): too large for A4, printed on A3.
_BASE = DockLayout.default()
FAR = DockLayout(_BASE.dictionary, _BASE.marker_size, (*_BASE.markers, MarkerSpec("far", 7, 0.25, 0.70, size=0.18)))
KITS = {"default-a4": (DockLayout.default(), "a4"), "wide-letter": (WIDE, "letter"), "far-a3": (FAR, "a3")}


@pytest.fixture(scope="module")
def kits() -> dict[str, bytes]:
    return {name: dock_kit_pdf(layout, PAPERS[paper]) for name, (layout, paper) in KITS.items()}


def render(pdf: bytes, page: int) -> NDArray[np.uint8]:
    """One page as grey pixels at DPI (0 black, 255 white)."""
    doc = pdfium.PdfDocument(pdf)
    try:
        img = doc[page].render(scale=DPI / 72, grayscale=True).to_numpy()
        return np.ascontiguousarray(img.reshape(img.shape[0], img.shape[1]))
    finally:
        doc.close()


def render_turned(pdf: bytes, page: int, degrees: float = 0.7) -> NDArray[np.uint8]:
    """One page turned a little about its centre, as a printer's driver may place it: a renderer then
    anti-aliases every edge, and cells drawn as separate rectangles would show hairlines between them."""
    doc = pdfium.PdfDocument(pdf)
    try:
        p = doc[page]
        w, h = p.get_size()
        turn = pdfium.PdfMatrix().translate(-w / 2, -h / 2).rotate(degrees).translate(w / 2, h / 2)
        for obj in list(p.get_objects()):
            obj.transform(turn)
        p.gen_content()
        img = p.render(scale=DPI / 72, grayscale=True).to_numpy()
        return np.ascontiguousarray(img.reshape(img.shape[0], img.shape[1]))
    finally:
        doc.close()


def detect(img: NDArray[np.uint8], layout: DockLayout) -> dict[int, NDArray[np.float64]]:
    """The markers found: id -> corners (TL, TR, BR, BL), pixels. Found at a quarter of the resolution (fast),
    their corners refined to sub-pixel at the full one."""
    small = cv2.resize(img, None, fx=1 / COARSE, fy=1 / COARSE, interpolation=cv2.INTER_AREA)
    params = cv2.aruco.DetectorParameters()
    params.cornerRefinementMethod = cv2.aruco.CORNER_REFINE_SUBPIX
    corners, ids, _ = cv2.aruco.ArucoDetector(layout.aruco_dictionary(), params).detectMarkers(small)
    assert ids is not None, "no marker found"
    found = {}
    criteria = (cv2.TERM_CRITERIA_EPS + cv2.TERM_CRITERIA_COUNT, 50, 0.001)
    for i, c in zip(ids.ravel(), corners, strict=True):
        full = ((c.reshape(4, 2) + 0.5) * COARSE - 0.5).astype(np.float32)
        found[int(i)] = cv2.cornerSubPix(img, full, (3 * COARSE, 3 * COARSE), (-1, -1), criteria).astype(np.float64)
    return found


def side_mm(corners: NDArray[np.float64]) -> float:
    """The mean of a marker's four edge lengths, millimetres."""
    return float(np.linalg.norm(np.roll(corners, -1, axis=0) - corners, axis=1).mean()) / PX_PER_MM


def scale_bar_mm(img: NDArray[np.uint8]) -> float:
    """The length of the page's scale bar: the one solid dark blob 95-105 mm wide and under 10 mm tall (found at a
    quarter of the resolution), measured at the full one along its solid part's middle row, sub-pixel by the grey
    levels of its ends."""
    small = cv2.resize(img, None, fx=1 / COARSE, fy=1 / COARSE, interpolation=cv2.INTER_AREA)
    n, _, stats, _ = cv2.connectedComponentsWithStats((small < 128).astype(np.uint8), connectivity=8)
    px = PX_PER_MM / COARSE
    bars = [
        i
        for i in range(1, n)
        if 95 * px <= stats[i, cv2.CC_STAT_WIDTH] <= 105 * px
        and stats[i, cv2.CC_STAT_HEIGHT] <= 10 * px
        and stats[i, cv2.CC_STAT_AREA] >= 200 * px**2  # solid, not a dimension line
    ]
    assert len(bars) == 1, f"{len(bars)} scale bars"
    x, y, w, h = (COARSE * int(v) for v in stats[bars[0], :4])
    box = img[y : y + h, x - 2 * COARSE : x + w + 2 * COARSE] < 128
    widths = box.sum(axis=1)
    solid = np.flatnonzero(widths >= widths.max() - 2)
    row = img[y + solid[len(solid) // 2], x - 2 * COARSE - 20 : x + w + 2 * COARSE + 20].astype(np.float64)
    return float((1.0 - row / 255.0).sum()) / PX_PER_MM


def assert_white_around(img: NDArray[np.uint8], corners: NDArray[np.float64], cell_mm: float) -> None:
    """At least one cell of white all round the marker (its quiet zone): nothing printed there."""
    (x0, y0), (x1, y1) = corners.min(axis=0), corners.max(axis=0)
    d = cell_mm * PX_PER_MM
    ring = img[int(y0 - d) : int(y1 + d) + 1, int(x0 - d) : int(x1 + d) + 1].copy()
    ring[int(d) - 2 : ring.shape[0] - int(d) + 2, int(d) - 2 : ring.shape[1] - int(d) + 2] = 255
    assert int(ring.min()) > 250


def assert_no_seams(img: NDArray[np.uint8], corners: NDArray[np.float64], bits: NDArray[np.uint8]) -> None:
    """Inside the black cells (3 px clear of any white cell), every pixel is black: no hairline between cells."""
    n, k = bits.shape[0], 64
    (x0, y0), (x1, y1) = np.floor(corners.min(axis=0)).astype(int), np.ceil(corners.max(axis=0)).astype(int)
    grid = np.kron((bits == 0).astype(np.uint8), np.ones((k, k), np.uint8))
    to_image = cv2.getPerspectiveTransform(
        np.array([[0, 0], [n * k, 0], [n * k, n * k], [0, n * k]], np.float32) - 0.5,
        (corners - (x0, y0)).astype(np.float32),
    )
    black = cv2.warpPerspective(grid, to_image, (x1 - x0, y1 - y0), flags=cv2.INTER_NEAREST, borderValue=0)
    core = cv2.erode(black, np.ones((7, 7), np.uint8), borderType=cv2.BORDER_CONSTANT, borderValue=0).astype(bool)
    assert core.sum() > 0.3 * core.size
    assert int(img[y0:y1, x0:x1][core].max()) < 16


@pytest.mark.parametrize("name", KITS)
def test_pages_are_the_paper_exactly(kits: dict[str, bytes], name: str) -> None:
    layout, paper = KITS[name]
    doc = pdfium.PdfDocument(kits[name])
    try:
        assert len(doc) == len(layout.markers) + 1  # a page per marker and the placement drawing
        for page in doc:
            assert page.get_size() == pytest.approx(PAGE_PT[paper], abs=0.01)
        meta = doc.get_metadata_dict()
    finally:
        doc.close()
    assert layout.dictionary in meta["Title"]
    assert PAPERS[paper].name in meta["Title"]


@pytest.mark.parametrize("name", KITS)
def test_each_marker_decodes_and_measures_its_side(kits: dict[str, bytes], name: str) -> None:
    layout, _ = KITS[name]
    for page, m in enumerate(layout.markers):
        img = render(kits[name], page)
        found = detect(img, layout)
        assert list(found) == [m.id]
        corners = found[m.id]
        error = side_mm(corners) - 1000 * layout.side(m.role)
        assert abs(error) < TOLERANCE_MM, f"{m.role}: side off by {error:+.3f} mm"
        assert abs(scale_bar_mm(img) - SCALE_BAR_MM) < TOLERANCE_MM
        # Upright, as the layout's corner order needs: the top-left corner is the top left one.
        assert corners[0, 0] < corners[1, 0]
        assert corners[0, 1] < corners[3, 1]
        assert abs(corners[:, 0].mean() - img.shape[1] / 2) < 2 * PX_PER_MM  # centred across the page
        assert_white_around(img, corners, 1000 * layout.side(m.role) / layout.modules)


def test_adjacent_black_cells_have_no_hairline_between_them(kits: dict[str, bytes]) -> None:
    layout, _ = KITS["wide-letter"]
    m = layout.markers[0]
    img = render_turned(kits["wide-letter"], 0)
    corners = detect(img, layout)[m.id]
    assert abs(side_mm(corners) - 1000 * layout.side(m.role)) < TOLERANCE_MM
    assert_no_seams(img, corners, layout.marker_bits(m.id))


def test_a_sheet_holds_small_markers_on_one_page_with_one_scale_bar() -> None:
    small = from_mapping(DockLayout, {**to_mapping(DockLayout.default()), "marker_size": 0.04}, "layout")
    pdf = dock_kit_pdf(small, PAPERS["a4"], sheet=True)
    doc = pdfium.PdfDocument(pdf)
    try:
        assert len(doc) == 2  # the three markers, then the placement drawing
    finally:
        doc.close()
    img = render(pdf, 0)
    found = detect(img, small)
    assert sorted(found) == [1, 2, 3]
    for corners in found.values():
        assert abs(side_mm(corners) - 40.0) < TOLERANCE_MM
    assert abs(scale_bar_mm(img) - SCALE_BAR_MM) < TOLERANCE_MM


def _label_centre_x_mm(textpage: pdfium.PdfTextPage, label: str) -> float:
    """The x of the label under a marker: the last place the text is (the notes above the drawing come first)."""
    searcher = textpage.search(label, match_whole_word=True)
    found, last = searcher.get_next(), None
    while found is not None:
        last, found = found, searcher.get_next()
    assert last is not None, label
    first, count = last
    left = textpage.get_charbox(first)[0]
    right = textpage.get_charbox(first + count - 1)[2]
    return (left + right) / 2 * PT_MM


@pytest.mark.parametrize("name", KITS)
def test_the_placement_drawing_puts_the_markers_where_the_layout_says(kits: dict[str, bytes], name: str) -> None:
    layout, _ = KITS[name]
    doc = pdfium.PdfDocument(kits[name])
    try:
        textpage = doc[len(layout.markers)].get_textpage()
        text = textpage.get_text_range()
        scale = re.search(r"drawn at 1:([0-9.]+)\.", text)
        assert scale is not None
        denominator = float(scale.group(1))
        x = {
            m.role: _label_centre_x_mm(textpage, f"{m.number} · {m.role}" if m.number else m.role)
            for m in layout.markers
        }
    finally:
        doc.close()
    mm = {m.role: 1000 * m.y for m in layout.markers}
    # The robot's left on the page's left; the labels' spacing is the markers' at the stated scale.
    assert x["left"] < x["center"] < x["right"]
    for a, b in (("left", "center"), ("center", "right")):
        assert (x[b] - x[a]) * denominator == pytest.approx(mm[a] - mm[b], abs=0.5 * denominator)
    for a, b in (("left", "center"), ("center", "right"), ("left", "right")):
        assert f"{abs(mm[a] - mm[b]):.1f} mm" in text
    for m in layout.markers:
        assert f"{1000 * m.z:.1f} mm" in text
        assert f"id {m.id}" in text
    assert "docking point" in text
    for m in layout.markers[3:]:  # another marker's place, beside marker 2's, in words and on the drawing
        offset = 1000 * (m.y - layout.marker("center").y)
        assert f"{m.role} (id {m.id}): its centre {abs(offset):.1f} mm to the left" in text.replace("\r\n", " ")
        assert (x["center"] - x[m.role]) * denominator == pytest.approx(offset, abs=0.5 * denominator)
    assert abs(scale_bar_mm(render(kits[name], len(layout.markers))) - SCALE_BAR_MM) < TOLERANCE_MM
    assert "flat" in text
    assert "upright" in text
    assert "square to the floor" in text


def test_a_marker_too_large_for_the_paper_is_refused_naming_it_and_the_printable_area() -> None:
    # 13.9 cm of DICT_5X5_100 with its margins: 186.7 mm, wider than A4 leaves for it (184 mm), narrower than
    # Letter does (189.9 mm).
    big = wide_layout(center=0.139)
    with pytest.raises(InputError, match=r"marker center \(id 41\) is 139\.0 mm .* A4 .* 190 x 277 mm") as exc:
        check_fits(big, PAPERS["a4"])
    assert "\n" not in str(exc.value)
    assert misfit(big, PAPERS["letter"]) is None
    with pytest.raises(InputError, match="A4"):
        dock_kit_pdf(big, PAPERS["a4"])
