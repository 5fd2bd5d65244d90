"""The validation layer (core.config and the loaders on it): a file a user hands in is used only when it describes
something that can exist; otherwise one line names the file, the key and the allowed range.

Judged against the simulator's truth where a wrong file would give numbers: a lens that shrinks the field of view
turns a dock 1.85 m away into one tens of metres away, and must be refused, not estimated.
"""

from __future__ import annotations

import csv
import json
import math
import time
from pathlib import Path

import cv2
import numpy as np
import pytest
import yaml

from monodock.cli.main import main
from monodock.core.camera import CameraModel
from monodock.core.config import load_json, load_yaml
from monodock.core.layout import DockLayout
from monodock.core.pose import DockPose
from monodock.core.robot import RobotConfig
from monodock.core.settings import to_mapping
from monodock.errors import ConfigError
from monodock.sim.nuisance import Nuisances
from monodock.sim.simulator import Simulator

TRUTH = DockPose(1.85, 0.05, math.radians(4.0))


@pytest.fixture(scope="module")
def scene(tmp_path_factory: pytest.TempPathFactory) -> tuple[Path, dict[str, object]]:
    """One clean frame of the dock at TRUTH and the simulator's camera as a mapping to break."""
    folder = tmp_path_factory.mktemp("scene")
    sim = Simulator(nuisances=Nuisances.clean(), seed=3)
    image = sim.frame(TRUTH, 0.0, np.random.default_rng(0)).image
    assert cv2.imwrite(str(folder / "frame.png"), image)
    sim.layout.save(folder / "layout.yaml")
    sim.robot.save(folder / "robot.yaml")
    return folder, sim.camera.to_ros_dict()


def _estimate(folder: Path, camera: dict[str, object], tmp_path: Path, capfd: pytest.CaptureFixture[str]):
    cam = tmp_path / "camera.yaml"
    cam.write_text(yaml.safe_dump(camera), encoding="utf-8")
    out = tmp_path / "est.csv"
    args = ["estimate", str(folder / "frame.png"), "--method", "board", "--camera", str(cam)]
    code = main(
        [*args, "--layout", str(folder / "layout.yaml"), "--robot", str(folder / "robot.yaml"), "--out", str(out)]
    )
    err = capfd.readouterr().err
    rows = list(csv.DictReader(out.open())) if out.exists() else []
    return code, err, rows


def test_the_true_camera_finds_the_dock_where_it_is(scene, tmp_path: Path, capfd: pytest.CaptureFixture[str]) -> None:
    """The control: the file as the simulator wrote it gives the truth, so the refusals below are the file's."""
    folder, camera = scene
    code, err, rows = _estimate(folder, camera, tmp_path, capfd)
    assert code == 0, err
    assert rows[0]["valid"] == "true"
    assert float(rows[0]["x_m"]) == pytest.approx(TRUTH.x, abs=0.02)


@pytest.mark.parametrize(
    ("where", "value", "message"),
    [
        (
            ("distortion_coefficients", 0),
            1e6,
            r"distortion_coefficients: the distortion changes the image's field of view 0.0\d+ times",
        ),
        (("distortion_coefficients", 0), -0.9, r"distortion_coefficients: the lens (cannot be inverted|folds back)"),
        (("camera_matrix", 0), 1e308, r"camera_matrix: fx must be within 0.1-10 times the image's longer side"),
        (("camera_matrix", 0), 30.0, r"camera_matrix: fx must be within .* \(64 to 6400 px\), got 30"),
        (("camera_matrix", 2), -5.0, r"camera_matrix: cx must be on the image \(0 to 640 px\), got -5"),
        (("camera_matrix", 8), 2.0, r"camera_matrix: expected \[fx s cx; 0 fy cy; 0 0 1\]"),
        (("camera_matrix", 1), 50.0, r"camera_matrix: skew must be 0 \(OpenCV's PnP ignores it"),
        (("distortion_coefficients", 0), 50.0, r"field of view 0.\d+ times against the pinhole"),
        (("image_width", None), 10**6, r"image_width: must be at most 16384"),
    ],
    ids=["k1 1e6", "k1 folding", "fx 1e308", "fx tiny", "cx off the image", "K[8] 2", "skew", "k1 50", "width 1e6"],
)
def test_an_implausible_camera_is_refused_not_estimated(
    scene, tmp_path: Path, capfd: pytest.CaptureFixture[str], where: tuple[str, int | None], value: float, message: str
) -> None:
    """Exit 2, one line naming the file and the key; no estimates written (the issue's k1 = 1e6 read 49 m)."""
    folder, camera = scene
    broken = json.loads(json.dumps(camera))
    key, index = where
    if index is None:
        broken[key] = value
    else:
        broken[key]["data"][index] = value
    code, err, rows = _estimate(folder, broken, tmp_path, capfd)
    assert code == 2
    assert len(err.strip().splitlines()) == 1, err
    assert "camera.yaml: " in err
    assert rows == []
    import re

    assert re.search(message, err), err


def _robot_with(**mount: float) -> dict[str, object]:
    data = to_mapping(RobotConfig.default())
    data["camera_mount"].update(mount)  # type: ignore[attr-defined]
    return data


@pytest.mark.parametrize(
    ("data", "message"),
    [
        (_robot_with(x=1e308), r"camera_mount.x: must be within -5 to 5 m, got 1e\+308"),
        (_robot_with(pitch=1e300), r"camera_mount.pitch: must be within -3.14159 to 3.14159 rad"),
        ({**to_mapping(RobotConfig.default()), "front_offset": 7.0}, r"front_offset: must be within 0 to 5 m"),
        ({**to_mapping(RobotConfig.default()), "max_linear_speed": 50.0}, r"max_linear_speed: must be within 0 to 5"),
    ],
)
def test_an_implausible_robot_is_refused(tmp_path: Path, data: dict[str, object], message: str) -> None:
    path = tmp_path / "robot.yaml"
    path.write_text(yaml.safe_dump(data), encoding="utf-8")
    with pytest.raises(ConfigError, match=f"robot.yaml: {message}") as info:
        RobotConfig.load(path)
    assert "\n" not in str(info.value)


@pytest.mark.parametrize(
    ("change", "message"),
    [
        ({"marker_size": 1e-300}, r"marker_size: must be within 0.005 to 2 m"),
        ({"marker_size": 3.0}, r"marker_size: must be within 0.005 to 2 m, got 3.0"),
        ({"markers": {"left": {"id": 1, "y": 1e308, "z": 0.3}}}, r"markers.left.y: must be within -5 to 5 m"),
    ],
)
def test_an_implausible_layout_is_refused(tmp_path: Path, change: dict[str, object], message: str) -> None:
    data = to_mapping(DockLayout.default())
    for key, value in change.items():
        if key == "markers":
            data["markers"].update(value)  # type: ignore[union-attr]
        else:
            data[key] = value
    path = tmp_path / "layout.yaml"
    path.write_text(yaml.safe_dump(data), encoding="utf-8")
    with pytest.raises(ConfigError, match=f"layout.yaml: {message}"):
        DockLayout.load(path)


def test_an_alias_bomb_is_refused_quickly_and_never_expanded(tmp_path: Path) -> None:
    """Nine levels of nine aliases (387 million strings once copied): refused while reading, in well under a second
    of counting, so that nothing downstream ever copies it into a dataset's metadata."""
    lines = ['a0: &a0 ["lol", "lol", "lol", "lol", "lol", "lol", "lol", "lol", "lol"]']
    lines += [f"a{i}: &a{i} [{', '.join([f'*a{i - 1}'] * 9)}]" for i in range(1, 9)]
    layout = yaml.safe_dump(to_mapping(DockLayout.default()))
    path = tmp_path / "layout.yaml"
    path.write_text(layout + "\n".join(lines) + "\n", encoding="utf-8")
    start = time.perf_counter()
    with pytest.raises(ConfigError, match=r"holds more than 1000000 values"):
        load_yaml(path, "layout")
    assert time.perf_counter() - start < 10.0


@pytest.mark.parametrize(
    ("text", "message"),
    [
        ("[" * 100_000 + "]" * 100_000, r"(nested more than 32 levels|nested too deep)"),
        ('{"x": ' + "9" * 5000 + "}", r"a value cannot be read"),
        ('{"x": NaN}', r"a value cannot be read \(NaN is not a number JSON allows\)"),
        ("[1, 2]", r"expected a JSON object at the top level"),
        ("{oops", r"not valid JSON"),
    ],
    ids=["100000 nested arrays", "5000 digits", "NaN", "a list", "garbage"],
)
def test_json_inputs_are_bounded(tmp_path: Path, text: str, message: str) -> None:
    path = tmp_path / "bundle.json"
    path.write_text(text, encoding="utf-8")
    with pytest.raises(ConfigError, match=message) as info:
        load_json(path, "bundle manifest")
    assert "\n" not in str(info.value)


def test_unknown_keys_are_warned_about_and_never_reach_a_bundle(
    work: Path, tmp_path: Path, capfd: pytest.CaptureFixture[str]
) -> None:
    """A layout with a key the schema does not know: labelling warns once and the dataset (and so every bundle
    trained from it) carries only the schema's keys."""
    layout = to_mapping(DockLayout.load(work / "layout.yaml"))
    layout["secret"] = {"nested": list(range(5))}
    path = tmp_path / "layout.yaml"
    path.write_text(yaml.safe_dump(layout), encoding="utf-8")
    out = tmp_path / "d.parquet"
    assert main(["label", str(work / "test_rec"), "--layout", str(path), "--out", str(out)]) == 0
    err = capfd.readouterr().err
    assert err.count("unknown key 'secret' is ignored") == 1, err

    from monodock.learning.dataset import read_dataset

    assert "secret" not in read_dataset(out).metadata["layout"]


def test_an_opencv_file_with_a_nan_names_the_file(tmp_path: Path) -> None:
    """The issue's cx: NaN in an OpenCV FileStorage file read as "no PnP solution"; now the file is named."""
    path = tmp_path / "cam.yml"
    fs = cv2.FileStorage(str(path), cv2.FILE_STORAGE_WRITE)
    fs.write("image_width", 640)
    fs.write("image_height", 480)
    fs.write("camera_matrix", np.array([[600.0, 0, np.nan], [0, 600.0, 240.0], [0, 0, 1]]))
    fs.write("distortion_coefficients", np.zeros(5))
    fs.release()
    with pytest.raises(ConfigError, match=r"cam.yml: camera_matrix or distortion_coefficients hold NaN"):
        CameraModel.load(path)


def test_a_malformed_opencv_file_is_one_line(tmp_path: Path) -> None:
    path = tmp_path / "cam.xml"
    path.write_text('<?xml version="1.0"?>\n<opencv_storage>\n<camera_matrix type_id="opencv-matrix"><rows>3', "utf-8")
    with pytest.raises(ConfigError, match=r"cam.xml: cannot be read as an OpenCV FileStorage") as info:
        CameraModel.load(path)
    assert "\n" not in str(info.value)


def test_a_refusal_stays_one_line_when_the_file_also_has_an_unknown_key(
    scene, tmp_path: Path, capfd: pytest.CaptureFixture[str]
) -> None:
    """The unknown key's warning is held while the command runs and dropped when it refuses (a refusal is one
    line); when the command succeeds, it is shown once."""
    folder, camera = scene
    broken = json.loads(json.dumps(camera))
    broken["vendor_note"] = "lens B"
    broken["camera_matrix"]["data"][4] = -24628.0
    code, err, _ = _estimate(folder, broken, tmp_path, capfd)
    assert code == 2
    assert err.strip().splitlines() == [err.strip()], err
    assert "vendor_note" not in err

    broken["camera_matrix"]["data"][4] = camera["camera_matrix"]["data"][4]  # type: ignore[index]
    (tmp_path / "ok").mkdir()
    code, err, rows = _estimate(folder, broken, tmp_path / "ok", capfd)
    assert code == 0, err
    assert err.count("unknown key 'vendor_note' is ignored") == 1, err
    assert rows[0]["valid"] == "true"


def test_every_shipped_file_is_plausible(caplog: pytest.LogCaptureFixture) -> None:
    """The set-ups the project ships (another layout, a 1280x720 wide lens, a pitched mount) and the example
    docking config pass the validation layer as they are, without a warning: the ranges fit real hardware."""
    from monodock.dock.config import load_docking_config

    root = Path(__file__).resolve().parents[2]
    setups = sorted((root / "bench" / "setups").iterdir())
    assert setups, "no shipped set-up to check"
    with caplog.at_level("WARNING", logger="monodock"):
        for folder in setups:
            CameraModel.load(folder / "camera.yaml")
            DockLayout.load(folder / "layout.yaml")
            RobotConfig.load(folder / "robot.yaml")
        load_docking_config(root / "docs" / "docking.yaml")
    assert caplog.records == []
