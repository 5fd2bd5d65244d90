"""Error summaries against hand-computed answers."""

from __future__ import annotations

import math

import numpy as np
import pytest

from monodock.core.pose import DockPose
from monodock.evaluation.metrics import band_table, pose_errors


def test_pose_errors_wrap_yaw_and_mark_missing() -> None:
    truth = [DockPose(1.0, 0.0, math.radians(179.0)), DockPose(2.0, 0.1, 0.0)]
    est = [DockPose(1.02, -0.01, math.radians(-179.0)), None]
    e = pose_errors(truth, est)
    np.testing.assert_allclose(e[0], [0.02, -0.01, math.radians(2.0)], atol=1e-12)
    assert np.all(np.isnan(e[1]))


def test_band_table_counts_and_means() -> None:
    depth = np.array([0.30, 0.40, 0.60, 2.50])
    errors = np.array([[0.01, 0.0, 0.0], [0.03, 0.0, 0.0], [np.nan, np.nan, np.nan], [-0.02, 0.0, 0.0]])
    rows = {r.band: r for r in band_table("board", depth, errors)}
    assert rows["25-50 cm"].frames == 2
    assert rows["25-50 cm"].depth_mae_cm == pytest.approx(2.0)
    assert rows["50-75 cm"].valid == 0
    assert rows["225-250 cm"].frames == 1  # the upper edge belongs to the last band
    assert rows["all"].frames == 4
    assert rows["all"].valid == 3
    assert rows["all"].depth_mae_cm == pytest.approx(2.0)
