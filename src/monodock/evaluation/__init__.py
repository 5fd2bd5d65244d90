"""Judging the methods: metrics, held-out evaluation, the physical limit, the robustness sweep, closed-loop dock-sim."""

from __future__ import annotations

from typing import TYPE_CHECKING

from monodock.core.face import lazy_face

if TYPE_CHECKING:
    from monodock.evaluation.dock_faults import FAULTS
    from monodock.evaluation.dock_results import DockSimSummary, TrialResult
    from monodock.evaluation.dock_sim import DockSimConfig, run_dock_sim
    from monodock.evaluation.heldout import HeldoutResult, HeldoutSummary, evaluate_heldout
    from monodock.evaluation.selftrain import SelfTrainConfig

__all__ = [
    "FAULTS",
    "DockSimConfig",
    "DockSimSummary",
    "HeldoutResult",
    "HeldoutSummary",
    "SelfTrainConfig",
    "TrialResult",
    "evaluate_heldout",
    "run_dock_sim",
]

__getattr__, __dir__ = lazy_face(__name__, __all__)
