"""The dock's survey from photographs (``calibrate.survey``), against the wrong world the simulator built.

Ground truth: ``sim.wrong_world`` draws the dock as a person builds it (each marker ±3 mm, ±2° tilt, 97-103 %
print); the simulator renders it; the survey sees only the pixels and the nominal file.
"""

from __future__ import annotations

import dataclasses
import math
from pathlib import Path

import numpy as np
import pytest

from monodock.calibrate.survey import SurveyLimits, survey_layout, surveyed_layout_text
from monodock.calibrate.survey_views import SurveyView, survey_views
from monodock.cli.main import main
from monodock.core import transforms
from monodock.core.frame import Frame
from monodock.core.images import encode_png
from monodock.core.layout import ROLES, DockLayout
from monodock.core.settings import from_mapping
from monodock.errors import InputError
from monodock.sim import Nuisances, Simulator
from monodock.sim.survey_views import handheld_poses, render_shot, robot_poses
from monodock.sim.wrong_world import WrongWorld, wrong_world

FAST = Nuisances().updated(supersample=2)


def _views(world: WrongWorld, count: int, *, robot: bool = False, seed: int = 0) -> tuple[list[SurveyView], Simulator]:
    sim = Simulator(layout=world.layout, robot=world.robot, nuisances=FAST, seed=seed)
    rng = np.random.default_rng(seed)
    poses = robot_poses(sim, count, rng) if robot else handheld_poses(sim, count, rng)
    frames = [Frame(f"v{k}", math.nan, render_shot(sim, f"v{k}", T, rng).image) for k, T in enumerate(poses)]
    views, _, offset = survey_views(frames, sim.camera, world.nominal_layout)
    assert offset is not None
    assert abs(offset.offset_px) < 0.03, "the simulator prints no ink: no edge offset"
    return views, sim


def _relative(layout: DockLayout, role: str) -> np.ndarray:
    return transforms.invert(layout.dock_T_marker("center")) @ layout.dock_T_marker(role)


@pytest.fixture(scope="module")
def handheld() -> tuple[WrongWorld, list[SurveyView], Simulator]:
    world = wrong_world(3)
    views, sim = _views(world, 18, seed=3)
    return world, views, sim


def test_survey_finds_each_marker_relative_to_the_centre_one(
    handheld: tuple[WrongWorld, list[SurveyView], Simulator],
) -> None:
    """Each marker's pose against the centre marker's within 0.5 mm and 0.2° once the print's overall scale is
    divided out (images cannot see it), and its side against the others' within 0.1 %; the raw positions are off
    by that scale alone."""
    world, views, sim = handheld
    survey = survey_layout(views, sim.camera, world.nominal_layout)
    got, truth = survey.layout, world.layout
    scale = math.exp(np.mean([math.log(got.side(r) / truth.side(r)) for r in ROLES]))
    assert abs(scale - 1.0) < 0.03, "the mean side is the nominal's: the print's mean scale, at most 3 % off"
    for role in ("left", "right"):
        A, B = _relative(got, role), _relative(truth, role)
        assert np.abs(A[:3, 3] / scale - B[:3, 3]).max() < 0.0005
        assert np.abs(A[:3, 3] - scale * B[:3, 3]).max() < 0.0005
        angle = math.degrees(math.acos(min(1.0, (np.trace(A[:3, :3].T @ B[:3, :3]) - 1.0) / 2.0)))
        assert angle < 0.2
    for role in ROLES:
        assert got.side(role) / scale == pytest.approx(truth.side(role), rel=1e-3)
    # The uncertainties it states are below the refusal limits, and the record travels with the file.
    limits = SurveyLimits()
    for m in survey.markers.values():
        assert m.sd["y"] < limits.position_sd
        assert m.sd["yaw"] < limits.angle_sd
    assert survey.rms_px < 0.2
    assert from_mapping(DockLayout, __import__("yaml").safe_load(surveyed_layout_text(survey)), "layout") == got


def test_robot_views_measure_the_heights_and_the_dock_s_up() -> None:
    """From the robot's own camera on the floor (the mount known), each marker's height within 0.3 mm and its
    lean against the floor (roll, pitch) within 0.1°, in the dock frame, not only relative to the centre marker.
    The height is the camera's (metric) plus the marker's rise over it in the print's scale: that scale's error
    times the rise is allowed on top."""
    world = wrong_world(4)
    views, sim = _views(world, 18, robot=True, seed=4)
    survey = survey_layout(views, sim.camera, world.nominal_layout, robot=world.robot)
    assert survey.heights_measured
    scale = math.exp(np.mean([math.log(survey.layout.side(r) / world.layout.side(r)) for r in ROLES]))
    camera_z = world.robot.base_T_optical()[2, 3]
    for role in ROLES:
        got, truth = survey.layout.marker(role), world.layout.marker(role)
        assert got.z == pytest.approx(truth.z, abs=3e-4 + abs(scale - 1.0) * abs(truth.z - camera_z))
        assert math.degrees(abs(got.roll - truth.roll)) < 0.1
        assert math.degrees(abs(got.pitch - truth.pitch)) < 0.1


def test_too_few_views_untied_markers_and_uncertain_values_are_refused_with_advice(
    handheld: tuple[WrongWorld, list[SurveyView], Simulator],
) -> None:
    world, views, sim = handheld
    nominal = world.nominal_layout
    with pytest.raises(InputError, match=r"^3 views show two or more dock markers; the survey needs at least 4"):
        survey_layout(views[:3], sim.camera, nominal)
    no_right = [dataclasses.replace(v, corners={r: c for r, c in v.corners.items() if r != "right"}) for v in views]
    with pytest.raises(InputError, match=r"^marker right \(id 3\) is in no view: add views that show it"):
        survey_layout(no_right, sim.camera, nominal)
    # The left marker only ever alone in its views, the others together.
    apart = [dataclasses.replace(v, corners={"left": v.corners["left"]}) for v in views[:4]]
    apart += [dataclasses.replace(v, corners={r: v.corners[r] for r in ("center", "right")}) for v in views[4:]]
    with pytest.raises(InputError, match=r"^marker left \(id 1\) is seen only alone \(4 views\): add views that show"):
        survey_layout(apart, sim.camera, nominal)
    # Left with right only, centre with nobody: nothing ties left and right to the centre.
    pairs = [dataclasses.replace(v, corners={r: v.corners[r] for r in ("left", "right")}) for v in views[:8]]
    pairs += [dataclasses.replace(v, corners={"center": v.corners["center"]}) for v in views[8:]]
    with pytest.raises(InputError, match=r"is seen only alone|no view ties marker"):
        survey_layout(pairs, sim.camera, nominal)
    with pytest.raises(InputError, match=r"uncertain by .* \(limit .*\): add .*; nothing written$"):
        survey_layout(views[:5], sim.camera, nominal, limits=SurveyLimits(1e-7, 1e-7, 1e-7))


def test_calibrate_layout_writes_the_survey_and_refuses_in_one_line(
    handheld: tuple[WrongWorld, list[SurveyView], Simulator], tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    world, _, sim = handheld
    rng = np.random.default_rng(5)
    photos = tmp_path / "photos"
    photos.mkdir()
    for k, T in enumerate(handheld_poses(sim, 12, rng)):
        (photos / f"p{k:02d}.png").write_bytes(encode_png(render_shot(sim, str(k), T, rng).image))
    camera, nominal, out = tmp_path / "camera.yaml", tmp_path / "nominal.yaml", tmp_path / "surveyed.yaml"
    sim.camera.save(camera)
    world.nominal_layout.save(nominal)
    args = ["calibrate", "layout", str(photos), "--camera", str(camera), "--layout", str(nominal), "--out", str(out)]
    assert main(args) == 0
    surveyed = DockLayout.load(out)
    assert not surveyed.flat
    assert surveyed.marker("left").id == world.layout.marker("left").id
    assert "left" in capsys.readouterr().out
    assert main(args) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1
    assert err[0].endswith("exists; pass --force to overwrite it")
    assert main([*args[:-2], "--out", str(tmp_path / "x.yaml"), "--max-position-sd", "0.000001"]) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1
    assert "add" in err[0]
    assert not (tmp_path / "x.yaml").exists()
    assert main(["calibrate", "layout", str(photos), "--layout", str(nominal), "--out", str(tmp_path / "y.yaml")]) == 2
    assert capsys.readouterr().err.strip().endswith("give --camera (the calibration of the camera that took the views)")
