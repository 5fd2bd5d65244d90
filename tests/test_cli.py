"""The command line against bad input and the simulator's truth: one clear line, non-zero exit, no traceback."""

from __future__ import annotations

import csv
import math
import subprocess
import sys
from pathlib import Path

import pytest

from monodock.cli import main
from monodock.layout import DockLayout


def run(args: list[str], capsys: pytest.CaptureFixture[str]) -> tuple[int, str, str]:
    code = main(args)
    out, err = capsys.readouterr()
    return code, out, err


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
        depth = float(r["depth_m"])
        assert 0.4 <= depth <= 1.2
        assert r["m2_in_view"] == "1"
        assert abs(float(r["yaw_deg"])) <= 30.0


def test_simulate_refuses_to_overwrite(sim_folder: Path, capsys: pytest.CaptureFixture[str]) -> None:
    code, _, err = run(["simulate", "--out", str(sim_folder), "--frames", "1"], capsys)
    assert code != 0
    assert "--force" in err
    assert len(err.strip().splitlines()) == 1


def test_estimate_board_matches_truth(sim_folder: Path, tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    est = tmp_path / "est.csv"
    code, _, _ = run(
        [
            "estimate",
            str(sim_folder / "images"),
            "--method",
            "board",
            "--camera",
            str(sim_folder / "camera.yaml"),
            "--layout",
            str(sim_folder / "layout.yaml"),
            "--robot",
            str(sim_folder / "robot.yaml"),
            "--out",
            str(est),
        ],
        capsys,
    )
    assert code == 0
    truth = {r["frame"]: r for r in csv.DictReader((sim_folder / "ground_truth.csv").open())}
    rows = list(csv.DictReader(est.open()))
    assert {r["frame"] for r in rows} == set(truth)
    for r in rows:
        assert r["valid"] == "true"
        t = truth[r["frame"]]
        assert abs(float(r["x_m"]) - float(t["x_m"])) < 0.01
        assert abs(float(r["y_m"]) - float(t["y_m"])) < 0.01
        assert abs(float(r["yaw_deg"]) - float(t["yaw_deg"])) < 1.0


def estimate_cmd(
    sim_folder: Path, out: Path, *inputs: str, camera: Path | None = None, layout: Path | None = None
) -> list[str]:
    """An `estimate` command on the simulated folder, with some calibration file swapped."""
    return [
        "estimate",
        *(inputs or (str(sim_folder / "images"),)),
        "--camera",
        str(camera or sim_folder / "camera.yaml"),
        "--layout",
        str(layout or sim_folder / "layout.yaml"),
        "--robot",
        str(sim_folder / "robot.yaml"),
        "--out",
        str(out),
    ]


def assert_one_line_error(code: int, err: str, needle: str) -> None:
    assert code != 0
    assert needle in err
    assert len(err.strip().splitlines()) == 1


def _calib(sim_folder: Path) -> list[str]:
    return [
        "--camera",
        str(sim_folder / "camera.yaml"),
        "--layout",
        str(sim_folder / "layout.yaml"),
        "--robot",
        str(sim_folder / "robot.yaml"),
    ]


def test_missing_input_file(sim_folder: Path, tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    code, _, err = run(
        ["estimate", str(tmp_path / "nope.png"), *_calib(sim_folder), "--out", str(tmp_path / "e.csv")], capsys
    )
    assert code != 0
    assert "nope.png" in err
    assert len(err.strip().splitlines()) == 1


def test_unreadable_image(sim_folder: Path, tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    bad = tmp_path / "corrupt.png"
    bad.write_bytes(b"\x89PNG\r\n\x1a\nthis is not a png")
    code, _, err = run(["estimate", str(bad), *_calib(sim_folder), "--out", str(tmp_path / "e.csv")], capsys)
    assert code != 0
    assert "corrupt.png" in err
    assert len(err.strip().splitlines()) == 1
    assert not (tmp_path / "e.csv").exists()
    # With --skip-bad the frame becomes an invalid row instead.
    code, _, _ = run(
        ["estimate", str(bad), *_calib(sim_folder), "--out", str(tmp_path / "e.csv"), "--skip-bad"], capsys
    )
    assert code == 0
    rows = list(csv.DictReader((tmp_path / "e.csv").open()))
    assert rows[0]["valid"] == "false"
    assert "corrupt" in rows[0]["reason"]


def test_image_of_another_size(sim_folder: Path, tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    import cv2
    import numpy as np

    img = tmp_path / "small.png"
    cv2.imwrite(str(img), np.zeros((100, 120), np.uint8))
    code, _, err = run(["estimate", str(img), *_calib(sim_folder), "--out", str(tmp_path / "e.csv")], capsys)
    assert code != 0
    assert "120x100" in err


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
    code, _, err = run(estimate_cmd(sim_folder, tmp_path / "e.csv", layout=layout), capsys)
    assert_one_line_error(code, err, needle)


def test_camera_without_camera_matrix(sim_folder: Path, tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    cam = tmp_path / "camera.yaml"
    import yaml

    data = yaml.safe_load((sim_folder / "camera.yaml").read_text())
    del data["camera_matrix"]
    cam.write_text(yaml.safe_dump(data))
    code, _, err = run(estimate_cmd(sim_folder, tmp_path / "e.csv", camera=cam), capsys)
    assert_one_line_error(code, err, "camera_matrix")


def test_show_overlay(sim_folder: Path, tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    import cv2

    png = tmp_path / "o.png"
    image = sorted((sim_folder / "images").glob("*.png"))[0]
    code, out, _ = run(["show", str(image), *_calib(sim_folder), "--out", str(png)], capsys)
    assert code == 0
    pic = cv2.imread(str(png))
    assert pic is not None
    assert pic.shape[:2] == (960, 1280)
    assert "DockPose" in out


def test_console_script_reports_without_traceback(tmp_path: Path) -> None:
    """Through a real process: the user sees one line, never a Python traceback."""
    proc = subprocess.run(
        [
            sys.executable,
            "-m",
            "monodock.cli",
            "show",
            str(tmp_path / "missing.png"),
            "--camera",
            str(tmp_path / "c.yaml"),
            "--layout",
            str(tmp_path / "l.yaml"),
            "--robot",
            str(tmp_path / "r.yaml"),
            "--out",
            str(tmp_path / "o.png"),
        ],
        capture_output=True,
        text=True,
        check=False,
    )
    assert proc.returncode != 0
    assert "Traceback" not in proc.stderr
    assert len(proc.stderr.strip().splitlines()) == 1


def test_default_layout_is_the_papers_charger() -> None:
    layout = DockLayout.default()
    assert layout.marker("center").y == 0.0
    assert layout.marker("left").y > 0 > layout.marker("right").y
    assert math.isclose(layout.marker_size, 0.10)
