"""A deterministic catalogue of hostile inputs, grouped by family, each judged against issue 18's contract.

Every case builds its input in a folder of its own from the valid world (``world.py``), runs one monodock command
in-process (or, for the docking config, its library loader; for interruption, a subprocess) and is judged by
``harness.judge``. ``test_catalogue.py`` runs every case as a test; ``run_catalogue.py`` prints the table of
outcomes per family.
"""

from __future__ import annotations

import contextlib
import json
import math
import os
import shutil
import sys
from collections.abc import Callable
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import cv2
import numpy as np
import pyarrow as pa
import pyarrow.parquet as pq

from fuzz.harness import UNKNOWN_MARK, Expect, Run, run_cli
from fuzz.hostile import (
    DELETE,
    HOSTILE_VALUES,
    HUGE_INT,
    alias_bomb_yaml,
    deep_list_json,
    deep_list_yaml,
    dump_json,
    dump_yaml,
    flip_bytes,
    jpeg_with_size,
    plausible_camera,
    plausible_layout,
    plausible_robot,
    png_with_ihdr,
    set_path,
)
from fuzz.world import TRUTH, World, frames_of, opencv_camera_text, write_recording
from monodock.core.camera import CameraModel
from monodock.core.layout import DockLayout
from monodock.core.robot import RobotConfig
from monodock.core.settings import to_mapping
from monodock.dock.config import DockingConfig, docking_config_to_dict
from monodock.estimation.bundle import seal_manifest

__all__ = ["CASES", "FAMILIES", "Case", "run_case"]

F_CAMERA = "camera, ROS YAML"
F_CAMERA_CV = "camera, OpenCV FileStorage"
F_LAYOUT = "layout"
F_ROBOT = "robot"
F_DOCKING = "docking config"
F_BUNDLE = "bundle manifest"
F_DATASET = "dataset"
F_IMAGE = "images and video"
F_RECORDING = "recording"
F_NUMERIC = "CLI numeric options"
F_OUTPUT = "outputs and --force"
F_INTERRUPT = "interruption (slow)"
FAMILIES = (
    F_CAMERA,
    F_CAMERA_CV,
    F_LAYOUT,
    F_ROBOT,
    F_DOCKING,
    F_BUNDLE,
    F_DATASET,
    F_IMAGE,
    F_RECORDING,
    F_NUMERIC,
    F_OUTPUT,
    F_INTERRUPT,
)

TRUTH_ROW = (TRUTH.x, TRUTH.y, TRUTH.yaw_deg)

# A case's builder writes its input into the folder and returns what to run and what the input deserves.
Plan = tuple[list[str], Expect]
Builder = Callable[[World, Path], Plan]


@dataclass(frozen=True)
class Case:
    """One hostile input: family, a short unique name, and its builder (or, for ``library``, a loader)."""

    family: str
    name: str
    build: Builder
    library: Callable[[World, Path], Run] | None = None
    slow: bool = False

    @property
    def id(self) -> str:
        return f"{self.family.split(',')[0].split(' ')[0]}:{self.name}"


CASES: list[Case] = []


def case(family: str, name: str, *, slow: bool = False) -> Callable[[Builder], Builder]:
    def add(build: Builder) -> Builder:
        CASES.append(Case(family, name, build, slow=slow))
        return build

    return add


def add(family: str, name: str, build: Builder) -> None:
    CASES.append(Case(family, name, build))


# --- running one case ---------------------------------------------------------------------------------


def run_case(c: Case, world: World, folder: Path, capfd: Any = None) -> tuple[Run, Expect]:
    """Build and run one case in ``folder`` (created fresh)."""
    if folder.exists():
        shutil.rmtree(folder)
    folder.mkdir(parents=True)
    argv, expect = c.build(world, folder)
    if c.library is not None:
        return c.library(world, folder), expect
    if c.slow and argv and argv[0] == "__subprocess__":
        from fuzz.interrupt import run_interrupted

        return run_interrupted(argv[1:], folder), expect
    run = run_cli(argv, inputs=expect.inputs, outputs=expect.outputs, capfd=capfd)
    return run, expect


# --- commands the file cases run -------------------------------------------------------------------------


def estimate(
    world: World,
    folder: Path,
    *,
    camera: Path | None = None,
    layout: Path | None = None,
    robot: Path | None = None,
    image: Path | None = None,
    refuse: bool = False,
    truth: bool = False,
    strict: bool = False,
    extra: tuple[str, ...] = (),
) -> Plan:
    """``estimate`` of the dock image with some calibration files swapped.

    ``refuse``: the file is implausible; exit 0 is allowed only without a valid row, unless ``strict`` (a value that
    is not a finite number at all: the file must be refused, naming it, not turned into "no PnP solution" rows).
    """
    out = folder / "EST.csv"
    img = image or world.image
    argv = ["estimate", str(img), *world.calibration(camera, layout, robot), "--out", str(out), *extra]
    inputs = tuple(p for p in (camera, layout, robot, img) if p is not None)
    expect = Expect(
        refuse=refuse,
        truth=TRUTH_ROW if truth else None,
        outputs=(out,),
        inputs=inputs,
        implausible_ok_without_valid=not strict,
    )
    return argv, expect


# HOSTILE_VALUES that are no finite number at all: a file holding one must be refused outright.
INVALID = {"nan", "inf", "-inf", "huge-int", "string", "list", "mapping", "null", "bool", "empty", "1e999"}


def write(folder: Path, name: str, content: str | bytes) -> Path:
    p = folder / name
    if isinstance(content, str):
        p.write_text(content, encoding="utf-8")
    else:
        p.write_bytes(content)
    return p


# --- camera, ROS camera_info YAML ---------------------------------------------------------------------

CAM = CameraModel.default().to_ros_dict()
CAM_FIELDS: dict[str, tuple[Any, ...]] = {
    "image_width": ("image_width",),
    "image_height": ("image_height",),
    "fx": ("camera_matrix", "data", 0),
    "cx": ("camera_matrix", "data", 2),
    "fy": ("camera_matrix", "data", 4),
    "cy": ("camera_matrix", "data", 5),
    "k1": ("distortion_coefficients", "data", 0),
    "k2": ("distortion_coefficients", "data", 1),
    "p1": ("distortion_coefficients", "data", 2),
    "p2": ("distortion_coefficients", "data", 3),
    "k3": ("distortion_coefficients", "data", 4),
}
# Per field, the HOSTILE_VALUES that keep a camera plausible (every other one must be refused).
_CAM_OK = {
    "k1": {"1e-300", "zero"},
    "k2": {"1e-300", "zero"},
    "p1": {"1e-300", "zero"},
    "p2": {"1e-300", "zero"},
    "k3": {"1e-300", "zero", "negative"},
    "cx": {"1e-300", "zero"},
    "cy": {"1e-300", "zero"},
}


def _camera_value_case(field: str, value: Any, label: str = "") -> Builder:
    def build(world: World, folder: Path) -> Plan:
        data = set_path(CAM, CAM_FIELDS[field], value)
        cam = write(folder, "camera.yaml", dump_yaml(data))
        return estimate(world, folder, camera=cam, refuse=not plausible_camera(data), strict=label in INVALID)

    return build


for _field in ("image_width", "fx", "cx", "k1", "p2"):
    for _label, _value in HOSTILE_VALUES:
        add(F_CAMERA, f"{_field}={_label}", _camera_value_case(_field, _value, _label))

# Implausible but finite: the k1 1e6 (valid poses 49 m away; truth 1.85 m) and friends.
for _field, _value, _ok in [
    ("k1", 1e6, False),
    ("k1", -1e6, False),
    ("k1", 50.0, False),
    ("k2", 1e4, False),
    ("k3", -1e5, False),
    ("p1", 10.0, False),
    ("fx", 61.0, False),  # 0.095x the image width
    ("fx", 6500.0, False),  # 10.2x
    ("fy", 1e5, False),
    ("cx", -700.0, False),
    ("cy", 5000.0, False),
    ("image_width", 60000, False),
    ("image_width", 641, False),  # not the image's size: each frame is refused
    ("image_height", 1, False),
    ("fx", 615, True),  # an int where a float was: the same camera
    ("image_width", 640.0, None),  # a float where an int was
]:
    if _ok is True:
        add(
            F_CAMERA,
            f"{_field}={_value!r}",
            lambda w, f, fld=_field, v=_value: estimate(
                w, f, camera=write(f, "camera.yaml", dump_yaml(set_path(CAM, CAM_FIELDS[fld], v))), truth=True
            ),
        )
    else:
        add(
            F_CAMERA,
            f"{_field}={_value!r}",
            lambda w, f, fld=_field, v=_value, ok=_ok: estimate(
                w, f, camera=write(f, "camera.yaml", dump_yaml(set_path(CAM, CAM_FIELDS[fld], v))), refuse=ok is False
            ),
        )


def _camera_text_case(
    text: str | bytes, *, refuse: bool = True, truth: bool = False, name: str = "camera.yaml", strict: bool = False
) -> Builder:
    def build(world: World, folder: Path) -> Plan:
        cam = write(folder, name, text)
        return estimate(world, folder, camera=cam, refuse=refuse, truth=truth, strict=strict)

    return build


_CAM_TEXT = dump_yaml(CAM)
for _key in CAM:
    required = _key in ("image_width", "image_height", "camera_matrix", "distortion_coefficients")
    add(
        F_CAMERA,
        f"missing {_key}",
        _camera_text_case(dump_yaml(set_path(CAM, (_key,), DELETE)), refuse=required, truth=not required),
    )
for _label, _text, _refuse in [
    ("unknown key", _CAM_TEXT + f"{UNKNOWN_MARK}: 1\n", False),
    ("alias bomb in an unknown key", _CAM_TEXT + alias_bomb_yaml(UNKNOWN_MARK), False),
    (
        "alias bomb as camera_matrix data",
        alias_bomb_yaml("bomb") + dump_yaml(set_path(CAM, ("camera_matrix", "data"), "BOMB")).replace("BOMB", "*b5"),
        True,
    ),
    ("python object tag", "!!python/object/apply:os.system ['echo pwned']\n", True),
    ("object tag on a value", _CAM_TEXT.replace("image_width: 640", "image_width: !!python/name:os.system"), True),
    ("nested lists 100,000 deep", deep_list_yaml(), True),
    ("nested lists 100,000 deep as fx", _CAM_TEXT.replace("[615.0,", "[" + deep_list_yaml() + ","), True),
    ("a list at the top", "[1, 2, 3]\n", True),
    ("a scalar at the top", "640\n", True),
    ("empty file", "", True),
    ("camera_matrix of 8 values", dump_yaml(set_path(CAM, ("camera_matrix", "data"), [615.0] * 8)), True),
    ("camera_matrix of strings", dump_yaml(set_path(CAM, ("camera_matrix", "data"), ["615"] * 9)), True),
    ("camera_matrix a number", dump_yaml(set_path(CAM, ("camera_matrix",), 615.0)), True),
    ("distortion of 3 values", dump_yaml(set_path(CAM, ("distortion_coefficients", "data"), [0.1, 0.0, 0.0])), True),
    (
        "distortion of 8 with plumb_bob",
        dump_yaml(set_path(CAM, ("distortion_coefficients", "data"), [0.0] * 8)),
        True,
    ),
    ("distortion_model equidistant", dump_yaml(set_path(CAM, ("distortion_model",), "equidistant")), True),
    ("distortion_model a number", dump_yaml(set_path(CAM, ("distortion_model",), 5)), True),
    ("camera_name a list", dump_yaml(set_path(CAM, ("camera_name",), [1, 2])), True),
    ("camera_name 100 kB", dump_yaml(set_path(CAM, ("camera_name",), "x" * 100_000)), False),
    ("skewed K (K[1]=50)", dump_yaml(set_path(CAM, ("camera_matrix", "data", 1), 50.0)), True),
    ("K[8]=0", dump_yaml(set_path(CAM, ("camera_matrix", "data", 8), 0.0)), True),
    ("K[6]=1", dump_yaml(set_path(CAM, ("camera_matrix", "data", 6), 1.0)), True),
    ("tab-indented YAML", _CAM_TEXT.replace("  ", "\t"), True),
    ("duplicate key", _CAM_TEXT + "image_width: 1280\n", True),
]:
    add(F_CAMERA, _label, _camera_text_case(_text, refuse=_refuse))
for _label, _bytes in [
    ("non-UTF-8 bytes in a value", _CAM_TEXT.encode().replace(b"sim_camera", b"sim_\xff\xfecamera")),
    ("UTF-16 file", _CAM_TEXT.encode("utf-16")),
    ("NUL bytes", _CAM_TEXT.encode().replace(b"\n", b"\x00\n", 3)),
    ("binary garbage", bytes(range(256)) * 8),
]:
    add(F_CAMERA, _label, _camera_text_case(_bytes))
for _frac in (0.1, 0.25, 0.5, 0.75, 0.9):
    add(F_CAMERA, f"truncated at {_frac:.0%}", _camera_text_case(_CAM_TEXT[: int(len(_CAM_TEXT) * _frac)]))
add(F_CAMERA, "the valid file", lambda w, f: estimate(w, f, camera=w.camera, truth=True))
add(
    F_CAMERA,
    "non-UTF-8 file name",
    lambda w, f: estimate(w, f, camera=write(f, os.fsdecode(b"cam\xff\xfe.yaml"), _CAM_TEXT), truth=True),
)
add(F_CAMERA, "camera file is a folder", lambda w, f: estimate(w, f, camera=f, refuse=True))
add(F_CAMERA, "camera file missing", lambda w, f: estimate(w, f, camera=f / "none.yaml", refuse=True))
add(F_CAMERA, "camera file is /dev/zero", lambda w, f: estimate(w, f, camera=Path("/dev/zero"), refuse=True))


# --- camera, OpenCV FileStorage --------------------------------------------------------------------------

_CV_TOKENS = [
    ("nan", ".nan", ".nan"),
    ("inf", ".inf", ".inf"),
    ("1e308", "1e308", "1e308"),
    ("1e999", "1e999", "1e999"),
    ("1e-300", "1e-300", "1e-300"),
    ("zero", "0.", "0."),
    ("negative", "-1.", "-1."),
    ("huge-int", "9" * 5000, "9" * 5000),
    ("string", "abc", "abc"),
    ("empty", "", ""),
]
_CV_OK = {"k1": {"1e-300", "zero"}, "k2": {"1e-300", "zero"}, "p1": {"1e-300", "zero"}, "k3": {"1e-300", "zero"}}
for _fmt in ("yaml", "xml"):
    for _field in ("width", "fx", "cy", "k1"):
        for _label, _ytok, _xtok in _CV_TOKENS:
            tok = _ytok if _fmt == "yaml" else _xtok
            if _fmt == "xml" and _label == "nan":
                tok = "nan"
            if _fmt == "xml" and _label == "inf":
                tok = "inf"
            ok = _label in _CV_OK.get(_field, set()) or (_field in ("cx", "cy") and _label in ("zero", "1e-300"))
            add(
                F_CAMERA_CV,
                f"{_fmt} {_field}={_label}",
                _camera_text_case(
                    opencv_camera_text(_fmt, **{_field: tok}),
                    refuse=not ok,
                    name=f"camera.{_fmt}",
                    strict=_label in INVALID,
                ),
            )
    add(F_CAMERA_CV, f"{_fmt} k1=1e6", _camera_text_case(opencv_camera_text(_fmt, k1="1e6"), name=f"camera.{_fmt}"))
    add(
        F_CAMERA_CV,
        f"{_fmt} valid",
        _camera_text_case(opencv_camera_text(_fmt), refuse=False, truth=True, name=f"camera.{_fmt}"),
    )
    _text = opencv_camera_text(_fmt)
    for _frac in (0.2, 0.5, 0.8, 0.95):
        add(
            F_CAMERA_CV,
            f"{_fmt} truncated at {_frac:.0%}",
            _camera_text_case(_text[: int(len(_text) * _frac)], name=f"camera.{_fmt}"),
        )
    add(
        F_CAMERA_CV,
        f"{_fmt} rows=2",
        _camera_text_case(
            _text.replace("rows: 3", "rows: 2").replace("<rows>3</rows>", "<rows>2</rows>"), name=f"camera.{_fmt}"
        ),
    )
    add(
        F_CAMERA_CV,
        f"{_fmt} dt=u",
        _camera_text_case(_text.replace("dt: d", "dt: u").replace("<dt>d</dt>", "<dt>u</dt>"), name=f"camera.{_fmt}"),
    )
    add(
        F_CAMERA_CV,
        f"{_fmt} no camera_matrix",
        _camera_text_case(_text.replace("camera_matrix", "cam_mat"), name=f"camera.{_fmt}"),
    )
    add(
        F_CAMERA_CV,
        f"{_fmt} garbage after header",
        _camera_text_case(_text[:20] + "\x01\x02{{{[[[<<<", name=f"camera.{_fmt}"),
    )
    add(
        F_CAMERA_CV,
        f"{_fmt} non-UTF-8",
        _camera_text_case(_text.encode().replace(b"640", b"6\xff0", 1), name=f"camera.{_fmt}"),
    )
add(F_CAMERA_CV, "json empty object", _camera_text_case("{}", name="camera.json"))
add(F_CAMERA_CV, "json garbage", _camera_text_case('{"camera_matrix": [', name="camera.json"))
add(
    F_CAMERA_CV,
    "yaml cx=.nan (issue: 'no PnP solution' instead of naming the file)",
    _camera_text_case(opencv_camera_text("yaml", cx=".nan"), name="camera.yaml", strict=True),
)
add(
    F_CAMERA,
    "k1 1e6 (issue: valid poses 49 m away, truth 1.85 m)",
    _camera_value_case("k1", 1e6, "1e6"),
)
add(F_CAMERA_CV, "yaml header only", _camera_text_case("%YAML:1.0\n", name="camera.yaml"))
add(F_CAMERA_CV, "xml header only", _camera_text_case('<?xml version="1.0"?>\n', name="camera.xml"))
add(
    F_CAMERA_CV,
    "xml unclosed",
    _camera_text_case('<?xml version="1.0"?>\n<opencv_storage><image_width>640', name="camera.xml"),
)
add(
    F_CAMERA_CV,
    "yaml image_size sequence of 3",
    _camera_text_case(
        opencv_camera_text("yaml").replace("image_width: 640\nimage_height: 480\n", "image_size: [640, 480, 1]\n"),
        name="camera.yaml",
    ),
)
add(
    F_CAMERA_CV,
    "yaml image_size nan",
    _camera_text_case(
        opencv_camera_text("yaml").replace("image_width: 640\nimage_height: 480\n", "image_size: [.nan, 480]\n"),
        name="camera.yaml",
    ),
)


# --- layout ------------------------------------------------------------------------------------------------

LAYOUT = to_mapping(DockLayout.default())
LAYOUT_FIELDS: dict[str, tuple[Any, ...]] = {
    "marker_size": ("marker_size",),
    "left.y": ("markers", "left", "y"),
    "center.id": ("markers", "center", "id"),
}
_LAYOUT_OK = {"center.z": {"1e-300", "zero", "negative"}, "center.id": {"zero"}, "left.y": set(), "right.y": set()}


def _layout_case(
    text: str | bytes, *, refuse: bool, truth: bool = False, label: bool = False, strict: bool = False
) -> Builder:
    def build(world: World, folder: Path) -> Plan:
        lay = write(folder, "layout.yaml", text)
        if label:
            out = folder / "ds.parquet"
            argv = ["label", str(world.recording), "--layout", str(lay), "--out", str(out)]
            return argv, Expect(refuse=refuse, outputs=(out,), inputs=(lay, world.recording))
        return estimate(world, folder, layout=lay, refuse=refuse, truth=truth, strict=strict)

    return build


for _field, _path in list(LAYOUT_FIELDS.items())[:3]:
    for _label, _value in HOSTILE_VALUES:
        _data = set_path(LAYOUT, _path, _value)
        add(
            F_LAYOUT,
            f"{_field}={_label}",
            _layout_case(dump_yaml(_data), refuse=not plausible_layout(_data), strict=_label in INVALID),
        )
for _label, _path, _value, _refuse in [
    ("marker_size 1e-300 (issue)", ("marker_size",), 1e-300, True),
    ("marker_size 4 mm", ("marker_size",), 0.004, True),
    ("marker_size 2.5 m", ("marker_size",), 2.5, True),
    ("marker_size 0.05 (wrong, plausible)", ("marker_size",), 0.05, None),
    ("y 1e308 (issue)", ("markers", "left", "y"), 1e308, True),
    ("y 6 m", ("markers", "left", "y"), 6.0, True),
    ("z -1e308", ("markers", "center", "z"), -1e308, True),
    ("id 50 (outside the dictionary)", ("markers", "center", "id"), 50, True),
    ("id huge", ("markers", "center", "id"), HUGE_INT, True),
    ("dictionary unknown", ("dictionary",), "DICT_9X9_1", True),
    ("dictionary getattr trap", ("dictionary",), "DICT___class__", True),
    ("dictionary a list", ("dictionary",), ["DICT_4X4_50"], True),
    ("markers a list", ("markers",), [1, 2, 3], True),
    ("a marker missing", ("markers", "right"), DELETE, True),
    ("an extra marker, named", ("markers",), {**LAYOUT["markers"], "top": {"id": 4, "y": 0, "z": 0.6}}, False),
    ("an extra marker, badly named", ("markers",), {**LAYOUT["markers"], "Top-1": {"id": 4, "y": 0, "z": 0.6}}, True),
    ("an extra marker, a papers' id", ("markers",), {**LAYOUT["markers"], "top": {"id": 2, "y": 0, "z": 0.6}}, True),
    ("an extra marker over marker 2", ("markers",), {**LAYOUT["markers"], "top": {"id": 4, "y": 0, "z": 0.32}}, True),
    (
        "17 markers",
        ("markers",),
        {**LAYOUT["markers"], **{f"m{i}": {"id": 4 + i, "y": 0, "z": 0.5 + 0.2 * i} for i in range(14)}},
        True,
    ),
]:
    if _refuse is None:
        add(F_LAYOUT, _label, _layout_case(dump_yaml(set_path(LAYOUT, _path, _value)), refuse=False))
    else:
        add(F_LAYOUT, _label, _layout_case(dump_yaml(set_path(LAYOUT, _path, _value)), refuse=_refuse))
_LAY_TEXT = dump_yaml(LAYOUT)
for _key in LAYOUT:
    add(F_LAYOUT, f"missing {_key}", _layout_case(dump_yaml(set_path(LAYOUT, (_key,), DELETE)), refuse=True))
for _label, _text, _refuse, _label_cmd in [
    ("the valid file", _LAY_TEXT, False, False),
    ("unknown key (estimate)", _LAY_TEXT + f"{UNKNOWN_MARK}: 1\n", False, False),
    ("unknown key (label: never copied into the dataset)", _LAY_TEXT + f"{UNKNOWN_MARK}: 1\n", False, True),
    (
        "alias bomb in an unknown key, label (issue: expanded into the dataset)",
        _LAY_TEXT + alias_bomb_yaml(UNKNOWN_MARK),
        False,
        True,
    ),
    ("alias bomb in an unknown key (estimate)", _LAY_TEXT + alias_bomb_yaml(UNKNOWN_MARK), False, False),
    ("python object tag", "!!python/object/apply:os.system ['echo pwned']\n", True, False),
    ("nested lists 100,000 deep", deep_list_yaml(), True, False),
    ("nested mapping 100,000 deep", "a: " * 1 + "{a: " * 100_000 + "1" + "}" * 100_000, True, False),
    ("empty file", "", True, False),
    ("truncated at 30%", _LAY_TEXT[: len(_LAY_TEXT) * 3 // 10], True, False),
    ("truncated at 70%", _LAY_TEXT[: len(_LAY_TEXT) * 7 // 10], True, False),
    ("non-UTF-8", _LAY_TEXT.encode().replace(b"DICT", b"D\xffICT"), True, False),
]:
    add(F_LAYOUT, _label, _layout_case(_text, refuse=_refuse, truth=_label == "the valid file", label=_label_cmd))


# --- robot ---------------------------------------------------------------------------------------------

ROBOT = to_mapping(RobotConfig.default())
ROBOT_FIELDS: dict[str, tuple[Any, ...]] = {
    "camera_mount.x": ("camera_mount", "x"),
    "camera_mount.pitch": ("camera_mount", "pitch"),
    "front_offset": ("front_offset",),
}
_ROBOT_OK = {
    "camera_mount.x": {"1e-300", "zero", "negative"},
    "camera_mount.z": {"1e-300", "zero", "negative"},
    "camera_mount.pitch": {"1e-300", "zero", "negative"},
    "camera_mount.yaw": {"1e-300", "zero", "negative"},
    "laser_mount.y": {"1e-300", "zero", "negative"},
    "front_offset": {"1e-300", "zero"},
}


def _robot_case(data: Any, *, refuse: bool, text: str | bytes | None = None, strict: bool = False) -> Builder:
    def build(world: World, folder: Path) -> Plan:
        rob = write(folder, "robot.yaml", text if text is not None else dump_yaml(data))
        return estimate(world, folder, robot=rob, refuse=refuse, strict=strict)

    return build


for _field, _path in ROBOT_FIELDS.items():
    for _label, _value in HOSTILE_VALUES:
        _data = set_path(ROBOT, _path, _value)
        add(
            F_ROBOT,
            f"{_field}={_label}",
            _robot_case(_data, refuse=not plausible_robot(_data), strict=_label in INVALID),
        )
for _label, _path, _value in [
    ("camera mount x 1e308 m (issue)", ("camera_mount", "x"), 1e308),
    ("camera mount x 6 m", ("camera_mount", "x"), 6.0),
    ("camera pitch 1e300 rad (issue)", ("camera_mount", "pitch"), 1e300),
    ("camera pitch 4 rad", ("camera_mount", "pitch"), 4.0),
    ("camera roll -7 rad", ("camera_mount", "roll"), -7.0),
    ("laser yaw 100 rad", ("laser_mount", "yaw"), 100.0),
    ("front_offset 1e308", ("front_offset",), 1e308),
    ("max_angular_speed 1e308", ("max_angular_speed",), 1e308),
    ("camera_mount a list", ("camera_mount",), [0.17, 0, 0.25]),
    ("camera_mount missing", ("camera_mount",), DELETE),
    ("laser_mount missing", ("laser_mount",), DELETE),
    ("front_offset missing", ("front_offset",), DELETE),
    ("camera_mount.x missing", ("camera_mount", "x"), DELETE),
]:
    add(F_ROBOT, _label, _robot_case(set_path(ROBOT, _path, _value), refuse=True))
_ROB_TEXT = dump_yaml(ROBOT)
add(F_ROBOT, "the valid file", lambda w, f: estimate(w, f, robot=w.robot, truth=True))
add(F_ROBOT, "unknown key", _robot_case(None, refuse=False, text=_ROB_TEXT + f"{UNKNOWN_MARK}: 1\n"))
add(F_ROBOT, "alias bomb", _robot_case(None, refuse=False, text=_ROB_TEXT + alias_bomb_yaml(UNKNOWN_MARK)))
add(F_ROBOT, "python object tag", _robot_case(None, refuse=True, text="!!python/object/new:os.system [ls]\n"))
add(F_ROBOT, "nested lists 100,000 deep", _robot_case(None, refuse=True, text=deep_list_yaml()))
add(F_ROBOT, "truncated at 50%", _robot_case(None, refuse=True, text=_ROB_TEXT[: len(_ROB_TEXT) // 2]))
add(
    F_ROBOT,
    "non-UTF-8",
    _robot_case(None, refuse=True, text=_ROB_TEXT.encode().replace(b"camera_mount", b"c\xffamera_mount")),
)
add(F_ROBOT, "empty", _robot_case(None, refuse=True, text=""))


# --- docking config (its library loader: dock-sim would run minutes of simulation on a good one) ----------

DOCKING = docking_config_to_dict(DockingConfig())


def _docking_library(text: str | bytes, refuse: bool) -> Callable[[World, Path], Run]:
    def run(world: World, folder: Path) -> Run:
        from fuzz.harness import run_library

        path = write(folder, "docking.yaml", text)

        def load() -> None:
            from monodock.dock.config import docking_config_from_dict, load_docking_config

            config = load_docking_config(path)
            values = _leaves(docking_config_to_dict(config))
            bad = [v for v in values if isinstance(v, float) and not (math.isfinite(v) and abs(v) <= 1e6)]
            if bad:
                raise AssertionError(f"loaded a docking config holding {bad[0]!r}")
            docking_config_from_dict(docking_config_to_dict(config))

        return run_library(load, inputs=(path,))

    return run


def _leaves(data: Any) -> list[Any]:
    if isinstance(data, dict):
        return [x for v in data.values() for x in _leaves(v)]
    return [data]


def _docking_paths() -> list[tuple[str, tuple[str, ...]]]:
    out = []
    for k, v in DOCKING.items():
        if isinstance(v, dict):
            out += [(f"{k}.{k2}", (k, k2)) for k2, v2 in v.items() if isinstance(v2, float)][:1]
        elif isinstance(v, float) and len(out) < 2:
            out.append((k, (k,)))
    return out


def _add_docking(name: str, text: str | bytes, refuse: bool) -> None:
    CASES.append(
        Case(F_DOCKING, name, lambda w, f: ([], Expect(refuse=refuse)), library=_docking_library(text, refuse))
    )


for _name, _path in _docking_paths():
    for _label, _value in HOSTILE_VALUES:
        _ok = _label in ("1e-300", "zero", "negative")  # the dataclass's own ranges decide; finite small is fine
        _add_docking(f"{_name}={_label}", dump_yaml(set_path(DOCKING, _path, _value)), not _ok and _label != "1e-300")
_DOCK_TEXT = dump_yaml(DOCKING)
for _label, _text, _refuse in [
    ("the valid file", _DOCK_TEXT, False),
    ("empty mapping", "{}\n", False),
    ("unknown key", _DOCK_TEXT + f"{UNKNOWN_MARK}: 1\n", True),
    ("calculate_frames huge int", dump_yaml(set_path(DOCKING, ("calculate_frames",), HUGE_INT)), True),
    ("calculate_frames 10**9", dump_yaml(set_path(DOCKING, ("calculate_frames",), 10**9)), True),
    ("refine_while_moving a string", dump_yaml(set_path(DOCKING, ("refine_while_moving",), "yes")), True),
    ("planner a list", dump_yaml(set_path(DOCKING, ("planner",), [1])), True),
    ("alias bomb", alias_bomb_yaml("x"), True),
    ("nested lists 100,000 deep", deep_list_yaml(), True),
    ("python object tag", "!!python/object/apply:os.system ['echo pwned']\n", True),
    ("truncated at 50%", _DOCK_TEXT[: len(_DOCK_TEXT) // 2], True),
    ("non-UTF-8", b"\xff\xfe" + _DOCK_TEXT.encode(), True),
]:
    _add_docking(_label, _text, _refuse)


# --- bundle manifest ------------------------------------------------------------------------------------


def _bundle_case(
    mutate: Callable[[dict[str, Any]], Any], *, seal: bool = True, refuse: bool = True, raw: str | bytes | None = None
) -> Builder:
    """``estimate --model`` with the bundle's manifest mutated (and re-sealed, so the edit reaches the checks
    behind the digest, unless ``seal`` is false); ``raw`` replaces the manifest's text outright."""

    def build(world: World, folder: Path) -> Plan:
        b = folder / "bundle"
        shutil.copytree(world.bundle, b)
        mf = b / "bundle.json"
        if raw is not None:
            mf.write_bytes(raw.encode() if isinstance(raw, str) else raw)
        else:
            manifest = mutate(json.loads(mf.read_text()))
            if seal and isinstance(manifest, dict):
                with contextlib.suppress(TypeError, ValueError):
                    manifest = seal_manifest(manifest)
                if any(isinstance(v, type(HUGE_INT)) for v in _leaves(manifest)):
                    pass
            mf.write_text(dump_json(manifest))
        out = folder / "EST.csv"
        argv = ["estimate", str(world.image), "--model", str(b), "--out", str(out)]
        return argv, Expect(refuse=refuse, outputs=(out,), inputs=(b,))

    return build


def _meta_set(path: tuple[Any, ...], value: Any) -> Callable[[dict[str, Any]], Any]:
    return lambda mf: set_path(mf, ("metadata", *path), value)


_BUNDLE_FIELDS: dict[str, tuple[Any, ...]] = {
    "camera fx": ("camera", "camera_matrix", "data", 0),
    "layout marker_size": ("layout", "marker_size"),
    "robot camera_mount.x": ("robot", "camera_mount", "x"),
}
_BUNDLE_OK = {
    "camera k1": {"1e-300", "zero"},
    "layout center.y": {"1e-300", "zero"},
    "robot camera_mount.x": {"1e-300", "zero", "negative"},
    "robot camera_mount.pitch": {"1e-300", "zero", "negative"},
}
for _field, _path in _BUNDLE_FIELDS.items():
    for _label, _value in HOSTILE_VALUES:
        if _label in ("nan", "inf", "-inf"):
            continue  # not sealable (JSON has no NaN); the unsealed cases below cover them
        _sub = set_path({"camera": CAM, "robot": ROBOT, "layout": LAYOUT}, _path, _value)
        _ok = plausible_camera(_sub["camera"]) and plausible_robot(_sub["robot"]) and plausible_layout(_sub["layout"])
        add(F_BUNDLE, f"sealed {_field}={_label}", _bundle_case(_meta_set(_path, _value), refuse=not _ok))
for _label, _mutate, _seal, _refuse in [
    ("sealed camera k1 1e6", _meta_set(("camera", "distortion_coefficients", "data", 0), 1e6), True, True),
    ("sealed robot camera_mount.x 1e308", _meta_set(("robot", "camera_mount", "x"), 1e308), True, True),
    ("sealed robot camera_mount.pitch 1e300", _meta_set(("robot", "camera_mount", "pitch"), 1e300), True, True),
    ("sealed layout marker_size 1e-300", _meta_set(("layout", "marker_size"), 1e-300), True, True),
    ("sealed without metadata.layout (issue: KeyError)", _meta_set(("layout",), DELETE), True, True),
    ("sealed without metadata.camera (issue: KeyError)", _meta_set(("camera",), DELETE), True, True),
    ("sealed without metadata.robot", _meta_set(("robot",), DELETE), True, True),
    ("sealed without metadata", lambda mf: set_path(mf, ("metadata",), DELETE), True, True),
    ("sealed metadata a list", lambda mf: set_path(mf, ("metadata",), [1]), True, True),
    ("sealed metadata.camera a string", _meta_set(("camera",), "camera.yaml"), True, True),
    ("sealed unknown metadata key", _meta_set((UNKNOWN_MARK,), 1), True, False),
    ("sealed feature_schema other", _meta_set(("feature_schema",), "other/9"), True, True),
    ("sealed segments missing", lambda mf: set_path(mf, ("segments",), DELETE), True, True),
    ("sealed segments width 0", lambda mf: set_path(mf, ("segments", "width_m"), 0.0), True, True),
    ("sealed segments width 1e-300", lambda mf: set_path(mf, ("segments", "width_m"), 1e-300), True, True),
    ("sealed segments count huge", lambda mf: set_path(mf, ("segments", "count"), 10**9), True, True),
    ("sealed segments a list", lambda mf: set_path(mf, ("segments",), [0.25, 0.05]), True, True),
    ("sealed sets empty", lambda mf: set_path(mf, ("sets",), {}), True, True),
    ("sealed sets a list", lambda mf: set_path(mf, ("sets",), []), True, True),
    ("sealed feature_names a string", lambda mf: set_path(mf, ("sets", "m2", "feature_names"), "abc"), True, True),
    (
        "sealed depth file traversal",
        lambda mf: set_path(mf, ("sets", "m2", "depth", "file"), "../../x.onnx"),
        True,
        True,
    ),
    ("sealed depth file absolute", lambda mf: set_path(mf, ("sets", "m2", "depth", "file"), "/etc/passwd"), True, True),
    ("sealed depth sha256 wrong", lambda mf: set_path(mf, ("sets", "m2", "depth", "sha256"), "0" * 64), True, True),
    ("sealed depth entry a number", lambda mf: set_path(mf, ("sets", "m2", "depth"), 3), True, True),
    ("sealed yaw entries short", lambda mf: set_path(mf, ("sets", "m2", "yaw"), []), True, True),
    ("sealed schema_version 1", lambda mf: set_path(mf, ("schema_version",), 1), True, True),
    ("sealed schema_version '2'", lambda mf: set_path(mf, ("schema_version",), "2"), True, True),
    ("sealed a list at the top", lambda mf: [mf], True, True),
    ("unsealed camera mount moved 1 m (issue)", _meta_set(("robot", "camera_mount", "x"), 1.17), False, True),
    ("unsealed camera fx 700", _meta_set(("camera", "camera_matrix", "data", 0), 700.0), False, True),
    ("unsealed layout marker_size 0.12", _meta_set(("layout", "marker_size"), 0.12), False, True),
    ("unsealed camera cx NaN", _meta_set(("camera", "camera_matrix", "data", 2), math.nan), False, True),
    ("unsealed digest removed", lambda mf: set_path(mf, ("manifest_sha256",), DELETE), False, True),
    ("unsealed digest a number", lambda mf: set_path(mf, ("manifest_sha256",), 1), False, True),
    ("re-indented, same content", lambda mf: mf, False, False),
]:
    add(F_BUNDLE, _label, _bundle_case(_mutate, seal=_seal, refuse=_refuse))
for _label, _raw in [
    ("5,000-digit number (issue)", '{"schema_version": ' + "9" * 5000 + "}"),
    ("5,000-digit number in metadata", None),
    ("nested arrays 100,000 deep (issue)", deep_list_json()),
    ("nested objects 100,000 deep", '{"a":' * 100_000 + "1" + "}" * 100_000),
    ("not JSON", "schema_version: 2\n"),
    ("empty", ""),
    ("non-UTF-8", b'{"schema_version": 2, "x": "\xff\xfe"}'),
    ("UTF-16", '{"schema_version": 2}'.encode("utf-16")),
    ("truncated", '{"schema_version": 2, "metadata": {"camera": '),
    ("NaN token", '{"schema_version": 2, "manifest_sha256": NaN}'),
    ("duplicate keys", '{"schema_version": 2, "schema_version": 2}'),
]:
    if _raw is None:
        add(F_BUNDLE, _label, _bundle_case(_meta_set(("layout", "marker_size"), HUGE_INT), seal=False))
    else:
        add(F_BUNDLE, _label, _bundle_case(lambda mf: mf, raw=_raw))


def _bundle_swap(name: str, action: Callable[[Path], None]) -> None:
    def build(world: World, folder: Path) -> Plan:
        b = folder / "bundle"
        shutil.copytree(world.bundle, b)
        action(b)
        out = folder / "EST.csv"
        return ["estimate", str(world.image), "--model", str(b), "--out", str(out)], Expect(
            refuse=True, outputs=(out,), inputs=(b,)
        )

    add(F_BUNDLE, name, build)


_bundle_swap("manifest missing", lambda b: (b / "bundle.json").unlink())
_bundle_swap("manifest is a folder", lambda b: ((b / "bundle.json").unlink(), (b / "bundle.json").mkdir()))
_bundle_swap(
    "an onnx file truncated", lambda b: next(b.glob("*.onnx")).write_bytes(next(b.glob("*.onnx")).read_bytes()[:50])
)
_bundle_swap("an onnx file removed", lambda b: next(b.glob("*.onnx")).unlink())


# --- dataset --------------------------------------------------------------------------------------------


def _dataset_case(
    change: Callable[[pa.Table, dict[str, Any]], tuple[pa.Table, Any]] | None,
    *,
    command: str = "evaluate",
    refuse: bool = True,
    raw: bytes | Callable[[bytes], bytes] | None = None,
    raw_meta: bytes | None = None,
) -> Builder:
    """``evaluate`` (or ``train``) on the world's dataset with its table or metadata changed."""

    def build(world: World, folder: Path) -> Plan:
        ds = folder / "data.parquet"
        if raw is not None:
            ds.write_bytes(raw(world.dataset.read_bytes()) if callable(raw) else raw)
        else:
            table = pq.read_table(world.dataset)
            meta = json.loads(table.schema.metadata[b"monodock"])
            if change is not None:
                table, meta = change(table, meta)
            text = raw_meta if raw_meta is not None else dump_json(meta).encode("utf-8", "surrogateescape")
            table = table.replace_schema_metadata({b"monodock": text})
            pq.write_table(table, ds)
        if command == "train":
            out = folder / "bundle"
            argv = ["train", str(ds), "--out", str(out), "--trials", "1", "--jobs", "1", "--sets", "m2"]
        else:
            out = folder / "report"
            argv = ["evaluate", str(ds), "--model", str(world.bundle), "--out", str(out)]
        return argv, Expect(refuse=refuse, outputs=(out,), inputs=(ds,))

    return build


def _meta(path: tuple[Any, ...], value: Any) -> Callable[[pa.Table, dict[str, Any]], tuple[pa.Table, Any]]:
    return lambda t, m: (t, set_path(m, path, value))


def _column(name: str, values: Callable[[int], pa.Array]) -> Callable[[pa.Table, dict[str, Any]], tuple[pa.Table, Any]]:
    def change(t: pa.Table, m: dict[str, Any]) -> tuple[pa.Table, Any]:
        i = t.column_names.index(name)
        return t.set_column(i, name, values(t.num_rows)), m

    return change


_DS_FIELDS = {
    "camera fx": ("camera", "camera_matrix", "data", 0),
    "robot camera_mount.x": ("robot", "camera_mount", "x"),
}
for _cmd in ("evaluate", "train"):
    for _field, _path in list(_DS_FIELDS.items())[: 2 if _cmd == "evaluate" else 1]:
        for _label, _value in HOSTILE_VALUES:
            if _label in ("1e-300", "zero", "negative") and "k1" in _field:
                continue
            _sub = set_path({"camera": CAM, "robot": ROBOT, "layout": LAYOUT}, _path, _value)
            _ok = (
                plausible_camera(_sub["camera"]) and plausible_robot(_sub["robot"]) and plausible_layout(_sub["layout"])
            )
            # train refuses the world's dataset anyway (too few rows): a clean refusal is right for it
            add(
                F_DATASET,
                f"{_cmd}: metadata {_field}={_label}",
                _dataset_case(_meta(_path, _value), command=_cmd, refuse=_cmd == "train" or not _ok),
            )
    for _label, _change, _raw, _raw_meta, _refuse in [
        ("metadata not JSON (issue)", None, None, b"{not json", True),
        ("metadata a list (issue)", None, None, b"[1, 2]", True),
        ("metadata non-UTF-8", None, None, b'{"schema": "\xff"}', True),
        ("metadata nested 100,000 deep", None, None, deep_list_json().encode(), True),
        ("metadata 5,000-digit number", None, None, b'{"schema": ' + b"9" * 5000 + b"}", True),
        ("metadata NaN in camera", _meta(("camera", "camera_matrix", "data", 0), math.nan), None, None, True),
        ("metadata without camera", _meta(("camera",), DELETE), None, None, True),
        ("metadata without robot", _meta(("robot",), DELETE), None, None, True),
        ("metadata without layout", _meta(("layout",), DELETE), None, None, True),
        ("metadata schema other", _meta(("schema",), "other/1"), None, None, True),
        ("metadata unknown key", _meta((UNKNOWN_MARK,), 1), None, None, False),
        ("a string column (issue)", _column("m2_tl_u", lambda n: pa.array(["x"] * n)), None, None, True),
        # Rows without a usable label or feature may be left out (then the report must say so, finitely); with no
        # row left to evaluate against (the world's dataset has no truth), evaluate refuses too (issue 24).
        ("label column NaN", _column("label_x_m", lambda n: pa.array([math.nan] * n)), None, None, True),
        ("label column 1e308", _column("label_x_m", lambda n: pa.array([1e308] * n)), None, None, True),
        ("feature column inf", _column("m2_tl_u", lambda n: pa.array([math.inf] * n)), None, None, _cmd == "train"),
        ("no rows (issue)", lambda t, m: (t.slice(0, 0), m), None, None, True),
        ("a column missing", lambda t, m: (t.drop_columns(["label_x_m"]), m), None, None, True),
        ("not Parquet", None, b"PAR1 garbage garbage PAR1", None, True),
        ("empty file", None, b"", None, True),
        ("truncated at 50%", None, (lambda b: b[: len(b) // 2]), None, True),
        ("bytes flipped", None, (lambda b: flip_bytes(b, 3, 16, 100)), None, True),
    ]:
        add(
            F_DATASET,
            f"{_cmd}: {_label}",
            _dataset_case(_change, command=_cmd, refuse=_refuse, raw=_raw, raw_meta=_raw_meta),
        )
add(F_DATASET, "evaluate: the valid dataset", _dataset_case(None, refuse=False))


def _scans_case(content: bytes) -> Builder:
    def build(world: World, folder: Path) -> Plan:
        views = folder / "views"
        views.mkdir()
        (views / "0000.png").write_bytes(world.png)
        (views / "scans.npz").write_bytes(content)
        out = folder / "out.yaml"
        argv = [
            "calibrate",
            "extrinsics",
            "--target-views",
            str(views),
            "--robot",
            str(world.robot),
            "--camera",
            str(world.camera),
            "--out",
            str(out),
        ]
        return argv, Expect(refuse=True, outputs=(out,), inputs=(views,))

    return build


def _npz_with_pickle() -> bytes:
    import io

    buf = io.BytesIO()
    np.savez(buf, ranges=np.array([{"a": 1}], dtype=object))
    return buf.getvalue()


add(F_DATASET, "calibrate extrinsics: garbage scans.npz (issue: BadZipFile)", _scans_case(b"not a zip file"))
add(F_DATASET, "calibrate extrinsics: empty scans.npz", _scans_case(b""))
add(F_DATASET, "calibrate extrinsics: pickled scans.npz", _scans_case(_npz_with_pickle()))


# --- images and video -----------------------------------------------------------------------------------


def _image_case(
    make: Callable[[World], bytes | np.ndarray],
    *,
    suffix: str = ".png",
    refuse: bool = True,
    truth: bool = False,
    show: bool = False,
    name: str | None = None,
) -> Builder:
    def build(world: World, folder: Path) -> Plan:
        data = make(world)
        if isinstance(data, np.ndarray):
            data = bytes(cv2.imencode(suffix, data)[1])
        img = write(folder, name or f"frame{suffix}", data)
        if show:
            out = folder / "overlay.png"
            argv = ["show", str(img), *world.calibration(), "--out", str(out)]
            return argv, Expect(refuse=refuse, outputs=(out,), inputs=(img,))
        return estimate(world, folder, image=img, refuse=refuse, truth=truth)

    return build


for _cmd_show in (False, True):
    _p = "show: " if _cmd_show else ""
    add(F_IMAGE, _p + "the valid PNG", _image_case(lambda w: w.png, refuse=False, truth=True, show=_cmd_show))
    add(
        F_IMAGE,
        _p + "16-bit PNG (issue: putText)",
        _image_case(lambda w: w.pixels.astype(np.uint16) * 257, refuse=False, truth=True, show=_cmd_show),
    )
    add(
        F_IMAGE,
        _p + "RGB PNG",
        _image_case(lambda w: cv2.cvtColor(w.pixels, cv2.COLOR_GRAY2BGR), refuse=False, truth=True, show=_cmd_show),
    )
    add(
        F_IMAGE,
        _p + "RGBA PNG",
        _image_case(lambda w: cv2.cvtColor(w.pixels, cv2.COLOR_GRAY2BGRA), refuse=False, truth=True, show=_cmd_show),
    )
    add(
        F_IMAGE,
        _p + "16-bit RGBA PNG",
        _image_case(
            lambda w: cv2.cvtColor(w.pixels, cv2.COLOR_GRAY2BGRA).astype(np.uint16) * 257,
            refuse=False,
            truth=True,
            show=_cmd_show,
        ),
    )
    add(
        F_IMAGE,
        _p + "float TIFF",
        _image_case(
            lambda w: w.pixels.astype(np.float32) / 255, suffix=".tiff", refuse=False, truth=True, show=_cmd_show
        ),
    )
    add(
        F_IMAGE,
        _p + "header 60000x60000 (issue)",
        _image_case(lambda w: png_with_ihdr(w.png, width=60000, height=60000), show=_cmd_show),
    )
    add(
        F_IMAGE,
        _p + "JPEG header 60000x60000",
        _image_case(lambda w: jpeg_with_size(w.jpg, 60000, 60000), suffix=".jpg", show=_cmd_show),
    )
    add(
        F_IMAGE,
        _p + "non-UTF-8 file name (issue)",
        _image_case(lambda w: w.png, refuse=False, truth=True, show=_cmd_show, name=os.fsdecode(b"frame\xff.png")),
    )
for _label, _fields in [
    ("width 0", {"width": 0}),
    ("height 0", {"height": 0}),
    ("width 2^31", {"width": 2**31}),
    ("width 1", {"width": 1}),
    ("width 641", {"width": 641}),
    ("height 20000", {"height": 20000}),
    ("bit depth 16", {"bit_depth": 16}),
    ("bit depth 3", {"bit_depth": 3}),
    ("bit depth 0", {"bit_depth": 0}),
    ("colour type 2 (RGB)", {"color_type": 2}),
    ("colour type 6 (RGBA)", {"color_type": 6}),
    ("colour type 3 without palette", {"color_type": 3}),
    ("colour type 7", {"color_type": 7}),
]:
    add(F_IMAGE, f"PNG header {_label}", _image_case(lambda w, fl=_fields: png_with_ihdr(w.png, **fl)))
for _frac in (0.0, 0.001, 0.01, 0.05, 0.25, 0.5, 0.75, 0.95, 0.999):
    add(F_IMAGE, f"PNG truncated at {_frac:.1%}", _image_case(lambda w, fr=_frac: w.png[: int(len(w.png) * fr)]))
    add(
        F_IMAGE,
        f"JPEG truncated at {_frac:.1%}",
        _image_case(lambda w, fr=_frac: w.jpg[: int(len(w.jpg) * fr)], suffix=".jpg"),
    )
for _seed in range(10):
    # A damaged file may still decode: refusing is right, and so is an estimate, if it is the truth's.
    add(
        F_IMAGE,
        f"PNG bytes flipped #{_seed}",
        _image_case(lambda w, s=_seed: flip_bytes(w.png, s, 8, 8), refuse=False, truth=True),
    )
    add(
        F_IMAGE,
        f"JPEG bytes flipped #{_seed}",
        _image_case(lambda w, s=_seed: flip_bytes(w.jpg, s, 8, 20), suffix=".jpg", refuse=False, truth=True),
    )
for _label, _make in [
    ("PNG CRC broken", lambda w: w.png[:29] + b"\x00\x00\x00\x00" + w.png[33:]),
    ("text named .png", lambda w: b"hello, I am not an image\n"),
    ("PNG signature only", lambda w: w.png[:8]),
    ("JPEG SOI only", lambda w: b"\xff\xd8"),
    ("image of another size 320x240", lambda w: cv2.resize(w.pixels, (320, 240))),
    ("image 1x1", lambda w: np.zeros((1, 1), np.uint8)),
    ("all black", lambda w: np.zeros_like(w.pixels)),
]:
    add(F_IMAGE, _label, _image_case(_make, refuse=_label != "all black"))
add(F_IMAGE, "empty file", _image_case(lambda w: b""))


def _video_case(cut: float | None, *, garbage: bool = False) -> Builder:
    def build(world: World, folder: Path) -> Plan:
        video = folder / "drive.avi"
        writer = cv2.VideoWriter(str(video), cv2.VideoWriter_fourcc(*"MJPG"), 10.0, (640, 480))
        for _ in range(3):
            writer.write(cv2.cvtColor(world.pixels, cv2.COLOR_GRAY2BGR))
        writer.release()
        data = video.read_bytes()
        if garbage:
            data = b"RIFF" + bytes(range(256)) * 20
        elif cut is not None:
            data = data[: int(len(data) * cut)]
        video.write_bytes(data)
        # A cut video gives the frames it holds: each valid row must be the truth's.
        return estimate(world, folder, image=video, refuse=garbage, truth=not garbage)

    return build


add(F_IMAGE, "video: valid MJPG", _video_case(None))
for _cut in (0.05, 0.3, 0.6, 0.9):
    add(F_IMAGE, f"video: truncated at {_cut:.0%}", _video_case(_cut))
add(F_IMAGE, "video: RIFF garbage", _video_case(None, garbage=True))


# --- recordings -----------------------------------------------------------------------------------------


def _recording_case(
    *,
    info: dict[str, Any] | None = None,
    image_msg: Callable[..., Any] | None = None,
    encoding: str = "mono8",
    damage: Callable[[Path], None] | None = None,
    refuse: bool = True,
    command: str = "label",
) -> Builder:
    def build(world: World, folder: Path) -> Plan:
        sim, frames = frames_of(world)
        rec = write_recording(folder / "rec", sim, frames, info=info, encoding=encoding, image_msg=image_msg)
        if damage is not None:
            damage(rec)
        if command == "label":
            out = folder / "ds.parquet"
            argv = ["label", str(rec), "--layout", str(world.layout), "--out", str(out)]
        else:
            out = folder / "EST.csv"
            argv = ["estimate", str(rec), *world.calibration(), "--out", str(out)]
        return argv, Expect(refuse=refuse, outputs=(out,), inputs=(rec,))

    return build


def _k(**entries: float) -> dict[str, Any]:
    K = np.array(CameraModel.default().K, dtype=np.float64)
    for name, v in entries.items():
        K[{"fx": 0, "cx": 2, "fy": 4, "cy": 5}[name]] = v
    return {"k": K}


def _d(**entries: float) -> dict[str, Any]:
    D = np.array(CameraModel.default().D, dtype=np.float64)
    for name, v in entries.items():
        D[{"k1": 0, "k2": 1, "p1": 2, "p2": 3, "k3": 4}[name]] = v
    return {"d": D}


add(F_RECORDING, "the valid recording", _recording_case(refuse=False))
for _label, _info in [
    ("camera_info fx NaN", _k(fx=math.nan)),
    ("camera_info fx inf", _k(fx=math.inf)),
    ("camera_info fx 1e308", _k(fx=1e308)),
    ("camera_info fx 1e-300", _k(fx=1e-300)),
    ("camera_info fx -615", _k(fx=-615.0)),
    ("camera_info fx 10000", _k(fx=10000.0)),
    ("camera_info cx 1e308", _k(cx=1e308)),
    ("camera_info cy -1e6", _k(cy=-1e6)),
    ("camera_info k1 1e6", _d(k1=1e6)),
    ("camera_info k1 NaN", _d(k1=math.nan)),
    ("camera_info k2 -1e5", _d(k2=-1e5)),
    ("camera_info p1 1e308", _d(p1=1e308)),
    ("camera_info D of 3", {"d": np.array([0.1, 0.0, 0.0])}),
    ("camera_info D of 1000", {"d": np.zeros(1000)}),
    ("camera_info K all zero (uncalibrated)", {"k": np.zeros(9)}),
    ("camera_info width 0", {"width": 0}),
    ("camera_info 1280x960, images 640x480 (issue: 0 rows labelled, exit 0)", {"width": 1280, "height": 960}),
    ("camera_info height 2^32-1", {"height": 2**32 - 1}),
    ("camera_info distortion_model equidistant", {"distortion_model": "equidistant"}),
    ("camera_info distortion_model non-ASCII", {"distortion_model": "plumb_bob\u00e9"}),
]:
    add(F_RECORDING, _label, _recording_case(info=_info))


def _raw_image(
    encoding: str,
    *,
    width: int = 640,
    height: int = 480,
    step: int | None = None,
    data_len: int | None = None,
    channels: int = 1,
) -> Callable[[float, np.ndarray], tuple[str, Any]]:
    from monodock.recording.messages import IMAGE, humble_typestore

    def make(t: float, image: np.ndarray) -> tuple[str, Any]:
        ts = humble_typestore()
        _, msg = __import__("monodock.recording.messages", fromlist=["encode_image"]).encode_image(
            image, "mono8", t, "camera"
        )
        data = np.repeat(image.reshape(-1), channels)
        if data_len is not None:
            data = np.resize(data, data_len)
        return IMAGE, ts.types[IMAGE](
            header=msg.header,
            height=height,
            width=width,
            encoding=encoding,
            is_bigendian=0,
            step=step if step is not None else width * channels,
            data=np.ascontiguousarray(data, dtype=np.uint8),
        )

    return make


def _compressed(data: Callable[[bytes], bytes], fmt: str = "png") -> Callable[[float, np.ndarray], tuple[str, Any]]:
    from monodock.recording.messages import COMPRESSED_IMAGE, humble_typestore

    def make(t: float, image: np.ndarray) -> tuple[str, Any]:
        ts = humble_typestore()
        _, msg = __import__("monodock.recording.messages", fromlist=["encode_image"]).encode_image(
            image, "png", t, "camera"
        )
        raw = data(bytes(msg.data))
        return COMPRESSED_IMAGE, ts.types[COMPRESSED_IMAGE](
            header=msg.header, format=fmt, data=np.frombuffer(raw, dtype=np.uint8).copy()
        )

    return make


for _cmd in ("label", "estimate"):
    for _label, _make in [
        ("encoding yuv444", _raw_image("yuv444", channels=3)),
        ("encoding 32FC1", _raw_image("32FC1", channels=4)),
        ("encoding empty", _raw_image("")),
        ("encoding bayer_rggb8", _raw_image("bayer_rggb8")),
        ("mono8 with data too short", _raw_image("mono8", data_len=1000)),
        ("mono8 step too small", _raw_image("mono8", step=10)),
        ("mono8 width 0", _raw_image("mono8", width=0, data_len=0)),
        ("mono8 claims 60000x60000", _raw_image("mono8", width=60000, height=60000)),
        ("mono8 step 2^32-1", _raw_image("mono8", step=2**32 - 1)),
        ("bgr8 with mono data", _raw_image("bgr8", channels=1, step=640 * 3)),
        ("png truncated", _compressed(lambda b: b[: len(b) // 2])),
        ("png header 60000x60000", _compressed(lambda b: png_with_ihdr(b, width=60000, height=60000))),
        (
            "png 16-bit",
            _compressed(
                lambda b: bytes(
                    cv2.imencode(".png", cv2.imdecode(np.frombuffer(b, np.uint8), 0).astype(np.uint16) * 257)[1]
                )
            ),
        ),
        ("compressed garbage", _compressed(lambda b: b"garbage" * 10)),
        ("compressed empty", _compressed(lambda b: b"")),
        ("compressed format nonsense", _compressed(lambda b: b, fmt="\xff\x00bogus")),
    ]:
        ok = _label in ("png 16-bit", "compressed format nonsense")  # the format string is only a hint
        add(F_RECORDING, f"{_cmd}: image {_label}", _recording_case(image_msg=_make, refuse=not ok, command=_cmd))


def _flip_bag(rec: Path) -> None:
    f = next(rec.glob("*.mcap"))
    f.write_bytes(flip_bytes(f.read_bytes(), 5, 32, 200))


def _truncate_bag(frac: float) -> Callable[[Path], None]:
    def damage(rec: Path) -> None:
        f = next(p for p in rec.iterdir() if p.suffix in (".mcap", ".db3"))
        data = f.read_bytes()
        f.write_bytes(data[: int(len(data) * frac)])

    return damage


for _frac in (0.0, 0.1, 0.4, 0.7, 0.95):
    # A recording cut short is read as far as it goes (with a warning): refusing or labelling what is there are both
    # right; the labels of what is there must be sane.
    add(F_RECORDING, f"bag file truncated at {_frac:.0%}", _recording_case(damage=_truncate_bag(_frac), refuse=False))
add(
    F_RECORDING,
    "metadata.yaml garbage",
    _recording_case(refuse=False, damage=lambda r: (r / "metadata.yaml").write_text("{{{")),
)
add(
    F_RECORDING,
    "metadata.yaml alias bomb",
    _recording_case(
        refuse=False,
        damage=lambda r: (r / "metadata.yaml").write_text(alias_bomb_yaml("rosbag2_bagfile_information", 7)),
    ),
)
add(
    F_RECORDING,
    "metadata.yaml object tag",
    _recording_case(
        refuse=False,
        damage=lambda r: (r / "metadata.yaml").write_text("!!python/object/apply:os.system ['echo pwned']\n"),
    ),
)
add(
    F_RECORDING, "metadata.yaml removed", _recording_case(refuse=False, damage=lambda r: (r / "metadata.yaml").unlink())
)
add(
    F_RECORDING,
    "metadata.yaml non-UTF-8",
    _recording_case(refuse=False, damage=lambda r: (r / "metadata.yaml").write_bytes(b"\xff\xfe\x00")),
)
add(
    F_RECORDING,
    "bag file bytes flipped",
    _recording_case(
        refuse=False,
        damage=_flip_bag,
    ),
)
add(F_RECORDING, "sqlite3 storage, valid", _recording_case(refuse=False))


# --- CLI numeric options ---------------------------------------------------------------------------------

_NUMBERS = ["nan", "inf", "-1", "0", "1e308", "9" * 5000, "abc"]


def _simulate(folder: Path, *options: str, refuse: bool = True) -> Plan:
    out = folder / "sim"
    argv = ["simulate", "--out", str(out), "--frames", "1", "--supersample", "1", "--clean", "--jobs", "1", *options]
    return argv, Expect(refuse=refuse, outputs=(out,))


# Values each option may take without being wrong (others must be refused).
_SIM_OPTIONS: dict[str, tuple[set[str], int]] = {
    # option: (values that are acceptable, how many values it takes)
    "--seed": ({"0", "-1", "1e308"}, 1),
    "--depth": (set(), 2),
    "--lateral": ({"0", "-1"}, 2),
    "--yaw": ({"0", "-1", "1e-300"}, 2),
    "--read-noise": ({"0", "1e-300"}, 1),
    "--exposure": ({"0", "1e-300"}, 1),
    "--gamma": (set(), 1),
    "--occluder-probability": ({"0", "1e-300"}, 1),
    "--side-walls": ({"1e308"}, 1),
}
for _opt, (_fine, _n) in _SIM_OPTIONS.items():
    for _v in _NUMBERS:
        if _opt == "--depth" and _v in ("1e-300",):
            continue
        vals = (
            [_v] * _n
            if _opt not in ("--depth", "--lateral", "--yaw")
            else (["0.5", _v] if _opt == "--depth" else [_v, "0.1"])
        )
        label = f"simulate {_opt} {' '.join(v[:8] for v in vals)}"
        add(F_NUMERIC, label, lambda w, f, o=_opt, vs=tuple(vals), ok=_v in _fine: _simulate(f, o, *vs, refuse=not ok))
for _label, _options, _refuse in [
    ("simulate --seed -1 (issue)", ("--seed", "-1"), False),
    ("simulate --depth 1 inf (issue)", ("--depth", "1", "inf"), True),
    ("simulate --gamma 0 (issue)", ("--gamma", "0"), True),
    ("simulate --depth 0.001 0.002", ("--depth", "0.001", "0.002"), True),
    ("simulate --depth 100 200", ("--depth", "100", "200"), False),
    ("simulate --frames 0", ("--frames", "0"), True),
    ("simulate --frames -5", ("--frames", "-5"), True),
    ("simulate --jobs 0", ("--jobs", "0"), False),
    ("simulate --jobs -3", ("--jobs", "-3"), False),
    ("simulate --format rosbag2 --camera-rate 1e-9 (issue)", ("--format", "rosbag2", "--camera-rate", "1e-9"), True),
    ("simulate --format rosbag2 --camera-rate nan", ("--format", "rosbag2", "--camera-rate", "nan"), True),
    ("simulate --format rosbag2 --camera-rate 1e308", ("--format", "rosbag2", "--camera-rate", "1e308"), True),
    ("simulate --format rosbag2 --lidar-rate 0", ("--format", "rosbag2", "--lidar-rate", "0"), True),
    ("simulate --format rosbag2 --lidar-rate -10", ("--format", "rosbag2", "--lidar-rate", "-10"), True),
    ("simulate --format rosbag2 --density 1,nan", ("--format", "rosbag2", "--density", "1,nan"), True),
    ("simulate --format rosbag2 --density -1,2", ("--format", "rosbag2", "--density", "-1,2"), True),
    ("simulate --format rosbag2 --density 1e308,1e308", ("--format", "rosbag2", "--density", "1e308,1e308"), True),
]:
    add(F_NUMERIC, _label, lambda w, f, o=_options, r=_refuse: _simulate(f, *o, refuse=r))


add(
    F_NUMERIC,
    "simulate --yaw 1000 2000 (issue: unwrapped yaws)",
    lambda w, f: _simulate(f, "--yaw", "1000", "2000", refuse=False),
)
for _v in _NUMBERS:
    add(
        F_NUMERIC,
        f"label --tolerance {_v[:8]}",
        lambda w, f, v=_v: (
            ["label", str(w.recording), "--layout", str(w.layout), "--out", str(f / "ds.parquet"), "--tolerance", v],
            Expect(refuse=v != "1e308", outputs=(f / "ds.parquet",)),
        ),
    )
    for _opt in ("--trials", "--fusion-holdout"):
        ok = (
            (_opt == "--seed" and _v in ("0", "-1"))
            or (_opt == "--fusion-holdout" and _v in ("0", "1e-300"))
            or (_opt == "--jobs" and _v == "0")
        )
        add(
            F_NUMERIC,
            f"train {_opt} {_v[:8]}",
            lambda w, f, o=_opt, v=_v: (
                [
                    "train",
                    str(w.dataset),
                    "--out",
                    str(f / "b"),
                    "--sets",
                    "m2",
                    *(["--trials", "1"] if o != "--trials" else []),
                    o,
                    v,
                ],
                # the world's dataset is too small to train: a refusal either way, but a clean one
                Expect(refuse=True, outputs=(f / "b",)),
            ),
        )
    for _opt in ("--square", "--max-views"):
        add(
            F_NUMERIC,
            f"calibrate intrinsics {_opt} {_v[:8]}",
            lambda w, f, o=_opt, v=_v: (
                ["calibrate", "intrinsics", str(w.image), "--out", str(f / "cam.yaml"), o, v],
                Expect(refuse=True, outputs=(f / "cam.yaml",)),
            ),
        )
    for _opt in ("--frame-drop-rate", "--camera-rate", "--standoff"):
        if _v in ("0", "1e-300") and _opt in ("--frame-drop-rate",):
            continue
        if _v in ("0", "-1") and _opt == "--max-retries":
            continue
        add(
            F_NUMERIC,
            f"dock-sim {_opt} {_v[:8]}",
            lambda w, f, o=_opt, v=_v: (
                [
                    *("dock-sim", "--method", "board", "--cases", "1", "--trials", "1", "--cache", str(f / "cache")),
                    *("--out", str(f / "ds"), o, v),
                ],
                Expect(refuse=True, outputs=(f / "ds",)),
            ),
        )
for _opt in ("--frames", "--calibration-frames", "--seed", "--supersample", "--jobs"):
    for _v in ("nan", "-1", "9" * 5000):
        add(
            F_NUMERIC,
            f"evaluate --robustness {_opt} {_v[:8]}",
            lambda w, f, o=_opt, v=_v: (
                [
                    "evaluate",
                    "--robustness",
                    "--model",
                    str(w.bundle),
                    "--out",
                    str(f / "r"),
                    o,
                    v,
                    *(["--frames", "-1"] if o != "--frames" else []),
                ],
                Expect(refuse=True, outputs=(f / "r",)),
            ),
        )


# --- outputs and --force ---------------------------------------------------------------------------------


def _copy_world(world: World, folder: Path) -> dict[str, Path]:
    """Copies of the inputs the output cases may (wrongly) overwrite."""
    out = {}
    for name, src in (
        ("camera", world.camera),
        ("layout", world.layout),
        ("robot", world.robot),
        ("image", world.image),
        ("dataset", world.dataset),
    ):
        out[name] = folder / src.name
        shutil.copy(src, out[name])
    out["recording"] = folder / "drive"
    shutil.copytree(world.recording, out["recording"])
    out["bundle"] = folder / "bundle"
    shutil.copytree(world.bundle, out["bundle"])
    out["pairs"] = _pairs_csv(folder / "pairs.csv")
    return out


def _pairs_csv(path: Path) -> Path:
    """LiDAR point / pixel pairs of the default robot and camera (``calibrate extrinsics --pairs``), exact."""
    from monodock.core import transforms
    from monodock.core.projection import project_to_image

    robot, camera = RobotConfig.default(), CameraModel.default()
    pts = np.array([[x, y, 0.0] for x in (0.8, 1.2, 1.6, 2.0) for y in (-0.3, -0.1, 0.1, 0.3)])
    px = project_to_image(transforms.apply(robot.base_T_laser(), pts), camera, robot)
    rows = [f"{p[0]},{p[1]},{q[0]},{q[1]}" for p, q in zip(pts, px, strict=True)]
    path.write_text("x,y,u,v\n" + "\n".join(rows) + "\n")
    return path


def _output_case(
    name: str, make: Callable[[World, Path, dict[str, Path]], tuple[list[str], Path]], *, refuse: bool = False
) -> None:
    def build(world: World, folder: Path) -> Plan:
        files = _copy_world(world, folder)
        argv, out = make(world, folder, files)
        inputs = tuple(files.values())
        return argv, Expect(refuse=refuse, outputs=(out,), inputs=inputs)

    add(F_OUTPUT, name, build)


def _est(files: dict[str, Path], out: Path, *extra: str) -> list[str]:
    return [
        "estimate",
        str(files["image"]),
        "--camera",
        str(files["camera"]),
        "--layout",
        str(files["layout"]),
        "--robot",
        str(files["robot"]),
        "--out",
        str(out),
        *extra,
    ]


for _target in ("image", "camera", "layout", "robot"):
    _output_case(
        f"estimate --out = the input {_target} --force (issue)",
        lambda w, f, fl, t=_target: (_est(fl, fl[t], "--force"), fl[t]),
    )
    _output_case(
        f"estimate --out = the input {_target}, no --force", lambda w, f, fl, t=_target: (_est(fl, fl[t]), fl[t])
    )
_output_case(
    "estimate --bag = the input image --force",
    lambda w, f, fl: (_est(fl, f / "e.csv", "--bag", str(fl["image"]), "--force"), f / "e.csv"),
)
_output_case(
    "estimate --out = --bag",
    lambda w, f, fl: (_est(fl, f / "x", "--bag", str(f / "x"), "--force"), f / "x"),
    refuse=True,
)


def _fifo(folder: Path) -> Path:
    p = folder / "pipe.csv"
    os.mkfifo(p)
    return p


_output_case(
    "estimate --out a FIFO --force (issue: device node)",
    lambda w, f, fl: (_est(fl, _fifo(f), "--force"), f / "pipe.csv"),
)
_output_case("estimate --out a FIFO, no --force", lambda w, f, fl: (_est(fl, _fifo(f)), f / "pipe.csv"))
_output_case(
    "estimate --out an existing folder --force",
    lambda w, f, fl: (_est(fl, fl["recording"], "--force"), fl["recording"]),
)
_output_case("estimate --out under a file", lambda w, f, fl: (_est(fl, fl["camera"] / "e.csv"), fl["camera"] / "e.csv"))
_output_case(
    "estimate --out /proc/version --force",
    lambda w, f, fl: (_est(fl, Path("/proc/version"), "--force"), Path("/proc/version")),
)
_output_case("estimate --out '' ", lambda w, f, fl: (_est(fl, Path("")), f / "none"))
_output_case(
    "show --out = the input image --force",
    lambda w, f, fl: (
        [
            "show",
            str(fl["image"]),
            "--camera",
            str(fl["camera"]),
            "--layout",
            str(fl["layout"]),
            "--robot",
            str(fl["robot"]),
            "--out",
            str(fl["image"]),
            "--force",
        ],
        fl["image"],
    ),
)
_output_case(
    "label --out = the input layout --force",
    lambda w, f, fl: (
        ["label", str(fl["recording"]), "--layout", str(fl["layout"]), "--out", str(fl["layout"]), "--force"],
        fl["layout"],
    ),
)
_output_case(
    "label --out = the recording --force",
    lambda w, f, fl: (
        ["label", str(fl["recording"]), "--layout", str(fl["layout"]), "--out", str(fl["recording"]), "--force"],
        fl["recording"],
    ),
)
_output_case(
    "train --out = the dataset --force",
    lambda w, f, fl: (
        ["train", str(fl["dataset"]), "--out", str(fl["dataset"]), "--force", "--trials", "1", "--sets", "m2"],
        fl["dataset"],
    ),
)
_output_case(
    "evaluate --out = the bundle --force",
    lambda w, f, fl: (
        ["evaluate", str(fl["dataset"]), "--model", str(fl["bundle"]), "--out", str(fl["bundle"]), "--force"],
        fl["bundle"],
    ),
)
_output_case(
    "evaluate --out = the dataset --force",
    lambda w, f, fl: (
        ["evaluate", str(fl["dataset"]), "--model", str(fl["bundle"]), "--out", str(fl["dataset"]), "--force"],
        fl["dataset"],
    ),
)
_output_case(
    "simulate --out = the folder holding --camera --force",
    lambda w, f, fl: (
        [
            "simulate",
            "--out",
            str(f),
            "--force",
            "--frames",
            "1",
            "--supersample",
            "1",
            "--jobs",
            "1",
            "--camera",
            str(fl["camera"]),
        ],
        f,
    ),
)
_output_case(
    # A recording is not an input of simulate (replacing one with --force is what --force is for); the folder that
    # holds its --camera is.
    "simulate --format rosbag2 --out = the folder holding --camera --force",
    lambda w, f, fl: (
        [
            "simulate",
            "--out",
            str(f),
            "--force",
            "--frames",
            "1",
            "--supersample",
            "1",
            "--jobs",
            "1",
            "--format",
            "rosbag2",
            "--camera",
            str(fl["camera"]),
        ],
        f,
    ),
)
_output_case(
    "calibrate intrinsics --out = an input image --force",
    lambda w, f, fl: (["calibrate", "intrinsics", str(fl["image"]), "--out", str(fl["image"]), "--force"], fl["image"]),
)
_output_case(
    "calibrate extrinsics --out = --robot --force",
    lambda w, f, fl: (
        [
            "calibrate",
            "extrinsics",
            "--pairs",
            str(fl["pairs"]),
            "--camera",
            str(fl["camera"]),
            "--robot",
            str(fl["robot"]),
            "--out",
            str(fl["robot"]),
            "--force",
        ],
        fl["robot"],
    ),
)
_output_case(
    "calibrate extrinsics --robot-out = --robot --force",
    lambda w, f, fl: (
        [
            "calibrate",
            "extrinsics",
            "--pairs",
            str(fl["pairs"]),
            "--camera",
            str(fl["camera"]),
            "--robot",
            str(fl["robot"]),
            "--out",
            str(f / "o.yaml"),
            "--robot-out",
            str(fl["robot"]),
            "--force",
        ],
        f / "o.yaml",
    ),
)
_output_case(
    "dock-sim --out = the folder holding --camera --force (issue: checked only after training)",
    lambda w, f, fl: (
        [
            "dock-sim",
            "--method",
            "board",
            "--cases",
            "1",
            "--trials",
            "1",
            "--out",
            str(f),
            "--force",
            "--camera",
            str(fl["camera"]),
            "--cache",
            str(f / "cache"),
        ],
        f,
    ),
)
_output_case(
    "dock-sim --out exists, no --force (issue: checked only after training)",
    lambda w, f, fl: (
        ["dock-sim", "--out", str(fl["bundle"]), "--trials", "1", "--cases", "1", "--cache", str(f / "cache")],
        fl["bundle"],
    ),
)


# --- interruption (subprocesses; slow) ---------------------------------------------------------------------


def _interrupt(
    name: str,
    argv: Callable[[World, Path], list[str]],
    signum: str,
    after_s: float,
    out: str,
    prepare: Callable[[World, Path], None] | None = None,
) -> None:
    def build(world: World, folder: Path) -> Plan:
        if prepare is not None:
            prepare(world, folder)
        return ["__subprocess__", signum, str(after_s), *argv(world, folder)], Expect(outputs=(folder / out,))

    CASES.append(Case(F_INTERRUPT, name, build, slow=True))


_interrupt(
    "SIGINT during simulate (rendering workers)",
    lambda w, f: ["simulate", "--out", str(f / "sim"), "--frames", "400", "--jobs", "2"],
    "SIGINT",
    3.0,
    "sim",
)
_interrupt(
    "SIGTERM during simulate (issue: hidden .OUT.* folder left)",
    lambda w, f: ["simulate", "--out", str(f / "sim"), "--frames", "400", "--jobs", "2"],
    "SIGTERM",
    3.0,
    "sim",
)
_interrupt(
    "SIGTERM during simulate --format rosbag2",
    lambda w, f: ["simulate", "--out", str(f / "rec"), "--frames", "400", "--jobs", "2", "--format", "rosbag2"],
    "SIGTERM",
    3.0,
    "rec",
)
_interrupt(
    "SIGINT during dock-sim (self-training)",
    lambda w, f: [
        "dock-sim",
        "--out",
        str(f / "ds"),
        "--trials",
        "1",
        "--cases",
        "1",
        "--jobs",
        "2",
        "--train-stops",
        "600",
        "--cache",
        str(f / "cache"),
    ],
    "SIGINT",
    6.0,
    "ds",
)


def _heavy(c: Case) -> bool:
    """Cases of several seconds each on this code (a report written, worker processes started, a long search)."""
    name = c.name
    return (
        (c.family == F_DATASET and name.startswith("evaluate:"))
        or (c.family == F_OUTPUT and any(w in name for w in ("evaluate", "dock-sim", "simulate")))
        or "--jobs" in name
        or "--depth 0.001" in name
    )


def in_default_run(c: Case) -> bool:
    """Whether a case runs in the default (bounded) test run: the issue's own examples and every third other case,
    unless heavy or an interruption; ``pytest -m slow`` and ``run_catalogue.py`` run them all."""
    if c.slow or (_heavy(c) and "(issue 24" not in c.name):  # issue 24's heavy examples take a few seconds
        return False
    return "(issue" in c.name or CASES.index(c) % 3 == 0


def family_counts() -> dict[str, int]:
    out = dict.fromkeys(FAMILIES, 0)
    for c in CASES:
        out[c.family] += 1
    return out


if __name__ == "__main__":  # pragma: no cover
    for fam, n in family_counts().items():
        print(f"{fam:30s} {n}")
    print("total", len(CASES), file=sys.stderr)


def _trainable_dataset(world: World, folder: Path) -> None:
    """A dataset of 300 labelled stops (simulated and labelled in-process, ~30 s): training it takes minutes."""
    from fuzz.harness import capture_fds
    from monodock.cli.main import main

    rec, ds = folder / "rec", folder / "train.parquet"
    common = ["--frames", "300", "--supersample", "1", "--jobs", "2", "--clean", "--format", "rosbag2"]
    with capture_fds() as said:
        made = main(["simulate", "--out", str(rec), *common]) == 0
        made = made and main(["label", str(rec), "--layout", str(world.layout), "--out", str(ds)]) == 0
    assert made, said


for _signal in ("SIGINT", "SIGTERM"):
    _interrupt(
        f"{_signal} during train --jobs 2 (issue: hung, bundle half-written)",
        lambda w, f: ["train", str(f / "train.parquet"), "--out", str(f / "bundle"), "--jobs", "2", "--trials", "3"],
        _signal,
        8.0,
        "bundle",
        prepare=_trainable_dataset,
    )


# --- issue 24: the hostile inputs that still broke the one-line promise -------------------------------------


def _loop(folder: Path, name: str = "loop") -> Path:
    """A symbolic link to itself: every open or resolve of it loops."""
    p = folder / name
    p.symlink_to(name)
    return p


def _loop_case(command: str) -> Builder:
    def build(world: World, folder: Path) -> Plan:
        loop = _loop(folder)
        out = folder / "out"
        calibration = world.calibration()
        argv = {
            "estimate": ["estimate", str(loop), *calibration, "--out", str(out)],
            "show": ["show", str(loop), *calibration, "--out", str(out)],
            "calibrate intrinsics": ["calibrate", "intrinsics", str(loop), "--out", str(out)],
            "run": ["run", "--source", str(loop), *calibration, "--out", str(out)],
            "label": ["label", str(loop), "--layout", str(world.layout), "--out", str(out)],
            "estimate --out": ["estimate", str(world.image), *calibration, "--out", str(loop), "--force"],
            "estimate --camera": ["estimate", str(world.image), *world.calibration(camera=loop), "--out", str(out)],
        }[command]
        if command == "estimate --out":  # the loop is the output: replacing it with --force is what --force is for
            return argv, Expect(outputs=(loop,))
        return argv, Expect(refuse=True, outputs=(out,), inputs=(loop,))

    return build


for _cmd in ("estimate", "show", "calibrate intrinsics", "run", "label", "estimate --camera", "estimate --out"):
    add(F_OUTPUT, f"{_cmd}: a symlink loop (issue 24: RuntimeError: Symlink loop)", _loop_case(_cmd))


def _truncated_for_intrinsics(world: World, folder: Path) -> Plan:
    rec = folder / "rec"
    shutil.copytree(world.recording, rec)
    _truncate_bag(0.4)(rec)
    out = folder / "camera.yaml"
    return ["calibrate", "intrinsics", str(rec), "--out", str(out)], Expect(refuse=True, outputs=(out,), inputs=(rec,))


add(
    F_RECORDING,
    "calibrate intrinsics: bag truncated at 40% (issue 24: a warning and an error)",
    _truncated_for_intrinsics,
)


@contextlib.contextmanager
def _file_size_limit(max_bytes: int) -> Any:
    """Writing a file past ``max_bytes`` fails with EFBIG, as a full disk fails with ENOSPC (the same path through
    libpng and Python; a tmpfs needs root). SIGXFSZ, which would kill the process, is ignored meanwhile."""
    import resource
    import signal

    soft, hard = resource.getrlimit(resource.RLIMIT_FSIZE)
    old = signal.signal(signal.SIGXFSZ, signal.SIG_IGN)
    resource.setrlimit(resource.RLIMIT_FSIZE, (max_bytes, hard))
    try:
        yield
    finally:
        resource.setrlimit(resource.RLIMIT_FSIZE, (soft, hard))
        signal.signal(signal.SIGXFSZ, old)


def _full_disk(fmt: str) -> Callable[[World, Path], Run]:
    def run(world: World, folder: Path) -> Run:
        out = folder / "sim"
        argv = ["simulate", "--out", str(out), "--frames", "3", "--supersample", "1", "--jobs", "1", "--format", fmt]
        import gc
        import warnings

        with _file_size_limit(20_000):
            run = run_cli(argv, outputs=(out,))
        with warnings.catch_warnings(record=True) as caught:  # a file left open (to the garbage collector)
            warnings.simplefilter("always")
            gc.collect()
        run.err += "".join(f"{w.category.__name__}: {w.message}\n" for w in caught)
        return run

    return run


for _fmt in ("folder", "rosbag2"):
    CASES.append(
        Case(
            F_OUTPUT,
            f"simulate --format {_fmt} onto a full disk (issue 24: libpng error: Write Error)",
            lambda w, f: ([], Expect(refuse=True, outputs=(f / "sim",))),
            library=_full_disk(_fmt),
        )
    )


def _all_nan(t: pa.Table, m: dict[str, Any]) -> tuple[pa.Table, Any]:
    for i, name in enumerate(t.column_names):
        if pa.types.is_floating(t.schema.field(name).type):
            t = t.set_column(i, name, pa.array([math.nan] * t.num_rows, pa.float64()))
    return t, m


add(F_DATASET, "evaluate: every number NaN (issue 24: empty tables, exit 0)", _dataset_case(_all_nan))


def _run_unreadable(skip_bad: bool) -> Builder:
    def build(world: World, folder: Path) -> Plan:
        img = write(folder, "frame.png", world.png[: len(world.png) // 3])
        out = folder / "rows.csv"
        argv = ["run", "--source", str(img), *world.calibration(), "--out", str(out)]
        if skip_bad:
            return [*argv, "--skip-bad"], Expect(refuse=False, outputs=(out,), inputs=(img,))
        return argv, Expect(refuse=True, outputs=(out,), inputs=(img,), implausible_ok_without_valid=False)

    return build


add(F_IMAGE, "run --source a truncated PNG (issue 24: exit 0 where estimate exits 2)", _run_unreadable(False))
add(F_IMAGE, "run --source a truncated PNG --skip-bad", _run_unreadable(True))


# A key named twice, in every YAML (and JSON) file monodock reads: refused, naming the key.
def _twice(text: str, key: str, value: str) -> str:
    """``text`` with the top-level ``key: ...`` line repeated with another value right after it."""
    lines = text.splitlines(keepends=True)
    i = next(k for k, line in enumerate(lines) if line.startswith(f"{key}:"))
    return "".join([*lines[: i + 1], f"{key}: {value}\n", *lines[i + 1 :]])


add(
    F_LAYOUT,
    "marker_size twice (issue 24: the last one taken, yaw moved 16 deg)",
    _layout_case(_twice(dump_yaml(LAYOUT), "marker_size", "0.12"), refuse=True),
)
add(
    F_CAMERA,
    "camera_name twice (issue 24: the last one taken)",
    _camera_text_case(_twice(_CAM_TEXT, "camera_name", "other"), refuse=True, strict=True),
)
add(
    F_ROBOT,
    "front_offset twice (issue 24: the last one taken)",
    _robot_case(None, refuse=True, text=_twice(_ROB_TEXT, "front_offset", "0.5"), strict=True),
)
_add_docking(
    "a key twice (issue 24: the last one taken)",
    _twice(_DOCK_TEXT, "control_period", "0.05"),
    True,
)


def _cv_twice(world: World, folder: Path) -> Plan:
    text = opencv_camera_text("yaml")
    cam = write(folder, "camera_cv.yaml", text.replace("image_width: 640\n", "image_width: 640\nimage_width: 800\n"))
    return estimate(world, folder, camera=cam, refuse=True, strict=True)


add(F_CAMERA_CV, "image_width twice (issue 24: OpenCV keeps the first)", _cv_twice)


def _json_twice(text: str) -> str:
    """A JSON object's text with its first key given twice: first a wrong value, then the file's own."""
    first = next(iter(json.loads(text)))
    return text.replace("{", f'{{"{first}": "wrong", ', 1)


def _manifest_twice(world: World, folder: Path) -> Plan:
    b = folder / "bundle"
    shutil.copytree(world.bundle, b)
    (b / "bundle.json").write_text(_json_twice((b / "bundle.json").read_text()))
    out = folder / "EST.csv"
    return ["estimate", str(world.image), "--model", str(b), "--out", str(out)], Expect(
        refuse=True, outputs=(out,), inputs=(b,), implausible_ok_without_valid=False
    )


def _metadata_twice(world: World, folder: Path) -> Plan:
    table = pq.read_table(world.dataset)
    meta = table.schema.metadata[b"monodock"].decode()
    ds = folder / "data.parquet"
    pq.write_table(table.replace_schema_metadata({b"monodock": _json_twice(meta).encode()}), ds)
    out = folder / "report"
    argv = ["evaluate", str(ds), "--model", str(world.bundle), "--out", str(out)]
    return argv, Expect(refuse=True, outputs=(out,), inputs=(ds,))


add(F_BUNDLE, "manifest key twice (issue 24: the last one taken)", _manifest_twice)
add(F_DATASET, "evaluate: metadata key twice (issue 24: the last one taken)", _metadata_twice)

# YAML 1.2 numbers: a float without a dot is a float (PyYAML's YAML 1.1 read 6e-4 as a string and refused it).
add(
    F_CAMERA,
    "distortion written 6e-4 and -4e-4 (issue 24: refused as strings)",
    _camera_text_case(_CAM_TEXT.replace("0.0006", "6e-4").replace("-0.0004", "-4e-4"), refuse=False, truth=True),
)
add(
    F_LAYOUT,
    "marker_size written 1e-1 (issue 24: YAML 1.1 read it as a string)",
    _layout_case(dump_yaml(LAYOUT).replace("marker_size: 0.1\n", "marker_size: 1e-1\n"), refuse=False, truth=True),
)
add(
    F_ROBOT,
    "camera mount x written 1e308 (issue 24: refused as a string, not as out of range)",
    _robot_case(None, refuse=True, text=_ROB_TEXT.replace("x: 0.17", "x: 1e308", 1), strict=True),
)


def _camera_beside_model(world: World, folder: Path) -> Run:
    """``--camera`` with a focal length 30 % longer than the bundle's camera: board x +30 %, which must not pass
    without a warning naming both focal lengths."""
    bundle_fx = CameraModel.default().fx
    scaled = set_path(set_path(CAM, CAM_FIELDS["fx"], CAM["camera_matrix"]["data"][0] * 1.3), CAM_FIELDS["fy"], 797.0)
    cam = write(folder, "camera.yaml", dump_yaml(scaled))
    out = folder / "EST.csv"
    argv = ["estimate", str(world.image), "--model", str(world.bundle), "--camera", str(cam), "--method", "board"]
    run = run_cli([*argv, "--out", str(out)], inputs=(cam,), outputs=(out,))
    warned = [line for line in run.err.splitlines() if ": warning: " in line and str(cam) in line]
    if run.code == 0 and not (warned and f"{bundle_fx:.1f}" in warned[0] and f"{bundle_fx * 1.3:.1f}" in warned[0]):
        run.err += f"silent: a camera other than the bundle's used without a warning naming both: {run.err!r}\n"
    return run


CASES.append(
    Case(
        F_CAMERA,
        "--camera beside --model, focal 30% longer (issue 24: used without a word)",
        lambda w, f: ([], Expect(outputs=(f / "EST.csv",))),
        library=_camera_beside_model,
    )
)

# The interrupt that ONNX Runtime swallows: a SIGINT while a model loads, which the library turns into its own
# error (as it did while train moved its bundle into place, exit 2). The command must still say "interrupted", 130.
_SWALLOWED = """
import os, signal, sys
import monodock.estimation.bundle as bundle


def swallowing(model):
    try:
        os.kill(os.getpid(), signal.SIGINT)
    except KeyboardInterrupt:
        pass
    raise RuntimeError("[ONNXRuntimeError] : 6 : RUNTIME_EXCEPTION : interrupted while loading")


bundle.ort_session = swallowing
from monodock.cli.main import main

sys.exit(main())
"""


def _swallowed_interrupt(world: World, folder: Path) -> Run:
    import subprocess
    import time

    out = folder / "EST.csv"
    argv = ["estimate", str(world.image), "--model", str(world.bundle), "--out", str(out)]
    src = Path(__file__).resolve().parents[2] / "src"
    env = {**os.environ, "PYTHONPATH": os.pathsep.join([str(src), os.environ.get("PYTHONPATH", "")])}
    t0 = time.perf_counter()
    proc = subprocess.run(
        [sys.executable, "-c", _SWALLOWED, *argv], capture_output=True, text=True, env=env, timeout=120, check=False
    )
    err = proc.stderr
    if proc.returncode != 130 or err.strip() != "monodock estimate: interrupted":
        err += f"silent: exit {proc.returncode}, not 130 with one line 'monodock estimate: interrupted'\n"
    # Judged as the clean refusal it is: exit 2, one line (unless it said otherwise above).
    code = 2 if proc.returncode == 130 else proc.returncode
    lines = "monodock estimate: error: interrupted\n" if "silent:" not in err else err
    return Run(argv, code, proc.stdout, lines, seconds=time.perf_counter() - t0)


CASES.append(
    Case(
        F_INTERRUPT,
        "SIGINT swallowed by ONNX Runtime while a bundle loads (issue 24: exit 2, not 130)",
        lambda w, f: ([], Expect(outputs=(f / "EST.csv",))),
        library=_swallowed_interrupt,
    )
)
