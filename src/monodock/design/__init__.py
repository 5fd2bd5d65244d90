"""Designing a dock: which markers a charger face needs for a start envelope (``designer``), from a detection model
measured against the simulator (``detection_model``). A generator of layouts, beside ``evaluation``, which judges."""

from __future__ import annotations

from monodock.design.designer import Design, Envelope, SimCheck, Tolerance, check_in_sim, check_poses, design
from monodock.design.detection_model import DETECTION_SOURCE

__all__ = ["DETECTION_SOURCE", "Design", "Envelope", "SimCheck", "Tolerance", "check_in_sim", "check_poses", "design"]
