"""A flag that means the same in several commands is declared once (issue 40): the commands that share it parse it
to the same value, with the same range and default, and the defaults that a config dataclass declares are its."""

from __future__ import annotations

import argparse
import math

import pytest

from monodock.calibrate.survey import SurveyLimits
from monodock.cli.calibrate_dock import survey_limits
from monodock.cli.demo import DemoConfig
from monodock.cli.main import parser


def _parse(argv: list[str]) -> argparse.Namespace:
    return parser().parse_args(argv)


def test_calibrate_layout_and_commission_read_the_same_survey_limits() -> None:
    limits = ["--max-views", "12", "--max-position-sd", "0.5", "--max-angle-sd", "0.2"]
    layout = _parse(["calibrate", "layout", "a.png", "--layout", "l.yaml", "--out", "o.yaml", *limits])
    files = ["--camera", "c.yaml", "--layout", "l.yaml", "--robot", "r.yaml", "--out", "o"]
    commission = _parse(["commission", "--survey", "a.png", "--drive", "d", "--teach", "t", *files, *limits])
    assert layout.max_views == commission.max_views == 12
    assert survey_limits(layout) == survey_limits(commission) == SurveyLimits(0.0005, math.radians(0.2), 0.0005)
    defaults = _parse(["calibrate", "layout", "a.png", "--layout", "l.yaml", "--out", "o.yaml"])
    assert (defaults.max_views, defaults.max_position_sd, defaults.max_angle_sd) == (40, 0.3, 0.15)


@pytest.mark.parametrize("command", [["calibrate", "mount"], ["teach"]])
def test_calibrate_mount_and_teach_take_the_same_recording_inputs(command: list[str]) -> None:
    args = _parse([*command, "bag", "--layout", "l.yaml", "--robot", "r.yaml", "--out", "o.yaml"])
    assert (args.recording, args.layout, args.robot, args.camera) == ("bag", "l.yaml", "r.yaml", None)
    with pytest.raises(SystemExit):
        _parse([*command, "bag", "--layout", "l.yaml", "--out", "o.yaml"])


def test_the_pairing_tolerance_and_camera_rate_are_one_declaration_each() -> None:
    extrinsics = _parse(["calibrate", "extrinsics", "--pairs", "p.csv", "--robot", "r.yaml", "--out", "o.yaml"])
    label = _parse(["label", "bag", "--layout", "l.yaml", "--out", "d.parquet"])
    assert extrinsics.tolerance == label.tolerance == 0.05
    assert _parse(["simulate", "--out", "o"]).camera_rate == _parse(["dock-sim"]).camera_rate == 15.0


def test_the_demo_flags_default_to_demo_config() -> None:
    args = _parse(["demo"])
    config = DemoConfig()
    assert (args.train_stops, args.test_stops, args.trials, args.dock_trials, args.seed) == (
        config.train.stops,
        config.test_stops,
        config.train.trials,
        config.dock_trials,
        config.seed,
    )
