"""A flag that means the same in several commands is declared once (issue 40): the commands that share it parse it
to the same value, with the same range and default, and the defaults that a config dataclass declares are its."""

from __future__ import annotations

import argparse
import math
import os
import subprocess
import sys

import pytest

from monodock.calibrate.survey import SurveyLimits
from monodock.cli.calibrate_dock import survey_limits
from monodock.cli.demo import DemoConfig
from monodock.cli.main import parser
from monodock.cli.options import SubParsers, add_command


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


def _documented(_args: argparse.Namespace) -> int:
    """the help, on
    two lines, at 100 %

    The description: the rest,
    re-flowed."""
    return 0


def _undocumented(_args: argparse.Namespace) -> int:
    return 0


def _command_line() -> tuple[argparse.ArgumentParser, SubParsers]:
    top = argparse.ArgumentParser(prog="top")
    return top, top.add_subparsers(dest="command", required=True)


def test_a_commands_help_and_description_are_its_run_functions_docstring(monkeypatch: pytest.MonkeyPatch) -> None:
    monkeypatch.setenv("COLUMNS", "120")
    top, sub = _command_line()
    p = add_command(sub, "doc", _documented, epilog="the end")
    p.add_argument("--x", type=int)
    (choice,) = sub._choices_actions
    assert choice.help == "the help, on two lines, at 100 %%"  # argparse %-formats a help: it shows 100 %
    assert p.description == "The description: the rest, re-flowed."
    assert "the help, on two lines, at 100 %\n" in top.format_help()
    assert "The description: the rest, re-flowed.\n" in p.format_help()
    assert p.epilog == "the end"
    args = top.parse_args(["doc", "--x", "3"])
    assert (args.func, args.x) == (_documented, 3)


def test_a_run_function_without_a_docstring_still_gives_a_working_command() -> None:
    top, sub = _command_line()
    p = add_command(sub, "bare", _undocumented)
    assert (sub._choices_actions[0].help, p.description) == (None, None)
    assert "bare" in top.format_help()
    assert p.format_help().startswith("usage: top bare [-h]")
    assert top.parse_args(["bare"]).func is _undocumented
    # python -OO strips every docstring: the command line still builds and prints its help.
    env = {**os.environ, "COLUMNS": "80"}
    done = subprocess.run(
        [sys.executable, "-OO", "-m", "monodock.cli.main", "--help"],
        capture_output=True,
        text=True,
        env=env,
        check=False,
    )
    assert done.returncode == 0, done.stderr
    assert "    teach\n" in done.stdout
