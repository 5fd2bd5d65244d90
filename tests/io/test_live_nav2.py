"""Live estimation (monodock run) and the Nav2 bag, against the simulator's truth; monodock without rclpy."""

from __future__ import annotations

import csv
import dataclasses
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

from monodock.cli.main import parser
from monodock.core.pose import DockPose, wrap_angle
from monodock.errors import InputError
from monodock.estimation.estimator import Estimator
from monodock.estimation.pnp import PoseEstimate, estimate_board
from monodock.io.frames import FrameSource, open_frames
from monodock.io.live import run_live
from monodock.io.nav2 import (
    DOCK_POSE_COVARIANCE_TOPIC,
    DOCK_POSE_TOPIC,
    POSE_WITH_COVARIANCE_STAMPED,
    PoseStampedBagWriter,
    planar_covariance,
    pose_covariance_6x6,
    read_pose_bag,
    write_pose_bag,
)
from monodock.io.rows import COVARIANCE_COLUMNS, LIVE_COLUMNS
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
    """``monodock ARGV`` through the real parser, with its errors raised (not printed)."""
    args = parser().parse_args(argv)
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


def test_no_monodock_module_needs_rclpy() -> None:
    """Every module but the ROS 2 ones (the two nodes and their command lines) imports with rclpy blocked; those
    then name rclpy."""
    script = """
import importlib, pkgutil, sys
sys.modules["rclpy"] = None  # any import of rclpy now fails
import monodock
ros = ("monodock.cli.ros_nodes", "monodock.ros.detector", "monodock.ros.dock_node")
names = [m.name for m in pkgutil.walk_packages(monodock.__path__, "monodock.") if m.name not in ros]
for name in names:
    importlib.import_module(name)
assert "monodock.io.live" in names and "monodock.io.nav2" in names and "monodock.dock.controller" in names
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
    lines = done.stdout.splitlines()[-3:]
    assert [line.split()[0] for line in lines] == [
        "monodock.cli.ros_nodes",
        "monodock.ros.detector",
        "monodock.ros.dock_node",
    ]
    assert all("rclpy" in line for line in lines)


def test_ros_node_without_rclpy_says_so() -> None:
    """Importing the ROS node without rclpy is a clear ImportError naming rclpy."""
    try:
        import rclpy  # noqa: F401
    except ImportError:
        with pytest.raises(ImportError, match="rclpy") as info:
            import monodock.ros.detector  # noqa: F401
        assert info.value.name == "rclpy"
        return
    pytest.skip("rclpy is installed; the node itself is exercised in a ROS 2 workspace")


# --- the covariance beside the pose -------------------------------------------------------------------------


def _cov_cells(cov: np.ndarray) -> dict[str, str]:
    """EST.csv covariance cells of a 3x3 (x, y, yaw) covariance, as estimates_csv formats them."""
    cells = ((0, 0), (0, 1), (0, 2), (1, 1), (1, 2), (2, 2))
    return {k: format(float(cov[i, j]), ".6g") for k, (i, j) in zip(COVARIANCE_COLUMNS, cells, strict=True)}


@pytest.mark.parametrize("storage", ["mcap", "sqlite3"])
def test_pose_bag_carries_the_covariance_on_a_second_topic(tmp_path: Path, storage: str) -> None:
    """Rows with covariance cells: PoseStamped for every valid row, PoseWithCovarianceStamped for those with a
    covariance, on detected_dock_pose_with_covariance; the (x, y, yaw) block round-trips into rows and columns
    (0, 1, 5) of the 6x6, the rest zero."""
    cov = np.array([[4e-6, 1e-7, -2e-6], [1e-7, 1e-6, 3e-7], [-2e-6, 3e-7, 9e-5]])
    empty = dict.fromkeys(COVARIANCE_COLUMNS, "")
    rows = [
        {
            "frame": "0",
            "stamp": "1.5",
            "valid": "true",
            "x_m": "0.8",
            "y_m": "-0.1",
            "yaw_deg": "10",
            **_cov_cells(cov),
        },
        {"frame": "1", "stamp": "1.6", "valid": "true", "x_m": "0.7", "y_m": "0.0", "yaw_deg": "0", **empty},
        {"frame": "2", "stamp": "1.7", "valid": "false", "x_m": "", "y_m": "", "yaw_deg": "", **empty},
        {
            "frame": "3",
            "stamp": "1.8",
            "valid": "true",
            "x_m": "0.6",
            "y_m": "0.05",
            "yaw_deg": "-5",
            **_cov_cells(2 * cov),
        },
    ]
    bag = tmp_path / "b"
    assert write_pose_bag(bag, rows, storage=storage) == 3
    plain = read_pose_bag(bag)
    assert [p.stamp for p in plain] == pytest.approx([1.5, 1.6, 1.8])
    assert all(p.covariance is None and p.pose_covariance is None for p in plain)
    with_cov = read_pose_bag(bag, DOCK_POSE_COVARIANCE_TOPIC)
    assert [p.msgtype for p in with_cov] == [POSE_WITH_COVARIANCE_STAMPED] * 2
    assert [p.topic for p in with_cov] == [DOCK_POSE_COVARIANCE_TOPIC] * 2
    for msg, twin, c in zip(with_cov, (plain[0], plain[2]), (cov, 2 * cov), strict=True):
        assert (msg.stamp, msg.frame_id, msg.position, msg.orientation) == (
            twin.stamp,
            twin.frame_id,
            twin.position,
            twin.orientation,
        )
        assert msg.covariance is not None
        full = np.array(msg.covariance).reshape(6, 6)
        np.testing.assert_allclose(full[np.ix_((0, 1, 5), (0, 1, 5))], c, rtol=1e-5)
        full[np.ix_((0, 1, 5), (0, 1, 5))] = 0.0
        assert not full.any()  # z, roll and pitch: fixed by the floor, zero
        np.testing.assert_allclose(msg.pose_covariance, c, rtol=1e-5)


def test_covariance_cells_that_are_not_a_covariance_are_refused(tmp_path: Path) -> None:
    row = {"frame": "7", "stamp": "1.0", "valid": "true", "x_m": "0.8", "y_m": "0", "yaw_deg": "0"}
    bad = _cov_cells(np.diag([1e-4, -1e-4, 1e-4]))
    with pytest.raises(InputError, match=r"frame 7.*positive semi-definite"):
        write_pose_bag(tmp_path / "b", [{**row, **bad}])
    half = {**_cov_cells(np.eye(3) * 1e-4), "cov_yy": ""}
    with pytest.raises(InputError, match=r"frame 7.*not all numbers"):
        write_pose_bag(tmp_path / "c", [{**row, **half}])


def test_a_bag_without_covariances_has_no_covariance_topic(tmp_path: Path) -> None:
    """Methods without a covariance (board here): the second topic is not created."""
    rows = [{"stamp": "1.5", "valid": "true", "x_m": "0.8", "y_m": "-0.1", "yaw_deg": "10"}]
    assert write_pose_bag(tmp_path / "b", rows) == 1
    with pytest.raises(InputError, match="no topic"):
        read_pose_bag(tmp_path / "b", DOCK_POSE_COVARIANCE_TOPIC)


def test_pose_covariance_6x6_layout() -> None:
    cov = np.arange(9, dtype=float).reshape(3, 3)
    cov = cov + cov.T
    full = pose_covariance_6x6(cov)
    assert len(full) == 36
    assert (full[0], full[1], full[5]) == (cov[0, 0], cov[0, 1], cov[0, 2])
    assert (full[6 * 5 + 5], full[6 * 5 + 1]) == (cov[2, 2], cov[2, 1])
    np.testing.assert_array_equal(planar_covariance(full), cov)
    with pytest.raises(ValueError, match="3x3"):
        pose_covariance_6x6(np.eye(2))


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

    est = Estimator(sim.camera, sim.layout, sim.robot, ("fused",), extra={"fused": board_with_covariance})
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


def test_ros_node_publishes_the_covariance_beside_the_pose(
    drive: tuple[Simulator, list[DockPose], Path, Path], monkeypatch: pytest.MonkeyPatch
) -> None:
    """The live node, against stand-ins for rclpy and the message packages (ROS 2 is not installed here): an
    image in, a PoseStamped out matching the truth and, with a covariance, a PoseWithCovarianceStamped of the
    same pose with the 6x6 layout of monodock.io.nav2; without one, the pose alone."""
    import array
    import importlib
    import sys
    import types

    sim, poses, _, folder = drive

    class Msg(types.SimpleNamespace):
        def __init__(self, **kw: object) -> None:
            super().__init__(**kw)

    class Stamped(Msg):
        def __init__(self, **kw: object) -> None:
            super().__init__(header=Msg(stamp=None, frame_id=""), **kw)

    published: dict[str, list[Any]] = {}
    callbacks: dict[str, Any] = {}

    class Node:
        def __init__(self, _name: str) -> None:
            pass

        def create_publisher(self, _type: object, topic: str, _depth: int) -> object:
            return Msg(publish=published.setdefault(topic, []).append)

        def create_subscription(self, _type: object, topic: str, callback: object, _depth: int) -> None:
            callbacks[topic] = callback

        def get_logger(self) -> object:
            return Msg(warning=pytest.fail, info=lambda _text: None)

    def module(name: str, **attrs: object) -> None:
        mod = types.ModuleType(name)
        mod.__dict__.update(attrs)
        monkeypatch.setitem(sys.modules, name, mod)

    module("rclpy")
    module("rclpy.node", Node=Node)
    module(
        "geometry_msgs.msg",
        Point=Msg,
        Pose=Msg,
        Quaternion=Msg,
        PoseStamped=Stamped,
        PoseWithCovariance=Msg,
        PoseWithCovarianceStamped=Stamped,
    )
    module("sensor_msgs.msg", CameraInfo=object, CompressedImage=object, Image=object)
    monkeypatch.delitem(sys.modules, "monodock.ros.detector", raising=False)
    ros_node = importlib.import_module("monodock.ros.detector")
    monkeypatch.delitem(sys.modules, "monodock.ros.detector")  # forgotten afterwards: it was built on stand-ins
    options = ros_node.DetectorOptions(
        layout=str(folder / "layout.yaml"), robot=str(folder / "robot.yaml"), image_topic="/cam"
    )
    node = ros_node.DockPoseNode(options)
    cov = np.array([[2e-6, 1e-7, 0.0], [1e-7, 1e-6, -2e-7], [0.0, -2e-7, 3e-5]])
    attach = [True]

    def board_with_covariance(det: Any) -> PoseEstimate:
        e = estimate_board(det, sim.camera, sim.layout, sim.robot)
        return dataclasses.replace(e, method="fused", covariance=cov if attach[0] else None)

    node.estimator = Estimator(sim.camera, sim.layout, sim.robot, ("fused",), extra={"fused": board_with_covariance})
    node.method = "fused"
    image = sim.frame(poses[0], 0.0, np.random.default_rng(1)).image
    h, w = image.shape
    header = Msg(stamp=Msg(sec=3, nanosec=250_000_000), frame_id="camera")
    raw = Msg(header=header, height=h, width=w, encoding="mono8", is_bigendian=0, step=w)
    raw.data = array.array("B", image.tobytes())
    callbacks["/cam"](raw)
    attach[0] = False
    callbacks["/cam"](raw)
    plain, with_cov = published["detected_dock_pose"], published["detected_dock_pose_with_covariance"]
    assert (len(plain), len(with_cov)) == (2, 1)
    out, both = plain[0], with_cov[0]
    assert out.header.stamp is header.stamp
    assert both.header.stamp is header.stamp
    assert out.header.frame_id == both.header.frame_id == "base_link"
    assert both.pose.pose is out.pose
    assert abs(out.pose.position.x - poses[0].x) < 0.01
    assert abs(out.pose.position.y - poses[0].y) < 0.01
    assert abs(2 * math.atan2(out.pose.orientation.z, out.pose.orientation.w) - poses[0].yaw) < math.radians(1.0)
    np.testing.assert_allclose(planar_covariance(both.pose.covariance), cov)
    assert sum(abs(v) for v in both.pose.covariance) == pytest.approx(float(np.abs(cov).sum()))
