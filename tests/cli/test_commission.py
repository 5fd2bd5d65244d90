"""``monodock commission`` end to end on a wrong world, every input made by ``monodock simulate``, as a user would.

Ground truth: the world's true layout and robot files (``sim.wrong_world``), which only the simulator sees.
"""

from __future__ import annotations

import json
import math
from pathlib import Path

import pytest

from monodock.cli.main import main
from monodock.core.robot import RobotConfig
from monodock.dock.config import load_docking_config
from monodock.sim.wrong_world import wrong_world


@pytest.mark.slow
@pytest.mark.timeout(900)
def test_commission_a_wrong_world_from_the_command_line(tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    world = wrong_world(6)
    files = {name: tmp_path / f"{name}.yaml" for name in ("true_layout", "true_robot", "layout", "robot")}
    world.layout.save(files["true_layout"])
    world.robot.save(files["true_robot"])
    world.nominal_layout.save(files["layout"])
    world.nominal_robot.save(files["robot"])
    truth = ["--layout", str(files["true_layout"]), "--robot", str(files["true_robot"])]
    wheels = ["--wheel-scale", *(str(w) for w in world.wheel_scale)]
    assert main(["simulate", "--views", "handheld", "--frames", "18", *truth, "--out", str(tmp_path / "survey")]) == 0
    drive = ["simulate", "--format", "rosbag2", "--drive", "commissioning", *truth, *wheels, "--out"]
    assert main([*drive, str(tmp_path / "drive")]) == 0
    teach = ["simulate", "--format", "rosbag2", "--drive", "teach", "--frame-every", "1", *truth, *wheels, "--out"]
    assert main([*teach, str(tmp_path / "teach")]) == 0
    out = tmp_path / "commissioned"
    args = [
        "commission", "--survey", str(tmp_path / "survey" / "images"), "--drive", str(tmp_path / "drive"),
        "--teach", str(tmp_path / "teach"), "--camera", str(tmp_path / "survey" / "camera.yaml"),
        "--layout", str(files["layout"]), "--robot", str(files["robot"]), "--out", str(out),
    ]  # fmt: skip
    capsys.readouterr()
    assert main(args) == 0
    said = capsys.readouterr().out
    assert "ready to dock" in said
    robot = RobotConfig.load(out / "robot.yaml")
    m, t = robot.camera_mount, world.robot.camera_mount
    # The print's scale, 1 % at most here, carries into the mount's position; the angles have no scale.
    assert abs(m.x - t.x) < 0.004
    assert abs(m.y - t.y) < 0.004
    for k in ("roll", "pitch", "yaw"):
        assert math.degrees(abs(getattr(m, k) - getattr(t, k))) < 0.2, k
    offset = load_docking_config(out / "docking.yaml").charging_offset
    assert abs(offset.x) < 0.02
    summary = json.loads((out / "summary.json").read_text(encoding="utf-8"))
    assert summary["ready"] is True
    page = (out / "report.html").read_text(encoding="utf-8")
    for picture in ("survey_views.png", "survey_layout.png", "drive.png", "teach.png"):
        assert picture in page
        assert (out / picture).stat().st_size > 10_000
    # A drive without odometry: not ready, in one line, the report written all the same and saying what to redo.
    stops = tmp_path / "stops"
    assert main(["simulate", "--format", "rosbag2", "--frames", "4", *truth, "--out", str(stops)]) == 0
    bad = [a if a != str(tmp_path / "drive") else str(stops) for a in args]
    bad[bad.index(str(out))] = str(tmp_path / "not_ready")
    capsys.readouterr()
    assert main(bad) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1
    assert "not ready: redo the mount" in err[0]
    assert "redo the mount" in (tmp_path / "not_ready" / "report.html").read_text(encoding="utf-8")
