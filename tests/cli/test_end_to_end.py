"""End to end: the demo's report, and estimation from a video, against the simulator's truth."""

from __future__ import annotations

import csv
import json
import math
from pathlib import Path

import cv2
import numpy as np
import pytest

from monodock.cli.main import main
from monodock.core.pose import DockPose
from monodock.sim import PoseDistribution, Simulator


def write_calibration(sim: Simulator, folder: Path) -> list[str]:
    """Save the simulator's camera, layout and robot files; return the matching CLI options."""
    sim.camera.save(folder / "camera.yaml")
    sim.layout.save(folder / "layout.yaml")
    sim.robot.save(folder / "robot.yaml")
    return [
        "--camera",
        str(folder / "camera.yaml"),
        "--layout",
        str(folder / "layout.yaml"),
        "--robot",
        str(folder / "robot.yaml"),
    ]


@pytest.mark.slow  # the whole pipeline, with 24 docking runs (every case with each docking method): ~2 minutes alone
@pytest.mark.timeout(900)
def test_demo_writes_report_with_truthful_numbers(tmp_path: Path) -> None:
    """`monodock demo` at a small size: the whole pipeline runs, the report's files exist, and every method's
    errors against the simulator's truth are what it can do.

    Bounds: the 1,000-frame benchmark measures board MAE 1.5 cm depth and 0.9 deg yaw; 40 held-out frames stay
    well inside twice that. The regression learns from 300 noisy LiDAR-labelled stops with one draw per model,
    so its bounds are loose, but far from a guess over 2.5 m and 60 degrees.

    The docking stage is also the docking benchmark's CI variant (it was a test of its own, which trained a
    second bundle and ran the same 24 runs again): every case with each method, by the truth.
    """
    out = tmp_path / "report"
    args = ["demo", "--out", str(out), "--train-stops", "300", "--test-stops", "40", "--trials", "1", "--jobs", "2"]
    assert main(args) == 0
    for name in (
        "report.html",
        "report.md",
        "summary.json",
        "fig12_depth.png",
        "fig13_angle.png",
        "miscalibration.png",
        "overlay_near.png",
        "train.parquet",
        "test.parquet",
        "bundle/bundle.json",
        "bundle/report/training.md",
    ):
        assert (out / name).is_file(), name
    assert not (out / "recordings").exists()  # the bags are working files, not part of the report
    truth = json.loads((out / "summary.json").read_text())["against_truth"]
    board, pnp, regression = truth["board"], truth["pnp"], truth["regression"]
    assert board["frames"] == pnp["frames"] == regression["frames"] == 40
    assert board["valid"] >= 39
    assert board["depth_mae_cm"] < 3.0
    assert board["yaw_mae_deg"] < 2.0
    assert board["lateral_mae_cm"] < 0.5
    assert regression["valid"] >= 36
    assert regression["depth_mae_cm"] < 4.0
    assert regression["yaw_mae_deg"] < 10.0
    # The fused method: bias-free corners and the planar fit beat board PnP on the same frames.
    fused = truth["fused"]
    assert fused["valid"] >= board["valid"] - 1
    assert fused["depth_mae_cm"] < board["depth_mae_cm"]
    assert fused["yaw_mae_deg"] < board["yaw_mae_deg"]
    # The closed-loop docking section: one start per case (24 runs), regression, board PnP and fused through the
    # EKF, judged by the truth. Every case must dock with each method (the regression may miss one); the medians
    # over 8 runs sit far inside their bounds (board/fused ~0.05 cm and ~0.1 deg; the regression, learnt from
    # these 300 stops with one draw per model, ~0.2 cm and ~0.3 deg against the papers' 2 cm and 3.07 deg).
    docking = json.loads((out / "summary.json").read_text())["docking"]
    runs = list(csv.DictReader((out / "docking" / "runs.csv").open()))
    for method in ("regression", "board", "fused"):
        assert docking[method]["runs"] == 8
        assert sorted(int(r["case"]) for r in runs if r["method"] == method) == list(range(1, 9)), method
        fastest = docking[method]["impact_speed_mps"]["max"]
        assert fastest is None or fastest < 0.05, method  # nobody hits the face at speed (None: never touched)
    for method in ("board", "fused"):
        assert docking[method]["successes"] == 8, method
        assert docking[method]["final_lateral_cm"]["median"] < 0.5, method
        assert docking[method]["final_heading_deg"]["median"] < 1.0, method
    assert abs(docking["fused"]["final_longitudinal_cm"]["median"]) < 0.5
    regression = docking["regression"]
    assert regression["successes"] >= 7
    assert regression["final_lateral_cm"]["median"] < 2.0  # the papers' 2 cm
    assert regression["final_heading_deg"]["median"] < 3.07  # and 3.07 degrees
    assert regression["final_longitudinal_cm"]["max"] < 2.0  # a stop short of the face stays docked
    for name in ("docking/runs.csv", "docking/trajectories_case_1.png", "docking/final_errors.png"):
        assert (out / name).is_file(), name
    # A second run must not replace the report without --force.
    assert main(["demo", "--out", str(out), "--train-stops", "2"]) != 0


def test_estimate_on_a_video_names_frames_by_index(tmp_path: Path) -> None:
    """A video of simulated frames: rows are named 0, 1, 2 ... and match the truth of each frame."""
    sim = Simulator(seed=11)
    poses = [sim.sample_pose(PoseDistribution(depth=(0.4, 1.2))) for _ in range(6)]
    video = tmp_path / "drive.avi"
    writer = cv2.VideoWriter(str(video), cv2.VideoWriter_fourcc(*"MJPG"), 10.0, sim.camera.size)
    assert writer.isOpened()
    for pose in poses:
        writer.write(cv2.cvtColor(sim.frame(pose).image, cv2.COLOR_GRAY2BGR))
    writer.release()
    est = tmp_path / "est.csv"
    code = main(["estimate", str(video), "--method", "board", *write_calibration(sim, tmp_path), "--out", str(est)])
    assert code == 0
    rows = list(csv.DictReader(est.open()))
    assert [r["frame"] for r in rows] == [str(i) for i in range(len(poses))]
    for r, truth in zip(rows, poses, strict=True):
        assert r["valid"] == "true"
        got = DockPose(float(r["x_m"]), float(r["y_m"]), math.radians(float(r["yaw_deg"])))
        # JPEG compression costs a little accuracy; 1.2 m at most.
        assert abs(got.x - truth.x) < 0.02
        assert abs(got.y - truth.y) < 0.01
        assert abs(math.degrees(got.yaw - truth.yaw)) < 1.5
        assert np.isfinite(float(r["stamp"]))


@pytest.mark.parametrize("bad", ["not a video at all", ""])
def test_estimate_on_a_broken_video(tmp_path: Path, bad: str, capsys: pytest.CaptureFixture[str]) -> None:
    """A file with a video suffix that is not a video: one line, non-zero exit."""
    video = tmp_path / "broken.mp4"
    video.write_text(bad)
    calibration = write_calibration(Simulator(), tmp_path)
    code = main(["estimate", str(video), *calibration, "--out", str(tmp_path / "e.csv")])
    err = capsys.readouterr().err
    assert code != 0
    assert "broken.mp4" in err
    assert len(err.strip().splitlines()) == 1
