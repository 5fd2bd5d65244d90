"""A plausible but wrong calibration is told once (issue 24): a camera given beside a bundle that is not the
bundle's, and geometric poses whose scale disagrees with the papers' regression over many frames.

The frames are the simulator's: the true corners of the dock at known poses (the true camera, the true layout)
with the detector's sub-pixel noise; the estimates are then made with a camera or a marker size 30 % off.
"""

from __future__ import annotations

import logging
import re
from pathlib import Path

import numpy as np
import pytest

from monodock.core.camera import CameraModel
from monodock.core.layout import DockLayout
from monodock.core.settings import from_mapping, to_mapping
from monodock.estimation.bundle import Bundle, load_bundle
from monodock.estimation.consistency import ScaleCheck
from monodock.estimation.factory import make_estimator
from monodock.estimation.pnp import PoseEstimate, estimate_board, estimate_single_marker
from monodock.estimation.regression import RegressionEstimator
from monodock.perception.detect import Detection
from monodock.sim import PoseDistribution, Simulator
from shared import noisy_detection

FRAMES = 300


def _scaled_layout(layout: DockLayout, factor: float) -> DockLayout:
    return from_mapping(DockLayout, {**to_mapping(layout), "marker_size": layout.marker_size * factor}, "scaled")


def _frames(sim: Simulator, count: int, seed: int) -> list[Detection]:
    """Detections of the dock across the bundle's trained depths, all three markers in view."""
    rng = np.random.default_rng(seed)
    dist = PoseDistribution(depth=(0.35, 1.4))
    return [
        noisy_detection(sim, sim.sample_pose(dist, rng=rng), ("left", "center", "right"), seed=seed * 10_000 + i)  # type: ignore[misc]
        for i in range(count)
    ]


def _run(bundle: Bundle, sim: Simulator, camera: CameraModel, layout: DockLayout, *, given: str) -> list[str]:
    said: list[str] = []
    check = ScaleCheck(
        RegressionEstimator(bundle, bundle.camera(), sim.robot).estimate,
        camera,
        layout,
        sim.robot,
        given_camera=given,
        bundle_camera=bundle.camera(),
        warn=said.append,
    )
    for det in _frames(sim, FRAMES, seed=11):
        estimates: dict[str, PoseEstimate] = {
            "board": estimate_board(det, camera, layout, sim.robot),
            "pnp": estimate_single_marker(det, camera, layout, sim.robot),
        }
        check.add(det, estimates)
    return said


def _ratio(warning: str) -> float:
    """The depth ratio a warning reports ("... depths are 1.27x the regression's ...")."""
    found = re.search(r"depths are ([0-9.]+)x", warning)
    assert found is not None, warning
    return float(found[1])


@pytest.fixture(scope="module")
def trained(work: Path) -> tuple[Bundle, Simulator]:
    """The pipeline's bundle (trained on simulated LiDAR labels with the default camera) and that simulator."""
    return load_bundle(work / "bundle"), Simulator(seed=7)


def test_the_true_calibration_raises_no_alarm_over_hundreds_of_frames(trained: tuple[Bundle, Simulator]) -> None:
    bundle, sim = trained
    assert _run(bundle, sim, sim.camera, sim.layout, given="") == []


def test_a_focal_length_30_percent_long_is_one_warning_naming_the_camera(trained: tuple[Bundle, Simulator]) -> None:
    bundle, sim = trained
    wrong = sim.camera.focal_scaled(1.3)
    said = _run(bundle, sim, wrong, sim.layout, given="camera.yaml")
    assert len(said) == 1, said
    # board and pnp put the dock 1.3x too far; the regression (the bundle's own camera) does not
    assert 1.2 < _ratio(said[0]) < 1.35
    assert "focal length" in said[0]
    assert f"{wrong.fx:.1f}" in said[0]
    assert f"{bundle.camera().fx:.1f}" in said[0]


def test_a_marker_size_30_percent_small_names_the_camera_and_the_marker_size(
    trained: tuple[Bundle, Simulator],
) -> None:
    bundle, sim = trained
    said = _run(bundle, sim, sim.camera, _scaled_layout(sim.layout, 0.7), given="")
    assert len(said) == 1, said
    # the square's size sets pnp's scale; the board's is shared with the markers' spacing, which stayed right
    assert _ratio(said[0]) < 0.9
    assert "marker_size" in said[0]
    assert "focal length" in said[0]


def test_a_camera_beside_the_bundle_that_is_not_its_own_is_one_warning_naming_both(
    trained: tuple[Bundle, Simulator], tmp_path: Path, caplog: pytest.LogCaptureFixture
) -> None:
    bundle, _sim = trained
    own, other = tmp_path / "own.yaml", tmp_path / "other.yaml"
    bundle.camera().save(own)
    bundle.camera().focal_scaled(1.3).save(other)
    with caplog.at_level(logging.WARNING, logger="monodock.input"):
        make_estimator(method="board", bundle=bundle, camera=own)
    assert caplog.records == []
    with caplog.at_level(logging.WARNING, logger="monodock.input"):
        make_estimator(method="board", bundle=bundle, camera=other)
    said = [r.getMessage() for r in caplog.records]
    assert len(said) == 1, said
    assert f"{bundle.camera().fx * 1.3:.1f}" in said[0]
    assert f"{bundle.camera().fx:.1f}" in said[0]
    assert str(other) in said[0]


@pytest.mark.slow
def test_estimate_on_rendered_frames_warns_once_with_a_wrong_focal_length_and_never_with_the_true_one(
    work: Path, tmp_path: Path, capfd: pytest.CaptureFixture[str]
) -> None:
    """End to end: 80 frames rendered with the true camera (every nuisance), ``estimate --model --method board``
    with the true camera (no warning) and with one 30 % long beside the bundle (its warning and the scale's)."""
    from monodock.cli.main import main

    sim = tmp_path / "sim"
    assert main(["simulate", "--out", str(sim), "--frames", "80", "--supersample", "1", "--depth", "0.4", "1.3"]) == 0
    wrong = tmp_path / "camera_13.yaml"
    CameraModel.load(sim / "camera.yaml").focal_scaled(1.3).save(wrong)
    common = ["estimate", str(sim / "images"), "--model", str(work / "bundle"), "--method", "board"]
    capfd.readouterr()
    assert main([*common, "--camera", str(sim / "camera.yaml"), "--out", str(tmp_path / "true.csv")]) == 0
    assert "warning" not in capfd.readouterr().err
    assert main([*common, "--camera", str(wrong), "--out", str(tmp_path / "wrong.csv")]) == 0
    said = [line for line in capfd.readouterr().err.splitlines() if ": warning: " in line]
    assert len(said) == 2, said  # the camera beside the bundle, and the scale over the frames
    assert 1.2 < _ratio(said[1]) < 1.35
