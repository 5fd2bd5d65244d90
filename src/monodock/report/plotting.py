"""matplotlib for the report's figures: its file-only backend chosen once, and the methods' colours and names.

Every report module that draws imports ``plt`` from here, so that ``matplotlib.use("Agg")`` runs once, before
pyplot is first imported, and no figure ever needs a display.
"""

from __future__ import annotations

from collections.abc import Iterator
from contextlib import contextmanager
from pathlib import Path
from typing import Any

import matplotlib

matplotlib.use("Agg")
import matplotlib.pyplot as plt
from matplotlib.figure import Figure

__all__ = ["METHOD_COLOURS", "METHOD_LABELS", "plt", "saved_figure"]

# One colour per method across every figure of the reports (the LiDAR labels are a reference, drawn in blue).
METHOD_COLOURS = {
    "lidar": "tab:blue",
    "regression": "tab:red",
    "pnp": "tab:green",
    "board": "tab:purple",
    "fused": "tab:orange",
    "fused (stale tables)": "tab:orange",
}
METHOD_LABELS = {
    "lidar": "LiDAR label",
    "regression": "regression (papers)",
    "pnp": "SolvePnP, marker 2",
    "board": "board PnP",
    "fused": "fused",
    "fused (stale tables)": "fused (stale tables)",
}


@contextmanager
def saved_figure(path: Path, *args: Any, dpi: int = 100, **kwargs: Any) -> Iterator[tuple[Figure, Any]]:
    """``plt.subplots(*args, **kwargs)`` to draw on in the block, laid out tight and written to ``path`` when the
    block ends without an error; closed either way."""
    fig, axes = plt.subplots(*args, **kwargs)
    try:
        yield fig, axes
        fig.tight_layout()
        fig.savefig(path, dpi=dpi)
    finally:
        plt.close(fig)
