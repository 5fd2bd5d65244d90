"""The dock database against Nav2's own: upstream's dock files and the staging pose, worked out by hand from
``simple_charging_dock.cpp`` (getStagingPose) and ``utils.hpp`` (parseDockFile, l2Norm), Kilted."""

from __future__ import annotations

import math
from pathlib import Path

import pytest

from monodock.core.pose2d import Pose2D
from monodock.dock.database import (
    PLUGIN,
    DockDatabase,
    DockInstance,
    DockType,
    load_dock_file,
    pose_distance,
    staging_pose,
)
from monodock.dock.nav2 import DockNotInDB, DockNotValid, Nav2Code
from monodock.errors import ConfigError

# opennav_docking/test/dock_files/test_dock_file.yaml, verbatim (Kilted).
UPSTREAM_FILE = """docks:
  dock1:
    type: "dockv3"
    frame: "mapA"
    pose: [0.3, 0.3, 0.0]
  dock2:
    type: "dockv1"
    pose: [0.0, 0.0, 0.4]
    id: "2"
"""


def test_upstream_s_own_dock_file_reads_as_upstream_reads_it(tmp_path: Path) -> None:
    path = tmp_path / "docks.yaml"
    path.write_text(UPSTREAM_FILE)
    docks = load_dock_file(path)
    assert docks == {
        "dock1": DockInstance("dock1", "dockv3", "mapA", Pose2D(0.3, 0.3, 0.0), ""),
        "dock2": DockInstance("dock2", "dockv1", "map", Pose2D(0.0, 0.0, 0.4), "2"),  # frame: map by default
    }


@pytest.mark.parametrize(
    ("text", "words"),
    [
        ("{}", "does not contain 'docks'"),
        ("docks: {a: {pose: [0, 0, 0]}}", "missing field 'docks.a.type'"),
        ("docks: {a: {type: t}}", "missing field 'docks.a.pose'"),
        ("docks: {a: {type: t, pose: [0, 0]}}", "docks.a.pose: expected a list of 3 numbers"),
        ("docks: {a: {type: t, pose: [0, 0, .nan]}}", "docks.a.pose: expected finite numbers"),
        ("docks: [a, b]", "docks: expected a mapping"),
    ],
)
def test_a_bad_dock_file_is_one_line_naming_the_field(tmp_path: Path, text: str, words: str) -> None:
    path = tmp_path / "docks.yaml"
    path.write_text(text)
    with pytest.raises(ConfigError) as raised:
        load_dock_file(path)
    assert words in str(raised.value)
    assert "\n" not in str(raised.value)


def test_the_staging_pose_is_upstream_s() -> None:
    # SimpleChargingDock's defaults: 0.7 m before the dock pose along its heading, the same heading.
    dock = Pose2D(2.0, 1.0, math.pi / 2)
    assert staging_pose(dock, DockType("t")) == pytest.approx(Pose2D(2.0, 0.3, math.pi / 2))
    turned = DockType("t", staging_x_offset=-1.0, staging_yaw_offset=math.pi)
    x, y, yaw = staging_pose(Pose2D(0.0, 0.0, 0.0), turned)
    assert (x, y) == pytest.approx((-1.0, 0.0))
    assert abs(math.sin(yaw)) < 1e-12
    assert math.cos(yaw) == pytest.approx(-1.0)
    # l2Norm: the heading difference counts as a distance (rad), as dock_prestaging_tolerance bounds it.
    assert pose_distance(Pose2D(0, 0, 0), Pose2D(0.3, 0.4, 0.0)) == pytest.approx(0.5)
    assert pose_distance(Pose2D(0, 0, 3.0), Pose2D(0, 0, -3.0)) == pytest.approx(2 * math.pi - 6.0)


def test_goals_find_their_dock_as_upstream_s_database_does() -> None:
    database = DockDatabase(
        {"monodock": DockType("monodock")},
        {"home_dock": DockInstance("home_dock", "monodock", pose=Pose2D(1, 2, 0))},
    )
    dock, dock_type = database.find_dock("home_dock")
    assert (dock.name, dock_type.name) == ("home_dock", "monodock")
    with pytest.raises(DockNotInDB) as missing:
        database.find_dock("other")
    assert missing.value.code == Nav2Code.DOCK_NOT_IN_DB == 901
    # A pose goal: its dock_type, or the only type when it gives none; an unknown type has no plugin.
    assert database.pose_goal("map", Pose2D(0, 0, 0), "")[1].name == "monodock"
    with pytest.raises(DockNotValid) as invalid:
        database.pose_goal("map", Pose2D(0, 0, 0), "tag_dock")
    assert invalid.value.code == 902
    two = DockDatabase({"a": DockType("a"), "b": DockType("b")})
    assert two.find_type("") is None  # more than one type: an empty one names none
    assert two.find_type("b") == DockType("b")


def test_a_database_refuses_a_foreign_plugin_and_a_dock_of_no_type() -> None:
    with pytest.raises(ConfigError, match="not monodock's"):
        DockDatabase({"charger": DockType("charger", plugin="opennav_docking::SimpleChargingDock")})
    with pytest.raises(ConfigError, match="type 'x' is not among the dock types"):
        DockDatabase({"monodock": DockType("monodock"), "b": DockType("b")}, {"d": DockInstance("d", "x")})
    with pytest.raises(ConfigError, match="no dock types"):
        DockDatabase({})
    assert PLUGIN == "monodock::ArucoChargingDock"
