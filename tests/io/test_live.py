"""Live estimation (`monodock run`, io.live) from a video, a camera and a recording, against the simulator's truth."""

from __future__ import annotations

import csv
import dataclasses
import io
import json
import math
from pathlib import Path
from typing import Any

import cv2
import numpy as np
import pytest

from monodock.core.pose import DockPose, wrap_angle
from monodock.errors import InputError
from monodock.estimation.estimator import Estimator
from monodock.estimation.methods import MethodFrame
from monodock.estimation.pnp import PoseEstimate, estimate_board
from monodock.io.frames import FrameSource, open_frames
from monodock.io.live import run_live
from monodock.io.nav2 import (
    DOCK_POSE_COVARIANCE_TOPIC,
    DOCK_POSE_TOPIC,
    PoseStampedBagWriter,
    read_pose_bag,
)
from monodock.io.rows import COVARIANCE_COLUMNS, LIVE_COLUMNS
from monodock.sim import Simulator
from shared import BLACK, FRAMES, calibration, run_cli


def check_against_truth(rows: list[dict[str, Any]], poses: list[DockPose]) -> None:
    """Every frame has a row, in order; the black one is invalid, the others match the truth."""
    assert [r["frame"] for r in rows] == [str(i) for i in range(FRAMES)]
    for i, (r, truth) in enumerate(zip(rows, poses, strict=True)):
        if i == BLACK:
            assert r["valid"] in ("false", False)
            assert r["reason"]
            continue
        assert r["valid"] in ("true", True), r["reason"]
        # MJPG costs a little accuracy; board PnP at 1.2 m at most.
        assert abs(float(r["x_m"]) - truth.x) < 0.02
        assert abs(float(r["y_m"]) - truth.y) < 0.02
        assert abs(math.degrees(wrap_angle(math.radians(float(r["yaw_deg"])) - truth.yaw))) < 1.5
        assert abs(float(r["stamp"]) - 0.1 * i) < 1e-3  # the video's position
        assert float(r["latency_ms"]) >= 0.0


def test_run_live_streams_rows_that_match_the_truth(drive: tuple[Simulator, list[DockPose], Path, Path]) -> None:
    """run_live: a header, then one flushed row per frame; the black frame is an invalid row, not a crash."""
    sim, poses, video, _ = drive
    sink = io.StringIO()
    seen: list[int] = []

    def on_row(_row: dict[str, str]) -> None:
        # Streamed: by the time a row is handed on, it is already in the sink.
        seen.append(sink.getvalue().count("\n"))

    est = Estimator(sim.camera, sim.layout, sim.robot, ("board",))
    with open_frames(str(video), skip_bad=True) as source:
        stats = run_live(source, est, "board", sink=sink, on_row=on_row)
    assert seen == list(range(2, FRAMES + 2))
    rows = list(csv.DictReader(io.StringIO(sink.getvalue())))
    assert tuple(rows[0]) == LIVE_COLUMNS
    check_against_truth(rows, poses)
    assert (stats.frames, stats.valid, stats.dropped) == (FRAMES, FRAMES - 1, 0)
    assert stats.fps > 0
    assert 0 < stats.latency_median_ms <= stats.latency_p95_ms


def test_cli_run_jsonl_and_nav2_bag(drive: tuple[Simulator, list[DockPose], Path, Path], tmp_path: Path) -> None:
    """`monodock run --out x.jsonl --bag B`: typed JSON lines, and a PoseStamped bag Nav2's docking server reads."""
    _, poses, video, folder = drive
    out, bag = tmp_path / "est.jsonl", tmp_path / "dock_bag"
    argv = ["run", "--source", str(video), "--method", "board", *calibration(folder), "--out", str(out)]
    assert run_cli([*argv, "--bag", str(bag), "--overlay-video", str(tmp_path / "overlay.avi")]) == 0
    rows = [json.loads(line) for line in out.read_text().splitlines()]
    check_against_truth(rows, poses)
    assert isinstance(rows[0]["x_m"], float)
    assert rows[BLACK]["x_m"] is None
    # The overlay video has every frame.
    cap = cv2.VideoCapture(str(tmp_path / "overlay.avi"))
    assert int(cap.get(cv2.CAP_PROP_FRAME_COUNT)) == FRAMES
    cap.release()

    msgs = read_pose_bag(bag)
    valid = [r for r in rows if r["valid"]]
    assert len(msgs) == len(valid) == FRAMES - 1
    for msg, r in zip(msgs, valid, strict=True):
        assert (msg.topic, msg.msgtype, msg.frame_id) == (DOCK_POSE_TOPIC, "geometry_msgs/msg/PoseStamped", "base_link")
        assert msg.stamp == pytest.approx(r["stamp"], abs=1e-6)
        assert msg.position == pytest.approx((r["x_m"], r["y_m"], 0.0), abs=1e-4)
        qx, qy, qz, qw = msg.orientation
        assert (qx, qy) == (0.0, 0.0)
        assert math.degrees(2 * math.atan2(qz, qw)) == pytest.approx(r["yaw_deg"], abs=1e-3)
        assert msg.pose.yaw_deg == pytest.approx(r["yaw_deg"], abs=1e-3)
    # Outputs are not replaced without --force.
    with pytest.raises(InputError, match="exists"):
        run_cli([*argv, "--bag", str(bag)])


@pytest.mark.parametrize("command", ["run", "estimate"])
def test_a_bag_of_image_files_is_refused_not_left_empty(
    drive: tuple[Simulator, list[DockPose], Path, Path], tmp_path: Path, command: str
) -> None:
    """Image files have no time stamps: poses are found in them, but a Nav2 bag of them would have no times.
    Refused with the reason, and no bag (empty or not) is left behind."""
    sim, poses, _, folder = drive
    image = tmp_path / "near.png"
    cv2.imwrite(str(image), sim.frame(poses[0], 0.0, np.random.default_rng(1)).image)
    out, bag = tmp_path / "est.csv", tmp_path / "dock_bag"
    source = ["--source", str(image)] if command == "run" else [str(image)]
    argv = [command, *source, "--method", "board", *calibration(folder), "--out", str(out), "--bag", str(bag)]
    with pytest.raises(InputError, match="--bag needs time-stamped frames"):
        run_cli(argv)
    assert not bag.exists()
    # Without --bag, the same image gives its pose.
    assert run_cli(argv[:-2]) == 0
    (row,) = list(csv.DictReader(out.open()))
    assert row["valid"] == "true"
    assert float(row["x_m"]) == pytest.approx(poses[0].x, abs=0.03)


@pytest.mark.parametrize("content", ["not a video at all", ""])
def test_a_video_that_cannot_be_opened(tmp_path: Path, content: str) -> None:
    """A broken video, a missing file and an absent camera: one line naming them."""
    video = tmp_path / "broken.mp4"
    video.write_text(content)
    for spec, name in ((str(video), "broken.mp4"), (str(tmp_path / "gone.avi"), "gone.avi"), ("7", "camera 7")):
        with pytest.raises(InputError) as info, open_frames(spec) as source:
            list(source)
        assert name in str(info.value)
        assert len(str(info.value).splitlines()) == 1


class FakeCamera:
    """A camera that sends ``frames`` images, then nothing."""

    def __init__(self, frames: int) -> None:
        self.left = frames

    def read(self) -> tuple[bool, Any]:
        if self.left <= 0:
            return False, None
        self.left -= 1
        return True, np.zeros((480, 640), np.uint8)

    def get(self, _prop: int) -> float:
        return 0.0

    def release(self) -> None:
        pass


def test_a_camera_that_stops_ends_the_run(drive: tuple[Simulator, list[DockPose], Path, Path]) -> None:
    """Frames then silence: the run stops with a message; silence from the start is an error."""
    sim = drive[0]
    est = Estimator(sim.camera, sim.layout, sim.robot, ("board",))
    said: list[str] = []
    source = FrameSource.of_capture("camera 0", "camera", FakeCamera(3), stall_timeout_s=0.1)
    stats = run_live(source, est, "board", sink=None, on_message=said.append)
    assert (stats.frames, stats.valid) == (3, 0)
    assert said == [stats.stop_reason]
    assert "camera 0: no frame for" in said[0]
    assert "stopping after 3 frames" in said[0]
    silent = FrameSource.of_capture("camera 0", "camera", FakeCamera(0), stall_timeout_s=0.1)
    with pytest.raises(InputError, match="nothing received"):
        run_live(silent, est, "board", sink=None)


def test_live_rows_and_bag_carry_a_methods_covariance(
    drive: tuple[Simulator, list[DockPose], Path, Path], tmp_path: Path
) -> None:
    """A method with a covariance (the board with one attached, as the fused method will give): the live rows
    carry it as numbers, and the bag gets the second topic with it, poses matching the truth."""
    sim, poses, video, _ = drive
    cov = np.diag([1e-6, 4e-7, 1e-5])

    def board_with_covariance(det: Any) -> PoseEstimate:
        e = estimate_board(det, sim.camera, sim.layout, sim.robot)
        return dataclasses.replace(e, method="fused", covariance=cov if e.pose is not None else None)

    @dataclasses.dataclass(frozen=True)
    class BoardWithCovariance:
        name: str = "fused"

        def estimate(self, frame: MethodFrame) -> PoseEstimate:
            return board_with_covariance(frame.detection)

    est = Estimator(sim.camera, sim.layout, sim.robot, {"fused": BoardWithCovariance()})
    sink = io.StringIO()
    with open_frames(str(video), skip_bad=True) as source, PoseStampedBagWriter(tmp_path / "cov_bag") as bag:
        run_live(source, est, "fused", sink=sink, output_format="jsonl", bag=bag, max_frames=5)
    rows = [json.loads(line) for line in sink.getvalue().splitlines()]
    assert len(rows) == 5
    assert all(isinstance(rows[0][k], float) for k in COVARIANCE_COLUMNS)
    assert rows[0]["cov_yawyaw"] == pytest.approx(1e-5)
    msgs = read_pose_bag(tmp_path / "cov_bag", DOCK_POSE_COVARIANCE_TOPIC)
    assert bag.written == bag.written_with_covariance == len(msgs) == 5
    for msg, truth in zip(msgs, poses, strict=False):
        assert abs(msg.pose.x - truth.x) < 0.02
        np.testing.assert_allclose(msg.pose_covariance, cov, rtol=1e-5)
