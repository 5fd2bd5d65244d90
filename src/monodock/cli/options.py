"""What several commands share: the one-line-error parser, calibration and nuisance options, the estimator's."""

from __future__ import annotations

import argparse
import dataclasses
import inspect
import math
import os
import re
from collections.abc import Callable, Mapping, Sequence
from typing import TYPE_CHECKING, Any

from monodock.core.camera import CameraModel
from monodock.core.layout import DockLayout
from monodock.core.robot import RobotConfig
from monodock.core.settings import Setting, flag_of, settings_of
from monodock.errors import InputError, MonodockError
from monodock.estimation.bundle import Bundle
from monodock.estimation.estimator import Estimator
from monodock.estimation.factory import REFINEMENTS, make_estimator
from monodock.estimation.factory import bundle_calibration as _bundle_calibration
from monodock.estimation.methods import METHOD_NAMES, NEEDS_BUNDLE

if TYPE_CHECKING:
    SubParsers = argparse._SubParsersAction[Any]
else:
    SubParsers = Any

__all__ = [
    "MAX_JOBS",
    "SEED_MAX",
    "SubParsers",
    "add_calibration",
    "add_camera_rate",
    "add_cluster",
    "add_command",
    "add_estimator_options",
    "add_flags",
    "add_jobs",
    "add_model_and_method",
    "add_pairing_tolerance",
    "add_recording_inputs",
    "add_refinement",
    "add_seed",
    "add_topics",
    "build_estimator",
    "bundle_calibration",
    "comma_list",
    "float_in",
    "int_in",
    "jobs",
    "load_calibration",
    "positive_seconds",
    "range_option",
    "recording_inputs",
]


def add_command(
    subparsers: SubParsers, name: str, run: Callable[[argparse.Namespace], int], **kwargs: Any
) -> argparse.ArgumentParser:
    """The sub-command ``name``, run by ``run``: its help is the first paragraph of ``run``'s docstring and its
    description the rest (argparse re-flows both), so a command's words are written once, where its code is. A ``%``
    in them is a percent sign; without a docstring (``python -OO``) the command has neither help nor description."""
    first, *rest = re.split(r"\n\s*\n", inspect.getdoc(run) or "", maxsplit=1)
    summary, description = " ".join(first.split()), " ".join(" ".join(rest).split())
    p: argparse.ArgumentParser = subparsers.add_parser(
        name, help=summary.replace("%", "%%") or None, description=description or None, **kwargs
    )
    p.set_defaults(func=run)
    return p


def add_calibration(p: argparse.ArgumentParser, *, required: bool) -> None:
    """``--camera``, ``--layout``, ``--robot``."""
    p.add_argument("--camera", required=required, help="camera file: ROS camera_info YAML or OpenCV FileStorage")
    p.add_argument("--layout", required=required, help="dock layout YAML")
    p.add_argument("--robot", required=required, help="robot YAML (camera and LiDAR mounts, front_offset)")


def load_calibration(args: argparse.Namespace) -> tuple[CameraModel, DockLayout, RobotConfig]:
    """The camera, layout and robot of the options, each the built-in default when not given."""
    camera = CameraModel.load(args.camera) if args.camera else CameraModel.default()
    layout = DockLayout.load(args.layout) if args.layout else DockLayout.default()
    robot = RobotConfig.load(args.robot) if args.robot else RobotConfig.default()
    return camera, layout, robot


def add_recording_inputs(p: argparse.ArgumentParser, *, of: str, layout: str, robot: str) -> None:
    """A recording of the robot at its dock and the files it is read with (``recording_inputs``): RECORDING,
    ``--layout`` and ``--robot`` (required), ``--camera`` (default: the recording's CameraInfo). ``of``: what the
    recording is of; ``layout``, ``robot``: the two files' help."""
    p.add_argument("recording", metavar="RECORDING", help=f"rosbag2 or ROS 1 bag of {of}")
    p.add_argument("--layout", required=True, help=layout)
    p.add_argument("--robot", required=True, help=robot)
    p.add_argument("--camera", help="camera file (default: the recording's CameraInfo)")


def recording_inputs(args: argparse.Namespace) -> tuple[DockLayout, RobotConfig, CameraModel | None]:
    """The layout, robot and camera of ``add_recording_inputs``' options, loaded in that order (the camera None
    without --camera: the recording's CameraInfo)."""
    layout, robot = DockLayout.load(args.layout), RobotConfig.load(args.robot)
    return layout, robot, CameraModel.load(args.camera) if args.camera else None


def comma_list(what: str, available: tuple[str, ...], *, everything: bool = False) -> Callable[[str], tuple[str, ...]]:
    """An argparse type: names from ``available`` separated by commas, each once, in the order given (``all``
    for every one with ``everything``); anything else is a one-line usage error naming the first unknown."""

    def parse(value: str) -> tuple[str, ...]:
        if everything and value == "all":
            return available
        names = tuple(dict.fromkeys(v.strip() for v in value.split(",") if v.strip()))
        if everything and "all" in names:
            raise argparse.ArgumentTypeError(f"'all' stands alone (every {what}), got '{value}'")
        bad = [n for n in names if n not in available]
        if bad or not names:
            choices = ("all", *available) if everything else available
            raise argparse.ArgumentTypeError(
                f"unknown {what} '{bad[0] if bad else value}' (available: {', '.join(choices)})"
            )
        return names

    return parse


# Every seed is a whole number in 0-SEED_MAX (numpy's generators refuse negative ones); worker processes 1-MAX_JOBS.
SEED_MAX = 2**32 - 1
MAX_JOBS = 64


def _bounds(low: float, high: float, low_open: bool, high_open: bool) -> str:
    return f"{'(' if low_open else '['}{low:g}, {high:g}{')' if high_open else ']'}"


def float_in(low: float, high: float, *, low_open: bool = False, high_open: bool = False) -> Callable[[str], float]:
    """An argparse type: a finite number within ``low``-``high`` (open ends excluded); anything else (NaN, inf,
    out of range, not a number) is a one-line usage error that gives the range."""
    where = _bounds(low, high, low_open, high_open)

    def parse(text: str) -> float:
        try:
            value = float(text)
        except ValueError:
            raise argparse.ArgumentTypeError(f"expected a number in {where}, got {text!r}") from None
        inside = (low < value if low_open else low <= value) and (value < high if high_open else value <= high)
        if not (math.isfinite(value) and inside):
            raise argparse.ArgumentTypeError(f"must be a number in {where}, got {text}")
        return value

    return parse


class _Ordered(argparse.Action):
    """``--flag MIN MAX``: MIN must not exceed MAX (a one-line usage error otherwise)."""

    def __call__(
        self, parser: argparse.ArgumentParser, namespace: argparse.Namespace, values: Any, option: str | None = None
    ) -> None:
        lo, hi = values
        if lo > hi:
            parser.error(f"argument {option}: MIN must not exceed MAX, got {lo:g} {hi:g}")
        setattr(namespace, self.dest, (lo, hi))


def range_option(
    p: argparse.ArgumentParser,
    flag: str,
    default: tuple[float, float],
    what: str,
    bounds: tuple[float, float],
    *,
    low_open: bool = False,
) -> None:
    """A ``--flag MIN MAX`` option: both finite and within ``bounds``, MIN <= MAX."""
    p.add_argument(
        flag,
        type=float_in(*bounds, low_open=low_open),
        nargs=2,
        default=default,
        action=_Ordered,
        metavar=("MIN", "MAX"),
        help=f"{what}, each in {_bounds(*bounds, low_open, False)}, MIN <= MAX (default {default[0]:g} {default[1]:g})",
    )


def int_in(low: int, high: int) -> Callable[[str], int]:
    """An argparse type: a whole number from ``low`` to ``high`` (a usage error, one line, otherwise)."""

    def parse(text: str) -> int:
        try:
            value = int(text)
        except ValueError:
            raise argparse.ArgumentTypeError(f"expected a whole number, got {text!r}") from None
        if not low <= value <= high:
            raise argparse.ArgumentTypeError(f"must be {low}-{high}, got {value}")
        return value

    return parse


def add_seed(p: argparse.ArgumentParser | argparse._ArgumentGroup, what: str = "seed", default: int | None = 0) -> None:
    """``--seed``: a whole number in 0-SEED_MAX."""
    shown = f" (default {default})" if default is not None else ""
    p.add_argument("--seed", type=int_in(0, SEED_MAX), default=default, help=f"{what}, 0-{SEED_MAX}{shown}")


def add_jobs(p: argparse.ArgumentParser | argparse._ArgumentGroup, default: str = "cores, at most 4") -> None:
    """``--jobs``: worker processes, 1-MAX_JOBS."""
    p.add_argument("--jobs", type=int_in(1, MAX_JOBS), help=f"worker processes, 1-{MAX_JOBS} (default: {default})")


def add_cluster(p: argparse.ArgumentParser | argparse._ArgumentGroup) -> None:
    """``--cluster``: the parallel stages on a Dask cluster (compute.cluster), else on the local cores."""
    p.add_argument(
        "--cluster",
        metavar="ADDRESS",
        help="run the parallel work on a Dask cluster: tcp://HOST:PORT of a running scheduler, or 'auto' for one on "
        "this machine (--jobs workers, default all cores); needs pip install 'monodock[cluster]' (docs/cluster.md)",
    )


def jobs(value: int | None) -> int:
    """Worker processes: the option's value, else the cores (at most 4)."""
    return value if value and value > 0 else max(1, min(4, os.cpu_count() or 1))


def positive_seconds(flag: str, value: float) -> float:
    """A positive, finite number of seconds, or InputError naming the flag."""
    if not (value > 0 and math.isfinite(value)):
        raise InputError(f"{flag} must be a positive number of seconds, got {value}")
    return value


def add_pairing_tolerance(p: argparse.ArgumentParser | argparse._ArgumentGroup, what: str) -> None:
    """``--tolerance``: an image and a scan pair when their stamps are at most this far apart, s, in (0, 10] (default
    0.05, ``calibrate.extrinsics.PAIRING_TOLERANCE_S``); ``what``: its help."""
    p.add_argument("--tolerance", type=float_in(0.0, 10.0, low_open=True), default=0.05, help=what)


def add_camera_rate(p: argparse.ArgumentParser | argparse._ArgumentGroup, what: str) -> None:
    """``--camera-rate``: the simulated camera's frames per second, 1-240 (default 15); ``what``: its help."""
    p.add_argument("--camera-rate", type=float_in(1.0, 240.0), default=15.0, help=what)


def add_topics(p: argparse.ArgumentParser) -> None:
    """A recording's topics (found by message type by default) and the image/scan pairing tolerance."""
    g = p.add_argument_group("recording topics (default: found by message type)")
    g.add_argument("--image-topic", help="sensor_msgs/Image or CompressedImage topic")
    g.add_argument("--camera-info-topic", help="sensor_msgs/CameraInfo topic")
    g.add_argument("--scan-topic", help="sensor_msgs/LaserScan topic")
    add_pairing_tolerance(g, "pair an image with a scan at most this far in stamp, s, in (0, 10] (0.05)")


def _flag_help(setting: Setting, helps: Mapping[str, str]) -> str | None:
    if setting.key in helps:
        text = helps[setting.key]
    else:
        text = setting.meta.help if setting.meta.cli_help is None else setting.meta.cli_help
    return text or None


def _flag_type(parse: Callable[[str], Any]) -> Callable[[str], Any]:
    """``parse`` as argparse's type: its error's text is the usage error, word for word."""

    def flag_type(word: str) -> Any:
        try:
            return parse(word)
        except (ValueError, MonodockError) as exc:
            raise argparse.ArgumentTypeError(str(exc)) from None

    flag_type.__name__ = parse.__name__
    return flag_type


def add_flags(
    p: argparse.ArgumentParser,
    cls: type[Any],
    *,
    first: Sequence[str] = (),
    skip: Sequence[str] = (),
    helps: Mapping[str, str] | None = None,
) -> None:
    """A flag per setting of an options class (``settings.flag_of``: ``--kebab-name``, or the one it declares, a
    positional for a name without dashes), its default the class's: ``first`` in that order (the flags' order in
    ``--help`` since before the declarations), then the others in declaration order; ``skip`` has flags added
    elsewhere. ``settings.to_argv`` is the inverse.

    A real is ``type=float`` unless the setting parses its words itself (a node checks its parameters in their own
    words), a choice of strings its choices, a boolean ``store_true`` when it defaults to false, else
    ``--x``/``--no-x``. ``helps`` gives a flag words of its own for this command, where ``cli_help`` (else
    ``help``) will not do.
    """
    declared = {s.key: s for s in settings_of(cls) if flag_of(s) is not None and s.key not in skip}
    for key in [*(k for k in first if k in declared), *(k for k in declared if k not in first)]:
        s = declared[key]
        flag = flag_of(s)
        assert flag is not None
        kw: dict[str, Any] = {"help": _flag_help(s, helps or {})}
        if flag.startswith("-") and flag.lstrip("-").replace("-", "_") != key:
            kw["dest"] = key
        if s.type is bool and s.default:
            kw.update(action=argparse.BooleanOptionalAction, default=True)
        elif s.type is bool:
            kw["action"] = "store_true"
        else:
            if s.default is not dataclasses.MISSING:
                kw["default"] = s.default
            if s.meta.parse is not None:
                kw["type"] = _flag_type(s.meta.parse)
            elif s.type in (float, int):
                kw["type"] = s.type
            if s.meta.choices:
                kw["choices"] = s.meta.choices
        p.add_argument(flag, **kw)


def add_model_and_method(p: argparse.ArgumentParser, methods: tuple[str, ...] = METHOD_NAMES) -> None:
    """``--model`` and ``--method``: the estimator's bundle and method (``build_estimator``)."""
    p.add_argument("--model", help="model bundle (carries its camera, layout and mounts; --camera may override)")
    p.add_argument(
        "--method",
        choices=methods,
        help="regression: the papers' models (default with --model); pnp: marker 2 alone (IPPE_SQUARE), the "
        "papers' baseline; board: all visible markers (default without --model); fused: planar PnP on "
        "bias-free corners combined with the regression, with a covariance (needs --model)",
    )


def add_refinement(p: argparse.ArgumentParser) -> None:
    """``--refinement``: the ArUco corner refinement (``build_estimator``)."""
    p.add_argument("--refinement", choices=REFINEMENTS, default="subpix", help="ArUco corner refinement")


def add_estimator_options(
    p: argparse.ArgumentParser, *, methods: tuple[str, ...] = METHOD_NAMES, camera_help: str, robot_help: str
) -> None:
    """The options of ``build_estimator``."""
    add_model_and_method(p, methods)
    p.add_argument("--camera", help=camera_help)
    p.add_argument("--layout", help="dock layout YAML (with --model: must match the bundle's)")
    p.add_argument("--robot", help=robot_help)
    add_refinement(p)


def build_estimator(args: argparse.Namespace) -> Estimator:
    """The Estimator of ``--model`` / ``--method`` / ``--camera --layout --robot`` (``estimation.factory``)."""
    if not args.model:
        if args.method in NEEDS_BUNDLE:
            raise InputError(f"the {args.method} method needs --model BUNDLE")
        missing = [f"--{k}" for k in ("camera", "layout", "robot") if not getattr(args, k, None)]
        if missing:
            raise InputError(f"without --model, give {' '.join(missing)} (the PnP methods need the calibration)")
    return make_estimator(
        method=args.method,
        bundle=args.model,
        camera=getattr(args, "camera", None),
        layout=getattr(args, "layout", None),
        robot=getattr(args, "robot", None),
        refinement=getattr(args, "refinement", "subpix"),
        check_scale=True,
    )


def bundle_calibration(args: argparse.Namespace, bundle: Bundle) -> tuple[CameraModel, DockLayout, RobotConfig]:
    """The bundle's camera, layout and mounts; --camera and --robot override, --layout must match."""
    return _bundle_calibration(
        bundle,
        camera=getattr(args, "camera", None),
        layout=getattr(args, "layout", None),
        robot=getattr(args, "robot", None),
    )
