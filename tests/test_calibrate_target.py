"""Camera-LiDAR extrinsics from simulated views of the diamond target: the full 6-DoF mount, bad input."""

from __future__ import annotations

import dataclasses
import math

import numpy as np
import pytest

from monodock.calibrate.extrinsics import extrinsics_from_target_views
from monodock.errors import InputError
from monodock.robot import Mount, RobotConfig
from monodock.sim import Nuisances, Simulator
from monodock.sim.target import DiamondTarget, TargetView, render_target_views

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

    from monodock.cli import main
    from monodock.sim.target import write_target_views

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
