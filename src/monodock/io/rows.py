"""EST.csv and its streamed forms: one row per frame and method (docs/user-guide.md, EST.csv), as CSV or JSON lines."""

from __future__ import annotations

import csv
import io
import json
import math
from collections.abc import Iterable
from typing import IO

from monodock.errors import InputError
from monodock.estimation.estimator import FrameEstimates

__all__ = [
    "COVARIANCE_COLUMNS",
    "CSV_COLUMNS",
    "LIVE_COLUMNS",
    "RowWriter",
    "estimate_row",
    "estimates_csv",
    "typed_row",
]

COVARIANCE_COLUMNS = ("cov_xx", "cov_xy", "cov_xyaw", "cov_yy", "cov_yyaw", "cov_yawyaw")
_COVARIANCE_INDEX = ((0, 0), (0, 1), (0, 2), (1, 1), (1, 2), (2, 2))

CSV_COLUMNS = (
    "frame",
    "stamp",
    "method",
    "valid",
    "x_m",
    "y_m",
    "yaw_deg",
    "markers_seen",
    "reprojection_px",
    "tilt_deg",
    "reason",
    # The pose covariance (SI units: m^2, m rad, rad^2) when the method gives one (fused), else empty.
    *COVARIANCE_COLUMNS,
)
# The EST.csv columns, and the milliseconds from the frame's arrival to its row being ready (``monodock run``).
LIVE_COLUMNS = (*CSV_COLUMNS, "latency_ms")
_NUMERIC = ("stamp", "x_m", "y_m", "yaw_deg", "reprojection_px", "tilt_deg", *COVARIANCE_COLUMNS, "latency_ms")


def _num(v: float, fmt: str) -> str:
    return format(v, fmt) if math.isfinite(v) else ""


def _cells(result: FrameEstimates, method: str) -> list[str]:
    """One frame's row for one method, as the EST.csv strings."""
    e = result.estimates[method]
    p = e.pose
    if e.markers_seen:
        seen = " ".join(e.markers_seen)
    else:
        seen = " ".join(result.detection.roles_seen) if result.detection else ""
    covariance = (
        [format(float(e.covariance[i, j]), ".6g") for i, j in _COVARIANCE_INDEX]
        if p is not None and e.covariance is not None
        else [""] * len(COVARIANCE_COLUMNS)
    )
    return [
        result.name,
        _num(result.stamp, ".6f"),
        method,
        "true" if p is not None else "false",
        _num(p.x, ".5f") if p else "",
        _num(p.y, ".5f") if p else "",
        _num(p.yaw_deg, ".4f") if p else "",
        seen,
        _num(e.reprojection_px, ".4f"),
        _num(e.tilt_deg, ".3f"),
        e.reason,
        *covariance,
    ]


def estimates_csv(results: Iterable[FrameEstimates]) -> str:
    """The EST.csv text (docs/user-guide.md): a header and one row per frame and method."""
    buf = io.StringIO()
    w = csv.writer(buf, lineterminator="\n")
    w.writerow(CSV_COLUMNS)
    for r in results:
        for method in r.estimates:
            w.writerow(_cells(r, method))
    return buf.getvalue()


def estimate_row(result: FrameEstimates, method: str, latency_ms: float) -> dict[str, str]:
    """The EST.csv row of one frame and method, with its latency: a ``LIVE_COLUMNS`` dict of strings."""
    return {**dict(zip(CSV_COLUMNS, _cells(result, method), strict=True)), "latency_ms": f"{latency_ms:.2f}"}


def typed_row(row: dict[str, str]) -> dict[str, object]:
    """A row for JSON: numbers as numbers (null when empty), ``valid`` as a boolean."""
    out: dict[str, object] = {}
    for k, v in row.items():
        if k == "valid":
            out[k] = v == "true"
        elif k in _NUMERIC:
            out[k] = float(v) if v else None
        else:
            out[k] = v
    return out


class RowWriter:
    """Rows to a text stream as CSV (header first) or JSON lines, flushed one by one so they can be followed."""

    def __init__(self, stream: IO[str], output_format: str) -> None:
        if output_format not in ("csv", "jsonl"):
            raise InputError(f"output format '{output_format}' is unknown (csv, jsonl)")
        self.stream, self.format = stream, output_format
        self._csv = csv.writer(stream, lineterminator="\n")
        if output_format == "csv":
            self._csv.writerow(LIVE_COLUMNS)
            stream.flush()

    def write(self, row: dict[str, str]) -> None:
        """Write one ``estimate_row`` and flush."""
        if self.format == "csv":
            self._csv.writerow([row[k] for k in LIVE_COLUMNS])
        else:
            self.stream.write(json.dumps(typed_row(row), allow_nan=False) + "\n")
        self.stream.flush()
