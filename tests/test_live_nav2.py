"""Live estimation (monodock run) and the Nav2 bag, against the simulator's truth; monodock without rclpy."""

from __future__ import annotations

import argparse
import csv
import io
import json
import math
import subprocess
import sys
from pathlib import Path
from typing import Any

import cv2
import numpy as np
import pytest

from monodock.errors import InputError
from monodock.estimate import Estimator
from monodock.live import LIVE_COLUMNS, FrameSource, add_parser, open_source, run_live
from monodock.nav2 import DOCK_POSE_TOPIC, read_pose_bag, write_pose_bag
from monodock.pose import DockPose, wrap_angle
from monodock.sim import Nuisances, PoseDistribution, Simulator

FRAMES = 30
BLACK = 12  # the frame that is all black: no markers


@pytest.fixture(scope="module")
def drive(tmp_path_factory: pytest.TempPathFactory) -> tuple[Simulator, list[DockPose], Path, Path]:
    """A 10 fps MJPG video of simulated frames with one black frame, the poses, and the calibration folder."""
    folder = tmp_path_factory.mktemp("drive")
    sim = Simulator(nuisances=Nuisances(supersample=4), seed=5)  # 4x4 edge samples: fast enough for a test
    poses = [sim.sample_pose(PoseDistribution(depth=(0.4, 1.2))) for _ in range(FRAMES)]
    video = folder / "drive.avi"
    writer = cv2.VideoWriter(str(video), cv2.VideoWriter_fourcc(*"MJPG"), 10.0, sim.camera.size)
    assert writer.isOpened()
    rng = np.random.default_rng(0)
    for i, pose in enumerate(poses):
        image = sim.frame(pose, 0.1 * i, rng).image
        if i == BLACK:
            image = np.zeros_like(image)
        writer.write(cv2.cvtColor(image, cv2.COLOR_GRAY2BGR))
    writer.release()
    sim.camera.save(folder / "camera.yaml")
    sim.layout.save(folder / "layout.yaml")
    sim.robot.save(folder / "robot.yaml")
    return sim, poses, video, folder


def calibration(folder: Path) -> list[str]:
    """The CLI options of the saved calibration files."""
    return [f"--{k}={folder / f'{k}.yaml'}" for k in ("camera", "layout", "robot")]


def run_cli(argv: list[str]) -> int:
    """`monodock run` through a parser of its own (cli.py wires add_parser the same way)."""
    parser = argparse.ArgumentParser(prog="monodock")
    add_parser(parser.add_subparsers(dest="command", required=True))
    args = parser.parse_args(argv)
    return int(args.func(args))


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
    with open_source(str(video)) as source:
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


def test_write_pose_bag_from_est_csv_rows(tmp_path: Path) -> None:
    """EST.csv rows as csv.DictReader gives them: only the valid ones with a stamp are published."""
    rows = [
        {"stamp": "1.5", "valid": "true", "x_m": "0.8", "y_m": "-0.1", "yaw_deg": "10"},
        {"stamp": "1.6", "valid": "false", "x_m": "", "y_m": "", "yaw_deg": ""},
        {"stamp": "", "valid": "true", "x_m": "0.7", "y_m": "0.0", "yaw_deg": "0"},
    ]
    assert write_pose_bag(tmp_path / "b", rows) == 1
    (msg,) = read_pose_bag(tmp_path / "b")
    assert msg.stamp == pytest.approx(1.5)
    assert msg.pose.x == pytest.approx(0.8)
    assert msg.pose.yaw_deg == pytest.approx(10.0)
    with pytest.raises(InputError, match="exists"):
        write_pose_bag(tmp_path / "b", rows)


@pytest.mark.parametrize("content", ["not a video at all", ""])
def test_a_video_that_cannot_be_opened(tmp_path: Path, content: str) -> None:
    """A broken video, a missing file and an absent camera: one line naming them."""
    video = tmp_path / "broken.mp4"
    video.write_text(content)
    for spec, name in ((str(video), "broken.mp4"), (str(tmp_path / "gone.avi"), "gone.avi"), ("7", "camera 7")):
        with pytest.raises(InputError) as info, open_source(spec) as source:
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
    source = FrameSource("camera 0", "camera", capture=FakeCamera(3), stall_timeout_s=0.1)
    stats = run_live(source, est, "board", sink=None, on_message=said.append)
    assert (stats.frames, stats.valid) == (3, 0)
    assert said == [stats.stop_reason]
    assert "camera 0: no frame for" in said[0]
    assert "stopping after 3 frames" in said[0]
    with pytest.raises(InputError, match="nothing received"):
        run_live(FrameSource("camera 0", "camera", capture=FakeCamera(0), stall_timeout_s=0.1), est, "board", sink=None)


def test_no_monodock_module_needs_rclpy() -> None:
    """Every module but the two ROS 2 ones imports with rclpy blocked; those then name rclpy."""
    script = """
import importlib, pkgutil, sys
sys.modules["rclpy"] = None  # any import of rclpy now fails
import monodock
ros = ("monodock.ros_node", "monodock.dock.ros2")
names = [m.name for m in pkgutil.walk_packages(monodock.__path__, "monodock.") if m.name not in ros]
for name in names:
    importlib.import_module(name)
assert "monodock.live" in names and "monodock.nav2" in names and "monodock.dock.controller" in names
for name in ros:
    try:
        importlib.import_module(name)
    except ImportError as exc:
        print(name, exc)
    else:
        raise SystemExit(name + " imported without rclpy")
"""
    done = subprocess.run([sys.executable, "-c", script], capture_output=True, text=True, timeout=120, check=False)
    assert done.returncode == 0, done.stderr
    lines = done.stdout.splitlines()[-2:]
    assert [line.split()[0] for line in lines] == ["monodock.ros_node", "monodock.dock.ros2"]
    assert all("rclpy" in line for line in lines)


def test_ros_node_without_rclpy_says_so() -> None:
    """Importing the ROS node without rclpy is a clear ImportError naming rclpy."""
    try:
        import rclpy  # noqa: F401
    except ImportError:
        with pytest.raises(ImportError, match="rclpy") as info:
            import monodock.ros_node  # noqa: F401
        assert info.value.name == "rclpy"
        return
    pytest.skip("rclpy is installed; the node itself is exercised in a ROS 2 workspace")
