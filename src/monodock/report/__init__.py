"""Rendering results as HTML, Markdown and PNG: the only place that imports matplotlib."""

from __future__ import annotations

from typing import TYPE_CHECKING

from monodock.core.face import lazy_face

if TYPE_CHECKING:
    from monodock.report.design import design_report
    from monodock.report.dock_kit import dock_kit_pdf
    from monodock.report.docking import write_dock_report
    from monodock.report.training import write_training_report

__all__ = [
    "design_report",
    "dock_kit_pdf",
    "write_dock_report",
    "write_training_report",
]

__getattr__, __dir__ = lazy_face(__name__, __all__)
