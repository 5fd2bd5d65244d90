"""Nav2-ready pose bags (io.nav2): detected_dock_pose and its covariance, written from EST rows and read back."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest

from monodock.errors import InputError
from monodock.io.nav2 import (
    DOCK_POSE_COVARIANCE_TOPIC,
    POSE_WITH_COVARIANCE_STAMPED,
    planar_covariance,
    pose_covariance_6x6,
    read_pose_bag,
    write_pose_bag,
)
from monodock.io.rows import COVARIANCE_COLUMNS


def test_write_pose_bag_from_est_csv_rows(tmp_path: Path) -> None:
    """EST.csv rows as csv.DictReader gives them: only the valid ones with a stamp are published."""
    rows = [
        {"stamp": "1.5", "valid": "true", "x_m": "0.8", "y_m": "-0.1", "yaw_deg": "10"},
        {"stamp": "1.6", "valid": "false", "x_m": "", "y_m": "", "yaw_deg": ""},
        {"stamp": "", "valid": "true", "x_m": "0.7", "y_m": "0.0", "yaw_deg": "0"},
    ]
    assert write_pose_bag(tmp_path / "b", rows) == 1
    (msg,) = read_pose_bag(tmp_path / "b")
    assert msg.stamp == pytest.approx(1.5)
    assert msg.pose.x == pytest.approx(0.8)
    assert msg.pose.yaw_deg == pytest.approx(10.0)
    with pytest.raises(InputError, match="exists"):
        write_pose_bag(tmp_path / "b", rows)


def _cov_cells(cov: np.ndarray) -> dict[str, str]:
    """EST.csv covariance cells of a 3x3 (x, y, yaw) covariance, as estimates_csv formats them."""
    cells = ((0, 0), (0, 1), (0, 2), (1, 1), (1, 2), (2, 2))
    return {k: format(float(cov[i, j]), ".6g") for k, (i, j) in zip(COVARIANCE_COLUMNS, cells, strict=True)}


@pytest.mark.parametrize("storage", ["mcap", "sqlite3"])
def test_pose_bag_carries_the_covariance_on_a_second_topic(tmp_path: Path, storage: str) -> None:
    """Rows with covariance cells: PoseStamped for every valid row, PoseWithCovarianceStamped for those with a
    covariance, on detected_dock_pose_with_covariance; the (x, y, yaw) block round-trips into rows and columns
    (0, 1, 5) of the 6x6, the rest zero."""
    cov = np.array([[4e-6, 1e-7, -2e-6], [1e-7, 1e-6, 3e-7], [-2e-6, 3e-7, 9e-5]])
    empty = dict.fromkeys(COVARIANCE_COLUMNS, "")
    rows = [
        {
            "frame": "0",
            "stamp": "1.5",
            "valid": "true",
            "x_m": "0.8",
            "y_m": "-0.1",
            "yaw_deg": "10",
            **_cov_cells(cov),
        },
        {"frame": "1", "stamp": "1.6", "valid": "true", "x_m": "0.7", "y_m": "0.0", "yaw_deg": "0", **empty},
        {"frame": "2", "stamp": "1.7", "valid": "false", "x_m": "", "y_m": "", "yaw_deg": "", **empty},
        {
            "frame": "3",
            "stamp": "1.8",
            "valid": "true",
            "x_m": "0.6",
            "y_m": "0.05",
            "yaw_deg": "-5",
            **_cov_cells(2 * cov),
        },
    ]
    bag = tmp_path / "b"
    assert write_pose_bag(bag, rows, storage=storage) == 3
    plain = read_pose_bag(bag)
    assert [p.stamp for p in plain] == pytest.approx([1.5, 1.6, 1.8])
    assert all(p.covariance is None and p.pose_covariance is None for p in plain)
    with_cov = read_pose_bag(bag, DOCK_POSE_COVARIANCE_TOPIC)
    assert [p.msgtype for p in with_cov] == [POSE_WITH_COVARIANCE_STAMPED] * 2
    assert [p.topic for p in with_cov] == [DOCK_POSE_COVARIANCE_TOPIC] * 2
    for msg, twin, c in zip(with_cov, (plain[0], plain[2]), (cov, 2 * cov), strict=True):
        assert (msg.stamp, msg.frame_id, msg.position, msg.orientation) == (
            twin.stamp,
            twin.frame_id,
            twin.position,
            twin.orientation,
        )
        assert msg.covariance is not None
        full = np.array(msg.covariance).reshape(6, 6)
        np.testing.assert_allclose(full[np.ix_((0, 1, 5), (0, 1, 5))], c, rtol=1e-5)
        full[np.ix_((0, 1, 5), (0, 1, 5))] = 0.0
        assert not full.any()  # z, roll and pitch: fixed by the floor, zero
        np.testing.assert_allclose(msg.pose_covariance, c, rtol=1e-5)


def test_covariance_cells_that_are_not_a_covariance_are_refused(tmp_path: Path) -> None:
    row = {"frame": "7", "stamp": "1.0", "valid": "true", "x_m": "0.8", "y_m": "0", "yaw_deg": "0"}
    bad = _cov_cells(np.diag([1e-4, -1e-4, 1e-4]))
    with pytest.raises(InputError, match=r"frame 7.*positive semi-definite"):
        write_pose_bag(tmp_path / "b", [{**row, **bad}])
    half = {**_cov_cells(np.eye(3) * 1e-4), "cov_yy": ""}
    with pytest.raises(InputError, match=r"frame 7.*not all numbers"):
        write_pose_bag(tmp_path / "c", [{**row, **half}])


def test_a_bag_without_covariances_has_no_covariance_topic(tmp_path: Path) -> None:
    """Methods without a covariance (board here): the second topic is not created."""
    rows = [{"stamp": "1.5", "valid": "true", "x_m": "0.8", "y_m": "-0.1", "yaw_deg": "10"}]
    assert write_pose_bag(tmp_path / "b", rows) == 1
    with pytest.raises(InputError, match="no topic"):
        read_pose_bag(tmp_path / "b", DOCK_POSE_COVARIANCE_TOPIC)


def test_pose_covariance_6x6_layout() -> None:
    cov = np.arange(9, dtype=float).reshape(3, 3)
    cov = cov + cov.T
    full = pose_covariance_6x6(cov)
    assert len(full) == 36
    assert (full[0], full[1], full[5]) == (cov[0, 0], cov[0, 1], cov[0, 2])
    assert (full[6 * 5 + 5], full[6 * 5 + 1]) == (cov[2, 2], cov[2, 1])
    np.testing.assert_array_equal(planar_covariance(full), cov)
    with pytest.raises(ValueError, match="3x3"):
        pose_covariance_6x6(np.eye(2))
