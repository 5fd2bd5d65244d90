"""Docks with more markers than the papers' three (issue 28): the layout file, and what the simulator and the
geometric methods make of a large far-field marker, against the simulator's truth."""

from __future__ import annotations

import math

import numpy as np
import pytest

from monodock.core.layout import MAX_MARKERS, DockLayout, MarkerSpec
from monodock.core.pose import DockPose
from monodock.core.robot import RobotConfig
from monodock.core.settings import from_mapping, to_mapping
from monodock.errors import ConfigError
from monodock.estimation.factory import make_estimator
from monodock.sim import Nuisances, Simulator

FAST = Nuisances().updated(supersample=2)


def far_layout() -> DockLayout:
    """Today's dock with a 30 cm marker above it, off to the left (its yaw is not ambiguous with the others)."""
    base = DockLayout.default()
    return DockLayout(base.dictionary, base.marker_size, (*base.markers, MarkerSpec("far", 7, 0.25, 0.75, size=0.30)))


def test_a_layout_of_the_papers_three_reads_and_writes_as_it_always_did() -> None:
    base = DockLayout.default()
    assert base.roles == ("left", "center", "right")
    assert from_mapping(DockLayout, to_mapping(base), "layout") == base
    assert list(to_mapping(base)["markers"]) == ["left", "center", "right"]
    assert [m.label for m in base.markers] == ["m1", "m2", "m3"]


def test_other_markers_follow_the_papers_three_in_the_file_s_order() -> None:
    data = to_mapping(far_layout())
    data["markers"] = {"side_b": {"id": 9, "y": -0.45, "z": 0.3}, **data["markers"]}  # listed first in the file
    layout = from_mapping(DockLayout, data, "layout")
    assert layout.roles == ("left", "center", "right", "side_b", "far")
    assert layout.side("far") == pytest.approx(0.30)
    assert layout.side("side_b") == layout.marker_size
    assert layout.marker("far").label == "far"
    assert layout.marker("far").number is None
    assert from_mapping(DockLayout, to_mapping(layout), "layout") == layout


@pytest.mark.parametrize(
    ("change", "says"),
    [
        ({"Far-1": {"id": 7, "y": 0.25, "z": 0.75}}, "unknown marker role"),
        ({"far": {"id": 2, "y": 0.25, "z": 0.75}}, "ids must be distinct"),
        ({"far": {"id": 7, "y": 0.05, "z": 0.35}}, "overlap"),
        ({f"m{i}": {"id": 4 + i, "y": 0.0, "z": 0.5 + 0.15 * i} for i in range(MAX_MARKERS - 2)}, "at most 16"),
    ],
)
def test_a_bad_extra_marker_is_refused_naming_it(change: dict[str, object], says: str) -> None:
    data = to_mapping(DockLayout.default())
    data["markers"] = {**data["markers"], **change}
    with pytest.raises(ConfigError, match=says):
        from_mapping(DockLayout, data, "layout")


def test_the_papers_three_are_still_required() -> None:
    data = to_mapping(far_layout())
    del data["markers"]["right"]
    with pytest.raises(ConfigError, match="right: missing"):
        from_mapping(DockLayout, data, "layout")


def _estimate(layout: DockLayout, truth: DockPose, method: str, seed: int) -> tuple[object, object]:
    sim = Simulator(layout=layout, nuisances=FAST, seed=seed)
    estimator = make_estimator(method=method, camera=sim.camera, layout=layout, robot=RobotConfig.default())
    frame = sim.frame(truth, rng=np.random.default_rng(seed))
    result = estimator.estimate("f", 0.0, frame.image)
    return result.detection, result.estimates[method]


@pytest.mark.parametrize(("depth", "lateral"), [(5.5, 0.73), (6.5, 0.0)])
def test_the_far_marker_is_seen_and_used_where_the_small_ones_fail(depth: float, lateral: float) -> None:
    # 5.5 m out and 7.5 degrees off the axis, a marker or two of today's dock is still decoded and the pose from it is
    # decimetres off; at 6.5 m none is. The 30 cm marker has about 6 px a cell there.
    truth = DockPose(depth, lateral, math.radians(-12.0))
    detection, est = _estimate(far_layout(), truth, "fused", seed=3)
    assert detection is not None
    assert "far" in detection.roles_seen
    assert est.pose is not None, est.reason
    assert "far" in est.markers_seen
    assert abs(est.pose.x - truth.x) < 0.02
    assert abs(est.pose.y - truth.y) < 0.01
    assert abs(math.degrees(est.pose.yaw - truth.yaw)) < 0.5
    _, today = _estimate(DockLayout.default(), truth, "fused", seed=3)
    assert today.pose is None or abs(today.pose.x - truth.x) > 0.1 or abs(today.pose.yaw - truth.yaw) > 0.1
    # Board PnP takes it too (a single far marker's pose: valid, less precise).
    _, board = _estimate(far_layout(), truth, "board", seed=3)
    assert board.pose is not None
    assert "far" in board.markers_seen
    # And the single-marker method, where marker 2 is not decoded, takes the far marker alone (IPPE_SQUARE): a
    # coarse pose, but the dock's, where today's dock gives none.
    pnp_detection, pnp = _estimate(far_layout(), truth, "pnp", seed=3)
    assert pnp_detection is not None
    if "center" not in pnp_detection.roles_seen:
        assert pnp.markers_seen == ("far",)
        assert pnp.pose is not None, pnp.reason
        assert abs(pnp.pose.x - truth.x) < 0.05 * truth.x  # ~28 px a side at 6.5 m: a few per cent
        assert abs(math.degrees(pnp.pose.yaw - truth.yaw)) < 6.0


def test_near_the_dock_the_extra_marker_leaves_the_papers_markers_estimate_alone() -> None:
    # 0.8 m out, the far marker out of the picture: the same pose as on today's dock, to the bit.
    truth = DockPose(0.8, 0.03, math.radians(4.0))
    detection, with_far = _estimate(far_layout(), truth, "board", seed=5)
    assert detection is not None
    assert "far" not in detection.roles_seen
    _, today = _estimate(DockLayout.default(), truth, "board", seed=5)
    assert with_far.pose == today.pose
    # marker 2 seen: the single-marker method is the papers' baseline on it, whatever else the dock carries
    _, pnp_far = _estimate(far_layout(), truth, "pnp", seed=5)
    _, pnp_today = _estimate(DockLayout.default(), truth, "pnp", seed=5)
    assert pnp_far.markers_seen == ("center",)
    assert pnp_far.pose == pnp_today.pose
