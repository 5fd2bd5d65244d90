"""The simulated world: textured planar rectangles (charger box, markers, walls, floor) and ray casting.

World coordinates are the ``dock`` frame (docs/architecture.md): origin on the floor below marker 2's centre on the
charger's front face, x into the charger, y left, z up. Both the camera renderer and the LiDAR cast rays
into the same surfaces, so what one sensor sees the other sees too.
"""

from __future__ import annotations

import functools
import math
from dataclasses import dataclass, field, replace

import numpy as np
from numpy.typing import ArrayLike, NDArray

from monodock.core.compiled import kernel
from monodock.core.layout import DockLayout
from monodock.errors import ConfigError

__all__ = ["ChargerGeometry", "Patch", "Surface", "World", "build_dock_world"]

PAPER_WHITE = 0.85  # albedo of the white print and of the charger face
INK_BLACK = 0.06  # albedo of the black print
NO_HIT_ALBEDO = 0.55  # what a ray that leaves the room sees (ceiling light)


@dataclass(frozen=True)
class Patch:
    """A grid of cells painted on a surface (a marker, a poster, a checkerboard).

    Attributes:
        s0, t0: the patch's top-left corner in the surface's (s, t) coordinates, metres.
        width, height: its extent along s and t, metres.
        values: albedo of each cell, shape (rows, cols); row 0 at t0, column 0 at s0.
    """

    s0: float
    t0: float
    width: float
    height: float
    values: NDArray[np.float64]


@dataclass(frozen=True)
class Surface:
    """A two-sided rectangle ``origin + s * s_axis + t * t_axis`` with s in [0, s_len], t in [0, t_len].

    Seen from its front, s runs to the right and t downwards, like image columns and rows, so a patch's
    cells appear unmirrored and upright.
    """

    name: str
    origin: NDArray[np.float64]
    s_axis: NDArray[np.float64]
    t_axis: NDArray[np.float64]
    s_len: float
    t_len: float
    albedo: float
    patches: tuple[Patch, ...] = ()

    @property
    def normal(self) -> NDArray[np.float64]:
        return np.cross(self.s_axis, self.t_axis)

    def point(self, s: float, t: float) -> NDArray[np.float64]:
        """The 3D point at surface coordinates (s, t)."""
        return self.origin + s * self.s_axis + t * self.t_axis

    def with_patches(self, *patches: Patch) -> Surface:
        return replace(self, patches=self.patches + patches)

    def shade(self, s: NDArray[np.float64], t: NDArray[np.float64]) -> NDArray[np.float64]:
        """Albedo at surface coordinates; later patches paint over earlier ones."""
        out = np.full(s.shape, self.albedo, dtype=np.float64)
        for p in self.patches:
            rows, cols = p.values.shape
            fs = (s - p.s0) / p.width
            ft = (t - p.t0) / p.height
            inside = (fs >= 0.0) & (fs < 1.0) & (ft >= 0.0) & (ft < 1.0)
            if not inside.any():
                continue
            c = np.minimum((fs[inside] * cols).astype(np.intp), cols - 1)
            r = np.minimum((ft[inside] * rows).astype(np.intp), rows - 1)
            out[inside] = p.values[r, c]
        return out


def rectangle(
    name: str,
    top_left: ArrayLike,
    right: ArrayLike,
    down: ArrayLike,
    width: float,
    height: float,
    albedo: float,
) -> Surface:
    """A surface from its top-left corner and unit directions to its right and downwards (seen from the front)."""
    return Surface(
        name,
        np.asarray(top_left, dtype=np.float64),
        np.asarray(right, dtype=np.float64),
        np.asarray(down, dtype=np.float64),
        float(width),
        float(height),
        float(albedo),
    )


@dataclass
class Hits:
    """Result of casting N rays: distance along each ray, the surface hit (-1: none) and where on it."""

    t: NDArray[np.float64]
    surface: NDArray[np.intp]
    s: NDArray[np.float64]
    u: NDArray[np.float64]


@dataclass(frozen=True)
class World:
    """A set of surfaces; rays see the nearest one."""

    surfaces: tuple[Surface, ...]
    no_hit_albedo: float = NO_HIT_ALBEDO

    def with_surfaces(self, *extra: Surface) -> World:
        return replace(self, surfaces=self.surfaces + extra)

    def surface_index(self, name: str) -> int:
        for i, s in enumerate(self.surfaces):
            if s.name == name:
                return i
        raise KeyError(name)

    def cast(self, origin: ArrayLike, directions: ArrayLike) -> Hits:
        """Nearest hit of rays ``origin + t * direction`` (t > 0); origin shape (3,) or (N, 3)."""
        d = np.ascontiguousarray(np.asarray(directions, dtype=np.float64).reshape(-1, 3))
        o = np.ascontiguousarray(np.asarray(origin, dtype=np.float64).reshape(-1, 3))
        t, k, s, u = _cast_rays(self.geometry, o, d)
        return Hits(t, k, s, u)

    @functools.cached_property
    def geometry(self) -> NDArray[np.float64]:
        """(K, 15) per surface: origin (3), s_axis (3), t_axis (3), normal (3), s_len, t_len, albedo (made once)."""
        rows = [
            np.concatenate([s.origin, s.s_axis, s.t_axis, s.normal, [s.s_len, s.t_len, s.albedo]])
            for s in self.surfaces
        ]
        return np.array(rows, dtype=np.float64).reshape(len(self.surfaces), 15)

    def shade(self, hits: Hits) -> NDArray[np.float64]:
        """Albedo seen along each ray."""
        out = np.full(hits.t.shape, self.no_hit_albedo)
        for k, surf in enumerate(self.surfaces):
            m = hits.surface == k
            if m.any():
                out[m] = surf.shade(hits.s[m], hits.u[m])
        return out


@kernel
def _cast_rays(
    geometry: NDArray[np.float64], origins: NDArray[np.float64], dirs: NDArray[np.float64]
) -> tuple[NDArray[np.float64], NDArray[np.intp], NDArray[np.float64], NDArray[np.float64]]:
    """Nearest hit of each ray among the surfaces (rows: origin, s_axis, t_axis, normal, s_len, t_len).

    ``origins`` is (N, 3) or (1, 3) for rays from one point. A ray parallel to a plane, or hitting it at t <= 1e-9,
    misses it; the surface bounds are inclusive.
    """
    n = dirs.shape[0]
    best_t = np.full(n, np.inf)
    best_k = np.full(n, -1, dtype=np.intp)
    best_s = np.zeros(n)
    best_u = np.zeros(n)
    one_origin = origins.shape[0] == 1
    for i in range(n):
        o = origins[0] if one_origin else origins[i]
        dx, dy, dz = dirs[i, 0], dirs[i, 1], dirs[i, 2]
        for k in range(geometry.shape[0]):
            g = geometry[k]
            rx, ry, rz = o[0] - g[0], o[1] - g[1], o[2] - g[2]
            t = -(rx * g[9] + ry * g[10] + rz * g[11]) / (dx * g[9] + dy * g[10] + dz * g[11])
            if not (t > 1e-9 and t < best_t[i]):  # also rejects NaN and inf (a ray parallel to the plane)
                continue
            s = rx * g[3] + ry * g[4] + rz * g[5] + t * (dx * g[3] + dy * g[4] + dz * g[5])
            u = rx * g[6] + ry * g[7] + rz * g[8] + t * (dx * g[6] + dy * g[7] + dz * g[8])
            if 0.0 <= s <= g[12] and 0.0 <= u <= g[13]:
                best_t[i], best_k[i], best_s[i], best_u[i] = t, k, s, u
    return best_t, best_k, best_s, best_u


@dataclass(frozen=True)
class ChargerGeometry:
    """The charger box: its front face (x = 0) carries the markers and reaches the floor."""

    width: float = 0.60
    height: float = 0.45
    depth: float = 0.30
    face_albedo: float = PAPER_WHITE
    body_albedo: float = 0.45


@dataclass(frozen=True)
class RoomGeometry:
    """The room around the charger: a back wall the charger stands against, floor, optional side walls."""

    back_wall: bool = True
    side_walls: float | None = None  # distance of side walls from the dock's approach axis, metres
    wall_albedo: float = 0.68
    floor_albedo: float = 0.32
    extent: float = 6.0
    wall_height: float = 2.5
    extra: tuple[Surface, ...] = field(default=())


def marker_patch(
    layout: DockLayout, marker_id: int, centre_s: float, centre_t: float, size: float | None = None
) -> Patch:
    """The marker's black/white cells as a patch centred at (centre_s, centre_t) on a surface; ``size`` is its
    side (default the layout's ``marker_size``)."""
    bits = layout.marker_bits(marker_id).astype(np.float64)
    values = INK_BLACK + bits * (PAPER_WHITE - INK_BLACK)
    side = layout.marker_size if size is None else size
    h = side / 2.0
    return Patch(centre_s - h, centre_t - h, side, side, values)


# The white paper around a marker printed on its own sheet, in modules each side: the quiet zone it is cut with.
CARD_MARGIN_MODULES = 1.5


def marker_card(layout: DockLayout, role: str) -> Surface:
    """A marker printed on a card of its own, where the layout places and tilts it: ``marker_<role>``.

    A marker that stands off the face or is tilted against it is not painted on the face: its card is a surface
    of its own, the marker in the middle and ``CARD_MARGIN_MODULES`` of white around it. A card that reaches
    behind the face is hidden there, as it would be inside the charger.
    """
    m = layout.marker(role)
    side = layout.side(role)
    T = layout.dock_T_marker(role)
    right, up = T[:3, 0], T[:3, 1]  # the marker's x (the robot's right) and y (up) in the dock frame
    margin = CARD_MARGIN_MODULES * side / layout.modules
    card = side + 2.0 * margin
    top_left = T[:3, 3] - right * (card / 2.0) + up * (card / 2.0)
    surface = rectangle(f"marker_{role}", top_left, right, -up, card, card, PAPER_WHITE)
    return surface.with_patches(marker_patch(layout, m.id, card / 2.0, card / 2.0, side))


def build_dock_world(
    layout: DockLayout,
    charger: ChargerGeometry | None = None,
    room: RoomGeometry | None = None,
) -> World:
    """The charger with the layout's markers on its face, standing against a wall on the floor."""
    ch = charger or ChargerGeometry()
    rm = room or RoomGeometry()
    half_w = max(ch.width / 2.0, *(abs(m.y) + 1.1 * layout.side(m.role) for m in layout.markers))
    height = max(ch.height, *(m.z + 1.1 * layout.side(m.role) for m in layout.markers))
    # The face, seen from the robot: s runs to the robot's right (-y), t downwards (-z).
    face = rectangle("charger_face", (0.0, half_w, height), (0, -1, 0), (0, 0, -1), 2 * half_w, height, ch.face_albedo)
    on_face = [m for m in layout.markers if not m.tilted]
    face = face.with_patches(
        *(marker_patch(layout, m.id, half_w - m.y, height - m.z, layout.side(m.role)) for m in on_face)
    )
    d = ch.depth
    surfaces = [
        face,
        *(marker_card(layout, m.role) for m in layout.markers if m.tilted),
        rectangle("charger_left", (0.0, half_w, height), (1, 0, 0), (0, 0, -1), d, height, ch.body_albedo),
        rectangle("charger_right", (d, -half_w, height), (-1, 0, 0), (0, 0, -1), d, height, ch.body_albedo),
        rectangle("charger_top", (d, half_w, height), (0, -1, 0), (-1, 0, 0), 2 * half_w, d, ch.body_albedo * 1.2),
    ]
    e = rm.extent
    surfaces.append(rectangle("floor", (d, e, 0.0), (0, -1, 0), (-1, 0, 0), 2 * e, 2 * e, rm.floor_albedo))
    if rm.back_wall:
        surfaces.append(
            rectangle(
                "back_wall",
                (d, e, rm.wall_height),
                (0, -1, 0),
                (0, 0, -1),
                2 * e,
                rm.wall_height,
                rm.wall_albedo,
            )
        )
    if rm.side_walls is not None:
        w = rm.side_walls
        if not (math.isfinite(w) and w > half_w):
            raise ConfigError(f"side walls must stand farther than the charger's half width ({half_w:.2f} m), got {w}")
        surfaces.append(
            rectangle(
                "wall_left",
                (-2 * e, w, rm.wall_height),
                (1, 0, 0),
                (0, 0, -1),
                2 * e + d,
                rm.wall_height,
                rm.wall_albedo,
            )
        )
        surfaces.append(
            rectangle(
                "wall_right",
                (d, -w, rm.wall_height),
                (-1, 0, 0),
                (0, 0, -1),
                2 * e + d,
                rm.wall_height,
                rm.wall_albedo,
            )
        )
    surfaces.extend(rm.extra)
    return World(tuple(surfaces))
