"""core.projection: the blind gap, against where the simulator's true corners of marker 2 leave the image."""

from __future__ import annotations

from monodock.core.pose import DockPose
from monodock.core.projection import blind_gap
from monodock.sim import Nuisances, Simulator


def test_blind_gap_is_where_marker_2_leaves_the_image() -> None:
    sim = Simulator(nuisances=Nuisances.clean())
    gap = blind_gap(sim.camera, sim.layout, sim.robot)
    assert 0.02 < gap < 0.3

    def in_view(g: float) -> bool:
        corners = sim.true_corners(DockPose(g + sim.robot.front_offset, 0.0, 0.0))["center"]
        return sim.in_view(corners)

    assert in_view(gap + 0.002)
    assert not in_view(gap - 0.002)
