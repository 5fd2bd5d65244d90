"""The demo's report reads like a product's first screen: built from a small result, its HTML opens with the
camera frame (every method's estimate drawn), the headline against the papers and the docking trajectories;
the long tables sit in collapsed sections; the settings are YAML a person can read, not Python reprs."""

from __future__ import annotations

import html
import math
import re
from pathlib import Path

import numpy as np
import pytest
import yaml

from monodock.cli.demo import DemoConfig, demo_settings
from monodock.core.pose import DockPose
from monodock.core.pose2d import Pose2D
from monodock.dock.states import State
from monodock.estimation.pnp import PoseEstimate, estimate_board, estimate_single_marker
from monodock.evaluation.dock_results import TrialResult
from monodock.evaluation.dock_sim import DockSimConfig, summarize
from monodock.evaluation.heldout import (
    HeldoutResult,
    MethodResult,
    MiscalibrationRow,
    Reference,
    band_rows,
    invalid_reasons,
    paper_samples,
)
from monodock.learning.dataset import LabelRun
from monodock.perception.detect import MarkerDetector
from monodock.report.demo import FRAME_FILE, DemoPage, DockingRun, FrameView, write_demo_report
from monodock.report.docking import write_dock_files
from monodock.sim import Nuisances, Simulator

METHODS = ("regression", "pnp", "board", "fused")


def _heldout(rows: int = 80) -> HeldoutResult:
    """A held-out result of made-up estimates around a made-up truth (the report only draws what it is given)."""
    rng = np.random.default_rng(4)
    depth = np.linspace(0.3, 2.4, rows)
    truth = np.column_stack([depth + 0.17, rng.uniform(-0.3, 0.3, rows), rng.uniform(-0.4, 0.4, rows)])
    lidar = truth + rng.normal(0.0, [0.01, 0.01, 0.01], (rows, 3))
    lidar[::17] = np.nan
    results = {}
    for k, m in enumerate(METHODS):
        poses = truth + rng.normal(0.0, 0.002 * (k + 1), (rows, 3))
        reasons = [""] * rows
        for i in range(k, rows, 23):
            poses[i] = np.nan
            reasons[i] = "no marker 2 (saw left)"
        results[m] = MethodResult(m, poses, tuple(reasons))
    refs = {Reference.TRUTH: truth, Reference.LIDAR: lidar}
    study = tuple(
        MiscalibrationRow(q, f, m, 1.0 * f, 100 * (f - 1), 0.1)
        for q in ("marker size", "focal length")
        for f in (1.0, 1.05, 1.5)
        for m in ("pnp", "board")
    )
    return HeldoutResult(
        rows=rows,
        results=results,
        references=refs,
        depth=depth,
        bands={name: tuple(band_rows(depth, ref, results)) for name, ref in refs.items()},
        samples=paper_samples(lidar, results, truth=truth),
        miscalibration=study,
        limit=None,
        limit_studied=False,
        invalid_reasons=invalid_reasons(results),
    )


def _docking(out: Path) -> DockingRun:
    """Two made-up runs per method, their files written into out/docking as the demo's are."""
    config = DockSimConfig(cases=(1, 5), trials=1, methods=("regression", "board", "fused"))
    results = []
    for case, start in ((1, Pose2D(-1.8, 0.4, -0.3)), (5, Pose2D(-1.2, -0.3, 0.2))):
        for m in config.methods:
            path = tuple((start.x + (-0.4 - start.x) * s, start.y * (1 - s), start.theta * (1 - s)) for s in (0, 1))
            numbers = (True, 0, 20.0, 0.1, 0.2, 0.1, None, 300, 1.0, 0.5, 0.1)
            results.append(TrialResult(case, 0, m, start, case, State.DOCKED, "", *numbers, path, ()))
    (out / "docking").mkdir()
    write_dock_files(out / "docking", results, config)
    return DockingRun(config, tuple(results), summarize(results, config))


def _frame() -> FrameView:
    """A rendered frame 1.2 m from the camera, its detection, the PnP methods' estimates and two made-up ones."""
    sim = Simulator(nuisances=Nuisances().updated(supersample=2), seed=3)
    pose = DockPose(1.37, 0.05, math.radians(4.0))
    image = sim.render(pose)
    det = MarkerDetector(sim.layout).detect(image)
    estimates = {
        "regression": PoseEstimate("regression", DockPose(1.38, 0.06, math.radians(5.0))),
        "pnp": estimate_single_marker(det, sim.camera, sim.layout, sim.robot),
        "board": estimate_board(det, sim.camera, sim.layout, sim.robot),
        "fused": PoseEstimate("fused", DockPose(1.371, 0.049, math.radians(4.1))),
    }
    return FrameView(image, det, estimates, pose, sim.true_corners(pose), sim.camera, sim.layout, sim.robot)


@pytest.fixture(scope="module")
def report(tmp_path_factory: pytest.TempPathFactory) -> tuple[Path, str]:
    out = tmp_path_factory.mktemp("demo_report")
    result = _heldout()
    docking = _docking(out)
    page = DemoPage(
        heldout=result,
        summary=result.summary(docking={m: b.overall for m, b in docking.summary.methods.items()}),
        docking=docking,
        frame=_frame(),
        lidar_overlays=(),
        training=None,
        label_run=LabelRun(),
        label_errors=(),
        settings=demo_settings(DemoConfig(), Simulator(seed=1000), 1000),
        trials=1,
        train_seconds=1.0,
    )
    write_demo_report(out, page)
    return out, (out / "report.html").read_text(encoding="utf-8")


def _first_screen(page: str) -> str:
    start = page.index('<div class="first-screen">')
    # The block ends where the next top-level section starts (its columns are divs inside it).
    return page[start : page.index("<h2>Settings</h2>")]


def _details(page: str) -> list[str]:
    return re.findall(r"<details>.*?</details>", page, flags=re.S)


def test_the_first_screen_shows_the_frame_the_papers_and_the_trajectories(report: tuple[Path, str]) -> None:
    out, page = report
    first = _first_screen(page)
    # It comes first: only the title and one lead paragraph before it.
    assert page.index('<div class="first-screen">') < page.index("<h2>")
    assert f'src="{FRAME_FILE}"' in first
    assert (out / FRAME_FILE).read_bytes()[:8] == b"\x89PNG\r\n\x1a\n"
    assert 'src="docking/trajectories.png"' in first
    assert (out / "docking" / "trajectories.png").is_file()
    # The headline against the papers: their regression and SolvePnP next to every method of ours.
    for figure in ("1.18", "3.11", "58.54", "6.64"):
        assert f"<td>{figure}</td>" in first
    for method in METHODS:
        assert f"<td>{method}</td>" in first
    assert "<details" not in first


def test_the_long_tables_are_in_collapsed_sections(report: tuple[Path, str]) -> None:
    _, page = report
    inside = "".join(_details(page))
    outside = re.sub(r"<details>.*?</details>", "", page, flags=re.S)
    for header in ("<th>depth band</th>", "<th>A: LiDAR (m)</th>", "<th>A: LiDAR (°)</th>", "<th>NEES</th>"):
        assert header in inside, header
        assert header not in outside, header
    assert "<details open" not in page


def test_the_settings_are_yaml_without_python_reprs(report: tuple[Path, str]) -> None:
    _, page = report
    blocks = [html.unescape(b) for b in re.findall(r'<pre class="settings[^"]*">(.*?)</pre>', page, flags=re.S)]
    assert len(blocks) == 2  # the demo's, and the docking runs'
    for text in blocks:
        settings = yaml.safe_load(text)
        assert isinstance(settings, dict)
        assert "Nuisances(" not in text
        assert "LidarModel(" not in text
    demo = yaml.safe_load(blocks[0])
    # Angles in degrees where a person reads them.
    assert demo["LiDAR"]["angle_min_deg"] == -180.0
    assert demo["LiDAR"]["angle_increment_deg"] == 0.5
    assert demo["held-out drive"]["nuisances"]["exposure"] == 1.0
    docking = yaml.safe_load(blocks[1])
    assert docking["nuisances"]["supersample"] == DockSimConfig().supersample == 16
    for repr_ in ("Nuisances(", "LidarModel(", "Mount(", "PlannerConfig("):
        assert repr_ not in page


def test_every_image_fits_the_page(report: tuple[Path, str]) -> None:
    """Images are at most the page's width (1240 px) and shrink with it: nothing makes the page scroll sideways."""
    _, page = report
    assert "img{max-width:100%;height:auto}" in page
    widths = [int(w) for w in re.findall(r'<img [^>]*width="(\d+)"', page)]
    assert widths
    assert max(widths) <= 1240
