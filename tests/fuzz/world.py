"""The valid inputs the fuzz suite starts from, built once into one folder in a few seconds.

Every hostile input of ``tests/fuzz`` is one of these with something changed: the built-in camera, layout, robot
and docking config as files (ROS camera_info YAML and OpenCV FileStorage YAML/XML for the camera), one simulated
image of the charger at a known pose (PNG and JPEG), a small rosbag2 recording of it (camera_info, images, scans,
/tf_static), the dataset ``monodock label`` makes of that recording, and a small model bundle of this monodock's
feature schema (trained on synthetic rows in a second, sealed as ``learning.export`` seals it).
"""

from __future__ import annotations

import math
import shutil
from collections.abc import Callable, Sequence
from pathlib import Path
from typing import Any

import cv2
import numpy as np
import yaml

from monodock.core.camera import CameraModel
from monodock.core.layout import DockLayout
from monodock.core.pose import DockPose
from monodock.core.robot import RobotConfig
from monodock.core.settings import to_mapping
from monodock.dock.config import DockingConfig, save_docking_config
from monodock.recording import messages as m
from monodock.recording.write import (
    CAMERA_FRAME,
    CAMERA_INFO_TOPIC,
    IMAGE_TOPIC,
    LATCHED,
    SCAN_TOPIC,
    SENSOR,
    TF_STATIC_TOPIC,
    BagWriter,
)
from monodock.sim import Nuisances, Simulator

__all__ = ["TRUTH", "TRUTH_DEPTH_M", "World", "build_world", "opencv_camera_text", "write_recording"]

# The example: the dock 1.85 m in front of the camera (DockPose x adds the camera mount's 0.17 m).
TRUTH_DEPTH_M = 1.85
TRUTH = DockPose(TRUTH_DEPTH_M + RobotConfig.default().camera_mount.x, 0.05, math.radians(4.0))
# A valid estimate of the clean image must be this close to the truth (board PnP at 1.85 m: a few cm).
TRUTH_TOLERANCE_M = 0.15
TRUTH_TOLERANCE_DEG = 5.0


class World:
    """Paths of the valid inputs (see the module docstring) and the pixels and bytes they hold.

    A plain class, not a dataclass, so that Hypothesis prints a failing example's world as one short line.
    """

    def __init__(self, **fields: Any) -> None:
        for name in self.__annotations__:
            setattr(self, name, fields[name])

    root: Path
    camera: Path
    camera_cv_yaml: Path
    camera_cv_xml: Path
    layout: Path
    robot: Path
    docking: Path
    image: Path
    image_jpg: Path
    recording: Path
    dataset: Path
    bundle: Path
    pixels: np.ndarray
    png: bytes
    jpg: bytes

    def __repr__(self) -> str:
        return f"World({self.root})"

    def calibration(
        self, camera: Path | None = None, layout: Path | None = None, robot: Path | None = None
    ) -> list[str]:
        """``--camera --layout --robot`` of the valid files, some swapped."""
        return [
            "--camera",
            str(camera or self.camera),
            "--layout",
            str(layout or self.layout),
            "--robot",
            str(robot or self.robot),
        ]


def opencv_camera_text(fmt: str = "yaml", **values: str) -> str:
    """The default camera as an OpenCV FileStorage file (``fmt`` "yaml" or "xml"), any value replaced by a token.

    Keys: width, height, fx, fy, cx, cy, k1, k2, p1, p2, k3 (tokens are written verbatim, e.g. ".nan", "1e308").
    """
    cam = CameraModel.default()
    v = {
        "width": str(cam.width),
        "height": str(cam.height),
        "fx": repr(cam.fx),
        "fy": repr(cam.fy),
        "cx": repr(cam.cx),
        "cy": repr(cam.cy),
        **{k: repr(d) for k, d in zip(("k1", "k2", "p1", "p2", "k3"), cam.D, strict=True)},
    }
    v.update(values)
    K = [v["fx"], "0.", v["cx"], "0.", v["fy"], v["cy"], "0.", "0.", "1."]
    D = [v["k1"], v["k2"], v["p1"], v["p2"], v["k3"]]
    if fmt == "xml":
        return (
            '<?xml version="1.0"?>\n<opencv_storage>\n'
            f"<image_width>{v['width']}</image_width>\n<image_height>{v['height']}</image_height>\n"
            '<camera_matrix type_id="opencv-matrix">\n  <rows>3</rows>\n  <cols>3</cols>\n  <dt>d</dt>\n'
            f"  <data>{' '.join(K)}</data></camera_matrix>\n"
            '<distortion_coefficients type_id="opencv-matrix">\n  <rows>1</rows>\n  <cols>5</cols>\n  <dt>d</dt>\n'
            f"  <data>{' '.join(D)}</data></distortion_coefficients>\n</opencv_storage>\n"
        )
    return (
        "%YAML:1.0\n---\n"
        f"image_width: {v['width']}\nimage_height: {v['height']}\n"
        f"camera_matrix: !!opencv-matrix\n   rows: 3\n   cols: 3\n   dt: d\n   data: [ {', '.join(K)} ]\n"
        "distortion_coefficients: !!opencv-matrix\n   rows: 1\n   cols: 5\n   dt: d\n"
        f"   data: [ {', '.join(D)} ]\n"
    )


def _camera_info(
    camera: CameraModel, stamp: float, overrides: dict[str, Any] | None
) -> Any:  # a sensor_msgs/CameraInfo
    msg = m.camera_info_msg(camera, stamp, CAMERA_FRAME)
    for key, value in (overrides or {}).items():
        setattr(msg, key, value)
    return msg


def write_recording(
    path: Path,
    sim: Simulator,
    frames: Sequence[tuple[float, np.ndarray, Any]],
    *,
    info: dict[str, Any] | None = None,
    encoding: str = "mono8",
    image_msg: Callable[[float, np.ndarray], tuple[str, Any]] | None = None,
    storage: str = "mcap",
) -> Path:
    """A rosbag2 of ``frames`` (stamp, image, scan) with camera_info (fields of ``info`` overridden) and /tf_static.

    ``image_msg(stamp, image)`` may build each image message itself (a bad encoding, a wrong size); the default is
    monodock's own ``encode_image`` with ``encoding``.
    """
    make = image_msg or (lambda t, img: m.encode_image(img, encoding, t, CAMERA_FRAME))
    msgtype = make(0.0, frames[0][1])[0]
    with BagWriter(path, storage=storage, force=True) as bag:
        tf = bag.connect(TF_STATIC_TOPIC, m.TF_MESSAGE, LATCHED)
        img = bag.connect(IMAGE_TOPIC, msgtype, SENSOR)
        cinfo = bag.connect(CAMERA_INFO_TOPIC, m.CAMERA_INFO, SENSOR)
        scan = bag.connect(SCAN_TOPIC, m.LASER_SCAN, SENSOR)
        bag.write(tf, m.tf_static_msg(sim.robot, frames[0][0], camera_frame=CAMERA_FRAME), frames[0][0])
        for t, image, s in frames:
            bag.write(scan, m.scan_msg(s), t + 0.001)
            bag.write(img, make(t, image)[1], t + 0.03)
            bag.write(cinfo, _camera_info(sim.camera, t, info), t + 0.03)
    return path


def _train_bundle(out: Path) -> Path:
    """A bundle of this monodock's feature schema for marker 2 alone: linear models on synthetic rows (~1 s)."""
    from monodock.learning.export import save_bundle
    from monodock.learning.tasks import TrainConfig, TrainingSet
    from monodock.learning.train import train
    from monodock.perception.features import MODEL_FEATURE_SCHEMA, model_feature_names

    rng = np.random.default_rng(0)
    names = model_feature_names("m2")
    n = 240
    depth = rng.uniform(0.25, 2.5, n)
    X = rng.normal(size=(n, len(names)))
    X[:, 0] = 60.0 / depth
    data = TrainingSet("m2", tuple(names), X, depth, rng.uniform(-30.0, 30.0, n), depth)
    result = train([data], TrainConfig(trials=1, jobs=1, seed=0, models=("linear",)), progress=False)
    metadata = {
        "feature_schema": MODEL_FEATURE_SCHEMA,
        "camera": CameraModel.default().to_ros_dict(),
        "layout": to_mapping(DockLayout.default()),
        "robot": to_mapping(RobotConfig.default()),
    }
    return save_bundle(out, result, metadata=metadata)


def build_world(root: Path) -> World:
    """Write every valid input into ``root`` (which must not hold them yet)."""
    from monodock.learning.dataset import label_recording, write_dataset

    root.mkdir(parents=True, exist_ok=True)
    camera, layout, robot = CameraModel.default(), DockLayout.default(), RobotConfig.default()
    camera.save(root / "camera.yaml")
    (root / "camera_cv.yaml").write_text(opencv_camera_text("yaml"))
    (root / "camera_cv.xml").write_text(opencv_camera_text("xml"))
    layout.save(root / "layout.yaml")
    robot.save(root / "robot.yaml")
    save_docking_config(DockingConfig(), root / "docking.yaml")

    sim = Simulator(nuisances=Nuisances.clean().updated(supersample=2), seed=0)
    rng = np.random.default_rng(0)
    near = DockPose(0.45 + robot.camera_mount.x, 0.0, 0.0)
    shots = [sim.frame(pose, 10.0 + k, rng) for k, pose in enumerate((TRUTH, near, TRUTH))]
    pixels = shots[0].image
    png = bytes(cv2.imencode(".png", pixels)[1])
    jpg = bytes(cv2.imencode(".jpg", pixels, [cv2.IMWRITE_JPEG_QUALITY, 95])[1])
    (root / "dock.png").write_bytes(png)
    (root / "dock.jpg").write_bytes(jpg)

    frames = [(10.0 + k, s.image, s.scan) for k, s in enumerate(shots)]
    recording = write_recording(root / "drive", sim, frames)
    ds, _, _ = label_recording(recording, layout, progress=False)
    write_dataset(root / "drive.parquet", ds)
    bundle = _train_bundle(root / "bundle")
    return World(
        root=root,
        camera=root / "camera.yaml",
        camera_cv_yaml=root / "camera_cv.yaml",
        camera_cv_xml=root / "camera_cv.xml",
        layout=root / "layout.yaml",
        robot=root / "robot.yaml",
        docking=root / "docking.yaml",
        image=root / "dock.png",
        image_jpg=root / "dock.jpg",
        recording=recording,
        dataset=root / "drive.parquet",
        bundle=bundle,
        pixels=pixels,
        png=png,
        jpg=jpg,
    )


_FRAMES: dict[Path, tuple[Simulator, list[tuple[float, np.ndarray, Any]]]] = {}


def frames_of(world: World) -> tuple[Simulator, list[tuple[float, np.ndarray, Any]]]:
    """The simulator and the (stamp, image, scan) frames of the world's recording, to write variants of it.

    Read once per world: a property writes a variant of the recording for each of its (up to 300) examples, and
    opening the bag costs ~0.2 s (rosbags parses its metadata.yaml). The images are read-only, so no example can
    change what the next one writes.
    """
    from monodock.recording import open_recording

    if world.recording not in _FRAMES:
        sim = Simulator(nuisances=Nuisances.clean().updated(supersample=2), seed=0)
        with open_recording(world.recording) as rec:
            images = [f.image for f in rec.images()]
            scans = rec.scans()
        for img in images:
            img.setflags(write=False)
        _FRAMES[world.recording] = (sim, [(10.0 + k, img, scans[k]) for k, img in enumerate(images)])
    sim, frames = _FRAMES[world.recording]
    return sim, list(frames)


def load_yaml_text(path: Path) -> Any:
    return yaml.safe_load(path.read_text())


def copy_tree(src: Path, dst: Path) -> Path:
    shutil.copytree(src, dst)
    return dst
