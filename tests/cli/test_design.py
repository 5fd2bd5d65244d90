"""``monodock design``: the folder it writes, and its refusals (one line, exit 2, nothing written)."""

from __future__ import annotations

import json
from pathlib import Path

import pytest

from monodock.cli.main import main
from monodock.core.camera import CameraModel
from monodock.core.layout import DockLayout

ROOT = Path(__file__).resolve().parents[2]
WIDE = ROOT / "bench" / "setups" / "wide"


def run(args: list[str], capsys: pytest.CaptureFixture[str]) -> tuple[int, str, str]:
    try:
        code = main(args)
    except SystemExit as exc:  # argparse's own usage errors
        code = int(exc.code or 0)
    out, err = capsys.readouterr()
    return code, out, err


def refuse_constant(name: str) -> None:
    raise AssertionError(f"design.json holds {name}, which is not JSON")


def assert_one_line_error(code: int, err: str, *needles: str) -> None:
    assert code == 2
    assert len(err.strip().splitlines()) == 1, err
    assert "Traceback" not in err
    for needle in needles:
        assert needle in err


@pytest.fixture
def camera_file(tmp_path: Path) -> Path:
    path = tmp_path / "camera.yaml"
    CameraModel.default().save(path)
    return path


def test_writes_the_layout_report_numbers_and_kit_and_replaces_only_with_force(
    tmp_path: Path, camera_file: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    out = tmp_path / "design"
    args = ["design", "--camera", str(camera_file), "--max-distance", "5", "--max-bearing", "60"]
    code, printed, err = run([*args, "--check-poses", "3", "--out", str(out)], capsys)
    assert code == 0, err
    names = {p.name for p in out.iterdir()}
    assert {"layout.yaml", "report.html", "design.json", "design_map.png", "design_check.png", "kit"} <= names
    layout = DockLayout.load(out / "layout.yaml")
    assert layout.roles[:3] == ("left", "center", "right")
    assert "far" in layout.roles
    numbers = json.loads((out / "design.json").read_text(), parse_constant=refuse_constant)
    assert numbers["sim_check"]["poses"] == 3
    assert numbers["envelope_covered"] == 1.0
    pdfs = list((out / "kit").glob("dock_kit_*.pdf"))
    assert len(pdfs) == 1
    assert pdfs[0].read_bytes().startswith(b"%PDF-")
    assert "design:" in printed

    code, _, err = run([*args, "--check-poses", "0", "--out", str(out)], capsys)
    assert_one_line_error(code, err, "exists", "--force")
    code, _, err = run([*args, "--check-poses", "0", "--tolerance", "5mm,0.5deg", "--out", str(out), "--force"], capsys)
    assert code == 0, err
    # Nothing rendered: the report says so, with no empty figure and no "nan %"; design.json stays strict JSON.
    assert not (out / "design_check.png").exists()
    text = (out / "report.md").read_text()
    assert "Not checked in the simulator" in text
    assert "nan" not in text.lower()
    unchecked = json.loads((out / "design.json").read_text(), parse_constant=refuse_constant)
    assert unchecked["sim_check"]["poses"] == 0
    assert unchecked["sim_check"]["within_3_sigma"] is None


@pytest.mark.parametrize(
    ("extra", "says"),
    [
        (["--max-distance", "0"], "--max-distance"),
        (["--max-distance", "-3"], "--max-distance"),
        (["--max-distance", "500"], "--max-distance"),
        (["--max-distance", "nan"], "--max-distance"),
        (["--max-bearing", "90"], "--max-bearing"),
        (["--max-bearing", "120"], "--max-bearing"),
        (["--tolerance", "1cm"], "--tolerance"),
        (["--tolerance", "-1cm,1deg"], "--tolerance"),
        (["--max-width", "0.2"], "no layout fits a 0.2 x 1.2 m face"),
        (["--max-width", "0.7", "--max-height", "0.7"], "no layout within a 0.7 x 0.7 m face"),
    ],
)
def test_bad_numbers_and_a_face_too_small_get_one_line(
    tmp_path: Path, camera_file: Path, extra: list[str], says: str, capsys: pytest.CaptureFixture[str]
) -> None:
    out = tmp_path / "design"
    code, _, err = run(
        ["design", "--camera", str(camera_file), *extra, "--check-poses", "0", "--out", str(out)], capsys
    )
    assert_one_line_error(code, err, says)
    assert not out.exists()


def test_a_missing_or_invalid_camera_or_robot_file_gets_one_line(
    tmp_path: Path, camera_file: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    out = tmp_path / "design"
    code, _, err = run(["design", "--camera", str(tmp_path / "nope.yaml"), "--out", str(out)], capsys)
    assert_one_line_error(code, err, "nope.yaml")
    bad = tmp_path / "bad.yaml"
    bad.write_text("image_width: 640\nimage_height: [\n")
    code, _, err = run(["design", "--camera", str(bad), "--out", str(out)], capsys)
    assert_one_line_error(code, err, "bad.yaml")
    code, _, err = run(["design", "--camera", str(camera_file), "--robot", str(bad), "--out", str(out)], capsys)
    assert_one_line_error(code, err, "bad.yaml")
    assert not out.exists()


def test_the_wide_set_up_gets_a_design_too(tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    out = tmp_path / "wide"
    code, _, err = run(
        ["design", "--camera", str(WIDE / "camera.yaml"), "--robot", str(WIDE / "robot.yaml"), "--check-poses", "2",
         "--out", str(out)],
        capsys,
    )  # fmt: skip
    assert code == 0, err
    numbers = json.loads((out / "design.json").read_text())
    assert numbers["sim_check"]["all_predicted_detected"] == 1.0
