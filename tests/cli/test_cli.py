"""The command line against the simulator's truth and against bad input (one clear line, non-zero exit)."""

from __future__ import annotations

import csv
import math
import subprocess
import sys
from pathlib import Path

import cv2
import numpy as np
import pytest
import yaml

from monodock.cli.main import main
from monodock.core.layout import DockLayout


def run(args: list[str], capsys: pytest.CaptureFixture[str]) -> tuple[int, str, str]:
    try:
        code = main(args)
    except SystemExit as exc:  # argparse's own usage errors: one line and exit 2 too (cli.main.Parser)
        code = int(exc.code or 0)
    out, err = capsys.readouterr()
    return code, out, err


def assert_one_line_error(code: int, err: str, needle: str) -> None:
    assert code != 0
    assert needle in err
    assert len(err.strip().splitlines()) == 1
    assert "Traceback" not in err


def calibration(folder: Path, *, camera: Path | None = None, layout: Path | None = None) -> list[str]:
    """The --camera/--layout/--robot options of a folder written by `simulate`, some optionally swapped."""
    return [
        "--camera",
        str(camera or folder / "camera.yaml"),
        "--layout",
        str(layout or folder / "layout.yaml"),
        "--robot",
        str(folder / "robot.yaml"),
    ]


def assert_estimates_match_truth(est: Path, truth_csv: Path, *, xy_m: float, yaw_deg: float) -> None:
    """Every frame of the truth has a valid row in EST.csv, within the given errors."""
    truth = {r["frame"]: r for r in csv.DictReader(truth_csv.open())}
    rows = list(csv.DictReader(est.open()))
    assert {r["frame"] for r in rows} == set(truth)
    for r in rows:
        t = truth[r["frame"]]
        assert r["valid"] == "true", r["reason"]
        assert abs(float(r["x_m"]) - float(t["x_m"])) < xy_m
        assert abs(float(r["y_m"]) - float(t["y_m"])) < xy_m
        assert abs(float(r["yaw_deg"]) - float(t["yaw_deg"])) < yaw_deg


def estimate_folder(
    sim_folder: Path,
    tmp_path: Path,
    capsys: pytest.CaptureFixture[str],
    *,
    camera: Path | None = None,
    layout: Path | None = None,
) -> tuple[int, str, str]:
    """`estimate` on the simulated images with one calibration file swapped."""
    calib = calibration(sim_folder, camera=camera, layout=layout)
    return run(["estimate", str(sim_folder / "images"), *calib, "--out", str(tmp_path / "e.csv")], capsys)


@pytest.fixture(scope="module")
def sim_folder(tmp_path_factory: pytest.TempPathFactory) -> Path:
    """A small simulated set written by the CLI itself (clean renders, 0.4-1.2 m)."""
    out = tmp_path_factory.mktemp("sim") / "set"
    code = main(
        [
            "simulate",
            "--out",
            str(out),
            "--frames",
            "6",
            "--seed",
            "3",
            "--clean",
            "--depth",
            "0.4",
            "1.2",
            "--jobs",
            "1",
            "--preview",
            "2",
        ]
    )
    assert code == 0
    return out


def test_simulate_writes_documented_folder(sim_folder: Path) -> None:
    for name in ("camera.yaml", "robot.yaml", "layout.yaml", "ground_truth.csv", "scans.npz"):
        assert (sim_folder / name).is_file(), name
    assert len(list((sim_folder / "images").glob("*.png"))) == 6
    assert len(list((sim_folder / "preview").glob("*.png"))) == 2
    rows = list(csv.DictReader((sim_folder / "ground_truth.csv").open()))
    assert len(rows) == 6
    for r in rows:
        assert 0.4 <= float(r["depth_m"]) <= 1.2
        assert r["m2_in_view"] == "1"
        assert abs(float(r["yaw_deg"])) <= 30.0
    scans = np.load(sim_folder / "scans.npz")
    assert scans["ranges"].shape[0] == 6
    assert list(scans["frame"]) == [r["frame"] for r in rows]


def test_simulate_refuses_to_overwrite(sim_folder: Path, capsys: pytest.CaptureFixture[str]) -> None:
    code, _, err = run(["simulate", "--out", str(sim_folder), "--frames", "1"], capsys)
    assert_one_line_error(code, err, "--force")


def test_estimate_board_matches_truth(sim_folder: Path, tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    est = tmp_path / "est.csv"
    code, _, _ = run(
        ["estimate", str(sim_folder / "images"), "--method", "board", *calibration(sim_folder), "--out", str(est)],
        capsys,
    )
    assert code == 0
    assert_estimates_match_truth(est, sim_folder / "ground_truth.csv", xy_m=0.01, yaw_deg=1.0)


NOVEL_LAYOUT = """\
dictionary: DICT_5X5_100
marker_size: 0.08
markers:
  left:   {id: 17, y: 0.25,  z: 0.42}
  center: {id: 4,  y: 0.00,  z: 0.36}
  right:  {id: 63, y: -0.22, z: 0.42}
"""
NOVEL_CAMERA = """\
image_width: 1280
image_height: 720
camera_name: wide
camera_matrix: {rows: 3, cols: 3, data: [910.0, 0, 655.3, 0, 908.5, 352.8, 0, 0, 1]}
distortion_model: plumb_bob
distortion_coefficients: {rows: 1, cols: 5, data: [-0.31, 0.12, -0.0008, 0.0011, -0.02]}
"""
NOVEL_ROBOT = """\
camera_mount: {x: 0.12, y: 0.03, z: 0.31, roll: 0.0, pitch: 0.06, yaw: -0.04}
laser_mount:  {x: 0.20, y: 0.0, z: 0.18, roll: 0.0, pitch: 0.0, yaw: 0.0}
front_offset: 0.30
"""


def test_cli_on_a_layout_camera_and_mounts_it_has_never_seen(
    tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    """Other dictionary, ids, sizes and spacing; a 1280x720 strong-barrel lens; a pitched, yawed, offset camera.

    simulate -> estimate (both methods) -> show, all from the files alone, against the simulator's truth.
    """
    files = {"layout.yaml": NOVEL_LAYOUT, "camera.yaml": NOVEL_CAMERA, "robot.yaml": NOVEL_ROBOT}
    for name, text in files.items():
        (tmp_path / name).write_text(text)
    sim = tmp_path / "sim"
    code, _, _ = run(
        [
            "simulate",
            "--out",
            str(sim),
            "--frames",
            "5",
            "--seed",
            "4",
            "--depth",
            "0.4",
            "1.4",
            *calibration(tmp_path),
            "--jobs",
            "1",
        ],
        capsys,
    )
    assert code == 0
    assert yaml.safe_load((sim / "layout.yaml").read_text())["dictionary"] == "DICT_5X5_100"
    for method, xy_m, yaw_deg in (("board", 0.01, 1.0), ("pnp", 0.02, 3.0)):
        est = tmp_path / f"{method}.csv"
        code, _, _ = run(
            ["estimate", str(sim / "images"), "--method", method, *calibration(tmp_path), "--out", str(est)], capsys
        )
        assert code == 0
        assert_estimates_match_truth(est, sim / "ground_truth.csv", xy_m=xy_m, yaw_deg=yaw_deg)
    png = tmp_path / "show.png"
    image = sorted((sim / "images").glob("*.png"))[0]
    code, _, _ = run(["show", str(image), *calibration(tmp_path), "--out", str(png)], capsys)
    assert code == 0
    pic = cv2.imread(str(png))
    assert pic is not None
    assert pic.shape[:2] == (720, 1280)  # a large camera is drawn at its own size


def test_missing_input_file(sim_folder: Path, tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    code, _, err = run(
        ["estimate", str(tmp_path / "nope.png"), *calibration(sim_folder), "--out", str(tmp_path / "e.csv")], capsys
    )
    assert_one_line_error(code, err, "nope.png")


def test_unreadable_image(sim_folder: Path, tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    bad = tmp_path / "corrupt.png"
    bad.write_bytes(b"\x89PNG\r\n\x1a\nthis is not a png")
    est = tmp_path / "e.csv"
    code, _, err = run(["estimate", str(bad), *calibration(sim_folder), "--out", str(est)], capsys)
    assert_one_line_error(code, err, "corrupt.png")
    assert not est.exists()
    # With --skip-bad the frame becomes an invalid row instead.
    code, _, _ = run(["estimate", str(bad), *calibration(sim_folder), "--out", str(est), "--skip-bad"], capsys)
    assert code == 0
    rows = list(csv.DictReader(est.open()))
    assert rows[0]["valid"] == "false"
    assert "corrupt" in rows[0]["reason"]


def test_image_of_another_size(sim_folder: Path, tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    img = tmp_path / "small.png"
    cv2.imwrite(str(img), np.zeros((100, 120), np.uint8))
    good = sorted((sim_folder / "images").glob("*.png"))[0]
    est = tmp_path / "e.csv"
    code, _, err = run(["estimate", str(img), *calibration(sim_folder), "--out", str(est)], capsys)
    assert_one_line_error(code, err, "120x100")
    # With --skip-bad it is an invalid row among the good ones.
    code, _, _ = run(
        ["estimate", str(good), str(img), *calibration(sim_folder), "--out", str(est), "--skip-bad"], capsys
    )
    assert code == 0
    rows = {r["frame"]: r for r in csv.DictReader(est.open())}
    assert rows[good.name]["valid"] == "true"
    assert rows["small.png"]["valid"] == "false"
    assert "120x100" in rows["small.png"]["reason"]


@pytest.mark.parametrize(
    ("text", "needle"),
    [
        (
            "dictionary: DICT_4X4_50\nmarker_size: 0.1\nmarkers:\n  left: {id: 1, y: 0.2, z: 0.3}\n"
            "  center: {id: 1, y: 0.0, z: 0.3}\n  right: {id: 3, y: -0.2, z: 0.3}\n",
            "distinct",
        ),
        (
            "dictionary: DICT_9X9_7\nmarker_size: 0.1\nmarkers:\n  left: {id: 1, y: 0.2, z: 0.3}\n"
            "  center: {id: 2, y: 0.0, z: 0.3}\n  right: {id: 3, y: -0.2, z: 0.3}\n",
            "DICT_9X9_7",
        ),
        (
            "dictionary: DICT_4X4_50\nmarker_size: 0.1\nmarkers:\n  left: {id: 1, y: 0.2, z: 0.3}\n"
            "  right: {id: 3, y: -0.2, z: 0.3}\n",
            "markers.center",
        ),
        (
            "dictionary: DICT_4X4_50\nmarker_size: 0.1\nmarkers:\n  left: {id: 1, y: 0.2, z: 0.3}\n"
            "  center: {id: 2, y: 0.0, z: 0.3}\n  right: {id: 77, y: -0.2, z: 0.3}\n",
            "77",
        ),
        ("dictionary: DICT_4X4_50\nmarker_size: -1\nmarkers: {}\n", "marker_size"),
    ],
)
def test_bad_layout(
    text: str, needle: str, sim_folder: Path, tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    layout = tmp_path / "layout.yaml"
    layout.write_text(text)
    code, _, err = estimate_folder(sim_folder, tmp_path, capsys, layout=layout)
    assert_one_line_error(code, err, needle)


def test_camera_without_camera_matrix(sim_folder: Path, tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    cam = tmp_path / "camera.yaml"
    data = yaml.safe_load((sim_folder / "camera.yaml").read_text())
    del data["camera_matrix"]
    cam.write_text(yaml.safe_dump(data))
    code, _, err = estimate_folder(sim_folder, tmp_path, capsys, camera=cam)
    assert_one_line_error(code, err, "camera_matrix")


def test_output_where_a_file_cannot_go(sim_folder: Path, tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    """An output path under a regular file: the OS refuses; the user gets one line, exit 2."""
    blocker = tmp_path / "blocker"
    blocker.write_text("a file, not a folder")
    code, _, err = run(
        ["estimate", str(sim_folder / "images"), *calibration(sim_folder), "--out", str(blocker / "e.csv")], capsys
    )
    assert code == 2
    assert_one_line_error(code, err, "blocker is a file, not a folder")


@pytest.mark.parametrize(
    ("args", "needle"),
    [
        (["demo", "--train-stops", "0"], "--train-stops"),
        (["simulate", "--out", "x", "--preview", "-1"], "--preview"),
        (["simulate", "--out", "x", "--supersample", "0"], "--supersample: must be 1-64, got 0"),
        (["dock-sim", "--out", "x", "--supersample", "65"], "--supersample: must be 1-64, got 65"),
        (["simulate", "--out", "x", "--depth", "2", "1"], "--depth"),
        (["train", "x", "--out", "x", "--trials", "0"], "--trials"),
        (["simulate", "--out", "x", "--format", "rosbag2", "--density", "1,2,x"], "--density"),
        (["simulate", "--out", "x", "--format", "rosbag2", "--density", "steep"], "density"),
        (["simulate", "--out", "x", "--format", "rosbag2", "--camera-rate", "0"], "--camera-rate"),
        (["label", "x", "--layout", "x", "--out", "x", "--tolerance", "-1"], "tolerance"),
    ],
)
def test_bad_numbers(args: list[str], needle: str, tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    args = [str(tmp_path / a) if a == "x" else a for a in args]
    code, _, err = run(args, capsys)
    assert_one_line_error(code, err, needle)
    assert not (tmp_path / "x").exists()


def test_show_overlay(sim_folder: Path, tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    png = tmp_path / "o.png"
    image = sorted((sim_folder / "images").glob("*.png"))[0]
    code, out, _ = run(["show", str(image), *calibration(sim_folder), "--out", str(png)], capsys)
    assert code == 0
    pic = cv2.imread(str(png))
    assert pic is not None
    assert pic.shape[:2] == (960, 1280)  # a 640x480 camera is drawn twice its size
    assert "DockPose" in out


@pytest.mark.parametrize(
    "argv",
    [
        [
            "show",
            "{tmp}/missing.png",
            "--camera",
            "{tmp}/c.yaml",
            "--layout",
            "{tmp}/l.yaml",
            "--robot",
            "{tmp}/r.yaml",
            "--out",
            "{tmp}/o.png",
        ],
        ["estimate", "--method", "nonsense", "x.png", "--out", "e.csv"],
        ["simulate"],
        ["no-such-command"],
    ],
)
def test_console_script_reports_without_traceback(argv: list[str], tmp_path: Path) -> None:
    """Through a real process, bad files and bad usage alike: one line on stderr, never a traceback."""
    proc = subprocess.run(
        [sys.executable, "-m", "monodock.cli.main", *(a.format(tmp=tmp_path) for a in argv)],
        capture_output=True,
        text=True,
        check=False,
    )
    assert proc.returncode == 2
    assert "Traceback" not in proc.stderr
    assert len(proc.stderr.strip().splitlines()) == 1


def test_default_layout_is_the_papers_charger() -> None:
    layout = DockLayout.default()
    assert layout.marker("center").y == 0.0
    assert layout.marker("left").y > 0 > layout.marker("right").y
    assert math.isclose(layout.marker_size, 0.10)
