"""Exact camera images of a World: per-pixel ray casting through the real lens, area-integrated.

Each pixel's value is the mean albedo over its square footprint on the sensor. Every pixel corner is cast
first (compiled and culled per tile: :mod:`monodock.sim.raycast`). A pixel whose four corners agree, and whose
neighbours' corners agree, lies inside one flat-shaded region and takes their mean. A pixel on or next to an
edge takes the exact area integral of what it sees over its footprint where one or two surfaces meet in it, and
otherwise the mean of S x S n-rooks samples (every sample with its own column and row, so an edge in any
direction is resolved to 1/S^2 of a pixel). Rays inside a pixel are interpolated between its exactly
undistorted corners: the lens map is smooth enough that this is accurate to ~1e-4 px.

:mod:`monodock.sim.reference` is the plain numpy renderer this one is checked against
(``tests/sim/test_render.py``, ``bench/render_speed.py``).
"""

from __future__ import annotations

import functools
import time
from dataclasses import dataclass

import numpy as np
from numpy.typing import ArrayLike, NDArray

from monodock.core.camera import CameraModel
from monodock.errors import ConfigError
from monodock.sim import raycast
from monodock.sim.reference import nrooks
from monodock.sim.world import World

__all__ = ["MAX_SUPERSAMPLE", "RenderStats", "render_radiance", "tile_boxes"]

_PROBE = 4  # S of the probe on pixels next to an edge
MAX_SUPERSAMPLE = 64  # 4,096 rays a sampled pixel; more buys nothing the area integral does not have


@functools.lru_cache(maxsize=8)
def tile_boxes(camera: CameraModel) -> tuple[NDArray[np.float64], int]:
    """Per culling tile, the box (x0, x1, y0, y1) of its pixel corners' rays, and the tiles per row."""
    rays = camera.vertex_rays()
    H, W, T = camera.height, camera.width, raycast.TILE
    tiles_y, tiles_x = (H - 1) // T + 1, (W - 1) // T + 1
    boxes = np.empty((tiles_y * tiles_x, 4))
    for ty in range(tiles_y):
        for tx in range(tiles_x):
            block = rays[ty * T : min((ty + 1) * T, H) + 1, tx * T : min((tx + 1) * T, W) + 1].reshape(-1, 2)
            lo, hi = block.min(axis=0), block.max(axis=0)
            boxes[ty * tiles_x + tx] = (lo[0], hi[0], lo[1], hi[1])
    return boxes, tiles_x


@dataclass
class RenderStats:
    """What one render did: pixels straddling an edge, integrated by area and sampled; seconds of each stage
    (culling the surfaces per tile, casting the pixel corners, the edge pixels), for ``bench/render_speed.py``."""

    edge_pixels: int = 0
    by_area: int = 0
    sampled: int = 0
    culling_s: float = 0.0
    corners_s: float = 0.0
    edges_s: float = 0.0
    flat_tiles: float = 0.0  # share of tiles filled without casting


def render_radiance(
    world: World,
    camera: CameraModel,
    world_T_optical: ArrayLike,
    *,
    supersample: int = 16,
    stats: RenderStats | None = None,
) -> NDArray[np.float32]:
    """Area-integrated albedo image, shape (height, width), float32 in [0, 1], of the world seen by the camera.

    Args:
        world: surfaces in world coordinates.
        camera: intrinsics and lens distortion.
        world_T_optical: 4x4 pose of the camera's optical frame in the world.
        supersample: S; pixels that cannot be integrated by area get S*S samples.
        stats: if given, filled with how many pixels were integrated and sampled, and each stage's seconds.
    """
    if not 1 <= supersample <= MAX_SUPERSAMPLE:
        raise ConfigError(f"supersample must be 1-{MAX_SUPERSAMPLE}, got {supersample}")
    t0 = time.perf_counter()
    T = np.asarray(world_T_optical, dtype=np.float64)
    scene = raycast.scene_arrays(world)
    surf = raycast.surfaces_in_optical(scene, T)
    rays = camera.vertex_rays()  # (H+1, W+1, 2) undistorted normalised coordinates of pixel corners
    boxes, tiles_x = tile_boxes(camera)
    polys, poly_counts, patch_polys, patch_counts = raycast.frame_geometry(surf, scene.patches, scene.patch_surface)
    candidates, counts, tile_patches, patch_count, flat, covered = raycast.tile_candidates(
        polys, poly_counts, patch_polys, patch_counts, scene.patch_surface, surf, boxes
    )
    tiles = (candidates, counts, tile_patches, patch_count)
    texture = (scene.patches, scene.patch_surface, scene.cells, scene.no_hit)
    t1 = time.perf_counter()
    vert = raycast.cast_vertices(rays, surf, *texture, *tiles, flat, tiles_x)
    t2 = time.perf_counter()
    image, tally = raycast.shade_pixels(
        vert, rays, surf, scene.patch_start, *texture, polys, poly_counts, *tiles, flat, covered, tiles_x,
        nrooks(supersample), nrooks(_PROBE),
    )  # fmt: skip
    if stats is not None:
        stats.edge_pixels, stats.by_area, stats.sampled = (int(v) for v in tally)
        stats.culling_s, stats.corners_s, stats.edges_s = t1 - t0, t2 - t1, time.perf_counter() - t2
        stats.flat_tiles = float(np.isfinite(flat).mean())
    return image
