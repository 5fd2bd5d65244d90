"""The docking benchmark's CI variant: every case, two starts each, the regression and board PnP, by the truth.

The full benchmark (25 starts per case with the cached 3,000-stop bundle) is ``monodock dock-sim --trials 25
--method regression,board``; its figures are in the README. Here the regression learns from a 1,500-stop drive,
so its bounds are the papers' (2 cm, 3.07°) rather than monodock's own figures.
"""

from __future__ import annotations

import json
from pathlib import Path

import pytest

from monodock.cli import main
from monodock.selftrain import SelfTrainConfig, simulate_and_train
from monodock.sim import Simulator

pytestmark = pytest.mark.slow


@pytest.mark.timeout(1200)
def test_every_case_docks_with_the_regression_and_board_pnp(tmp_path: Path) -> None:
    bundle = tmp_path / "bundle"
    simulate_and_train(tmp_path / "work", bundle, Simulator(), SelfTrainConfig(stops=1500, trials=2), jobs=2)
    out = tmp_path / "dock"
    args = ["dock-sim", "--trials", "2", "--method", "regression,board", "--model", str(bundle), "--out", str(out)]
    assert main([*args, "--jobs", "2"]) == 0
    summary = json.loads((out / "summary.json").read_text())
    assert summary["method"] == "regression"
    regression, board = summary["methods"]["regression"], summary["methods"]["board"]
    for block in (regression, board):
        assert block["overall"]["runs"] == 16
        assert set(block["cases"]) == {str(c) for c in range(1, 9)}
    assert board["overall"]["successes"] == 16
    assert board["overall"]["final_lateral_cm"]["median"] < 0.5
    assert board["overall"]["final_heading_deg"]["median"] < 1.0
    assert regression["overall"]["successes"] >= 14
    assert regression["overall"]["final_lateral_cm"]["median"] < 2.0  # the papers' 2 cm
    assert regression["overall"]["final_heading_deg"]["median"] < 3.07  # and 3.07 degrees
    # Nobody hits the face at speed.
    assert board["overall"]["impact_speed_mps"]["max"] < 0.05
    assert regression["overall"]["impact_speed_mps"]["max"] < 0.05
