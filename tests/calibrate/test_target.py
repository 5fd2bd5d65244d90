"""Camera-LiDAR extrinsics from simulated views of the diamond target: the full 6-DoF mount, bad input."""

from __future__ import annotations

import dataclasses
import math

import numpy as np
import pytest

from monodock.calibrate.extrinsics import extrinsics_from_target_views
from monodock.calibrate.target import DiamondTarget, TargetView
from monodock.core.robot import Mount, RobotConfig
from monodock.errors import InputError
from monodock.sim import Nuisances, Simulator
from monodock.sim.target import render_target_views

TRUE_LASER = Mount(0.12, -0.03, 0.19, 0.0, math.radians(1.0), math.radians(2.0))
PRIOR_LASER = Mount(0.15, 0.0, 0.21, 0.0, 0.0, math.radians(-1.0))


def _sim() -> Simulator:
    robot = dataclasses.replace(RobotConfig.default(), laser_mount=TRUE_LASER)
    return Simulator(robot=robot, nuisances=Nuisances().updated(supersample=2), seed=3)


def test_target_views_recover_the_full_mount() -> None:
    """28 views of the diamond: all six mount fields from a prior 3 cm / 3 deg off to within 1 cm / 0.5 deg."""
    sim = _sim()
    views = render_target_views(sim, DiamondTarget(), 28, seed=7)
    result = extrinsics_from_target_views(views, sim.camera, sim.robot.base_T_optical(), PRIOR_LASER)
    m = result.laser_mount
    assert result.method == "target pairs (SolvePnP)"
    assert result.count >= 20
    # The bar: translation within 1 cm, rotation within 0.5 deg, z and pitch included.
    assert abs(m.x - TRUE_LASER.x) < 0.01
    assert abs(m.y - TRUE_LASER.y) < 0.01
    assert abs(m.z - TRUE_LASER.z) < 0.01
    for k in ("roll", "pitch", "yaw"):
        assert abs(math.degrees(getattr(m, k) - getattr(TRUE_LASER, k))) < 0.5


def test_views_without_the_target_give_one_line_error() -> None:
    """Views where the camera never sees the board: InputError naming the count."""
    sim = _sim()
    views = render_target_views(sim, DiamondTarget(), 3, seed=1)
    blank = [TargetView(np.zeros_like(v.image), v.scan) for v in views] * 3
    with pytest.raises(InputError, match="board not found") as exc:
        extrinsics_from_target_views(blank, sim.camera, sim.robot.base_T_optical(), PRIOR_LASER)
    assert "\n" not in str(exc.value)


def test_cli_target_views_writes_the_mount(tmp_path: pytest.TempPathFactory) -> None:
    """``monodock calibrate extrinsics --target-views``: the views as a folder, the mount written as YAML."""
    import yaml

    from monodock.calibrate.target import write_target_views
    from monodock.cli.main import main

    sim = _sim()
    write_target_views(tmp_path / "views", render_target_views(sim, DiamondTarget(), 24, seed=9))
    sim.camera.save(tmp_path / "camera.yaml")
    dataclasses.replace(sim.robot, laser_mount=PRIOR_LASER).save(tmp_path / "prior.yaml")
    out = tmp_path / "laser.yaml"
    argv = [
        "calibrate",
        "extrinsics",
        "--target-views",
        str(tmp_path / "views"),
        "--camera",
        str(tmp_path / "camera.yaml"),
    ]
    assert main([*argv, "--robot", str(tmp_path / "prior.yaml"), "--out", str(out)]) == 0
    got = yaml.safe_load(out.read_text())["laser_mount"]
    assert abs(got["x"] - TRUE_LASER.x) < 0.01
    assert abs(got["z"] - TRUE_LASER.z) < 0.01
    assert abs(math.degrees(got["pitch"] - TRUE_LASER.pitch)) < 0.5


def test_cli_target_recording(tmp_path: pytest.TempPathFactory) -> None:
    """The target seen edge-on in a rosbag2 recording (images, CameraInfo and scans on their own stamps): the
    command pairs them by stamp, takes the camera from CameraInfo, and writes the six-field mount."""
    import yaml
    from rosbags.rosbag2 import StoragePlugin, Writer

    from monodock.cli.main import main
    from monodock.recording import CAMERA_INFO_TOPIC, IMAGE_TOPIC, SCAN_TOPIC
    from monodock.recording.messages import camera_info_msg, encode_image, humble_typestore, scan_msg

    sim = _sim()
    views = render_target_views(sim, DiamondTarget(), 24, seed=9)
    ts = humble_typestore()
    bag = tmp_path / "target_bag"
    with Writer(bag, version=8, storage_plugin=StoragePlugin.MCAP) as w:
        img_c = w.add_connection(IMAGE_TOPIC, "sensor_msgs/msg/Image", typestore=ts)
        info_c = w.add_connection(CAMERA_INFO_TOPIC, "sensor_msgs/msg/CameraInfo", typestore=ts)
        scan_c = w.add_connection(SCAN_TOPIC, "sensor_msgs/msg/LaserScan", typestore=ts)
        for k, v in enumerate(views):
            t = 100.0 + 2.0 * k
            msgtype, img = encode_image(v.image, "mono8", t, "camera_optical_frame")
            w.write(img_c, int(t * 1e9), ts.serialize_cdr(img, msgtype))
            info = camera_info_msg(sim.camera, t, "camera_optical_frame")
            w.write(info_c, int(t * 1e9), ts.serialize_cdr(info, "sensor_msgs/msg/CameraInfo"))
            ts_scan = t + 0.03  # the LiDAR's own clock
            scan = scan_msg(dataclasses.replace(v.scan, stamp=ts_scan))
            w.write(scan_c, int(ts_scan * 1e9), ts.serialize_cdr(scan, "sensor_msgs/msg/LaserScan"))
    dataclasses.replace(sim.robot, laser_mount=PRIOR_LASER).save(tmp_path / "prior.yaml")
    out = tmp_path / "laser.yaml"
    argv = ["calibrate", "extrinsics", "--target-views", str(bag), "--robot", str(tmp_path / "prior.yaml")]
    assert main([*argv, "--out", str(out), "--overlay", str(tmp_path / "overlay.png")]) == 0
    assert (tmp_path / "overlay.png").read_bytes()[:8] == b"\x89PNG\r\n\x1a\n"
    got = yaml.safe_load(out.read_text())["laser_mount"]
    assert abs(got["y"] - TRUE_LASER.y) < 0.01
    assert abs(got["z"] - TRUE_LASER.z) < 0.01
    assert abs(math.degrees(got["yaw"] - TRUE_LASER.yaw)) < 0.5


@pytest.mark.parametrize(
    ("text", "said"),
    [
        (
            "dictionary: getPredefinedDictionary\n",
            "dictionary: unknown ArUco dictionary 'getPredefinedDictionary' (e.g. DICT_4X4_50)",
        ),
        (
            "markers: [{id: 20, s: 0.13, t: 0.13}, {id: 20, s: 0.37, t: 0.13}]\n",
            "markers: marker ids must be distinct, got 20 more than once",
        ),
    ],
)
def test_a_target_file_with_a_bad_dictionary_or_a_repeated_id_is_one_line(
    tmp_path: pytest.TempPathFactory, text: str, said: str
) -> None:
    """Not a traceback from OpenCV, and not a second marker silently found at the first one's corners."""
    path = tmp_path / "target.yaml"  # type: ignore[operator]
    path.write_text(text)
    with pytest.raises(InputError) as caught:
        DiamondTarget.load(path)
    assert str(caught.value) == f"{path}: {said}"
