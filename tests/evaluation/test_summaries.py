"""The summary.json contracts are typed: dock-sim's summary writes the layout other tools read and reads back
to the same values; the evaluation's summary has its keys; and computing never loads the plotting library."""

from __future__ import annotations

import dataclasses
import json
import math
import subprocess
import sys
from pathlib import Path

import numpy as np

from monodock.core.pose2d import Pose2D
from monodock.dock.states import FailureReason, State
from monodock.evaluation.dock_results import DockSimSummary, FilterFrame, TrialResult
from monodock.evaluation.dock_sim import DockSimConfig, summarize
from monodock.evaluation.heldout import (
    HeldoutResult,
    MethodResult,
    Reference,
    band_rows,
    invalid_reasons,
    paper_samples,
)


def _trial(case: int, method: str, *, success: bool, lateral: float, frames: tuple[FilterFrame, ...]) -> TrialResult:
    start = Pose2D(-1.5, 0.3 * (case % 2), 0.1)
    return TrialResult(
        case=case,
        trial=0,
        method=method,
        start=start,
        classified_case=case if success else None,
        state=State.DOCKED if success else State.FAILED,
        reason="" if success else "markers lost: for 1.2 s during the approach",
        failure=None if success else FailureReason.MARKERS_LOST,
        success=success,
        retries=0 if success else 2,
        time_s=18.5 + case,
        lateral_cm=lateral,
        longitudinal_cm=0.2,
        heading_deg=-0.3,
        impact_speed=None if success else 0.01,
        frames=280,
        wall_s=30.0,
        render_s=25.0,
        perceive_s=3.0,
        path=((start.x, start.y, start.theta), (-0.34, 0.0, 0.0)),
        log=((0.0, "acquire"),),
        filter_frames=frames,
    )


def _frames(rng: np.random.Generator) -> tuple[FilterFrame, ...]:
    """Frames at 20-240 cm from the camera, a few without an estimate (coasting), one with a NaN NEES."""
    out = []
    for k, x in enumerate(np.linspace(0.37, 2.57, 23)):
        truth = (float(x), 0.01, 0.02)
        filtered = (float(x) + 0.001, 0.011, 0.021)
        raw = None if k % 7 == 0 else (float(x) + float(rng.normal(0, 0.003)), 0.012, 0.018)
        out.append(FilterFrame(truth, filtered, raw, math.nan if k == 3 else 2.5))
    return tuple(out)


def _summary() -> DockSimSummary:
    rng = np.random.default_rng(1)
    config = DockSimConfig(cases=(2, 7), trials=1, methods=("board", "fused"))
    results = [
        _trial(2, "board", success=True, lateral=0.4, frames=_frames(rng)),
        _trial(2, "fused", success=True, lateral=-0.2, frames=_frames(rng)),
        _trial(7, "board", success=False, lateral=3.1, frames=()),
        _trial(7, "fused", success=True, lateral=0.1, frames=_frames(rng)),
    ]
    return summarize(results, config)


def test_dock_sim_summary_writes_the_contract_and_reads_back(tmp_path: Path) -> None:
    summary = _summary()
    path = tmp_path / "summary.json"
    path.write_text(summary.to_json(), encoding="utf-8")
    raw = json.loads(path.read_text(encoding="utf-8"))
    # The layout other tools read: the first method's groups at the top, every method under "methods".
    assert list(raw) == ["method", "overall", "cases", "methods", "filter", "settings", "speed"]
    assert raw["method"] == "board"
    assert raw["overall"] == raw["methods"]["board"]["overall"]
    assert set(raw["cases"]) == {"2", "7"}
    assert raw["overall"]["failures"] == {"markers-lost": 1}
    assert raw["overall"]["retries"] == {"total": 2, "max": 2}
    assert raw["overall"]["final_lateral_cm"]["max"] == 3.1
    assert [b["depth_cm"] for b in raw["filter"]["board"]["bands"]] == [[d, d + 25] for d in range(25, 250, 25)]
    assert raw["filter"]["fused"]["under_25cm"]["frames"] == 0
    assert raw["settings"]["tolerances"] == {"lateral_cm": 2.0, "longitudinal_cm": 2.0, "heading_deg": 3.0}
    assert raw["settings"]["distance_m"] == [1.0, 2.5]
    back = DockSimSummary.read(path)
    assert back == summary
    assert back.to_json() == path.read_text(encoding="utf-8")
    # Attributes, not string keys.
    assert back.overall.successes == 1
    assert back.cases[7].failures == {"markers-lost": 1}
    assert back.methods["fused"].overall.success_rate == 1.0
    assert back.filter["board"].all.filtered is not None


def test_heldout_summary_has_the_contract_keys() -> None:
    rows = 40
    rng = np.random.default_rng(2)
    truth = np.column_stack([np.linspace(0.5, 2.5, rows), rng.uniform(-0.3, 0.3, rows), np.zeros(rows)])
    lidar = truth + 0.01
    results = {m: MethodResult(m, truth + 0.002, ("",) * rows) for m in ("regression", "pnp", "board")}
    refs = {Reference.TRUTH: truth, Reference.LIDAR: lidar}
    depth = truth[:, 0] - 0.17
    result = HeldoutResult(
        rows=rows,
        results=results,
        references=refs,
        depth=depth,
        bands={k: tuple(band_rows(depth, v, results)) for k, v in refs.items()},
        samples=paper_samples(lidar, results, truth=truth),
        miscalibration=(),
        limit=None,
        limit_studied=True,
        invalid_reasons=invalid_reasons(results),
    )
    summary = json.loads(result.summary().to_json())
    assert list(summary) == [
        "rows",
        "has_truth",
        "against_truth",
        "against_lidar",
        "physical_limit",
        "miscalibration",
        "invalid_reasons",
    ]
    assert summary["physical_limit"] == {}  # studied, but no refined corners to measure the noise on
    assert set(summary["against_truth"]) == {"regression", "pnp", "board"}
    assert summary["against_truth"]["board"]["depth_mae_cm"] == result.summary().overall["board"].depth_mae_cm
    assert summary["against_lidar"]["pnp"]["valid"] == rows


def test_computing_the_evaluations_loads_no_plotting_library() -> None:
    """Layers: evaluation computes, report draws; only report imports matplotlib."""
    code = (
        "import sys\n"
        "import monodock.evaluation.heldout, monodock.evaluation.limit, monodock.evaluation.robustness\n"
        "import monodock.evaluation.dock_sim, monodock.evaluation.metrics\n"
        "bad = sorted(m for m in sys.modules if m.split('.')[0] == 'matplotlib' or m.startswith('monodock.report'))\n"
        "print(bad)\n"
    )
    out = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, check=True).stdout
    assert out.strip() == "[]"


def test_runs_are_grouped_by_the_case_executed_as_well_as_by_the_start_region(tmp_path: Path) -> None:
    """A start in region 2 that executed case 4 counts under case 2's start region and under executed case 4; a
    mission that never planned under 0; the read-back keeps both groupings."""
    rng = np.random.default_rng(2)
    turned = dataclasses.replace(_trial(2, "board", success=True, lateral=0.3, frames=_frames(rng)), classified_case=4)
    straight = _trial(2, "board", success=True, lateral=0.1, frames=())
    lost = _trial(7, "board", success=False, lateral=3.0, frames=())
    summary = summarize([turned, straight, lost], DockSimConfig(cases=(2, 7), trials=2, methods=("board",)))
    runs = summary.methods["board"]
    assert {c: g.runs for c, g in runs.cases.items()} == {2: 2, 7: 1}
    assert {c: g.runs for c, g in runs.executed.items()} == {0: 1, 2: 1, 4: 1}
    assert runs.cases[2].case_agreement == 0.5
    assert runs.executed[0].failures == {"markers-lost": 1}
    path = tmp_path / "summary.json"
    path.write_text(summary.to_json(), encoding="utf-8")
    assert DockSimSummary.read(path).methods["board"].executed == runs.executed
