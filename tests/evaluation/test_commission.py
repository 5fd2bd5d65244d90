"""Commissioning a wrong world (``evaluation.commission``), measured against the world the simulator built.

Ground truth: ``sim.wrong_world`` draws the dock, the camera mount, the contacts and the wheels as a person builds
them; the survey, the drive and the back-off see only pixels and odometry, and the nominal files.
"""

from __future__ import annotations

import math

import pytest

from monodock.evaluation.commission import commission_world, summarize_worlds


@pytest.mark.slow
@pytest.mark.timeout(600)
def test_a_commissioned_world_is_as_good_as_its_exact_files_where_images_can_tell() -> None:
    """One world, commissioned end to end: each marker against the centre one within 0.5 mm and 0.2° (the print's
    overall scale divided out: no image shows it), the mount within 3 mm and 0.2°, and the fused method with the
    commissioned layout (at the world's scale, with the true robot) within 1.2x of its accuracy with the exact
    files, where the nominal files are tens of times worse and the commissioned files as a whole within the ruler's
    and the mount's reach (a few millimetres, a few tenths of a degree)."""
    world = commission_world(5, frames=40, docking_trials=0)
    s = summarize_worlds([world])
    assert s.marker["position_scaled_max_mm"] < 0.5
    assert s.marker["angle_max_deg"] < 0.2
    for k in ("x", "y"):
        assert abs(world.mount_error[k]) < 0.003, k
    for k in ("roll", "pitch", "yaw"):
        assert math.degrees(abs(world.mount_error[k])) < 0.2, k
    exact, layout = s.overall["exact"]["fused"], s.overall["layout"]["fused"]
    nominal, commissioned = s.overall["nominal"]["fused"], s.overall["commissioned"]["fused"]
    assert layout["n"] == exact["n"] == 40
    for key in ("x_mm", "y_mm", "yaw_deg"):
        assert layout[key] < 1.2 * exact[key], key
        assert nominal[key] > 20 * exact[key], key
    assert commissioned["x_mm"] < 6.0
    assert commissioned["y_mm"] < 4.0
    assert commissioned["yaw_deg"] < 0.3
    assert 0.0 < world.mount_sd["yaw"] < math.radians(0.2)
