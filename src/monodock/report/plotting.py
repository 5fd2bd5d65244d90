"""matplotlib for the report's figures: its file-only backend chosen once, and the methods' colours and names.

Every report module that draws imports ``plt`` from here, so that ``matplotlib.use("Agg")`` runs once, before
pyplot is first imported, and no figure ever needs a display.
"""

from __future__ import annotations

import matplotlib

matplotlib.use("Agg")
import matplotlib.pyplot as plt

__all__ = ["METHOD_COLOURS", "METHOD_LABELS", "plt"]

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
