"""Property-based tests (Hypothesis): files generated around the valid ones, through the library and the CLI.

Each property holds for every generated input: the command exits 0 with sane outputs (finite numbers; no
``valid=true`` estimate from a physically implausible file; nothing unknown copied out) or exits 2 with exactly one
stderr line; never exit 1, a traceback, a library's own log line, a hang, a half-written output or a changed input.
A library loader returns a plausible object or raises MonodockError, nothing else.

Every property is collected twice: ``test_x`` under the bounded, derandomized ``fuzz`` profile (the default run)
and ``test_x_slow`` under ``fuzz-slow``, marked slow (``pytest -m slow``). See README.md.
"""

from __future__ import annotations

import copy
import io
import json
import math
import re
import shutil
import tempfile
from collections.abc import Callable
from pathlib import Path
from typing import Any

import cv2
import numpy as np
import pyarrow.parquet as pq
import pytest
import yaml
from hypothesis import given, settings
from hypothesis import strategies as st

from fuzz.catalogue import CAM, CAM_FIELDS, DOCKING, LAYOUT, ROBOT, TRUTH_ROW
from fuzz.harness import UNKNOWN_MARK, Expect, dump, judge, run_cli, run_library
from fuzz.hostile import (
    DELETE,
    HUGE_INT,
    HugeInt,
    alias_bomb_yaml,
    dump_json,
    dump_yaml,
    plausible_camera,
    plausible_layout,
    plausible_robot,
    png_with_ihdr,
    set_path,
)
from fuzz.world import World, frames_of, opencv_camera_text, write_recording
from monodock.core.camera import CameraModel
from monodock.core.layout import DockLayout
from monodock.core.robot import RobotConfig
from monodock.estimation.bundle import seal_manifest

# Examples are whole files; Hypothesis warns that printing them is long, which is what they are.
pytestmark = pytest.mark.filterwarnings("ignore:Generating overly large repr")

# --- machinery ---------------------------------------------------------------------------------------------

Body = Callable[[World, Path, Any, Any], None]


def _folder(world: World) -> Path:
    (world.root / "hyp").mkdir(exist_ok=True)
    return Path(tempfile.mkdtemp(dir=world.root / "hyp"))


def properties(strategy: st.SearchStrategy[Any]) -> Callable[[Body], tuple[Any, Any]]:
    """The bounded and the slow test of ``body(world, folder, capfd, example)``."""

    def deco(body: Body) -> tuple[Any, Any]:
        def make(profile: str) -> Any:
            @settings(settings.get_profile(profile))
            @given(example=strategy)
            def test(world: World, capfd: pytest.CaptureFixture[str], example: Any) -> None:
                folder = _folder(world)
                try:
                    body(world, folder, capfd, example)
                finally:
                    shutil.rmtree(folder, ignore_errors=True)

            return test

        slow = pytest.mark.timeout(3600)(pytest.mark.slow(make("fuzz-slow")))
        return pytest.mark.timeout(120)(make("fuzz")), slow

    return deco


def assert_contract(argv: list[str], expect: Expect, capfd: Any) -> None:
    run = run_cli(argv, inputs=expect.inputs, outputs=expect.outputs, capfd=capfd)
    found = judge(run, expect)
    assert not found, "; ".join(f"{k}: {d}" for k, d in found) + "\n" + dump(run)


def assert_loader(call: Callable[[], Any], capfd: Any, *, plausible: bool) -> Any:
    """A library loader returns or raises MonodockError (one line); an implausible file must not load."""
    capfd.readouterr()
    holder: dict[str, Any] = {}

    def go() -> None:
        holder["value"] = call()

    run = run_library(go)
    found = judge(run, Expect())
    assert not found, "; ".join(f"{k}: {d}" for k, d in found) + "\n" + dump(run)
    if run.code == 2:
        assert len(run.err.strip().splitlines()) == 1, run.err
    loaded = "value" in holder
    assert plausible or not loaded, f"an implausible file loaded: {holder.get('value')!r}"
    return holder.get("value")


def parsed(text: str | bytes) -> Any:
    """What PyYAML makes of a file's text (None when it cannot)."""
    try:
        return yaml.safe_load(text)
    except Exception:
        return None


# --- strategies ------------------------------------------------------------------------------------------

hostile_numbers = st.one_of(
    st.floats(allow_nan=True, allow_infinity=True),
    st.sampled_from([math.nan, math.inf, -math.inf, 1e308, -1e308, 1e-300, -1e-300, 0.0, -0.0, 0, -1]),
    st.integers(min_value=-(10**9), max_value=10**9),
    st.just(HUGE_INT),
    st.text(max_size=6),
    st.lists(st.floats(allow_nan=False, allow_infinity=False), max_size=3),
    st.none(),
    st.booleans(),
)


def near(value: Any) -> st.SearchStrategy[Any]:
    """Plausible-looking values around a valid one (scaled, shifted, or of the other number type)."""
    if isinstance(value, bool) or not isinstance(value, int | float):
        return st.just(value)
    v = float(value)
    spread = max(abs(v), 0.1)
    floats = st.floats(min_value=v - 2 * spread, max_value=v + 2 * spread, allow_nan=False)
    if isinstance(value, int):
        return st.one_of(st.integers(min_value=int(v - 2 * spread), max_value=int(v + 2 * spread)), floats)
    return floats


def _get(data: Any, path: tuple[Any, ...]) -> Any:
    for p in path:
        data = data[p]
    return data


def _leaf_paths(data: Any, prefix: tuple[Any, ...] = ()) -> list[tuple[Any, ...]]:
    if isinstance(data, dict):
        return [p for k, v in data.items() for p in _leaf_paths(v, (*prefix, k))]
    if isinstance(data, list):
        return [p for i, v in enumerate(data) for p in _leaf_paths(v, (*prefix, i))]
    return [prefix]


@st.composite
def mutated(draw: st.DrawFn, base: dict[str, Any], paths: list[tuple[Any, ...]] | None = None) -> str | bytes:
    """The YAML text of ``base`` with 1-3 leaves replaced (hostile or nearby values), maybe a key dropped or added,
    maybe truncated or a non-UTF-8 byte put in."""
    candidates = paths or _leaf_paths(base)
    data: Any = copy.deepcopy(base)
    for path in draw(st.lists(st.sampled_from(candidates), min_size=1, max_size=3)):
        value = draw(st.one_of(hostile_numbers, near(_get(base, path))))
        data = set_path(data, path, value)
    shape = draw(st.sampled_from(["none", "none", "drop", "unknown", "bomb", "truncate", "bytes"]))
    if shape == "drop":
        data = set_path(data, draw(st.sampled_from(candidates))[:1], DELETE)
    if shape == "unknown":
        data = {**data, UNKNOWN_MARK: draw(hostile_numbers)}
    text = dump_yaml(data)
    if shape == "bomb":
        text += alias_bomb_yaml(UNKNOWN_MARK, levels=5)
    if shape == "truncate":
        text = text[: draw(st.integers(0, len(text)))]
    if shape == "bytes":
        raw = text.encode()
        at = draw(st.integers(0, len(raw)))
        return raw[:at] + draw(st.sampled_from([b"\xff", b"\xc3", b"\x00", b"\xfe\xff"])) + raw[at:]
    return text


def _write(folder: Path, name: str, content: str | bytes) -> Path:
    p = folder / name
    p.write_bytes(content.encode() if isinstance(content, str) else content)
    return p


def _estimate(
    world: World, folder: Path, *, refuse: bool, truth: bool = False, **swap: Path
) -> tuple[list[str], Expect]:
    out = folder / "EST.csv"
    image = swap.pop("image", world.image)
    argv = ["estimate", str(image), *world.calibration(**swap), "--out", str(out)]
    inputs = (image, *swap.values())
    return argv, Expect(refuse=refuse, truth=TRUTH_ROW if truth else None, outputs=(out,), inputs=inputs)


def _plausible(check: Callable[[dict[str, Any]], bool], text: str | bytes) -> bool:
    data = parsed(text)
    if isinstance(text, bytes):
        try:
            text.decode("utf-8")
        except UnicodeDecodeError:
            return False
    return isinstance(data, dict) and check(data)


# --- camera, layout, robot files -----------------------------------------------------------------------


@properties(mutated(CAM, [*CAM_FIELDS.values()]))
def _camera_ros(world: World, folder: Path, capfd: Any, text: str | bytes) -> None:
    cam = _write(folder, "camera.yaml", text)
    ok = _plausible(plausible_camera, text)
    assert_loader(lambda: CameraModel.load(cam), capfd, plausible=ok)
    assert_contract(*_estimate(world, folder, refuse=not ok, camera=cam), capfd)


test_camera_ros, test_camera_ros_slow = _camera_ros

_CV_KEYS = ("width", "height", "fx", "fy", "cx", "cy", "k1", "k2", "p1", "p2", "k3")
_cv_token = st.one_of(
    st.floats(allow_nan=True, allow_infinity=True).map(repr),
    st.sampled_from([".nan", ".inf", "-.inf", "nan", "inf", "1e999", "9" * 5000, "", "abc", "0x10", "1e-300"]),
    st.integers(min_value=-(10**6), max_value=10**6).map(str),
    st.floats(min_value=-1000, max_value=2000).map(repr),
)


@st.composite
def opencv_files(draw: st.DrawFn) -> tuple[str, str, dict[str, str]]:
    fmt = draw(st.sampled_from(["yaml", "xml"]))
    values = draw(st.dictionaries(st.sampled_from(_CV_KEYS), _cv_token, min_size=1, max_size=3))
    text = opencv_camera_text(fmt, **values)
    if draw(st.booleans()) and draw(st.booleans()):
        text = text[: draw(st.integers(0, len(text)))]
    return fmt, text, values


def _cv_plausible(values: dict[str, str], text: str, fmt: str) -> bool:
    if text != opencv_camera_text(fmt, **values):
        return False  # truncated
    data = copy.deepcopy(CAM)
    for key, token in values.items():
        hexadecimal = re.fullmatch(r"[+-]?0[xX][0-9a-fA-F]+", token) is not None  # OpenCV reads 0x10 as 16
        try:
            v: Any = int(token, 16) if hexadecimal else float(token.replace(".nan", "nan").replace(".inf", "inf"))
        except ValueError:
            return False
        if key in ("width", "height"):
            if not hexadecimal and (not v.is_integer() or "." in token or "e" in token.lower()):
                return False
            v = int(v)
            path: tuple[Any, ...] = ("image_width",) if key == "width" else ("image_height",)
        else:
            path = CAM_FIELDS[key]
        data = set_path(data, path, v)
    return plausible_camera(data)


@properties(opencv_files())
def _camera_opencv(world: World, folder: Path, capfd: Any, example: tuple[str, str, dict[str, str]]) -> None:
    fmt, text, values = example
    cam = _write(folder, f"camera.{fmt}", text)
    ok = _cv_plausible(values, text, fmt)
    assert_loader(lambda: CameraModel.load(cam), capfd, plausible=ok)
    assert_contract(*_estimate(world, folder, refuse=not ok, camera=cam), capfd)


test_camera_opencv, test_camera_opencv_slow = _camera_opencv


@properties(mutated(LAYOUT))
def _layout(world: World, folder: Path, capfd: Any, text: str | bytes) -> None:
    lay = _write(folder, "layout.yaml", text)
    ok = _plausible(plausible_layout, text)
    assert_loader(lambda: DockLayout.load(lay), capfd, plausible=ok)
    assert_contract(*_estimate(world, folder, refuse=not ok, layout=lay), capfd)


test_layout, test_layout_slow = _layout


@properties(mutated(ROBOT))
def _robot(world: World, folder: Path, capfd: Any, text: str | bytes) -> None:
    rob = _write(folder, "robot.yaml", text)
    ok = _plausible(plausible_robot, text)
    assert_loader(lambda: RobotConfig.load(rob), capfd, plausible=ok)
    assert_contract(*_estimate(world, folder, refuse=not ok, robot=rob), capfd)


test_robot, test_robot_slow = _robot


@properties(mutated(DOCKING))
def _docking(world: World, folder: Path, capfd: Any, text: str | bytes) -> None:
    from monodock.dock.config import docking_config_to_dict, load_docking_config

    path = _write(folder, "docking.yaml", text)
    data = parsed(text)
    # Plausible: a mapping of known keys whose numbers are finite and within 1e6 (the dataclass checks the rest).
    config = assert_loader(lambda: load_docking_config(path), capfd, plausible=True)
    if config is not None:
        assert isinstance(data, dict)
        assert UNKNOWN_MARK not in data
        for leaf in _leaf_paths(docking_config_to_dict(config)):
            v = _get(docking_config_to_dict(config), leaf)
            assert not isinstance(v, float) or (math.isfinite(v) and abs(v) <= 1e6), (leaf, v)


test_docking_config, test_docking_config_slow = _docking


# --- bundle manifest ---------------------------------------------------------------------------------------


@st.composite
def manifest_edits(draw: st.DrawFn) -> tuple[list[tuple[tuple[Any, ...], Any]], bool]:
    base = json.loads(_MANIFEST_TEXT)
    meta_paths = [("metadata", *p) for p in _leaf_paths(base["metadata"])]
    other = [p for p in _leaf_paths(base) if p[0] in ("segments", "sets", "schema_version")]
    edits = []
    for path in draw(st.lists(st.sampled_from(meta_paths * 3 + other), min_size=1, max_size=2)):
        value = draw(
            st.one_of(
                hostile_numbers.filter(lambda v: not (isinstance(v, float) and not math.isfinite(v))),
                near(_get(base, path)),
            )
        )
        edits.append((path, value))
    return edits, draw(st.booleans()) or draw(st.booleans())  # sealed 3 times in 4


_MANIFEST_TEXT = ""


def _manifest_text(world: World) -> str:
    global _MANIFEST_TEXT  # noqa: PLW0603 - the strategy needs the manifest before the fixture is at hand
    if not _MANIFEST_TEXT:
        _MANIFEST_TEXT = (world.bundle / "bundle.json").read_text()
    return _MANIFEST_TEXT


@pytest.fixture(autouse=True)
def _manifest(world: World) -> None:
    _manifest_text(world)


def _bundle_plausible(manifest: dict[str, Any]) -> bool:
    meta = manifest["metadata"]
    return (
        isinstance(meta, dict)
        and _plausible_dict(plausible_camera, meta.get("camera"))
        and _plausible_dict(plausible_layout, meta.get("layout"))
        and _plausible_dict(plausible_robot, meta.get("robot"))
    )


def _plausible_dict(check: Callable[[dict[str, Any]], bool], data: Any) -> bool:
    return (
        isinstance(data, dict)
        and not any(isinstance(_get(data, p), HugeInt) for p in _leaf_paths(data))
        and check(data)
    )


def _bundle_property(world: World, folder: Path, capfd: Any, example: tuple[list[Any], bool]) -> None:
    edits, seal = example
    b = folder / "bundle"
    shutil.copytree(world.bundle, b)
    manifest = json.loads(_manifest_text(world))
    for path, value in edits:
        manifest = set_path(manifest, path, value)
    edited = manifest != json.loads(_manifest_text(world))
    if seal:
        try:
            manifest = seal_manifest(manifest)
        except (TypeError, ValueError):  # a 5,000-digit number: not sealable, written as it is
            seal = False
    (b / "bundle.json").write_text(dump_json(manifest))
    # Unsealed edits must be refused; sealed ones of an implausible calibration too. Sealed edits of the models'
    # own entries may be refused or not (they are checked by their own checksums and shapes).
    refuse = (edited and not seal) or not _bundle_plausible(manifest)
    out = folder / "EST.csv"
    argv = ["estimate", str(world.image), "--model", str(b), "--out", str(out)]
    assert_contract(argv, Expect(refuse=refuse, outputs=(out,), inputs=(b,)), capfd)


test_bundle_manifest, test_bundle_manifest_slow = properties(manifest_edits())(_bundle_property)


# --- dataset metadata --------------------------------------------------------------------------------------


@st.composite
def dataset_edits(draw: st.DrawFn) -> list[tuple[tuple[Any, ...], Any]]:
    paths = [(k, *p) for k in ("camera", "robot", "layout") for p in _leaf_paths(_DATASET_META[k])]
    paths += [(k,) for k in ("camera", "robot", "layout", "schema")]
    out = []
    for path in draw(st.lists(st.sampled_from(paths), min_size=1, max_size=2)):
        out.append((path, draw(st.one_of(hostile_numbers, st.just(DELETE)))))
    return out


_DATASET_META: dict[str, Any] = {
    "camera": CAM,
    "robot": ROBOT,
    "layout": LAYOUT,
}


def _dataset_property(world: World, folder: Path, capfd: Any, edits: list[tuple[tuple[Any, ...], Any]]) -> None:
    from monodock.learning.dataset import read_dataset

    table = pq.read_table(world.dataset)
    meta = json.loads(table.schema.metadata[b"monodock"])
    for path, value in edits:
        meta = set_path(meta, path, value)
    ds_path = folder / "data.parquet"
    pq.write_table(table.replace_schema_metadata({b"monodock": dump_json(meta)}), ds_path)
    ok = (
        meta.get("schema") == "monodock.learning.dataset/2"
        and _plausible_dict(plausible_camera, meta.get("camera"))
        and _plausible_dict(plausible_robot, meta.get("robot"))
        and _plausible_dict(plausible_layout, meta.get("layout"))
    )

    def load() -> object:
        ds = read_dataset(ds_path)
        return ds.camera(), ds.robot(), ds.layout()

    assert_loader(load, capfd, plausible=ok)
    out = folder / "bundle"
    argv = ["train", str(ds_path), "--out", str(out), "--trials", "1", "--jobs", "1", "--sets", "m2"]
    # The world's dataset has too few rows to train on: a clean refusal is the right answer, whatever the edit.
    assert_contract(argv, Expect(refuse=True, outputs=(out,), inputs=(ds_path,)), capfd)


test_dataset_metadata, test_dataset_metadata_slow = properties(dataset_edits())(_dataset_property)


# --- images ------------------------------------------------------------------------------------------------


@st.composite
def image_bytes(draw: st.DrawFn) -> tuple[str, str, Any]:
    """(kind of edit, suffix, parameters): bytes around the valid PNG/JPEG."""
    kind = draw(st.sampled_from(["truncate", "flip", "ihdr", "depth", "channels", "jpeg-truncate", "jpeg-flip"]))
    if kind in ("truncate", "jpeg-truncate"):
        return kind, ".png" if kind == "truncate" else ".jpg", draw(st.floats(0.0, 1.0, exclude_max=True))
    if kind in ("flip", "jpeg-flip"):
        return (
            kind,
            ".png" if kind == "flip" else ".jpg",
            draw(
                st.lists(st.tuples(st.floats(0.0, 1.0, exclude_max=True), st.integers(0, 255)), min_size=1, max_size=12)
            ),
        )
    if kind == "ihdr":
        return (
            kind,
            ".png",
            draw(
                st.fixed_dictionaries(
                    {},
                    optional={
                        "width": st.one_of(st.integers(0, 2**31 - 1), st.sampled_from([0, 1, 639, 641, 60000])),
                        "height": st.one_of(st.integers(0, 2**31 - 1), st.sampled_from([0, 1, 479, 481, 60000])),
                        "bit_depth": st.sampled_from([0, 1, 2, 4, 8, 16, 3, 255]),
                        "color_type": st.sampled_from([0, 2, 3, 4, 6, 1, 7, 255]),
                    },
                )
            ),
        )
    if kind == "depth":
        return kind, draw(st.sampled_from([".png", ".tiff"])), draw(st.sampled_from(["uint16", "float32", "int8"]))
    return kind, ".png", draw(st.sampled_from([1, 2, 3, 4]))


def _image(world: World, kind: str, suffix: str, p: Any) -> tuple[bytes, bool]:
    """The bytes, and whether they still hold the valid picture (then a valid row must match the truth)."""
    if kind == "truncate":
        return world.png[: int(len(world.png) * p)], False
    if kind == "jpeg-truncate":
        return world.jpg[: int(len(world.jpg) * p)], False
    if kind in ("flip", "jpeg-flip"):
        b = bytearray(world.png if kind == "flip" else world.jpg)
        for where, value in p:
            b[int(where * len(b))] = value
        return bytes(b), bytes(b) == (world.png if kind == "flip" else world.jpg)
    if kind == "ihdr":
        h = png_with_ihdr(world.png, **p)
        return h, h == world.png
    if kind == "depth":
        img = world.pixels
        arr = {
            "uint16": img.astype(np.uint16) * 257,
            "float32": img.astype(np.float32) / 255,
            "int8": (img // 2).astype(np.int8),
        }[p]
        ok, buf = cv2.imencode(suffix, arr)
        return (bytes(buf) if ok else b""), ok and p != "int8"
    img = world.pixels
    if p == 2:  # grey and alpha: a PNG colour type OpenCV reads but cannot write
        from PIL import Image

        buf = io.BytesIO()
        Image.fromarray(np.dstack([img, np.full_like(img, 255)]), mode="LA").save(buf, format="PNG")
        return buf.getvalue(), True
    arr = {1: img, 3: cv2.cvtColor(img, cv2.COLOR_GRAY2BGR), 4: cv2.cvtColor(img, cv2.COLOR_GRAY2BGRA)}[p]
    return bytes(cv2.imencode(".png", arr)[1]), True


@properties(image_bytes())
def _images(world: World, folder: Path, capfd: Any, example: tuple[str, str, Any]) -> None:
    kind, suffix, p = example
    data, same_picture = _image(world, kind, suffix, p)
    img = _write(folder, f"frame{suffix}", data)
    # A damaged image may still decode (a flipped byte in pixel data): then its rows are judged only for sanity.
    argv, expect = _estimate(world, folder, refuse=False, truth=same_picture, image=img)
    assert_contract(argv, expect, capfd)
    out = folder / "overlay.png"
    assert_contract(
        ["show", str(img), *world.calibration(), "--out", str(out)], Expect(outputs=(out,), inputs=(img,)), capfd
    )


test_images, test_images_slow = _images


# --- recordings --------------------------------------------------------------------------------------------


@st.composite
def camera_info_edits(draw: st.DrawFn) -> dict[str, Any]:
    K = np.array(CameraModel.default().K)
    D = np.array(CameraModel.default().D)
    big = st.floats(allow_nan=True, allow_infinity=True, width=64)
    out: dict[str, Any] = {}
    for i in draw(st.lists(st.sampled_from([0, 2, 4, 5]), max_size=2)):
        # Around the valid value, even when an earlier draw already changed K[i] (to NaN, say).
        K[i] = draw(st.one_of(big, near(float(CameraModel.default().K[i]))))
    for i in draw(st.lists(st.integers(0, 4), max_size=2)):
        D[i] = draw(st.one_of(big, st.floats(-2, 2)))
    out["k"], out["d"] = K, D
    if draw(st.booleans()):
        out["width"] = draw(st.one_of(st.integers(0, 2**32 - 1), st.sampled_from([0, 640, 1280])))
    if draw(st.booleans()):
        out["distortion_model"] = draw(st.sampled_from(["plumb_bob", "rational_polynomial", "equidistant", ""]))
    return out


def _info_plausible(info: dict[str, Any]) -> bool:
    K, D = info["k"], info["d"]
    # An empty distortion_model is what many drivers publish; ROS tools, and monodock, read it as plumb_bob.
    model = info.get("distortion_model") or "plumb_bob"
    data = {
        "image_width": info.get("width", 640),
        "image_height": 480,
        "camera_matrix": {"data": [float(v) for v in K]},
        "distortion_coefficients": {"data": [float(v) for v in D]},
        "distortion_model": model,
    }
    # The recording's images are 640x480: a camera_info of another size cannot label them.
    return data["image_width"] == 640 and plausible_camera(data)


@properties(camera_info_edits())
def _recording(world: World, folder: Path, capfd: Any, info: dict[str, Any]) -> None:
    sim, frames = frames_of(world)
    rec = write_recording(folder / "rec", sim, frames, info=info)
    out = folder / "ds.parquet"
    argv = ["label", str(rec), "--layout", str(world.layout), "--out", str(out)]
    assert_contract(argv, Expect(refuse=not _info_plausible(info), outputs=(out,), inputs=(rec,)), capfd)


test_recording_camera_info, test_recording_camera_info_slow = _recording


# --- CLI numeric options -----------------------------------------------------------------------------------

_number_text = st.one_of(
    st.floats(allow_nan=True, allow_infinity=True).map(repr),
    st.integers(min_value=-(10**6), max_value=10**6).map(str),
    st.sampled_from(["nan", "inf", "-inf", "1e999", "1e-300", "9" * 5000, "", "abc", "0x10", "1_000", " 1"]),
)
_SIMULATE = [
    "--seed",
    "--depth",
    "--lateral",
    "--yaw",
    "--read-noise",
    "--exposure",
    "--gamma",
    "--vignetting",
    "--side-walls",
]


@st.composite
def simulate_options(draw: st.DrawFn) -> list[str]:
    opt = draw(st.sampled_from(_SIMULATE))
    n = 2 if opt in ("--depth", "--lateral", "--yaw") else 1
    return [opt, *(draw(_number_text) for _ in range(n))]


@properties(simulate_options())
def _simulate(world: World, folder: Path, capfd: Any, options: list[str]) -> None:
    out = folder / "sim"
    argv = ["simulate", "--out", str(out), "--frames", "1", "--supersample", "1", "--clean", "--jobs", "1", *options]
    # Any value may be refused; an accepted one must give sane files (finite, yaws wrapped).
    assert_contract(argv, Expect(outputs=(out,)), capfd)


test_simulate_options, test_simulate_options_slow = _simulate


@properties(
    st.tuples(
        st.sampled_from(["label --tolerance", "train --trials", "train --fusion-holdout", "calibrate --square"]),
        _number_text,
    )
)
def _other_options(world: World, folder: Path, capfd: Any, example: tuple[str, str]) -> None:
    which, value = example
    if which.startswith("label"):
        out = folder / "ds.parquet"
        argv = ["label", str(world.recording), "--layout", str(world.layout), "--out", str(out), "--tolerance", value]
        expect = Expect(outputs=(out,))
    elif which.startswith("train"):
        out = folder / "b"
        argv = ["train", str(world.dataset), "--out", str(out), "--sets", "m2", which.split()[1], value]
        expect = Expect(refuse=True, outputs=(out,))  # too few rows to train, whatever the option
    else:
        out = folder / "cam.yaml"
        argv = ["calibrate", "intrinsics", str(world.image), "--out", str(out), "--square", value]
        expect = Expect(refuse=True, outputs=(out,))  # no checkerboard in the image
    assert_contract(argv, expect, capfd)


test_numeric_options, test_numeric_options_slow = _other_options
