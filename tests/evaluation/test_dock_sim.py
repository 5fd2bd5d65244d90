"""Closed-loop docking through faults, with both planners, and undock and re-dock, by the truth.

Every case with the regression, board PnP and the fused method (the docking benchmark's CI variant) runs in the
demo's test (tests/cli/test_end_to_end.py), which already trains a bundle and docks from every case. The full
benchmark (25 starts per case with the cached 3,000-stop bundle) is ``monodock dock-sim --trials 25 --method
regression,board``; its figures are in the README.
"""

from __future__ import annotations

import json
from pathlib import Path

import pytest

from monodock.cli.main import main

pytestmark = pytest.mark.slow


@pytest.mark.timeout(900)
def test_both_planners_recover_from_faults_and_redock(tmp_path: Path) -> None:
    """Board PnP from a forward and a reversing start region, with both planners, nominal and with two faults (a
    passer-by hiding the markers mid-approach; someone stepping behind the reversing robot), each docking followed
    by an undock and a re-dock: every run docks charging, the faults were sprung, nothing was hit."""
    out = tmp_path / "dock"
    args = ["dock-sim", "--cases", "1,6", "--trials", "1", "--method", "board", "--planner", "papers,monodock"]
    args += ["--faults", "none,occlusion,person-behind", "--redock", "--out", str(out), "--jobs", "2"]
    assert main(args) == 0
    summary = json.loads((out / "summary.json").read_text())
    groups = summary["methods"]
    assert set(groups) == {
        f"board/{planner}/{fault}"
        for planner in ("papers", "monodock")
        for fault in ("none", "occlusion", "person-behind")
    }
    for label, block in groups.items():
        g = block["overall"]
        assert g["runs"] == 2, label
        assert g["successes"] == 2, label
        assert g["charging"] == 2, label
        assert g["collisions"] == 0, label
        assert g["redock"] == {"tried": 2, "redocked": 2}, label
        assert any(int(c) >= 5 for c, e in block["executed"].items() if e["runs"]), label  # a reversing run
    for planner in ("papers", "monodock"):
        assert groups[f"board/{planner}/occlusion"]["overall"]["faults_triggered"] == 2
        assert groups[f"board/{planner}/occlusion"]["overall"]["recoveries"] >= 1
        assert groups[f"board/{planner}/person-behind"]["overall"]["faults_triggered"] >= 1
    assert "| person-behind |" in (out / "report.md").read_text()
