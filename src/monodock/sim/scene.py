"""Random but seeded scene dressing: clutter on the wall and floor, and occluders in front of a marker."""

from __future__ import annotations

import numpy as np

from monodock.core.layout import DockLayout
from monodock.sim.world import INK_BLACK, PAPER_WHITE, Patch, Surface, World, rectangle

__all__ = ["add_clutter", "occluder_for"]


def _distractor_ids(layout: DockLayout, rng: np.random.Generator, count: int) -> list[int]:
    size = int(layout.aruco_dictionary().bytesList.shape[0])
    taken = {m.id for m in layout.markers}
    free = [i for i in range(size) if i not in taken]
    return [int(i) for i in rng.choice(free, size=min(count, len(free)), replace=False)]


def add_clutter(world: World, layout: DockLayout, rng: np.random.Generator) -> World:
    """Posters and ArUco markers of ids the dock does not use on the back wall, marks on the floor.

    Nothing is placed on the charger face, so the dock's own markers keep their quiet zone.
    """
    surfaces = list(world.surfaces)
    face = next(s for s in surfaces if s.name == "charger_face")
    half_w = face.s_len / 2.0
    for i, surf in enumerate(surfaces):
        if surf.name == "back_wall":
            patches: list[Patch] = []
            centre_s = surf.s_len / 2.0  # the wall's s runs like the face's: s = extent - y
            for _ in range(int(rng.integers(4, 9))):
                w, h = rng.uniform(0.15, 0.8), rng.uniform(0.1, 0.6)
                side = rng.choice([-1.0, 1.0])
                y = side * rng.uniform(half_w + 0.05, 1.6)
                patches.append(
                    Patch(centre_s - y - w / 2, rng.uniform(0.3, 1.6), w, h, rng.uniform(0.05, 0.95, (1, 1)))
                )
            for marker_id in _distractor_ids(layout, rng, int(rng.integers(1, 3))):
                bits = layout.marker_bits(marker_id).astype(np.float64)
                size = layout.marker_size * rng.uniform(0.7, 1.5)
                side = rng.choice([-1.0, 1.0])
                y = side * rng.uniform(half_w + 0.2, 1.5)
                values = INK_BLACK + bits * (PAPER_WHITE - INK_BLACK)
                patches.append(Patch(centre_s - y - size / 2, rng.uniform(1.5, 2.1), size, size, values))
            surfaces[i] = surf.with_patches(*patches)
        elif surf.name == "floor":
            patches = []
            for _ in range(int(rng.integers(2, 6))):
                w, h = rng.uniform(0.05, 1.5), rng.uniform(0.03, 0.4)
                s0 = surf.s_len / 2.0 + rng.uniform(-1.5, 1.5) - w / 2.0
                t0 = rng.uniform(0.4, 3.0)
                patches.append(Patch(s0, t0, w, h, rng.uniform(0.1, 0.8, (1, 1))))
            surfaces[i] = surf.with_patches(*patches)
    return World(tuple(surfaces), world.no_hit_albedo)


def occluder_for(
    layout: DockLayout,
    camera_centre: np.ndarray,
    rng: np.random.Generator,
) -> Surface:
    """A dark upright board between the camera and one dock marker, hiding part of it."""
    marker = layout.markers[int(rng.integers(0, 3))]
    target = np.array([0.0, marker.y + rng.uniform(-0.6, 0.6) * layout.marker_size, marker.z])
    frac = rng.uniform(0.3, 0.7)
    centre = camera_centre + frac * (target - camera_centre)
    to_cam = camera_centre - centre
    to_cam[2] = 0.0
    normal = to_cam / max(float(np.linalg.norm(to_cam)), 1e-9)
    right = np.cross(np.array([0.0, 0.0, 1.0]), normal)
    width = layout.marker_size * rng.uniform(0.3, 0.8) * frac
    height = layout.marker_size * 3.0
    top_left = centre - right * width / 2 + np.array([0.0, 0.0, height / 2])
    return rectangle("occluder", top_left, right, (0, 0, -1), width, height, float(rng.uniform(0.1, 0.5)))
