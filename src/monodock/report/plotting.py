"""matplotlib for the reports: the file-only Agg backend, chosen once here before pyplot loads (no display)."""

from __future__ import annotations

import matplotlib

matplotlib.use("Agg")
import matplotlib.pyplot as plt

__all__ = ["plt"]
