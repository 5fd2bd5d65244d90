"""A report page built section by section: report.html for a browser, report.md beside it, summary.json.

The page is laid out for a 1280 px wide window: nothing is wider than the page (images shrink to fit, long
tables wrap their headers), long tables go into collapsed ``<details>`` sections, and settings are shown as
YAML, the way a person would write them in a file.
"""

from __future__ import annotations

import dataclasses
import enum
import html
import math
import re
from collections.abc import Iterator, Mapping, Sequence
from contextlib import contextmanager
from pathlib import Path

import numpy as np
import yaml

__all__ = ["HtmlReport", "plain", "settings_yaml"]

_STYLE = """body{font-family:system-ui,sans-serif;max-width:1240px;margin:1em auto;padding:0 12px;line-height:1.4;
color:#1b1b1b}
h1{font-size:1.5em;margin:0.2em 0 0.1em}h2{font-size:1.25em;margin-top:1.4em}h3{font-size:1.05em}
p.lead{margin:0 0 0.6em;color:#444}p.note{font-size:85%;color:#444;margin:0.2em 0 0.8em}
table{border-collapse:collapse;margin:0.6em 0;font-size:0.9em}
td,th{border:1px solid #ccc;padding:2px 5px;text-align:right}th{background:#f4f4f4;font-weight:600}
td:first-child,th:first-child{text-align:left}tr.all{font-weight:bold;background:#eef}tr.paper{color:#555;
background:#fafafa}
td{white-space:nowrap}table.wrap td{white-space:normal}
img{max-width:100%;height:auto}
figure{display:inline-block;margin:0.4em 0.4em 0.4em 0;max-width:100%;vertical-align:top}
figcaption{font-size:85%;color:#444}
pre.settings{background:#f6f8fa;border:1px solid #ddd;padding:8px 12px;font-size:0.85em;white-space:pre-wrap}
pre.long{column-count:2;column-gap:2em}
details{margin:0.5em 0;border:1px solid #ddd;border-radius:4px;padding:0.3em 0.8em}
details>summary{cursor:pointer;font-weight:600}
.first-screen{display:grid;grid-template-columns:minmax(0,560px) minmax(0,1fr);gap:12px 20px;align-items:start}
.first-screen figure{margin:0}.first-screen table{margin-top:0}
.first-screen h2{margin:0 0 0.3em;font-size:1.1em}
.row{display:flex;flex-wrap:wrap;gap:8px}"""


def plain(value: object) -> object:
    """``value`` as YAML's plain types: dataclasses and mappings as dicts, tuples as lists, enums by value,
    numpy scalars as Python numbers, paths as text; floats rounded to 6 significant digits for people."""
    if dataclasses.is_dataclass(value) and not isinstance(value, type):
        return {f.name: plain(getattr(value, f.name)) for f in dataclasses.fields(value)}
    if isinstance(value, Mapping):
        return {str(k): plain(v) for k, v in value.items()}
    if isinstance(value, list | tuple):
        return [plain(v) for v in value]
    if isinstance(value, enum.Enum):
        return plain(value.value)
    if isinstance(value, np.generic):
        return plain(value.item())
    if isinstance(value, bool | int | str) or value is None:
        return value
    if isinstance(value, float):
        return float(f"{value:.6g}") if math.isfinite(value) else value
    return str(value)


class _SettingsDumper(yaml.SafeDumper):
    """YAML with lists on one line ("range_m: [0.12, 12.0]" reads better than a column) and mappings in blocks."""


def _flow_list(dumper: yaml.SafeDumper, data: list[object]) -> yaml.Node:
    return dumper.represent_sequence("tag:yaml.org,2002:seq", data, flow_style=True)


_SettingsDumper.add_representer(list, _flow_list)


def settings_yaml(values: Mapping[str, object]) -> str:
    """Settings as a YAML document, keys in the given order."""
    return yaml.dump(
        plain(values), Dumper=_SettingsDumper, sort_keys=False, allow_unicode=True, default_flow_style=False, width=100
    )


def _cells(line: str) -> list[str]:
    """The cells of one markdown table line; an escaped pipe (``\\|``) is part of a cell."""
    inner = line.strip()
    inner = inner.removeprefix("|")
    inner = inner[:-1] if inner.endswith("|") and not inner.endswith("\\|") else inner
    return [c.strip().replace("\\|", "|") for c in re.split(r"(?<!\\)\|", inner)]


def table_html(markdown: str, *, css_class: str = "") -> str:
    """A GitHub-flavoured markdown table as HTML; rows whose second cell is "all" are emphasised."""
    lines = [ln for ln in markdown.strip().splitlines() if ln.strip()]
    head = _cells(lines[0])
    cls = f' class="{css_class}"' if css_class else ""
    out = [f"<table{cls}>", "<tr>" + "".join(f"<th>{html.escape(h)}</th>" for h in head) + "</tr>"]
    for ln in lines[2:]:
        cells = _cells(ln)
        row = ' class="all"' if len(cells) > 1 and cells[1] == "all" else ""
        out.append(f"<tr{row}>" + "".join(f"<td>{html.escape(c)}</td>" for c in cells) + "</tr>")
    out.append("</table>")
    return "\n".join(out)


class HtmlReport:
    """A report built section by section, written as report.html, report.md and summary.json."""

    def __init__(self, title: str, *, lead: str = "") -> None:
        self.title = title
        self._html: list[str] = []
        self._md: list[str] = [f"# {title}\n"]
        if lead:
            self._html.append(f'<p class="lead">{html.escape(lead)}</p>')
            self._md.append(lead + "\n")

    def heading(self, text: str, level: int = 2) -> None:
        self._html.append(f"<h{level}>{html.escape(text)}</h{level}>")
        self._md.append(f"{'#' * level} {text}\n")

    def paragraph(self, text: str) -> None:
        self._html.append(f"<p>{html.escape(text)}</p>")
        self._md.append(text + "\n")

    def note(self, text: str) -> None:
        """A short paragraph in small print, e.g. under a table."""
        self._html.append(f'<p class="note">{html.escape(text)}</p>')
        self._md.append(text + "\n")

    def settings(self, values: Mapping[str, object]) -> None:
        """Settings as a YAML block (nested mappings allowed)."""
        text = settings_yaml(values)
        # A long block reads in two columns rather than down a whole screen.
        css = "settings long" if text.count("\n") > 24 else "settings"
        self._html.append(f'<pre class="{css}">{html.escape(text)}</pre>')
        self._md.append(f"```yaml\n{text}```\n")

    def table(self, markdown: str, *, wrap: bool = False) -> None:
        """A markdown table; ``wrap`` lets long cells break over lines."""
        self._html.append(table_html(markdown, css_class="wrap" if wrap else ""))
        self._md.append(markdown.strip() + "\n")

    def image(self, file: str, caption: str = "", width: int = 1050) -> None:
        """An image file (relative to the report), at most ``width`` px wide and never wider than the page."""
        cap = f"<figcaption>{html.escape(caption)}</figcaption>" if caption else ""
        self._html.append(
            f'<figure style="max-width:{width}px"><img src="{html.escape(file)}" width="{width}" alt="'
            f'{html.escape(caption or file)}">{cap}</figure>'
        )
        self._md.append(f"![{caption}]({file})\n")

    def bullets(self, items: Sequence[str]) -> None:
        self._html.append("<ul>" + "".join(f"<li>{html.escape(i)}</li>" for i in items) + "</ul>")
        self._md.append("".join(f"- {i}\n" for i in items))

    @contextmanager
    def details(self, summary: str, *, open_: bool = False) -> Iterator[None]:
        """A collapsed section (``<details>``) around what is added inside the ``with``; a heading in report.md."""
        self._html.append(f"<details{' open' if open_ else ''}><summary>{html.escape(summary)}</summary>")
        self._md.append(f"**{summary}**\n")
        try:
            yield
        finally:
            self._html.append("</details>")

    @contextmanager
    def block(self, css_class: str) -> Iterator[None]:
        """A ``<div>`` of the given class around what is added inside the ``with`` (layout only; not in the md)."""
        self._html.append(f'<div class="{html.escape(css_class)}">')
        try:
            yield
        finally:
            self._html.append("</div>")

    def write(self, out: Path, summary_json: str) -> None:
        """Write the three files into ``out`` (images are file names relative to it)."""
        page = (
            f'<!doctype html>\n<html><head><meta charset="utf-8">'
            f'<meta name="viewport" content="width=device-width, initial-scale=1">'
            f"<title>{html.escape(self.title)}</title><style>{_STYLE}</style></head><body>\n"
            f"<h1>{html.escape(self.title)}</h1>\n" + "\n".join(self._html) + "\n</body></html>\n"
        )
        (out / "report.html").write_text(page, encoding="utf-8")
        (out / "report.md").write_text("\n".join(self._md), encoding="utf-8")
        (out / "summary.json").write_text(summary_json, encoding="utf-8")
