"""Dock-sim's report from a handful of made-up runs: the trajectory and per-run figures are written, the executed
case is counted against the start region, and reversing is found where (and only where) the robot backed up."""

from __future__ import annotations

import math
import re
from pathlib import Path

import numpy as np
import pytest

from monodock.core.pose2d import Pose2D
from monodock.core.robot import RobotConfig
from monodock.dock.states import FailureReason, State
from monodock.evaluation.dock_results import TrialResult
from monodock.evaluation.dock_sim import DockSimConfig, summarize
from monodock.report.dock_figures import run_plot
from monodock.report.dock_runs import (
    agreement_table,
    executed_case_table,
    path_times,
    phases,
    reverse_mask,
    run_file,
    select_runs,
    signed_speeds,
    variant_label,
    variants,
)
from monodock.report.docking import trajectory_file, write_dock_report

FRONT = RobotConfig.default().front_offset
STEP = 0.04  # metres per 0.2 s sample: 0.2 m/s
Pt = tuple[float, float, float]


def _drive(p: Pt, to: tuple[float, float]) -> list[Pt]:
    """Samples after p along a straight leg to ``to``, the heading fixed: forwards or backwards, as it points."""
    n = max(1, math.ceil(math.dist(p[:2], to) / STEP))
    return [(p[0] + (to[0] - p[0]) * k / n, p[1] + (to[1] - p[1]) * k / n, p[2]) for k in range(1, n + 1)]


def _turn(p: Pt, heading: float) -> list[Pt]:
    """Samples after p of a turn on the spot to ``heading``."""
    n = max(1, math.ceil(abs(heading - p[2]) / 0.1))
    return [(p[0], p[1], p[2] + (heading - p[2]) * k / n) for k in range(1, n + 1)]


def _run(
    case: int,
    executed: int | None,
    legs: list[tuple[str, list[Pt]]],
    start: Pt,
    *,
    success: bool = True,
    planner: str = "monodock",
    times: bool = True,
    point_a: tuple[float, float] | None = (-1.34, 0.0),
) -> TrialResult:
    """A run through ``legs`` (state, its samples), logged as it entered each state."""
    path, log = [start], []
    for state, samples in legs:
        log.append((round(0.2 * (len(path) - 1), 3), f"{state}: made up"))
        path += samples
    end = 0.2 * (len(path) - 1)
    log.append((end, "docked" if success else "failed: timeout"))
    x, y, h = path[-1]
    return TrialResult(
        case=case,
        trial=0,
        method="pnp",
        start=Pose2D(*start),
        classified_case=executed,
        state=State.DOCKED if success else State.FAILED,
        reason="",
        success=success,
        retries=0,
        time_s=end,
        lateral_cm=y * 100,
        longitudinal_cm=(-x - FRONT) * 100,
        heading_deg=math.degrees(h),
        impact_speed=None,
        frames=10,
        wall_s=1.0,
        render_s=0.5,
        perceive_s=0.1,
        path=tuple(path),
        log=tuple(log),
        failure=None if success else FailureReason.TIMEOUT,
        planner=planner,
        point_a=point_a if executed is not None else None,
        path_t=tuple(0.2 * i for i in range(len(path))) if times else (),
    )


def _forward(planner: str = "monodock") -> TrialResult:
    """Case 1: turn to A, drive there, turn to the face, approach."""
    s: Pt = (-2.0, 0.4, -0.3)
    turn1 = _turn(s, math.atan2(-0.4, 0.66))
    drive = _drive(turn1[-1], (-1.34, 0.0))
    turn2 = _turn(drive[-1], 0.0)
    approach = _drive(turn2[-1], (-FRONT, 0.0))
    legs = [("moving1-turn", turn1), ("moving1-drive", drive), ("moving2", turn2), ("moving3", approach)]
    return _run(1, 1, legs, s, planner=planner)


def _reversing() -> tuple[TrialResult, list[int]]:
    """Case 5 (past A): reverse to A facing the dock, turn, approach; and the path indices of the reverse leg."""
    s: Pt = (-0.8, 0.3, 0.3)
    turn1 = _turn(s, math.atan2(0.3, 0.54))
    back = _drive(turn1[-1], (-1.34, 0.0))  # facing away from A
    turn2 = _turn(back[-1], 0.0)
    approach = _drive(turn2[-1], (-FRONT, 0.0))
    legs = [("moving1-turn", turn1), ("moving1-back", back), ("moving2", turn2), ("moving3", approach)]
    first = 1 + len(turn1)
    return _run(5, 5, legs, s), list(range(first, first + len(back)))


def _failed() -> TrialResult:
    """Started in region 3, executed case 4, stopped short of the face."""
    s: Pt = (-1.9, 0.2, 0.3)
    turn1 = _turn(s, -0.2)
    drive = _drive(turn1[-1], (-1.34, 0.0))
    approach = _drive(drive[-1], (-0.9, 0.1))
    legs = [("moving1-turn", turn1), ("moving1-drive", drive), ("moving3", approach)]
    return _run(3, 4, legs, s, success=False)


def _never_planned() -> TrialResult:
    """Turned on the spot looking for the dock, never planned; an old result without path_t."""
    s: Pt = (-1.5, -0.5, 0.4)
    return _run(2, None, [("acquire", _turn(s, 1.2))], s, success=False, times=False)


@pytest.fixture(scope="module")
def runs() -> tuple[list[TrialResult], list[int]]:
    reversing, back = _reversing()
    return [_forward(), reversing, _failed(), _never_planned(), _forward("papers")], back


def test_reversing_is_marked_on_the_reverse_leg_only(runs: tuple[list[TrialResult], list[int]]) -> None:
    results, back = runs
    reversing = results[1]
    mask = reverse_mask(reversing.path)
    assert len(mask) == len(reversing.path)
    assert np.flatnonzero(mask).tolist() == back
    # Forward driving and turns on the spot are not reversing.
    for r in (results[0], results[2], results[3]):
        assert not reverse_mask(r.path).any()
    # The speed along the heading: negative on the reverse leg only, about 0.2 m/s while moving.
    t0, t1, v = signed_speeds(reversing)
    assert len(t0) == len(t1) == len(reversing.path) - 1
    assert np.allclose(t1 - t0, 0.2)
    assert (np.flatnonzero(v < -0.1) + 1).tolist() == back
    assert np.allclose(np.abs(v[np.abs(v) > 0.01]), 0.2, atol=0.03)


def test_an_old_run_without_path_times_gets_the_sampling(runs: tuple[list[TrialResult], list[int]]) -> None:
    old = runs[0][3]
    assert old.path_t == ()
    t = path_times(old)
    assert np.allclose(t, 0.2 * np.arange(len(old.path)))
    assert [p.state for p in phases(old)] == ["acquire", "failed"]


def test_the_executed_case_is_counted_against_the_start_region(runs: tuple[list[TrialResult], list[int]]) -> None:
    results = runs[0]
    monodock = [r for r in results if r.planner == "monodock"]
    vs = variants(monodock)
    assert vs == [("pnp", "monodock")]
    table = agreement_table(monodock, vs)
    head, rule = table.splitlines()[:2]
    assert head.count("|") == rule.count("|")
    rows = {cells[1]: cells for cells in (re.split(r"\s*\|\s*", ln.strip("| ")) for ln in table.splitlines()[2:])}
    # Four runs: regions 1 and 5 ran their own case, region 3 ran case 4, region 2 never planned.
    assert rows["all"][-1] == "2/4 (50 %)"
    assert rows["3"][2 + 4] == "1"  # "ran 4"
    assert rows["3"][-1] == "0/1 (0 %)"
    assert rows["2"][-2] == "1"  # none
    planned = [r for r in monodock if r.classified_case is not None]
    assert agreement_table(planned, vs, regions=False).splitlines()[2].endswith("| 2/3 (67 %) |")
    success = executed_case_table(monodock, vs)
    assert "| 4 | 0/1 |" in success
    assert "| 5 | 1/1 |" in success
    assert "| none (never planned) | 0/1 |" in success
    assert "| all | 2/4 |" in success


def test_variants_are_labelled_by_planner_only_when_several_ran(runs: tuple[list[TrialResult], list[int]]) -> None:
    results = runs[0]
    config = DockSimConfig(methods=("pnp",), planners=("monodock", "papers"))
    vs = variants(results, config)
    assert vs == [("pnp", "monodock"), ("pnp", "papers")]
    assert [variant_label(v, config.planner_kinds) for v in vs] == ["pnp · monodock", "pnp · papers"]
    assert variant_label(("pnp", "monodock"), ("monodock",)) == "pnp"
    table = executed_case_table(results, vs)
    assert "| 1 | 1/1 | 1/1 |" in table


def test_the_selection_keeps_firsts_and_failures_under_the_cap(runs: tuple[list[TrialResult], list[int]]) -> None:
    results = runs[0]
    vs = variants(results)
    assert len(select_runs(results, vs)) == len(results)
    two = select_runs(results, vs, cap=2)
    assert len(two) == 2
    assert any(not r.success for r in two)
    assert len({run_file(r) for r in results}) == len(results)


def test_the_report_writes_every_figure(tmp_path: Path, runs: tuple[list[TrialResult], list[int]]) -> None:
    results = runs[0]
    config = DockSimConfig(cases=(1, 2, 3, 5), trials=1, methods=("pnp",), planners=("monodock", "papers"))
    write_dock_report(tmp_path, results, summarize(results, config), config)
    png = b"\x89PNG\r\n\x1a\n"
    expected = ["trajectories.png", "final_errors.png", "runs.csv", "report.html", "summary.json"]
    expected += [trajectory_file(c) for c in (1, 2, 3, 4, 5, None)]
    expected += [run_file(r) for r in results]
    for name in expected:
        assert (tmp_path / name).is_file(), name
        if name.endswith(".png"):
            assert (tmp_path / name).read_bytes()[:8] == png, name
    page = (tmp_path / "report.html").read_text(encoding="utf-8")
    for r in results:
        assert f'src="{run_file(r)}"' in page
    assert f'src="{trajectory_file(None)}"' in page
    assert "<td>pnp · papers</td>" in page
    assert "<th>agree</th>" in page


def test_a_run_figure_without_a_path(tmp_path: Path, runs: tuple[list[TrialResult], list[int]]) -> None:
    """A run that recorded nothing still gets its figure (empty axes), not an exception."""
    r = runs[0][3]
    empty = TrialResult(**{**r.__dict__, "path": (), "path_t": (), "log": ()})
    config = DockSimConfig()
    run_plot(empty, tmp_path / "empty.png", layout=config.layout, robot=config.robot, drive=config.drive)
    assert (tmp_path / "empty.png").is_file()
