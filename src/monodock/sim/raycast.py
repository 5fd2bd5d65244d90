"""Compiled ray casting of a World for the renderer: culled per tile, edges integrated by exact area.

The numpy reference (:mod:`monodock.sim.reference`) casts every pixel corner against every surface and
supersamples every edge pixel on 16 x 16 rays. Here the same image costs a small fraction of that:

- **Projected polygons.** Every surface and every painted patch is a rectangle; clipped to the half-space in
  front of the camera and projected to the normalised image plane (x/z, y/z) it is a convex polygon: exactly the
  rays that can hit it.
- **Culling per tile.** A 16 x 16-pixel tile casts only against the surfaces whose polygon overlaps the tile's
  box of rays (separating axes, conservative). A tile inside one surface's polygon and clear of its patches is
  one flat colour and is filled without casting.
- **Edges by area.** A pixel's footprint is the quad Q of its four corner rays. The surfaces it can see are those
  whose polygon overlaps Q; with one or two of them (and at most one painted patch under each) its value is the
  exact area integral: Q is clipped to each surface's polygon, where two overlap to the half-plane on which
  one is nearer (two planes' depth order flips along one line in the image), and to each painted cell in the
  surface's (s, u) coordinates; areas are measured on the normalised image plane, through each plane's
  homography, where a pixel's area is uniform (the lens's Jacobian varies by ~1e-4 across a pixel). Where
  three surfaces meet or patches overlap, the pixel is sampled on the reference's S x S n-rooks pattern.

Rays are normalised camera coordinates d = (x, y, 1) in the optical frame. A surface is moved into that frame
once per image, so a ray costs two multiply-adds for the plane and one division.
"""

from __future__ import annotations

import weakref

import numpy as np
from numpy.typing import NDArray

from monodock.core.compiled import inlined, kernel
from monodock.sim.polygon import box_inside, clip_half_plane, edge_line, overlaps_box, signed_area
from monodock.sim.world import World

__all__ = [
    "FLAT",
    "TILE",
    "SceneArrays",
    "cast_vertices",
    "frame_geometry",
    "scene_arrays",
    "shade_pixels",
    "surfaces_in_optical",
    "tile_candidates",
]

TILE = 16  # pixels per side of a culling tile
NEAR = 1e-6  # metres: the clip plane in front of the camera for the projected polygons
MAX_CELLS = 64  # a footprint over more painted cells than this is sampled instead
FLAT = 1e-9  # albedo differences below this are one flat region (as the reference)
MAX_POLY = 8  # vertices of a projected rectangle (4, or 5 when the near plane cuts it)
_BUF = 40  # vertices of a clipped polygon: Q (4) by two polygons (5 edges each), a half-plane, a cell (4)
# Rows (x, y pairs) of the per-pixel polygon buffer: the quad, up to _SEEN surfaces' parts of it, an overlap and
# one side of it, then scratch for polygon clipping and for the texture integral.
_SEEN = 4
_QUAD, _PART, _OVERLAP, _SIDE, _CLIP, _TEX = 0, 2, 2 + 2 * _SEEN, 4 + 2 * _SEEN, 7 + 2 * _SEEN, 11 + 2 * _SEEN
_ROWS = _TEX + 6

# Columns of the per-frame surface table (optical frame).
_N, _SA, _TA, _NUM, _S0, _T0, _SLEN, _TLEN, _ALB, _OFF = 0, 3, 6, 9, 10, 11, 12, 13, 14, 15
_SURF_COLS = 18  # ... the surface's origin relative to the camera is columns 15:18


class SceneArrays:
    """A World flattened for the compiled kernels: its surfaces' geometry and their patches' cells.

    Attributes:
        geometry: (K, 15) per surface: origin (3), s_axis (3), t_axis (3), normal (3), s_len, t_len, albedo.
        patch_start: (K + 1,) surface k's patches are rows patch_start[k]:patch_start[k+1] of ``patches``.
        patches: (P, 9) per patch, in painting order: s0, t0, width, height, rows, cols, offset into
            ``cells``, s0 + width, t0 + height.
        patch_surface: (P,) the surface each patch is painted on.
        cells: every patch's cell albedos, row-major, concatenated.
        no_hit: albedo of a ray that hits nothing.
    """

    def __init__(self, world: World) -> None:
        surfaces = world.surfaces
        self.geometry = world.geometry
        starts = [0]
        rows: list[list[float]] = []
        owner: list[int] = []
        cells: list[NDArray[np.float64]] = []
        offset = 0
        for k, s in enumerate(surfaces):
            for p in s.patches:
                values = np.asarray(p.values, dtype=np.float64)
                r, c = values.shape
                rows.append([p.s0, p.t0, p.width, p.height, r, c, offset, p.s0 + p.width, p.t0 + p.height])
                owner.append(k)
                cells.append(values.ravel())
                offset += values.size
            starts.append(len(rows))
        self.patch_start = np.asarray(starts, dtype=np.int64)
        self.patches = np.asarray(rows, dtype=np.float64).reshape(len(rows), 9)
        self.patch_surface = np.asarray(owner, dtype=np.int64)
        self.cells = np.concatenate(cells) if cells else np.zeros(0)
        self.no_hit = float(world.no_hit_albedo)


_SCENES: dict[int, tuple[weakref.ref[World], SceneArrays]] = {}


def scene_arrays(world: World) -> SceneArrays:
    """The World's flattened arrays, made once per World object (a simulator renders one world many times)."""
    key = id(world)
    hit = _SCENES.get(key)
    if hit is not None and hit[0]() is world:
        return hit[1]
    scene = SceneArrays(world)
    _SCENES[key] = (weakref.ref(world, lambda _ref, key=key: _SCENES.pop(key, None)), scene)  # type: ignore[misc]
    return scene


def surfaces_in_optical(scene: SceneArrays, world_T_optical: NDArray[np.float64]) -> NDArray[np.float64]:
    """The per-frame surface table, (K, 18): each surface's plane and axes in the camera's optical frame.

    For a ray d = (x, y, 1) from the camera: t = num / (n . d) is the distance factor to the plane, and the hit's
    surface coordinates are s = s0 + t (sa . d), u = t0 + t (ta . d). Columns: n (3), sa (3), ta (3), num,
    s0, t0, s_len, t_len, albedo, and the surface origin relative to the camera in the optical frame (3).
    """
    R = world_T_optical[:3, :3]
    centre = world_T_optical[:3, 3]
    g = scene.geometry
    origin, sa, ta, n = g[:, 0:3], g[:, 3:6], g[:, 6:9], g[:, 9:12]
    rel = centre - origin  # the camera relative to each surface origin, world frame
    out = np.empty((len(g), _SURF_COLS))
    out[:, _N : _N + 3] = n @ R
    out[:, _SA : _SA + 3] = sa @ R
    out[:, _TA : _TA + 3] = ta @ R
    out[:, _NUM] = -np.einsum("kd,kd->k", rel, n)
    out[:, _S0] = np.einsum("kd,kd->k", rel, sa)
    out[:, _T0] = np.einsum("kd,kd->k", rel, ta)
    out[:, _SLEN] = g[:, 12]
    out[:, _TLEN] = g[:, 13]
    out[:, _ALB] = g[:, 14]
    out[:, _OFF : _OFF + 3] = -rel @ R
    return out


# --- small helpers, inlined into the kernels --------------------------------------------------------------


@inlined
def _shade(
    k: int, s: float, u: float, surf: NDArray[np.float64], patches: NDArray[np.float64],
    patch_surface: NDArray[np.int64], cells: NDArray[np.float64], no_hit: float,
    tile_patches: NDArray[np.int64], tile: int, n_patches: int,
) -> float:  # fmt: skip
    """Albedo at (s, u) on surface k (-1: nothing hit), from the patches that reach the tile; the last painted
    wins."""
    if k < 0:
        return no_hit
    for i in range(n_patches - 1, -1, -1):
        p = tile_patches[tile, i]
        if patch_surface[p] != k:
            continue
        if s < patches[p, 0] or s >= patches[p, 7] or u < patches[p, 1] or u >= patches[p, 8]:
            continue
        fs = (s - patches[p, 0]) / patches[p, 2]
        ft = (u - patches[p, 1]) / patches[p, 3]
        if fs >= 0.0 and fs < 1.0 and ft >= 0.0 and ft < 1.0:
            rows = int(patches[p, 4])
            cols = int(patches[p, 5])
            c = min(int(fs * cols), cols - 1)
            r = min(int(ft * rows), rows - 1)
            return float(cells[int(patches[p, 6]) + r * cols + c])
    return float(surf[k, _ALB])


@inlined
def _cast(
    x: float, y: float, surf: NDArray[np.float64], candidates: NDArray[np.int64], tile: int, count: int
) -> tuple[int, float, float]:
    """Nearest hit of the ray (x, y, 1) among the tile's surfaces ``candidates[tile, :count]``: (k or -1, s, u)."""
    best_t = np.inf
    best_k = -1
    best_s = 0.0
    best_u = 0.0
    for i in range(count):
        k = candidates[tile, i]
        t = surf[k, _NUM] / (surf[k, 0] * x + surf[k, 1] * y + surf[k, 2])
        if not (t > 1e-9 and t < best_t):  # also rejects NaN and inf (a ray parallel to the plane)
            continue
        s = surf[k, _S0] + t * (surf[k, 3] * x + surf[k, 4] * y + surf[k, 5])
        if s < 0.0 or s > surf[k, _SLEN]:
            continue
        u = surf[k, _T0] + t * (surf[k, 6] * x + surf[k, 7] * y + surf[k, 8])
        if u < 0.0 or u > surf[k, _TLEN]:
            continue
        best_t, best_k, best_s, best_u = t, k, s, u
    return best_k, best_s, best_u


@kernel
def _clip_polygon(
    buf: NDArray[np.float64], src: int, n: int, q: NDArray[np.float64], q_row: int, m: int, dst: int
) -> int:
    """Polygon buf[src] (rows src, src+1: x, y) clipped to the convex polygon q[q_row] (rows q_row, q_row+1;
    m vertices) into buf[dst].

    q[q_row] is counter-clockwise by ``signed_area``'s sign (positive); uses rows _CLIP.._CLIP+3 as scratch.
    """
    qx, qy = q[q_row], q[q_row + 1]
    # Wholly inside (the common case away from a silhouette): a copy.
    inside = True
    for i in range(m):
        a, b, c = edge_line(qx, qy, i, m)
        for v in range(n):
            if a * buf[src, v] + b * buf[src + 1, v] + c < 0.0:
                inside = False
                break
        if not inside:
            break
    cur = src
    for i in range(m):
        if n == 0 or inside:
            break
        a, b, c = edge_line(qx, qy, i, m)
        out = _CLIP if cur != _CLIP else _CLIP + 2
        n = clip_half_plane(buf, cur, n, a, b, c, out)
        cur = out
    for i in range(n):
        buf[dst, i] = buf[cur, i]
        buf[dst + 1, i] = buf[cur + 1, i]
    return n


@inlined
def _image_area(ps: NDArray[np.float64], pu: NDArray[np.float64], n: int, surf: NDArray[np.float64], k: int) -> float:
    """Area on the normalised image plane of a polygon given in surface k's (s, u) coordinates.

    The plane-to-image map is a homography, so the polygon stays a polygon: map its vertices, then shoelace.
    """
    if n < 3:
        return 0.0
    area = 0.0
    x_prev = y_prev = x_first = y_first = 0.0
    for i in range(n):
        X = surf[k, _OFF] + ps[i] * surf[k, 3] + pu[i] * surf[k, 6]
        Y = surf[k, _OFF + 1] + ps[i] * surf[k, 4] + pu[i] * surf[k, 7]
        Z = surf[k, _OFF + 2] + ps[i] * surf[k, 5] + pu[i] * surf[k, 8]
        x = X / Z
        y = Y / Z
        if i == 0:
            x_first, y_first = x, y
        else:
            area += x_prev * y - x * y_prev
        x_prev, y_prev = x, y
    area += x_prev * y_first - x_first * y_prev
    return abs(area) * 0.5


@kernel
def _texture_integral(
    k: int, buf: NDArray[np.float64], row: int, n: int, surf: NDArray[np.float64],
    patch_start: NDArray[np.int64], patches: NDArray[np.float64], cells: NDArray[np.float64],
) -> float:  # fmt: skip
    """Integral of surface k's albedo over the polygon buf[row] (normalised image coordinates), by area.

    NaN when more than one patch reaches the polygon (their painting order would need a polygon boolean) or it
    spans more than MAX_CELLS cells: the caller samples the pixel instead. Uses rows _TEX.._TEX+5 of ``buf``.
    """
    area = abs(signed_area(buf[row], buf[row + 1], n))
    albedo = surf[k, _ALB]
    if area == 0.0 or patch_start[k + 1] == patch_start[k]:
        return float(albedo * area)
    # The polygon in the surface's (s, u) coordinates: each vertex is a ray, hit on the plane.
    ps, pu = buf[_TEX], buf[_TEX + 1]
    s_lo = u_lo = np.inf
    s_hi = u_hi = -np.inf
    for i in range(n):
        x, y = buf[row, i], buf[row + 1, i]
        t = surf[k, _NUM] / (surf[k, 0] * x + surf[k, 1] * y + surf[k, 2])
        ps[i] = surf[k, _S0] + t * (surf[k, 3] * x + surf[k, 4] * y + surf[k, 5])
        pu[i] = surf[k, _T0] + t * (surf[k, 6] * x + surf[k, 7] * y + surf[k, 8])
        s_lo, s_hi = min(s_lo, ps[i]), max(s_hi, ps[i])
        u_lo, u_hi = min(u_lo, pu[i]), max(u_hi, pu[i])
    found = -1
    for p in range(patch_start[k], patch_start[k + 1]):
        if patches[p, 0] < s_hi and patches[p, 7] > s_lo and patches[p, 1] < u_hi and patches[p, 8] > u_lo:
            if found >= 0:
                return np.nan
            found = p
    if found < 0:
        return float(albedo * area)
    s0, t0 = patches[found, 0], patches[found, 1]
    rows, cols, offset = int(patches[found, 4]), int(patches[found, 5]), int(patches[found, 6])
    cw, ch = patches[found, 2] / cols, patches[found, 3] / rows
    c_lo = int(np.floor((s_lo - s0) / cw))
    c_hi = int(np.floor((s_hi - s0) / cw))
    r_lo = int(np.floor((u_lo - t0) / ch))
    r_hi = int(np.floor((u_hi - t0) / ch))
    if r_lo == r_hi and c_lo == c_hi and 0 <= r_lo < rows and 0 <= c_lo < cols:
        return float(cells[offset + r_lo * cols + c_lo] * area)  # inside one cell (its bounding box is): no clipping
    c_lo, c_hi, r_lo, r_hi = max(c_lo, 0), min(c_hi, cols - 1), max(r_lo, 0), min(r_hi, rows - 1)
    if (c_hi - c_lo + 1) * (r_hi - r_lo + 1) > MAX_CELLS:
        return np.nan
    total = albedo * area
    for r in range(r_lo, r_hi + 1):
        for c in range(c_lo, c_hi + 1):
            value = cells[offset + r * cols + c]
            if value == albedo:
                continue
            # The polygon clipped to the cell's rectangle: four half-planes, ping-ponging between rows _TEX + 2..5.
            m = clip_half_plane(buf, _TEX, n, 1.0, 0.0, -(s0 + c * cw), _TEX + 2)
            m = clip_half_plane(buf, _TEX + 2, m, -1.0, 0.0, s0 + (c + 1) * cw, _TEX + 4)
            m = clip_half_plane(buf, _TEX + 4, m, 0.0, 1.0, -(t0 + r * ch), _TEX + 2)
            m = clip_half_plane(buf, _TEX + 2, m, 0.0, -1.0, t0 + (r + 1) * ch, _TEX + 4)
            total += (value - albedo) * _image_area(buf[_TEX + 4], buf[_TEX + 5], m, surf, k)
    return float(total)


@kernel
def _project_rectangle(
    ox: float, oy: float, oz: float, ax: float, ay: float, az: float, bx: float, by: float, bz: float,
    out_x: NDArray[np.float64], out_y: NDArray[np.float64],
) -> int:  # fmt: skip
    """The rectangle o + [0, 1] a + [0, 1] b (optical frame) clipped to z >= NEAR and projected to (x/z, y/z).

    Returns the vertex count; the polygon is oriented positively (``area`` > 0).
    """
    cx = (ox, ox + ax, ox + ax + bx, ox + bx)
    cy = (oy, oy + ay, oy + ay + by, oy + by)
    cz = (oz, oz + az, oz + az + bz, oz + bz)
    n = 0
    for c in range(4):
        d = (c + 1) % 4
        in_c = cz[c] >= NEAR
        in_d = cz[d] >= NEAR
        if in_c:
            out_x[n] = cx[c] / cz[c]
            out_y[n] = cy[c] / cz[c]
            n += 1
        if in_c != in_d:
            f = (NEAR - cz[c]) / (cz[d] - cz[c])
            out_x[n] = (cx[c] + f * (cx[d] - cx[c])) / NEAR
            out_y[n] = (cy[c] + f * (cy[d] - cy[c])) / NEAR
            n += 1
    if n >= 3 and signed_area(out_x, out_y, n) < 0.0:
        for i in range(n // 2):
            j = n - 1 - i
            out_x[i], out_x[j] = out_x[j], out_x[i]
            out_y[i], out_y[j] = out_y[j], out_y[i]
    return n


@inlined
def _depth_line(surf: NDArray[np.float64], a: int, b: int) -> tuple[float, float, float]:
    """The line l with l . d > 0 exactly where plane a is nearer than plane b along the ray d = (x, y, 1).

    Along d a plane is hit at t = num / (n . d); the nearer of two planes has the larger 1/t = (n . d) / num.
    """
    return (
        surf[a, 0] / surf[a, _NUM] - surf[b, 0] / surf[b, _NUM],
        surf[a, 1] / surf[a, _NUM] - surf[b, 1] / surf[b, _NUM],
        surf[a, 2] / surf[a, _NUM] - surf[b, 2] / surf[b, _NUM],
    )


# --- kernels ----------------------------------------------------------------------------------------------


@kernel
def frame_geometry(
    surf: NDArray[np.float64], patches: NDArray[np.float64], patch_surface: NDArray[np.int64]
) -> tuple[NDArray[np.float64], NDArray[np.int64], NDArray[np.float64], NDArray[np.int64]]:
    """Every surface's and every patch's projected polygon: (K, 2, MAX_POLY) vertices and counts, then patches'."""
    K = surf.shape[0]
    P = patches.shape[0]
    polys = np.zeros((K, 2, MAX_POLY))
    counts = np.zeros(K, dtype=np.int64)
    for k in range(K):
        counts[k] = _project_rectangle(
            surf[k, _OFF], surf[k, _OFF + 1], surf[k, _OFF + 2],
            surf[k, _SLEN] * surf[k, 3], surf[k, _SLEN] * surf[k, 4], surf[k, _SLEN] * surf[k, 5],
            surf[k, _TLEN] * surf[k, 6], surf[k, _TLEN] * surf[k, 7], surf[k, _TLEN] * surf[k, 8],
            polys[k, 0], polys[k, 1],
        )  # fmt: skip
    patch_polys = np.zeros((P, 2, MAX_POLY))
    patch_counts = np.zeros(P, dtype=np.int64)
    for p in range(P):
        k = patch_surface[p]
        s0, t0, w, h = patches[p, 0], patches[p, 1], patches[p, 2], patches[p, 3]
        patch_counts[p] = _project_rectangle(
            surf[k, _OFF] + s0 * surf[k, 3] + t0 * surf[k, 6],
            surf[k, _OFF + 1] + s0 * surf[k, 4] + t0 * surf[k, 7],
            surf[k, _OFF + 2] + s0 * surf[k, 5] + t0 * surf[k, 8],
            w * surf[k, 3], w * surf[k, 4], w * surf[k, 5],
            h * surf[k, 6], h * surf[k, 7], h * surf[k, 8],
            patch_polys[p, 0], patch_polys[p, 1],
        )  # fmt: skip
    return polys, counts, patch_polys, patch_counts


@kernel
def tile_candidates(  # noqa: PLR0912 - a compiled kernel
    polys: NDArray[np.float64], poly_counts: NDArray[np.int64], patch_polys: NDArray[np.float64],
    patch_counts: NDArray[np.int64], patch_surface: NDArray[np.int64], surf: NDArray[np.float64],
    tile_boxes: NDArray[np.float64],
) -> tuple[
    NDArray[np.int64], NDArray[np.int64], NDArray[np.int64], NDArray[np.int64], NDArray[np.float64], NDArray[np.int64]
]:  # fmt: skip
    """Per tile, the surfaces and the patches whose polygon overlaps its box of rays, and its flat albedo.

    Returns surfaces (tiles, K) and their counts, patches (tiles, P) in painting order and their counts, per
    tile the albedo of a flat tile (NaN: cast it; -1: nothing to hit), and the surface that covers the tile
    alone (-1: none). A tile is covered when one surface alone can be seen in it and its polygon covers the
    whole box; flat when it is covered and no patch reaches the box.
    """
    K = polys.shape[0]
    P = patch_polys.shape[0]
    n_tiles = tile_boxes.shape[0]
    out = np.empty((n_tiles, K), dtype=np.int64)
    counts = np.zeros(n_tiles, dtype=np.int64)
    tile_patches = np.empty((n_tiles, max(P, 1)), dtype=np.int64)
    patch_count = np.zeros(n_tiles, dtype=np.int64)
    flat = np.full(n_tiles, np.nan)
    covered = np.full(n_tiles, -1, dtype=np.int64)
    for i in range(n_tiles):
        x0, x1, y0, y1 = tile_boxes[i, 0], tile_boxes[i, 1], tile_boxes[i, 2], tile_boxes[i, 3]
        for k in range(K):
            if overlaps_box(polys[k, 0], polys[k, 1], poly_counts[k], x0, x1, y0, y1):
                out[i, counts[i]] = k
                counts[i] += 1
        # Occlusion: a surface that covers the whole tile and is nearer than another on all of it hides it (the
        # wall behind the charger's face). The depth order is linear in the ray, so the box's corners decide.
        for a in range(counts[i]):
            k = out[i, a]
            if k < 0 or not box_inside(polys[k, 0], polys[k, 1], poly_counts[k], x0, x1, y0, y1):
                continue
            for b in range(counts[i]):
                j = out[i, b]
                if j < 0 or j == k:
                    continue
                la, lb, lc = _depth_line(surf, k, j)
                if (
                    la * x0 + lb * y0 + lc > 0.0
                    and la * x0 + lb * y1 + lc > 0.0
                    and la * x1 + lb * y0 + lc > 0.0
                    and la * x1 + lb * y1 + lc > 0.0
                ):
                    out[i, b] = -1
        kept = 0
        for a in range(counts[i]):
            if out[i, a] >= 0:
                out[i, kept] = out[i, a]
                kept += 1
        counts[i] = kept
        for p in range(P):
            visible = False
            for a in range(kept):
                visible = visible or out[i, a] == patch_surface[p]
            if visible and overlaps_box(patch_polys[p, 0], patch_polys[p, 1], patch_counts[p], x0, x1, y0, y1):
                tile_patches[i, patch_count[i]] = p
                patch_count[i] += 1
        if counts[i] == 0:
            flat[i] = -1.0
        elif counts[i] == 1:
            k = out[i, 0]
            if box_inside(polys[k, 0], polys[k, 1], poly_counts[k], x0, x1, y0, y1):
                covered[i] = k
                if patch_count[i] == 0:
                    flat[i] = surf[k, _ALB]
    return out, counts, tile_patches, patch_count, flat, covered


@inlined
def _flat_albedo(flat: float, no_hit: float) -> float:
    """A flat tile's albedo from ``tile_candidates``' code for it (-1: nothing to hit, the background's)."""
    return flat if flat >= 0.0 else no_hit


@kernel
def cast_vertices(
    rays: NDArray[np.float64], surf: NDArray[np.float64], patches: NDArray[np.float64],
    patch_surface: NDArray[np.int64], cells: NDArray[np.float64], no_hit: float,
    candidates: NDArray[np.int64], counts: NDArray[np.int64], tile_patches: NDArray[np.int64],
    patch_count: NDArray[np.int64], flat: NDArray[np.float64], tiles_x: int,
) -> NDArray[np.float64]:  # fmt: skip
    """Every pixel corner's albedo, (H + 1, W + 1)."""
    H1, W1 = rays.shape[0], rays.shape[1]
    albedo = np.empty((H1, W1))
    tiles_y = (H1 - 2) // TILE + 1
    for i in range(H1):
        ty = min(i // TILE, tiles_y - 1)
        # A tile's span of the row at a time: its flat colour and its counts are read once, not at every corner.
        for tx in range(tiles_x):
            t = ty * tiles_x + tx
            j1 = (tx + 1) * TILE if tx < tiles_x - 1 else W1  # the last tile takes the last corner column too
            f = flat[t]
            if not np.isnan(f):  # the tile is one colour
                albedo[i, tx * TILE : j1] = _flat_albedo(f, no_hit)
                continue
            count, n_patches = counts[t], patch_count[t]
            for j in range(tx * TILE, j1):
                k, s, u = _cast(rays[i, j, 0], rays[i, j, 1], surf, candidates, t, count)
                albedo[i, j] = _shade(k, s, u, surf, patches, patch_surface, cells, no_hit, tile_patches, t, n_patches)
    return albedo


@kernel
def _sample(
    r: int, c: int, offsets: NDArray[np.float64], rays: NDArray[np.float64], surf: NDArray[np.float64],
    patches: NDArray[np.float64], patch_surface: NDArray[np.int64], cells: NDArray[np.float64], no_hit: float,
    candidates: NDArray[np.int64], tile: int, count: int, tile_patches: NDArray[np.int64], n_patches: int,
    stats: NDArray[np.float64],
) -> None:  # fmt: skip
    """Mean, min, max and first albedo over the pixel's n-rooks samples (rays bilinear between its corners),
    into stats[0:4]."""
    total = 0.0
    lo = np.inf
    hi = -np.inf
    x00, y00 = rays[r, c, 0], rays[r, c, 1]
    x01, y01 = rays[r, c + 1, 0], rays[r, c + 1, 1]
    x10, y10 = rays[r + 1, c, 0], rays[r + 1, c, 1]
    x11, y11 = rays[r + 1, c + 1, 0], rays[r + 1, c + 1, 1]
    for i in range(offsets.shape[0]):
        ox, oy = offsets[i, 0], offsets[i, 1]
        w00, w01, w10, w11 = (1 - ox) * (1 - oy), ox * (1 - oy), (1 - ox) * oy, ox * oy
        x = w00 * x00 + w01 * x01 + w10 * x10 + w11 * x11
        y = w00 * y00 + w01 * y01 + w10 * y10 + w11 * y11
        k, s, u = _cast(x, y, surf, candidates, tile, count)
        v = _shade(k, s, u, surf, patches, patch_surface, cells, no_hit, tile_patches, tile, n_patches)
        if i == 0:
            stats[3] = v
        total += v
        lo = min(lo, v)
        hi = max(hi, v)
    stats[0] = total / offsets.shape[0]
    stats[1] = lo
    stats[2] = hi


@inlined
def _by_area(  # noqa: PLR0912,PLR0915 - a compiled kernel
    r: int, c: int, rays: NDArray[np.float64], surf: NDArray[np.float64], patch_start: NDArray[np.int64],
    patches: NDArray[np.float64], cells: NDArray[np.float64], no_hit: float, polys: NDArray[np.float64],
    poly_counts: NDArray[np.int64], boxes: NDArray[np.float64], candidates: NDArray[np.int64], tile: int,
    count: int, cover: int, buf: NDArray[np.float64], scratch: NDArray[np.int64],
) -> float:  # fmt: skip
    """The pixel's mean albedo by exact area over its footprint quad; NaN where it must be sampled (inlined into
    ``shade_pixels``, its one caller: a call per edge pixel cost its array arguments' reference counting).

    The surfaces whose polygon overlaps the quad are found first; one that is behind another wherever both
    could be seen (a side of the charger behind its face) is dropped. One or two left: their parts of the quad,
    each seen except where the other overlaps it and is nearer, are integrated; three or more: NaN.
    """
    qx, qy = buf[_QUAD], buf[_QUAD + 1]
    qx[0], qy[0] = rays[r, c, 0], rays[r, c, 1]
    qx[1], qy[1] = rays[r, c + 1, 0], rays[r, c + 1, 1]
    qx[2], qy[2] = rays[r + 1, c + 1, 0], rays[r + 1, c + 1, 1]
    qx[3], qy[3] = rays[r + 1, c, 0], rays[r + 1, c, 1]
    quad = signed_area(qx, qy, 4)
    if quad < 0.0:  # orient the quad positively, like the polygons
        qx[1], qx[3] = qx[3], qx[1]
        qy[1], qy[3] = qy[3], qy[1]
        quad = -quad
    if not quad > 0.0:
        return np.nan
    if cover >= 0:  # one surface covers the whole tile and hides the rest: the quad lies inside it
        return _texture_integral(cover, buf, _QUAD, 4, surf, patch_start, patches, cells) / quad
    tiny = 1e-12 * quad
    seen, sizes, areas, hidden = scratch[0], scratch[1], buf[_SIDE + 2], scratch[2]
    q_x0, q_x1 = min(qx[0], qx[1], qx[2], qx[3]), max(qx[0], qx[1], qx[2], qx[3])
    q_y0, q_y1 = min(qy[0], qy[1], qy[2], qy[3]), max(qy[0], qy[1], qy[2], qy[3])
    n_seen = 0
    for i in range(count):
        k = candidates[tile, i]
        if boxes[k, 0] > q_x1 or boxes[k, 1] < q_x0 or boxes[k, 2] > q_y1 or boxes[k, 3] < q_y0:
            continue  # the polygon's bounding box misses the quad's
        if n_seen == _SEEN:
            return np.nan
        row = _PART + 2 * n_seen
        n = _clip_polygon(buf, _QUAD, 4, polys[k], 0, poly_counts[k], row)
        if n < 3:
            continue
        area = abs(signed_area(buf[row], buf[row + 1], n))
        if area <= tiny:
            continue
        seen[n_seen], sizes[n_seen], areas[n_seen] = k, n, area
        n_seen += 1
    # Drop a surface whose part lies wholly inside another's, and behind it.
    hidden[:] = 0
    left = n_seen
    if n_seen > 2:
        for j in range(n_seen):
            for i in range(n_seen):
                if i == j or hidden[i] or hidden[j]:
                    continue
                m = _clip_polygon(buf, _PART + 2 * j, sizes[j], buf, _PART + 2 * i, sizes[i], _OVERLAP)
                la, lb, lc = _depth_line(surf, seen[i], seen[j])
                m = clip_half_plane(buf, _OVERLAP, m, la, lb, lc, _SIDE)
                if abs(signed_area(buf[_SIDE], buf[_SIDE + 1], m)) >= areas[j] * (1.0 - 1e-9):
                    hidden[j] = True
                    left -= 1
    if left > 2:
        return np.nan  # three surfaces meet here
    a = b = -1
    for i in range(n_seen):
        if not hidden[i]:
            if a < 0:
                a = i
            else:
                b = i
    if a < 0:
        return no_hit
    row_a = _PART + 2 * a
    total = _texture_integral(seen[a], buf, row_a, sizes[a], surf, patch_start, patches, cells)
    covered = areas[a]
    if b >= 0:
        row_b = _PART + 2 * b
        total += _texture_integral(seen[b], buf, row_b, sizes[b], surf, patch_start, patches, cells)
        covered += areas[b]
        # Where both parts overlap, each plane is seen only on its side of the line where their depths cross.
        n_ab = _clip_polygon(buf, row_a, sizes[a], buf, row_b, sizes[b], _OVERLAP)
        if n_ab >= 3:
            covered -= abs(signed_area(buf[_OVERLAP], buf[_OVERLAP + 1], n_ab))
            la, lb, lc = _depth_line(surf, seen[a], seen[b])
            m = clip_half_plane(buf, _OVERLAP, n_ab, -la, -lb, -lc, _SIDE)  # b nearer: a is hidden there
            total -= _texture_integral(seen[a], buf, _SIDE, m, surf, patch_start, patches, cells)
            m = clip_half_plane(buf, _OVERLAP, n_ab, la, lb, lc, _SIDE)  # a nearer: b is hidden there
            total -= _texture_integral(seen[b], buf, _SIDE, m, surf, patch_start, patches, cells)
    return float((total + no_hit * max(quad - covered, 0.0)) / quad)


@kernel
def shade_pixels(
    vert: NDArray[np.float64], rays: NDArray[np.float64], surf: NDArray[np.float64],
    patch_start: NDArray[np.int64], patches: NDArray[np.float64], patch_surface: NDArray[np.int64],
    cells: NDArray[np.float64], no_hit: float, polys: NDArray[np.float64], poly_counts: NDArray[np.int64],
    candidates: NDArray[np.int64], counts: NDArray[np.int64], tile_patches: NDArray[np.int64],
    patch_count: NDArray[np.int64], flat: NDArray[np.float64], covered: NDArray[np.int64], tiles_x: int,
    full: NDArray[np.float64], probe: NDArray[np.float64],
) -> tuple[NDArray[np.float32], NDArray[np.int64]]:  # fmt: skip
    """The image from its corners' albedos: flat pixels take their corners' mean, edge pixels their area.

    A pixel straddles an edge when its four corners disagree; it and its eight neighbours (a region smaller than
    a pixel can hide between one pixel's corners, the neighbours' corners see it) take the exact area integral,
    or where that cannot be had, the reference's sampling: the ``full`` n-rooks pattern on a straddling pixel,
    the ``probe`` first on a neighbour and the full pattern only if the probe finds an edge.
    Returns the image and counts: [edge pixels, by area, sampled].
    """
    H, W = vert.shape[0] - 1, vert.shape[1] - 1
    image = np.empty((H, W), dtype=np.float32)
    edge = np.zeros((H, W), dtype=np.uint8)  # 2: straddles an edge, 1: next to one, 0: flat
    tally = np.zeros(3, dtype=np.int64)
    tiles_y = (H - 1) // TILE + 1
    for r in range(H):
        ty = min(r // TILE, tiles_y - 1)
        lower_inside = (r + 1) % TILE != 0 or ty == tiles_y - 1  # the pixels' lower corners lie in their tile too
        for tx in range(tiles_x):
            c0, c1 = tx * TILE, ((tx + 1) * TILE if tx < tiles_x - 1 else W)
            f = flat[ty * tiles_x + tx]
            if lower_inside and not np.isnan(f):
                # A flat tile's corners are all one albedo (cast_vertices): so are its pixels' but in its last column,
                # whose right corners lie in the next tile. Their mean, computed as below, once. (The tile's box of
                # rays reaches those corners too, so they are that albedo but at a float tie on a polygon's boundary;
                # left to the loop below, as they were before, the image stays the same bit for bit.)
                v = _flat_albedo(f, no_hit)
                inner = c1 if tx == tiles_x - 1 else c1 - 1
                image[r, c0:inner] = (v + v + v + v) / 4.0
                c0 = inner
            for c in range(c0, c1):
                a, b, d, e = vert[r, c], vert[r, c + 1], vert[r + 1, c], vert[r + 1, c + 1]
                image[r, c] = (a + b + d + e) / 4.0
                if max(a, b, d, e) - min(a, b, d, e) > FLAT:
                    tally[0] += 1
                    for i in range(max(r - 1, 0), min(r + 2, H)):
                        for j in range(max(c - 1, 0), min(c + 2, W)):
                            edge[i, j] = max(edge[i, j], 1)
                    edge[r, c] = 2
    boxes = np.empty((polys.shape[0], 4))  # each surface polygon's bounding box: x0, x1, y0, y1
    for k in range(polys.shape[0]):
        n = poly_counts[k]
        boxes[k, 0], boxes[k, 1] = (polys[k, 0, :n].min(), polys[k, 0, :n].max()) if n > 0 else (np.inf, -np.inf)
        boxes[k, 2], boxes[k, 3] = (polys[k, 1, :n].min(), polys[k, 1, :n].max()) if n > 0 else (np.inf, -np.inf)
    tex = (patches, patch_surface, cells, no_hit)
    buf = np.empty((_ROWS, _BUF))
    scratch = np.empty((3, _SEEN), dtype=np.int64)
    stats = np.empty(4)
    for r in range(H):
        for c in range(W):
            if edge[r, c] == 0:
                continue
            t = min(r // TILE, tiles_y - 1) * tiles_x + min(c // TILE, tiles_x - 1)
            v = _by_area(
                r,
                c,
                rays,
                surf,
                patch_start,
                patches,
                cells,
                no_hit,
                polys,
                poly_counts,
                boxes,
                candidates,
                t,
                counts[t],
                covered[t],
                buf,
                scratch,
            )
            if not np.isnan(v):
                image[r, c] = v
                tally[1] += 1
                continue
            tally[2] += 1
            if edge[r, c] == 1:
                _sample(r, c, probe, rays, surf, *tex, candidates, t, counts[t], tile_patches, patch_count[t], stats)
                mean = (vert[r, c] + vert[r, c + 1] + vert[r + 1, c] + vert[r + 1, c + 1]) / 4.0
                if not (stats[2] - stats[1] > FLAT or abs(stats[3] - mean) > FLAT):
                    continue
            _sample(r, c, full, rays, surf, *tex, candidates, t, counts[t], tile_patches, patch_count[t], stats)
            image[r, c] = stats[0]
    return image, tally
