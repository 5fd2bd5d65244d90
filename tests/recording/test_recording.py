"""Recordings: the simulated drive, rosbag2 round trips and foreign bags, checked against the simulator's truth."""

from __future__ import annotations

import itertools
import math
import shutil
from pathlib import Path
from typing import Any

import cv2
import numpy as np
import pytest
from numpy.typing import NDArray
from rosbags.rosbag1 import Writer as Writer1
from rosbags.rosbag2 import StoragePlugin, Writer
from rosbags.typesys import Stores, get_types_from_msg, get_typestore

from monodock.core import transforms
from monodock.core.camera import CameraModel
from monodock.core.frame import Frame
from monodock.core.robot import Mount, RobotConfig
from monodock.core.scan import LaserScan
from monodock.errors import ConfigError, InputError
from monodock.io.frames import open_frames
from monodock.recording import open_recording, pair_nearest
from monodock.sim import Nuisances, Simulator
from monodock.sim.drive import PAPER_SEGMENT_COUNTS, SEGMENTS, DriveConfig, Stop, plan_drive, segment_bounds
from monodock.sim.recording import write_recording

SEED = 21
ROS2 = get_typestore(Stores.ROS2_HUMBLE)
ROS1 = get_typestore(Stores.ROS1_NOETIC)
# rosbags' Noetic store has no tf2_msgs; a ROS 1 robot's bag carries the definition, as this one will.
ROS1.register(get_types_from_msg("geometry_msgs/TransformStamped[] transforms", "tf2_msgs/msg/TFMessage"))


def frames_of(inputs: list[Path], **options: Any) -> list[Frame]:
    """Every frame of ``open_frames(inputs, **options)``."""
    with open_frames(inputs, **options) as source:
        return list(source)


# --- the simulated world and its truth -------------------------------------------------------------


@pytest.fixture(scope="module")
def sim() -> Simulator:
    """A small, fast camera (with distortion) on a robot whose mounts are not the defaults."""
    camera = CameraModel.from_intrinsics(
        320, 240, 307.5, 306.5, 161.2, 118.5, (-0.12, 0.08, 0.0006, -0.0004, -0.02), name="small"
    )
    robot = RobotConfig(
        camera_mount=Mount(0.16, 0.02, 0.27, 0.01, 0.06, -0.03),
        laser_mount=Mount(0.12, -0.01, 0.19, 0.0, 0.0, 0.04),
        front_offset=0.33,
    )
    return Simulator(camera=camera, robot=robot, nuisances=Nuisances().updated(supersample=2), seed=3)


@pytest.fixture(scope="module")
def stops(sim: Simulator) -> list[Stop]:
    return plan_drive(sim, DriveConfig(stops=6, depth=(0.5, 1.8)), np.random.default_rng(5))


@pytest.fixture(scope="module")
def truth_images(sim: Simulator, stops: list[Stop]) -> list[NDArray[np.uint8]]:
    """Each stop's image rendered straight from the simulator with the frame's seed (SEED, index)."""
    return [sim.frame(s.pose, s.image_stamp, np.random.default_rng([SEED, s.index])).image for s in stops]


def truth_scans(sim: Simulator, stops: list[Stop]) -> list[LaserScan]:
    """Each stop's scans straight from the simulator with their seeds (SEED, index, k)."""
    return [
        sim.scan(s.pose, stamp=t, rng=np.random.default_rng([SEED, s.index, k]))
        for s in stops
        for k, t in enumerate(s.scan_stamps)
    ]


@pytest.fixture(scope="module")
def mcap_bag(tmp_path_factory: pytest.TempPathFactory, sim: Simulator, stops: list[Stop]) -> Path:
    out = tmp_path_factory.mktemp("bags") / "drive"
    write_recording(out, sim, stops, seed=SEED, progress=False)
    return out


def as_bgr(image: NDArray[np.uint8]) -> NDArray[np.uint8]:
    return np.asarray(cv2.cvtColor(image, cv2.COLOR_GRAY2BGR), dtype=np.uint8)


def assert_scans_equal(got: list[LaserScan], want: list[LaserScan]) -> None:
    assert len(got) == len(want)
    for g, w in zip(got, want, strict=True):
        assert g.stamp == pytest.approx(w.stamp, abs=1e-6)
        assert g.frame_id == w.frame_id
        assert np.isnan(w.ranges).any()
        assert np.isinf(w.ranges).any()
        np.testing.assert_array_equal(g.ranges, w.ranges)  # NaN where NaN, inf where inf
        for name in ("angle_min", "angle_max", "angle_increment", "range_min", "range_max", "scan_time"):
            assert getattr(g, name) == pytest.approx(getattr(w, name), rel=1e-6), name  # float32 in the message


def assert_mounts_equal(got: RobotConfig, want: RobotConfig) -> None:
    for name in ("camera_mount", "laser_mount"):
        g, w = getattr(got, name), getattr(want, name)
        np.testing.assert_allclose(g.matrix(), w.matrix(), atol=1e-9, err_msg=name)
        for k in ("x", "y", "z", "roll", "pitch", "yaw"):
            assert getattr(g, k) == pytest.approx(getattr(w, k), abs=1e-9), f"{name}.{k}"


# --- the drive -------------------------------------------------------------------------------------


def test_drive_stamps_follow_two_clocks_and_increase(sim: Simulator) -> None:
    config = DriveConfig(stops=40, depth=(0.6, 1.6))
    stops = plan_drive(sim, config, np.random.default_rng(0))
    assert [s.index for s in stops] == list(range(40))
    times = []
    for s in stops:
        assert 0.6 <= s.pose.x - sim.robot.camera_mount.x <= 1.6
        assert abs(s.pose.y) <= 0.4
        assert abs(math.degrees(s.pose.yaw)) <= 30
        assert 3 <= len(s.scan_stamps) <= 4  # 0.35 s of a 10 Hz LiDAR
        span = [s.image_stamp, *s.scan_stamps]
        assert max(span) - min(span) < config.dwell_s
        assert s.image_stamp not in s.scan_stamps
        times.append((min(span), max(span)))
        np.testing.assert_allclose(np.diff(s.scan_stamps), 0.1, atol=1e-6)
    for (_, end), (start, _) in itertools.pairwise(times):
        assert start - end >= config.transit_s[0]
    # Each clock keeps its phase across stops: stamps are whole periods apart.
    cam = np.array([s.image_stamp for s in stops])
    lidar = np.array([t for s in stops for t in s.scan_stamps])
    cam_phase = (cam - cam[0]) * config.camera_rate_hz
    lidar_phase = (lidar - lidar[0]) * config.lidar_rate_hz
    np.testing.assert_allclose(cam_phase, np.round(cam_phase), atol=1e-4)
    np.testing.assert_allclose(lidar_phase, np.round(lidar_phase), atol=1e-4)


def test_paper_density_follows_table_2(sim: Simulator) -> None:
    n = 2000
    stops = plan_drive(sim, DriveConfig(stops=n, density="paper"), np.random.default_rng(1))
    depth = np.array([s.pose.x - sim.robot.camera_mount.x for s in stops])
    counts = np.array(PAPER_SEGMENT_COUNTS, dtype=np.float64)
    assert counts.size == SEGMENTS
    assert counts[-1] == counts[-2]
    for lo, hi in ((1.00, 1.35), (2.25, 2.50), (0.25, 0.40)):
        k0, k1 = round((lo - 0.25) / 0.05), round((hi - 0.25) / 0.05)
        assert segment_bounds(k0)[0] == pytest.approx(lo)
        assert segment_bounds(k1 - 1)[1] == pytest.approx(hi)
        p = counts[k0:k1].sum() / counts.sum()
        got = int(np.sum((depth >= lo) & (depth < hi)))
        sigma = math.sqrt(n * p * (1 - p))
        assert abs(got - n * p) < 4 * sigma + 1, (lo, hi, got, n * p)
    near = np.sum((depth >= 1.00) & (depth < 1.35))
    far = np.sum((depth >= 2.25) & (depth < 2.50))
    assert near > 20 * far


def test_uniform_density_inside_a_partial_depth_range(sim: Simulator) -> None:
    stops = plan_drive(sim, DriveConfig(stops=600, depth=(0.52, 0.98)), np.random.default_rng(2))
    depth = np.array([s.pose.x - sim.robot.camera_mount.x for s in stops])
    assert depth.min() >= 0.52
    assert depth.max() <= 0.98
    # Partly covered segments get their share: the depths are uniform over the range, not per segment.
    hist, _ = np.histogram(depth, bins=4, range=(0.52, 0.98))
    assert np.all(np.abs(hist - 150) < 4 * math.sqrt(150 * 0.75))


@pytest.mark.parametrize(
    ("change", "field"),
    [
        ({"stops": 0}, "stops"),
        ({"camera_rate_hz": 0.0}, "camera_rate_hz"),
        ({"lidar_rate_hz": -10.0}, "lidar_rate_hz"),
        ({"dwell_s": float("nan")}, "dwell_s"),
        ({"density": "dense"}, "density"),
        ({"density": (1.0,) * 44}, "45 weights"),
        ({"density": (1.0,) * 44 + (-1.0,)}, "non-negative"),
        ({"scan_loss": 1.5}, "scan_loss"),
        ({"depth": (2.0, 1.0)}, "depth"),
    ],
)
def test_drive_config_errors_name_the_field(change: dict[str, Any], field: str) -> None:
    with pytest.raises(ConfigError, match=field):
        DriveConfig(**change)


def test_density_without_weight_in_range_is_an_error(sim: Simulator) -> None:
    weights = (0.0,) * 10 + (1.0,) * 35  # nothing below 75 cm
    with pytest.raises(ConfigError, match="zero weight"):
        plan_drive(sim, DriveConfig(stops=3, depth=(0.3, 0.6), density=weights), np.random.default_rng(0))


# --- write -> read round trips -------------------------------------------------------------------


@pytest.mark.parametrize(
    ("storage", "encoding"),
    [("mcap", "mono8"), ("sqlite3", "mono8"), ("mcap", "bgr8"), ("sqlite3", "png"), ("mcap", "png")],
)
def test_round_trip_matches_the_simulator(
    tmp_path: Path,
    sim: Simulator,
    stops: list[Stop],
    truth_images: list[NDArray[np.uint8]],
    storage: str,
    encoding: str,
) -> None:
    seen: list[int] = []
    summary = write_recording(
        tmp_path / "rec",
        sim,
        stops,
        seed=SEED,
        storage=storage,
        encoding=encoding,
        progress=False,
        on_frame=lambda i, _: seen.append(i),
    )
    assert seen == list(range(len(stops)))
    suffix = ".mcap" if storage == "mcap" else ".db3"
    assert sorted(p.name for p in summary.path.iterdir()) == ["metadata.yaml", f"rec{suffix}"]
    assert not [p for p in tmp_path.iterdir() if p.name != "rec"]  # no temporary folder left behind
    want_scans = truth_scans(sim, stops)
    assert (summary.images, summary.scans) == (len(stops), len(want_scans))
    assert summary.bytes == sum(p.stat().st_size for p in summary.path.iterdir())

    with open_recording(summary.path) as rec:
        assert rec.warnings == []
        image_type = "sensor_msgs/msg/CompressedImage" if encoding == "png" else "sensor_msgs/msg/Image"
        assert rec.topics[rec.image_topic] == (image_type, len(stops))
        assert rec.topics["/tf_static"] == ("tf2_msgs/msg/TFMessage", 1)
        frames = list(rec.images())
        assert [f.name for f in frames] == [str(i) for i in range(len(stops))]
        for f, s, want in zip(frames, stops, truth_images, strict=True):
            assert f.error == ""
            assert f.stamp == pytest.approx(s.image_stamp, abs=1e-6)  # the header stamp, not the receive time
            assert f.image is not None
            np.testing.assert_array_equal(f.image, as_bgr(want) if encoding == "bgr8" else want)
        camera = rec.camera()
        assert camera is not None
        assert (camera.size, camera.K, camera.D, camera.distortion_model) == (
            sim.camera.size,
            sim.camera.K,
            sim.camera.D,
            sim.camera.distortion_model,
        )
        base = RobotConfig(front_offset=0.5)
        robot = rec.robot(base)
        assert_mounts_equal(robot, sim.robot)
        assert robot.front_offset == 0.5  # what tf cannot tell comes from the robot given
        assert rec.has_mounts()
        assert_scans_equal(rec.scans(), want_scans)
        truth = rec.ground_truth()
        assert len(truth) == len(stops)
        for (stamp, pose), s in zip(truth, stops, strict=True):
            assert stamp == pytest.approx(s.image_stamp, abs=1e-6)
            assert (pose.x, pose.y, pose.yaw) == pytest.approx((s.pose.x, s.pose.y, s.pose.yaw), abs=1e-12)


def test_jpeg_is_close_and_parallel_rendering_matches(
    tmp_path: Path, sim: Simulator, stops: list[Stop], truth_images: list[NDArray[np.uint8]]
) -> None:
    summary = write_recording(tmp_path / "j", sim, stops[:3], seed=SEED, encoding="jpeg", jobs=2, progress=False)
    with open_recording(summary.path) as rec:
        frames = list(rec.images())
    assert len(frames) == 3
    for f, want in zip(frames, truth_images[:3], strict=True):
        assert f.image is not None
        assert f.image.shape == want.shape
        assert np.mean(np.abs(f.image.astype(float) - want)) < 3.0


def test_camera_and_scan_stamps_differ_and_pair_within_a_stop(mcap_bag: Path, stops: list[Stop]) -> None:
    with open_recording(mcap_bag) as rec:
        image_stamps = np.array([f.stamp for f in rec.images()])
        scan_stamps = np.array([s.stamp for s in rec.scans()])
    assert not set(image_stamps) & set(scan_stamps)
    pairs = pair_nearest(image_stamps, scan_stamps, tolerance_s=0.5 / DriveConfig().lidar_rate_hz + 1e-6)
    stop_of_scan = np.concatenate([[s.index] * len(s.scan_stamps) for s in stops])
    assert np.all(pairs >= 0)
    np.testing.assert_array_equal(stop_of_scan[pairs], [s.index for s in stops])


def test_lost_scans_leave_images_unpaired(sim: Simulator) -> None:
    stops = plan_drive(sim, DriveConfig(stops=60, scan_loss=0.7), np.random.default_rng(4))
    images = [s.image_stamp for s in stops]
    scans = [t for s in stops for t in s.scan_stamps]
    pairs = pair_nearest(images, scans, tolerance_s=0.05)
    assert np.sum(pairs == -1) > 5
    ok = pairs >= 0
    assert np.all(np.abs(np.asarray(scans)[pairs[ok]] - np.asarray(images)[ok]) <= 0.05)


def test_pair_nearest_known_answers() -> None:
    np.testing.assert_array_equal(pair_nearest([0.0, 1.0, 2.05, 5.0], [2.0, 0.1, 1.0, 2.1], 0.2), [1, 2, 0, -1])
    assert pair_nearest([1.0], [], 1.0).tolist() == [-1]
    assert pair_nearest([], [1.0], 1.0).tolist() == []


def test_existing_output_needs_force(tmp_path: Path, sim: Simulator, stops: list[Stop]) -> None:
    out = tmp_path / "rec"
    out.mkdir()
    (out / "keep.txt").write_text("mine")
    with pytest.raises(InputError, match="exists"):
        write_recording(out, sim, stops[:1], seed=SEED, progress=False)
    assert (out / "keep.txt").read_text() == "mine"
    write_recording(out, sim, stops[:1], seed=SEED, progress=False, force=True)
    assert (out / "metadata.yaml").is_file()
    assert not (out / "keep.txt").exists()
    with pytest.raises(ConfigError, match="storage"):
        write_recording(tmp_path / "x", sim, stops[:1], seed=SEED, storage="rosbag", progress=False)
    with pytest.raises(ConfigError, match="encoding"):
        write_recording(tmp_path / "x", sim, stops[:1], seed=SEED, encoding="rgb16", progress=False)
    assert not (tmp_path / "x").exists()


def test_stops_without_scans(tmp_path: Path, sim: Simulator) -> None:
    """A dwell shorter than a LiDAR period leaves some stops without a scan; the bag holds just what there is."""
    stops = plan_drive(sim, DriveConfig(stops=3, dwell_s=0.02), np.random.default_rng(8))
    assert any(not s.scan_stamps for s in stops)
    summary = write_recording(tmp_path / "r", sim, stops, seed=SEED, progress=False)
    with open_recording(summary.path) as rec:
        assert len(list(rec.images())) == 3
        assert [s.stamp for s in rec.scans()] == pytest.approx([t for s in stops for t in s.scan_stamps], abs=1e-6)
    assert summary.scans == sum(len(s.scan_stamps) for s in stops)


# --- bags cut short ----------------------------------------------------------------------------------


@pytest.mark.parametrize(
    ("storage", "encoding", "keep", "at_least"),
    # bgr8 images at 320x240 (230 kB) fill more than one of rosbags' 1 MB MCAP chunks: that cut lands in the
    # second chunk, and more images are read than the first chunk holds.
    [("mcap", "mono8", 0.6, 1), ("mcap", "bgr8", 0.9, 5), ("sqlite3", "mono8", 0.6, 1)],
)
def test_bag_cut_short_reads_what_is_there(
    tmp_path: Path,
    sim: Simulator,
    stops: list[Stop],
    truth_images: list[NDArray[np.uint8]],
    storage: str,
    encoding: str,
    keep: float,
    at_least: int,
) -> None:
    summary = write_recording(
        tmp_path / "rec", sim, stops, seed=SEED, storage=storage, encoding=encoding, progress=False
    )
    data = next(p for p in summary.path.iterdir() if p.suffix in (".mcap", ".db3"))
    with data.open("r+b") as fh:
        fh.truncate(int(data.stat().st_size * keep))
    with open_recording(summary.path) as rec:
        frames = list(rec.images())
        truth = rec.ground_truth()
        scans = rec.scans()
        assert rec.camera() is not None
        assert_mounts_equal(rec.robot(RobotConfig()), sim.robot)
        warnings = rec.warnings
    assert any("cut short after" in w for w in warnings), warnings
    assert at_least <= len(frames) < len(stops)
    for f, want in zip(frames, truth_images, strict=False):
        assert f.image is not None
        np.testing.assert_array_equal(f.image, as_bgr(want) if encoding == "bgr8" else want)
    assert len(frames) <= len(truth) <= len(stops)  # a stop's ground truth is written before its image
    want_scans = truth_scans(sim, stops)
    assert 0 < len(scans) < len(want_scans)
    assert_scans_equal(scans, want_scans[: len(scans)])
    # The bare storage file reads the same.
    with open_recording(data) as rec:
        assert len(list(rec.images())) == len(frames)


def test_cut_short_warning_reaches_the_frame_source(tmp_path: Path, mcap_bag: Path) -> None:
    bag = tmp_path / "cut"
    shutil.copytree(mcap_bag, bag)
    data = bag / "drive.mcap"
    data.write_bytes(data.read_bytes()[: data.stat().st_size // 2])
    said: list[str] = []
    frames = frames_of([bag], on_warning=said.append)
    assert frames
    assert len(said) == 1
    assert "cut short" in said[0]


# --- foreign bags ------------------------------------------------------------------------------------


def ros1_time(stamp: float) -> Any:
    ns = round(stamp * 1e9)
    return ROS1.types["builtin_interfaces/msg/Time"](sec=ns // 10**9, nanosec=ns % 10**9)


def ros1_header(stamp: float, frame: str) -> Any:
    return ROS1.types["std_msgs/msg/Header"](seq=0, stamp=ros1_time(stamp), frame_id=frame)


def ros1_transform(parent: str, child: str, T: NDArray[np.float64]) -> Any:
    from monodock.core.transforms import quaternion_from_matrix

    t = ROS1.types
    x, y, z, w = quaternion_from_matrix(T[:3, :3])
    return t["geometry_msgs/msg/TransformStamped"](
        header=ros1_header(1.0, parent),
        child_frame_id=child,
        transform=t["geometry_msgs/msg/Transform"](
            translation=t["geometry_msgs/msg/Vector3"](x=T[0, 3], y=T[1, 3], z=T[2, 3]),
            rotation=t["geometry_msgs/msg/Quaternion"](x=x, y=y, z=z, w=w),
        ),
    )


def write_ros1_bag(
    path: Path,
    sim: Simulator,
    stops: list[Stop],
    images: list[NDArray[np.uint8]],
    *,
    image_frame: str = "/camera_optical",
    scan_frame: str = "laser",
) -> list[LaserScan]:
    """A ROS 1 bag as a real robot records it: rgb8 with padded rows, CameraInfo K/D, a tf chain via camera_link
    (the images' and the scans' header frames as given).

    Returns the scans written, straight from the simulator.
    """
    t = ROS1.types
    scans = truth_scans(sim, stops)
    cam = sim.camera
    link_T_optical = transforms.transform(transforms.LINK_R_OPTICAL, (0.0, 0.0, 0.0))
    with Writer1(path) as w:
        tf = w.add_connection("/tf_static", "tf2_msgs/msg/TFMessage", typestore=ROS1, latching=1)
        img = w.add_connection("/usb_cam/image_raw", "sensor_msgs/msg/Image", typestore=ROS1)
        info = w.add_connection("/usb_cam/camera_info", "sensor_msgs/msg/CameraInfo", typestore=ROS1)
        scan = w.add_connection("/scan", "sensor_msgs/msg/LaserScan", typestore=ROS1)
        chain = [
            ros1_transform("base_link", "camera_link", sim.robot.base_T_camera_link()),
            ros1_transform("camera_link", "camera_optical", link_T_optical),
            ros1_transform("base_footprint", "base_link", np.eye(4)),
            ros1_transform("base_link", "laser", sim.robot.base_T_laser()),
        ]
        w.write(tf, 10**9, ROS1.serialize_ros1(t["tf2_msgs/msg/TFMessage"](transforms=chain), "tf2_msgs/msg/TFMessage"))
        for s, image in zip(stops, images, strict=True):
            rgb = np.repeat(image[:, :, None], 3, axis=2)
            rgb[:, :, 0] = 255 - image  # a red channel unlike the others: a BGR/RGB swap would show
            pad = np.zeros((cam.height, 3 * cam.width + 8), np.uint8)
            pad[:, : 3 * cam.width] = rgb.reshape(cam.height, -1)
            msg = t["sensor_msgs/msg/Image"](
                header=ros1_header(s.image_stamp, image_frame),
                height=cam.height,
                width=cam.width,
                encoding="rgb8",
                is_bigendian=0,
                step=3 * cam.width + 8,
                data=pad.ravel(),
            )
            late = round((s.image_stamp + 0.5) * 1e9)  # receive time well after the stamp
            w.write(img, late, ROS1.serialize_ros1(msg, "sensor_msgs/msg/Image"))
            ci = t["sensor_msgs/msg/CameraInfo"](
                header=ros1_header(s.image_stamp, "camera_optical"),
                height=cam.height,
                width=cam.width,
                distortion_model="plumb_bob",
                D=np.array(cam.D),
                K=np.array(cam.K),
                R=np.eye(3).ravel(),
                P=np.zeros(12),
                binning_x=0,
                binning_y=0,
                roi=t["sensor_msgs/msg/RegionOfInterest"](x_offset=0, y_offset=0, height=0, width=0, do_rectify=False),
            )
            w.write(info, late, ROS1.serialize_ros1(ci, "sensor_msgs/msg/CameraInfo"))
        for sc in scans:
            msg = t["sensor_msgs/msg/LaserScan"](
                header=ros1_header(sc.stamp, scan_frame),
                angle_min=sc.angle_min,
                angle_max=sc.angle_max,
                angle_increment=sc.angle_increment,
                time_increment=sc.time_increment,
                scan_time=sc.scan_time,
                range_min=sc.range_min,
                range_max=sc.range_max,
                ranges=sc.ranges,
                intensities=np.zeros(0, np.float32),
            )
            w.write(scan, round((sc.stamp + 0.2) * 1e9), ROS1.serialize_ros1(msg, "sensor_msgs/msg/LaserScan"))

    return scans


def test_ros1_bag_reads_the_same(
    tmp_path: Path, sim: Simulator, stops: list[Stop], truth_images: list[NDArray[np.uint8]]
) -> None:
    path = tmp_path / "robot.bag"
    cam = sim.camera
    scans = write_ros1_bag(path, sim, stops[:2], truth_images[:2])
    with open_recording(path) as rec:
        assert rec.image_topic == "/usb_cam/image_raw"
        assert rec.camera_info_topic == "/usb_cam/camera_info"
        assert rec.truth_topic is None
        assert rec.ground_truth() == []
        frames = list(rec.images())
        assert len(frames) == 2
        for f, s, image in zip(frames, stops, truth_images, strict=False):
            assert f.stamp == pytest.approx(s.image_stamp, abs=1e-6)
            assert f.image is not None
            np.testing.assert_array_equal(f.image[:, :, :2], np.repeat(image[:, :, None], 2, axis=2))
            np.testing.assert_array_equal(f.image[:, :, 2], 255 - image)
        camera = rec.camera()
        assert camera is not None
        assert (camera.K, camera.D, camera.size) == (cam.K, cam.D, cam.size)
        assert_mounts_equal(rec.robot(RobotConfig()), sim.robot)
        assert_scans_equal(rec.scans(), scans)
        assert rec.warnings == []


def test_ros1_bag_cut_short(
    tmp_path: Path, sim: Simulator, stops: list[Stop], truth_images: list[NDArray[np.uint8]]
) -> None:
    path = tmp_path / "robot.bag"
    write_ros1_bag(path, sim, stops[:3], truth_images[:3])
    path.write_bytes(path.read_bytes()[: int(path.stat().st_size * 0.6)])
    with open_recording(path) as rec:
        frames = list(rec.images())
        robot = rec.robot(RobotConfig())
        scans = rec.scans()
        warnings = rec.warnings
    assert any("cut short after" in w for w in warnings), warnings
    assert 1 <= len(frames) < 3
    # The tf came before the cut; the scans (written last) did not, so the LiDAR mount stays the one given.
    np.testing.assert_allclose(robot.camera_mount.matrix(), sim.robot.camera_mount.matrix(), atol=1e-9)
    assert scans == []
    assert robot.laser_mount == RobotConfig().laser_mount
    for f, image in zip(frames, truth_images, strict=False):
        assert f.image is not None
        np.testing.assert_array_equal(f.image[:, :, 2], 255 - image)


@pytest.mark.parametrize(
    ("image_frame", "warning"),
    [
        ("camera_link", "image frame camera_link is not an optical frame (its z is up)"),
        ("elsewhere", "/tf_static has no base_link -> elsewhere; camera mount from the robot"),
    ],
)
def test_sensor_frames_the_tf_tree_cannot_place_are_told(
    tmp_path: Path,
    sim: Simulator,
    stops: list[Stop],
    truth_images: list[NDArray[np.uint8]],
    image_frame: str,
    warning: str,
) -> None:
    """An image frame that is a body frame is taken as the camera mount as it is; one the tf tree does not reach,
    like a scan frame it does not reach, keeps the robot file's mount; each with its warning."""
    path = tmp_path / "robot.bag"
    write_ros1_bag(path, sim, stops[:1], truth_images[:1], image_frame=image_frame, scan_frame="lidar")
    with open_recording(path) as rec:
        robot = rec.robot(RobotConfig())
        warnings = rec.warnings
    lidar = "/tf_static has no base_link -> lidar; LiDAR mount from the robot"
    assert warnings == [f"{path}: {warning}", f"{path}: {lidar}"]
    if image_frame == "camera_link":
        np.testing.assert_allclose(robot.camera_mount.matrix(), sim.robot.base_T_camera_link(), atol=1e-9)
    else:
        assert robot.camera_mount == RobotConfig().camera_mount
    assert robot.laser_mount == RobotConfig().laser_mount


def write_ros2_bag(path: Path, messages: list[tuple[str, str, Any, float]], storage: str = "mcap") -> Path:
    """A rosbag2 of (topic, type, message, stamp) written with rosbags, as another tool would."""
    plugin = StoragePlugin.MCAP if storage == "mcap" else StoragePlugin.SQLITE3
    with Writer(path, version=9, storage_plugin=plugin) as w:
        conns: dict[str, Any] = {}
        for topic, msgtype, msg, stamp in messages:
            if topic not in conns:
                conns[topic] = w.add_connection(topic, msgtype, typestore=ROS2)
            w.write(conns[topic], round(stamp * 1e9), ROS2.serialize_cdr(msg, msgtype))
    return path


def ros2_header(stamp: float, frame: str = "cam") -> Any:
    ns = round(stamp * 1e9)
    t = ROS2.types
    return t["std_msgs/msg/Header"](
        stamp=t["builtin_interfaces/msg/Time"](sec=ns // 10**9, nanosec=ns % 10**9), frame_id=frame
    )


def raw_image(
    stamp: float, encoding: str, data: NDArray[np.uint8], width: int, height: int, step: int, **kw: Any
) -> Any:
    return ROS2.types["sensor_msgs/msg/Image"](
        header=ros2_header(stamp),
        height=height,
        width=width,
        encoding=encoding,
        is_bigendian=kw.get("is_bigendian", 0),
        step=step,
        data=np.ascontiguousarray(data, dtype=np.uint8).ravel(),
    )


def compressed_image(stamp: float, data: bytes, fmt: str = "mono8; png compressed mono8") -> Any:
    return ROS2.types["sensor_msgs/msg/CompressedImage"](
        header=ros2_header(stamp), format=fmt, data=np.frombuffer(data, dtype=np.uint8)
    )


def test_image_encodings_decode_to_the_same_pixels(tmp_path: Path, truth_images: list[NDArray[np.uint8]]) -> None:
    img = truth_images[0]
    h, w = img.shape
    bgr = np.stack([img, 255 - img, img // 2], axis=2)
    wide = img.astype(np.uint16) * 256 + 77  # mono16 scales down to the 8-bit image
    cases: list[tuple[str, NDArray[np.uint8], int, dict[str, Any]]] = [
        ("mono8", np.pad(img, ((0, 0), (0, 5))), w + 5, {}),
        ("bgr8", bgr, 3 * w, {}),
        ("rgb8", bgr[:, :, ::-1], 3 * w, {}),
        ("bgra8", np.dstack([bgr, np.full_like(img, 9)]), 4 * w, {}),
        ("rgba8", np.dstack([bgr[:, :, ::-1], np.full_like(img, 9)]), 4 * w, {}),
        ("mono16", wide.astype("<u2").view(np.uint8), 2 * w, {}),
        ("mono16", wide.astype(">u2").view(np.uint8), 2 * w, {"is_bigendian": 1}),
        ("yuv444", bgr, 3 * w, {}),  # not supported: this frame fails, the others carry on
    ]
    messages = [
        ("/image", "sensor_msgs/msg/Image", raw_image(10.0 + i, enc, data, w, h, step, **kw), 10.0 + i)
        for i, (enc, data, step, kw) in enumerate(cases)
    ]
    with open_recording(write_ros2_bag(tmp_path / "enc", messages)) as rec:
        frames = list(rec.images())
    assert [f.stamp for f in frames] == [10.0 + i for i in range(len(cases))]
    for f, (enc, *_) in zip(frames, cases, strict=True):
        if enc == "yuv444":
            assert f.image is None
            assert "yuv444" in f.error
            continue
        assert f.error == "", enc
        want = img if enc in ("mono8", "mono16") else bgr
        np.testing.assert_array_equal(f.image, want, err_msg=enc)


def test_undecodable_compressed_image_costs_only_its_frame(
    tmp_path: Path, truth_images: list[NDArray[np.uint8]]
) -> None:
    good = [bytes(cv2.imencode(".png", im)[1]) for im in truth_images[:2]]
    messages = [
        ("/c", "sensor_msgs/msg/CompressedImage", compressed_image(1.0, good[0]), 1.0),
        ("/c", "sensor_msgs/msg/CompressedImage", compressed_image(2.0, good[1][:200]), 2.0),  # cut PNG
        ("/c", "sensor_msgs/msg/CompressedImage", compressed_image(3.0, good[1]), 3.0),
    ]
    bag = write_ros2_bag(tmp_path / "c", messages, storage="sqlite3")
    with open_recording(bag) as rec:
        frames = list(rec.images())
    assert [f.name for f in frames] == ["0", "1", "2"]
    assert frames[1].image is None
    assert "frame 1" in frames[1].error
    assert "does not decode" in frames[1].error
    np.testing.assert_array_equal(frames[0].image, truth_images[0])
    np.testing.assert_array_equal(frames[2].image, truth_images[1])
    # Through the frame source the bad frame is an error unless skip_bad.
    with pytest.raises(InputError, match="skip-bad"):
        frames_of([bag])
    assert [f.image is None for f in frames_of([bag], skip_bad=True)] == [False, True, False]


def test_images_come_in_stamp_order(tmp_path: Path, truth_images: list[NDArray[np.uint8]]) -> None:
    h, w = truth_images[0].shape
    stamps = [3.0, 1.0, 2.0]  # received in this order, stamped otherwise
    messages = [
        ("/i", "sensor_msgs/msg/Image", raw_image(s, "mono8", truth_images[k], w, h, w), 10.0 + k)
        for k, s in enumerate(stamps)
    ]
    frames = frames_of([write_ros2_bag(tmp_path / "o", messages)])
    assert [(f.name, f.stamp) for f in frames] == [("0", 1.0), ("1", 2.0), ("2", 3.0)]
    np.testing.assert_array_equal(frames[0].image, truth_images[1])
    np.testing.assert_array_equal(frames[2].image, truth_images[0])


# --- errors ------------------------------------------------------------------------------------------


def one_line(exc: pytest.ExceptionInfo[InputError]) -> str:
    text = str(exc.value)
    assert "\n" not in text
    assert "Traceback" not in text
    return text


@pytest.fixture
def scan_only_bag(tmp_path: Path) -> Path:
    scan = ROS2.types["sensor_msgs/msg/LaserScan"](
        header=ros2_header(1.0, "laser"),
        angle_min=-1.0,
        angle_max=1.0,
        angle_increment=1.0,
        time_increment=0.0,
        scan_time=0.1,
        range_min=0.1,
        range_max=10.0,
        ranges=np.array([1.0, np.nan, np.inf], np.float32),
        intensities=np.zeros(0, np.float32),
    )
    return write_ros2_bag(tmp_path / "scans", [("/scan", "sensor_msgs/msg/LaserScan", scan, 1.0)])


def test_bag_without_images_is_refused(scan_only_bag: Path) -> None:
    with pytest.raises(InputError) as exc:
        open_recording(scan_only_bag)
    text = one_line(exc)
    assert "no sensor_msgs/Image or CompressedImage topic (topics: /scan [sensor_msgs/LaserScan])" in text
    assert "/scan" in text


def test_two_image_topics_need_a_flag(tmp_path: Path, truth_images: list[NDArray[np.uint8]]) -> None:
    h, w = truth_images[0].shape
    png = bytes(cv2.imencode(".png", truth_images[1])[1])
    bag = write_ros2_bag(
        tmp_path / "two",
        [
            ("/left/image_raw", "sensor_msgs/msg/Image", raw_image(1.0, "mono8", truth_images[0], w, h, w), 1.0),
            ("/right/image_raw/compressed", "sensor_msgs/msg/CompressedImage", compressed_image(1.0, png), 1.0),
        ],
    )
    with pytest.raises(InputError) as exc:
        open_recording(bag)
    assert "--image-topic" in one_line(exc)
    assert "/left/image_raw" in one_line(exc)
    with open_recording(bag, image_topic="/right/image_raw/compressed") as rec:
        np.testing.assert_array_equal(next(rec.images()).image, truth_images[1])
        assert rec.camera() is None
        assert rec.scans() == []
    with pytest.raises(InputError) as exc:
        open_recording(bag, image_topic="/front/image_raw")
    assert "no such topic" in one_line(exc)
    assert "/right/image_raw/compressed" in one_line(exc)


def test_named_topic_of_the_wrong_kind(mcap_bag: Path) -> None:
    wrong = "--scan-topic /camera/camera_info is sensor_msgs/CameraInfo, not sensor_msgs/LaserScan"
    with pytest.raises(InputError, match=wrong):
        open_recording(mcap_bag, scan_topic="/camera/camera_info")
    with pytest.raises(InputError, match="no such topic"):
        open_recording(mcap_bag, camera_info_topic="/camera_info")


@pytest.mark.parametrize(
    ("name", "content", "needle"),
    [
        ("notes.txt", b"hello", "not a recording"),
        ("fake.mcap", b"hello, not an mcap", "not a recording"),
        ("fake.bag", b"#ROSBAG V2.0\n" + b"\x00" * 3, "cannot read the recording"),
        ("empty.db3", b"", "not a recording"),
        ("missing.mcap", None, "recording not found"),
    ],
)
def test_not_a_recording(tmp_path: Path, name: str, content: bytes | None, needle: str) -> None:
    path = tmp_path / name
    if content is not None:
        path.write_bytes(content)
    with pytest.raises(InputError) as exc:
        open_recording(path)
    assert needle in one_line(exc)
    assert name in one_line(exc)


def test_folder_without_metadata(tmp_path: Path, mcap_bag: Path) -> None:
    empty = tmp_path / "empty"
    empty.mkdir()
    with pytest.raises(InputError, match=r"no metadata\.yaml"):
        open_recording(empty)
    # A recorder that died before writing metadata.yaml: the storage file is read directly, with a warning.
    bare = tmp_path / "bare"
    bare.mkdir()
    shutil.copy(mcap_bag / "drive.mcap", bare / "drive.mcap")
    with open_recording(bare) as rec:
        assert len(list(rec.images())) == len(rec.ground_truth()) > 0
        assert any("no metadata.yaml" in w for w in rec.warnings)


def test_wrong_suffix_is_read_by_content(tmp_path: Path, mcap_bag: Path, stops: list[Stop]) -> None:
    renamed = tmp_path / "drive.bag"
    shutil.copy(mcap_bag / "drive.mcap", renamed)
    with open_recording(renamed) as rec:
        assert [f.stamp for f in rec.images()] == pytest.approx([s.image_stamp for s in stops], abs=1e-6)


def test_the_frame_source_names_recording_frames_by_index(mcap_bag: Path, stops: list[Stop]) -> None:
    frames = frames_of([mcap_bag])
    assert [f.name for f in frames] == [str(i) for i in range(len(stops))]
    assert [f.stamp for f in frames] == pytest.approx([s.image_stamp for s in stops], abs=1e-6)
    assert [f.name for f in frames_of([mcap_bag / "drive.mcap"])] == [f.name for f in frames]
