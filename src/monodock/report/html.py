"""The demo report: the error table by depth band, an error plot and overlay pictures, as HTML."""

from __future__ import annotations

import html
import itertools
import json
import math
from collections.abc import Sequence
from dataclasses import asdict
from pathlib import Path

import matplotlib

matplotlib.use("Agg")
import matplotlib.pyplot as plt
import numpy as np
from numpy.typing import NDArray

from monodock.evaluation.metrics import BandRow, band_table, markdown_table

__all__ = ["PAPER_FIGURES", "HtmlReport", "error_plot", "method_tables", "write_html_report"]

# The Sensors 2025 paper's headline numbers (mean errors against LiDAR labels, Tables 4-5).
PAPER_FIGURES = {
    "regression (paper)": {"depth_cm": 1.18, "yaw_deg": 3.11},
    "SolvePnP (paper)": {"depth_cm": 58.54, "yaw_deg": 6.64},
}

_COLOURS = {"pnp": "tab:orange", "board": "tab:blue", "regression": "tab:green", "fused": "tab:purple"}


def method_tables(depth: NDArray[np.float64], errors: dict[str, NDArray[np.float64]]) -> list[BandRow]:
    """Rows of every method, band by band, with the overall row last for each."""
    rows: list[BandRow] = []
    for method, e in errors.items():
        rows += band_table(method, depth, e)
    return rows


def error_plot(depth: NDArray[np.float64], errors: dict[str, NDArray[np.float64]], path: Path) -> None:
    """|depth|, |lateral| and |yaw| error against depth for each method: points and per-band medians."""
    fig, axes = plt.subplots(1, 3, figsize=(15, 4.2), constrained_layout=True)
    edges = np.arange(0.25, 2.51, 0.25)
    centres = (edges[:-1] + edges[1:]) / 2
    for ax, col, scale, label in zip(
        axes,
        (0, 1, 2),
        (100.0, 100.0, math.degrees(1.0)),
        ("|depth error| (cm)", "|lateral error| (cm)", "|yaw error| (°)"),
        strict=True,
    ):
        for method, e in errors.items():
            v = np.abs(e[:, col]) * scale
            ok = np.isfinite(v)
            colour = _COLOURS.get(method)
            ax.scatter(depth[ok] * 100, np.maximum(v[ok], 1e-3), s=6, alpha=0.35, color=colour)
            med = [
                np.median(v[ok & (depth >= lo) & (depth < hi)]) if np.any(ok & (depth >= lo) & (depth < hi)) else np.nan
                for lo, hi in itertools.pairwise(edges)
            ]
            ax.plot(centres * 100, med, "-o", color=colour, label=f"{method} (band median)")
        ax.set_yscale("log")
        ax.set_xlabel("depth from the camera (cm)")
        ax.set_ylabel(label)
        ax.grid(True, which="both", alpha=0.3)
        ax.legend(fontsize=8)
    fig.suptitle("SolvePnP baselines against the simulator's ground truth")
    fig.savefig(path, dpi=110)
    plt.close(fig)


def _table_html(markdown: str) -> str:
    lines = [ln for ln in markdown.strip().splitlines() if ln.strip()]
    head = [c.strip() for c in lines[0].strip("|").split("|")]
    out = ["<table>", "<tr>" + "".join(f"<th>{html.escape(h)}</th>" for h in head) + "</tr>"]
    for ln in lines[2:]:
        cells = [c.strip() for c in ln.strip("|").split("|")]
        cls = ' class="all"' if len(cells) > 1 and cells[1] == "all" else ""
        out.append(f"<tr{cls}>" + "".join(f"<td>{html.escape(c)}</td>" for c in cells) + "</tr>")
    out.append("</table>")
    return "\n".join(out)


def write_html_report(
    out: Path,
    *,
    title: str,
    settings: dict[str, object],
    rows: Sequence[BandRow],
    plot: str,
    overlays: Sequence[tuple[str, str]],
    notes: Sequence[str] = (),
) -> None:
    """report.html, report.md and summary.json in ``out`` (plot and overlays are file names in ``out``)."""
    md = markdown_table(rows)
    paper = "".join(
        f"<tr><td>{html.escape(k)}</td><td>{v['depth_cm']:.2f}</td><td>{v['yaw_deg']:.2f}</td></tr>"
        for k, v in PAPER_FIGURES.items()
    )
    overall = [r for r in rows if r.band == "all"]
    ours = "".join(
        f"<tr><td>{html.escape(r.method)} (this run, vs truth)</td><td>{r.depth_mae_cm:.2f}</td>"
        f"<td>{r.yaw_mae_deg:.2f}</td></tr>"
        for r in overall
    )
    settings_html = "".join(
        f"<tr><td>{html.escape(str(k))}</td><td>{html.escape(str(v))}</td></tr>" for k, v in settings.items()
    )
    pics = "".join(
        f'<figure><img src="{html.escape(f)}" width="640"><figcaption>{html.escape(c)}</figcaption></figure>'
        for f, c in overlays
    )
    notes_html = "".join(f"<li>{html.escape(n)}</li>" for n in notes)
    page = f"""<!doctype html>
<html><head><meta charset="utf-8"><title>{html.escape(title)}</title>
<style>body{{font-family:sans-serif;max-width:1100px;margin:2em auto;line-height:1.4}}
table{{border-collapse:collapse;margin:1em 0}}td,th{{border:1px solid #ccc;padding:3px 8px;text-align:right}}
td:first-child,th:first-child{{text-align:left}}tr.all{{font-weight:bold;background:#eef}}
td{{white-space:nowrap}}table.settings td{{text-align:left;white-space:normal}}
figure{{display:inline-block;margin:0.5em}}</style></head><body>
<h1>{html.escape(title)}</h1>
<h2>Settings</h2><table class="settings">{settings_html}</table>
<h2>Headline: mean absolute error, all depths</h2>
<table><tr><th>method</th><th>depth MAE cm</th><th>yaw MAE °</th></tr>{ours}{paper}</table>
<p>The papers' figures are against LiDAR labels on their robot, with a SolvePnP whose depths are ~1.5x the
LiDAR's (a calibration error); ours are against the simulator's exact truth, with every method given the
same, correct calibration.</p>
<h2>Error by depth band</h2>{_table_html(md)}
<h2>Errors against depth</h2><img src="{html.escape(plot)}" width="1050">
<h2>Overlays</h2><p>Green: detected corners (filled dot: corner 0) and ids; red crosses: true corners;
arrows: the board estimate's dock axes (x red into the charger, y green left, z blue up).</p>{pics}
<h2>Notes</h2><ul>{notes_html}</ul>
</body></html>
"""
    (out / "report.html").write_text(page, encoding="utf-8")
    (out / "report.md").write_text(f"# {title}\n\n{md}\n", encoding="utf-8")
    summary = {"settings": settings, "rows": [asdict(r) for r in rows], "paper": PAPER_FIGURES}
    (out / "summary.json").write_text(json.dumps(summary, indent=2, default=str), encoding="utf-8")


_STYLE = """body{font-family:sans-serif;max-width:1150px;margin:2em auto;line-height:1.4}
table{border-collapse:collapse;margin:1em 0}td,th{border:1px solid #ccc;padding:3px 8px;text-align:right}
td:first-child,th:first-child{text-align:left}tr.all{font-weight:bold;background:#eef}
td{white-space:nowrap}table.settings td{text-align:left;white-space:normal}
figure{display:inline-block;margin:0.5em}figcaption{font-size:90%;color:#444}"""


class HtmlReport:
    """A report built section by section, written as report.html, report.md and summary.json."""

    def __init__(self, title: str) -> None:
        self.title = title
        self._html: list[str] = []
        self._md: list[str] = [f"# {title}\n"]

    def heading(self, text: str, level: int = 2) -> None:
        self._html.append(f"<h{level}>{html.escape(text)}</h{level}>")
        self._md.append(f"{'#' * level} {text}\n")

    def paragraph(self, text: str) -> None:
        self._html.append(f"<p>{html.escape(text)}</p>")
        self._md.append(text + "\n")

    def settings(self, values: dict[str, object]) -> None:
        rows = "".join(
            f"<tr><td>{html.escape(str(k))}</td><td>{html.escape(str(v))}</td></tr>" for k, v in values.items()
        )
        self._html.append(f'<table class="settings">{rows}</table>')
        self._md.append("".join(f"- {k}: {v}\n" for k, v in values.items()))

    def table(self, markdown: str) -> None:
        self._html.append(_table_html(markdown))
        self._md.append(markdown.strip() + "\n")

    def image(self, file: str, caption: str = "", width: int = 1050) -> None:
        cap = f"<figcaption>{html.escape(caption)}</figcaption>" if caption else ""
        self._html.append(f'<figure><img src="{html.escape(file)}" width="{width}">{cap}</figure>')
        self._md.append(f"![{caption}]({file})\n")

    def bullets(self, items: Sequence[str]) -> None:
        self._html.append("<ul>" + "".join(f"<li>{html.escape(i)}</li>" for i in items) + "</ul>")
        self._md.append("".join(f"- {i}\n" for i in items))

    def write(self, out: Path, summary: dict[str, object]) -> None:
        """Write the three files into ``out`` (images are file names relative to it)."""
        page = (
            f'<!doctype html>\n<html><head><meta charset="utf-8"><title>{html.escape(self.title)}</title>'
            f"<style>{_STYLE}</style></head><body>\n<h1>{html.escape(self.title)}</h1>\n"
            + "\n".join(self._html)
            + "\n</body></html>\n"
        )
        (out / "report.html").write_text(page, encoding="utf-8")
        (out / "report.md").write_text("\n".join(self._md), encoding="utf-8")
        (out / "summary.json").write_text(json.dumps(summary, indent=2, default=str), encoding="utf-8")
