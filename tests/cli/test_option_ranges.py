"""Every numeric option of every command has a range, says it in --help, and refuses anything outside it (NaN,
inf, negative seeds, MIN > MAX, counts that would exhaust memory) with one usage line and exit 2 (issue 18)."""

from __future__ import annotations

import argparse
import os
import re
from collections.abc import Iterator
from pathlib import Path

import pytest

from monodock.cli import show
from monodock.cli.main import main, parser
from monodock.cli.options import SEED_MAX

# Options still checked when the command runs (their tests drive the parser directly); their help gives the range.
CHECKED_IN_RUN = {("calibrate", "intrinsics", "--square"), ("calibrate", "intrinsics", "--max-blur"),
                  ("calibrate", "intrinsics", "--max-views"), ("calibrate", "intrinsics", "--min-views")}  # fmt: skip


Option = tuple[tuple[str, ...], argparse.Action]


def numeric_options(p: argparse.ArgumentParser, prefix: tuple[str, ...] = ()) -> Iterator[Option]:
    for action in p._actions:
        if isinstance(action, argparse._SubParsersAction):
            for name, sub in action.choices.items():
                yield from numeric_options(sub, (*prefix, name))
        elif action.type is not None and action.option_strings:
            name = getattr(action.type, "__qualname__", "")
            if action.type in (int, float) or name.startswith(("float_in", "int_in", "_rate")):
                yield prefix, action


def test_every_numeric_option_has_a_range_in_its_help() -> None:
    found = list(numeric_options(parser()))
    assert len(found) > 40
    for prefix, action in found:
        flag = action.option_strings[0]
        assert action.type not in (int, float) or (*prefix, flag) in CHECKED_IN_RUN, (prefix, flag)
        assert action.help, (prefix, flag)
        assert re.search(r"\d\s*-\s*\d|\d, \d|less than one frame", action.help), (prefix, flag, action.help)


def run(argv: list[str], capfd: pytest.CaptureFixture[str]) -> tuple[int, str]:
    try:
        code = main(argv)
    except SystemExit as exc:
        code = int(exc.code or 0)
    return code, capfd.readouterr().err


SIMULATE = [
    (["--seed", "-1"], "--seed"),
    (["--seed", str(SEED_MAX + 1)], "--seed"),
    (["--depth", "1", "inf"], "--depth"),
    (["--depth", "nan", "1"], "--depth"),
    (["--depth", "0", "1"], "--depth"),
    (["--depth", "2", "1"], "MIN must not exceed MAX"),
    (["--lateral", "-inf", "0"], "--lateral"),
    (["--lateral", "1", "-1"], "MIN must not exceed MAX"),
    (["--yaw", "1000", "2000"], "--yaw: must be a number in [-180, 180]"),
    (["--yaw", "-200", "0"], "--yaw"),
    (["--yaw", "nan", "0"], "--yaw"),
    (["--gamma", "0"], "--gamma"),
    (["--gamma", "nan"], "--gamma"),
    (["--exposure", "0"], "--exposure"),
    (["--read-noise", "1e300"], "--read-noise"),
    (["--motion-blur", "1e9"], "--motion-blur"),
    (["--defocus", "1e9"], "--defocus"),
    (["--vignetting", "5"], "--vignetting"),
    (["--occluder-probability", "2"], "--occluder-probability"),
    (["--exposure-jitter", "1e6"], "--exposure-jitter"),
    (["--shot-noise", "1e300"], "--shot-noise"),
    (["--side-walls", "0"], "--side-walls"),
    (["--side-walls", "nan"], "--side-walls"),
    (["--format", "rosbag2", "--camera-rate", "1e-9"], "--camera-rate"),
    (["--format", "rosbag2", "--camera-rate", "nan"], "--camera-rate"),
    (["--format", "rosbag2", "--lidar-rate", "1e12"], "--lidar-rate"),
    (["--format", "rosbag2", "--density", "1,nan"], "density"),
    (["--frames", "0"], "--frames"),
    (["--frames", "10000000000"], "--frames"),
    (["--preview", "-3"], "--preview"),
    (["--jobs", "-2"], "--jobs"),
    (["--jobs", "100000"], "--jobs"),
    (["--supersample", "x"], "--supersample"),
]


@pytest.mark.parametrize(("extra", "needle"), SIMULATE)
def test_simulate_refuses_numbers_out_of_range(
    extra: list[str], needle: str, tmp_path: Path, capfd: pytest.CaptureFixture[str]
) -> None:
    code, err = run(["simulate", "--out", str(tmp_path / "out"), "--frames", "1", *extra], capfd)
    lines = err.strip().splitlines()
    assert code == 2, err
    assert len(lines) == 1, err
    assert needle in lines[0], err
    assert "Traceback" not in err
    assert not (tmp_path / "out").exists()


OTHERS = [
    (["train", "x", "--out", "o", "--trials", "100000000"], "--trials"),
    (["train", "x", "--out", "o", "--fusion-holdout", "nan"], "--fusion-holdout"),
    (["train", "x", "--out", "o", "--seed", "-1"], "--seed"),
    (["train", "x", "--out", "o", "--jobs", "-1"], "--jobs"),
    (["label", "x", "--layout", "x", "--out", "o", "--tolerance", "nan"], "--tolerance"),
    (["label", "x", "--layout", "x", "--out", "o", "--tolerance", "1e300"], "--tolerance"),
    (["run", "--source", "x", "--max-frames", "0"], "--max-frames"),
    (["calibrate", "intrinsics", "x", "--out", "o", "--square", "nan"], "--square"),
    (["calibrate", "intrinsics", "x", "--out", "o", "--square", "1e300"], "--square"),
    (["calibrate", "intrinsics", "x", "--out", "o", "--max-views", "100000000"], "--max-views"),
    (["calibrate", "intrinsics", "x", "--out", "o", "--max-blur", "inf"], "--max-blur"),
    (["calibrate", "extrinsics", "--pairs", "x", "--robot", "x", "--out", "o", "--tolerance", "inf"], "--tolerance"),
    (["evaluate", "--robustness", "--model", "x", "--out", "o", "--frames", "100000000"], "--frames"),
    (["evaluate", "--robustness", "--model", "x", "--out", "o", "--seed", "-1"], "--seed"),
    (["dock-sim", "--trials", "100000000"], "--trials"),
    (["dock-sim", "--seed", "-1"], "--seed"),
    (["dock-sim", "--distance", "1", "nan"], "--distance"),
    (["dock-sim", "--distance", "1", "1e300"], "--distance"),
    (["dock-sim", "--max-heading", "nan"], "--max-heading"),
    (["dock-sim", "--camera-rate", "1e-9"], "--camera-rate"),
    (["dock-sim", "--exposure", "nan"], "--exposure"),
    (["dock-sim", "--standoff", "inf"], "--standoff"),
    (["dock-sim", "--max-retries", "100000000"], "--max-retries"),
    (["dock-sim", "--train-stops", "10000000000"], "--train-stops"),
    (["dock-sim", "--jobs", "-1"], "--jobs"),
    (["demo", "--out", "o", "--seed", "-1"], "--seed"),
    (["demo", "--out", "o", "--jobs", "-1"], "--jobs"),
    (["demo", "--out", "o", "--train-stops", "1e3"], "--train-stops"),
]


@pytest.mark.parametrize(("argv", "needle"), OTHERS)
def test_other_commands_refuse_numbers_out_of_range(
    argv: list[str], needle: str, tmp_path: Path, capfd: pytest.CaptureFixture[str]
) -> None:
    argv = [str(tmp_path / a) if a in ("x", "o") else a for a in argv]
    code, err = run(argv, capfd)
    lines = err.strip().splitlines()
    assert code == 2, err
    assert len(lines) == 1, err
    assert needle in lines[0], err
    assert "Traceback" not in err
    assert not (tmp_path / "o").exists()


def test_yaw_range_at_the_limits_is_accepted() -> None:
    """±180 itself is inside the documented range (the parser accepts it; the simulator then finds poses)."""
    args = parser(["simulate"]).parse_args(["simulate", "--out", "x", "--yaw", "-180", "180", "--depth", "0.5", "0.5"])
    assert args.yaw == (-180.0, 180.0)
    assert args.depth == (0.5, 0.5)


@pytest.mark.parametrize(
    ("error", "line"),
    [
        (OSError("disk on fire"), "monodock show: error: disk on fire"),
        (
            PermissionError(13, "Permission denied", "/data/out/.est.csv.k3j_x9a2"),
            "/data/out/est.csv: Permission denied",
        ),
        (OSError(28, "No space left on device", "/data/.bundle.old.ab12cd34"), "/data/bundle: No space left on device"),
        (OSError(2, "No such file", os.fsdecode(b"/d/caf\xe9.png")), "/d/caf\\xe9.png: No such file"),
    ],
)
def test_os_errors_read_as_one_line_with_the_users_path(
    error: OSError, line: str, monkeypatch: pytest.MonkeyPatch, capfd: pytest.CaptureFixture[str]
) -> None:
    """No "error::" when the OSError has no file; an atomic write's temp name is told as the user's path."""

    def fail(_args: argparse.Namespace) -> None:
        raise error

    monkeypatch.setattr(show, "load_calibration", fail)
    code, err = run(["show", "x.png", "--out", "o.png", "--camera", "c", "--layout", "l", "--robot", "r"], capfd)
    assert code == 2
    assert err.strip() == (line if line.startswith("monodock") else f"monodock show: error: {line}")
