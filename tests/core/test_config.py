"""The one YAML/JSON reader (issue 24): YAML 1.2's numbers, a key named twice refused, and YAML that monodock
writes read back unchanged here and by a YAML 1.1 reader."""

from __future__ import annotations

import math
from pathlib import Path

import pytest
import yaml

from monodock.core.camera import CameraModel
from monodock.core.config import load_yaml, parse_json, parse_yaml, yaml_text
from monodock.core.layout import DockLayout
from monodock.core.settings import to_mapping
from monodock.errors import ConfigError

ROOT = Path(__file__).resolve().parents[2]


@pytest.mark.parametrize(
    ("text", "value"),
    [
        ("6e-4", 6e-4),
        ("-4E-4", -4e-4),
        ("1e308", 1e308),
        ("1.", 1.0),
        (".5", 0.5),
        ("+5", 5),
        ("012", 12),  # YAML 1.1: octal 10
        ("0o17", 15),
        ("0x1F", 31),
        ("yes", "yes"),  # YAML 1.1: True
        ("off", "off"),
        ("True", True),
        ("FALSE", False),
        ("1:30", "1:30"),  # YAML 1.1: 90 (sexagesimal)
        ("2024-01-01", "2024-01-01"),  # YAML 1.1: a date
        ("~", None),
        ("-.inf", -math.inf),
    ],
)
def test_plain_scalars_follow_yaml_1_2(text: str, value: object) -> None:
    got = parse_yaml(f"a: {text}\n", "t.yaml")["a"]
    assert type(got) is type(value)
    assert got == value


def test_a_distortion_written_without_a_dot_gives_the_camera_it_describes(tmp_path: Path) -> None:
    cam = CameraModel.default()
    text = cam.to_ros_dict()
    path = tmp_path / "camera.yaml"
    path.write_text(yaml_text(text, flow=None).replace("0.0006", "6e-4").replace("-0.0004", "-4e-4"))
    assert "6e-4" in path.read_text()
    assert pytest.approx(cam.D) == CameraModel.load(path).D


@pytest.mark.parametrize(
    ("text", "key", "lines"),
    [
        ("marker_size: 0.1\ndictionary: DICT_4X4_50\nmarker_size: 0.12\n", "marker_size", "lines 1 and 3"),
        ("markers:\n  left: {id: 1, y: 0.2, z: 0.3, y: 0.4}\n", "y", "lines 2 and 2"),
        ("a: &x {b: 1}\nc:\n  <<: *x\n  b: 2\nc: 3\n", "c", "lines 2 and 5"),
    ],
)
def test_a_key_named_twice_is_refused_naming_it_and_the_file(tmp_path: Path, text: str, key: str, lines: str) -> None:
    path = tmp_path / "layout.yaml"
    path.write_text(text)
    with pytest.raises(ConfigError) as err:
        load_yaml(path, "layout")
    assert str(err.value).startswith(f"{path}: key '{key}' appears twice ({lines})")


def test_a_merge_key_may_override_what_it_merges() -> None:
    assert parse_yaml("a: &x {b: 1, c: 1}\nd:\n  <<: *x\n  b: 2\n", "t.yaml")["d"] == {"b": 2, "c": 1}


def test_a_json_key_named_twice_is_refused() -> None:
    with pytest.raises(ConfigError, match="key 'schema' appears twice"):
        parse_json('{"schema": "a", "x": {"y": 1}, "schema": "b"}', "bundle.json")
    assert parse_json('{"a": {"b": 1}, "b": {"b": 2}}', "ok.json") == {"a": {"b": 1}, "b": {"b": 2}}


@pytest.mark.parametrize("name", ["6e-4", "yes", "on", "012", "0o17", "1:30", "null", "True"])
def test_what_monodock_writes_reads_back_the_same_by_both_yaml_versions(name: str) -> None:
    layout = DockLayout.default()
    data = {**CameraModel.default().to_ros_dict(), "camera_name": name, "layout": to_mapping(layout)}
    text = yaml_text(data, flow=None)
    assert parse_yaml(text, "t.yaml") == data
    assert yaml.safe_load(text) == data


def test_every_shipped_yaml_reads_the_same_under_yaml_1_1_and_1_2() -> None:
    files = [
        *sorted((ROOT / "config").glob("*.yaml")),
        *sorted((ROOT / "docs").glob("*.yaml")),
        *sorted((ROOT / "bench" / "setups").rglob("*.yaml")),
    ]
    assert files
    for path in files:
        assert load_yaml(path, "shipped") == yaml.safe_load(path.read_text()), path
