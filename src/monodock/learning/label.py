"""LiDAR labels for the regression (papers §4.1, Fig. 7–9): depth and angle of the dock from the scan.

The papers project LiDAR points into the image and keep those inside marker 2's columns. Done in 3-D it is
exact for any camera tilt and lens: the plane through the camera centre and marker 2's left edge contains
that edge's extension down to the scan plane, so a scan point lies "across" the marker when it is between
the planes of the left and right edges. The point nearest the plane through the marker's centre gives the
papers' depth label; the papers' angle comes from the leftmost and rightmost point across the marker.

One 8–10 cm marker holds only a handful of returns, so a line through them is degrees off (docs/benchmarks.md).
The angle label, and the lateral and line depth at marker 2's centre plane, come instead from a line over
the whole charger face. The label does not know the charger's width: it finds the face segment in the
scan. The points across the marker (and across markers 1 and 3 when given) seed a line; the segment grows
along the scan, one return at a time, to neighbours that stay close to the refitted line and contiguous
with it (it ends at a range jump, a hole, or where the returns leave the line: the charger's side walls,
the wall behind, clutter); a total-least-squares fit with MAD-based outlier rejection then gives the line.
"""

from __future__ import annotations

import dataclasses
import math
from collections.abc import Sequence

import numpy as np
from numpy.typing import NDArray

from monodock.core import transforms
from monodock.core.camera import CameraModel
from monodock.core.robot import RobotConfig
from monodock.core.scan import LaserScan
from monodock.perception.features import lens_centre

__all__ = [
    "FACE_GAP_M",
    "FACE_TOLERANCE_M",
    "LABEL_COLUMNS",
    "MIN_FACE_POINTS",
    "MIN_POINTS",
    "LidarLabel",
    "label_frame",
    "points_across_marker",
]

LABEL_COLUMNS = (
    "label_valid",
    "label_reason",
    "label_x_m",
    "label_yaw_deg",
    "label_yaw_endpoints_deg",
    "label_y_m",
    "label_x_line_m",
    "label_points",
    "label_span_m",
    "label_line_rms_m",
    "label_centre_offset_m",
    "label_yaw_marker_deg",
    "label_y_marker_m",
    "label_x_line_marker_m",
    "label_face_points",
    "label_face_span_m",
    "label_face_rms_m",
    "label_face_rejected",
)

MIN_POINTS = 3
"""Fewest returns across marker 2 for a label."""
MIN_FACE_POINTS = 5
"""Fewest returns on the fitted face line for a label (fewer cannot reject an outlier)."""
FACE_TOLERANCE_M = 0.04
"""How far from the current face line a return may be to join the segment: 4 sigma of a 1 cm range noise."""
FACE_GAP_M = 0.04
"""Gap along the face line between neighbouring returns that ends the segment (widened far away)."""
# Far away, or seen obliquely, the beams themselves land farther apart than FACE_GAP_M: allow 3 spacings
# (range noise moves returns along an oblique face too), the incidence counted up to 80 degrees.
_GAP_BEAMS = 3.0
_MIN_COS_INCIDENCE = math.cos(math.radians(80.0))
# More missing beams than this in a row is a hole in the face (or its end), not a dropout.
_MAX_BEAM_STEP = 4
# Two returns in a row off the line end the segment; one is a spike and is stepped over.
_MAX_MISSES = 2
# Outlier rejection: residual scale from the MAD, floored so that a noise-free scan keeps its points.
_REJECT_SIGMAS = 3.0
_SIGMA_FLOOR_M = 0.001
_MAX_REFITS = 10
# Above this many seed points, the candidate lines of the consensus go through a subsample of them.
_CONSENSUS_CANDIDATES = 40
# Growth passes, each from the line of the last (the first from the seed's).
_GROW_PASSES = 4


@dataclasses.dataclass(frozen=True)
class LidarLabel:
    """The teacher's answer for one frame, in base_link, and how much to trust it.

    Attributes:
        x: depth label, the papers' way: base_link x of the scan point nearest marker 2's centre plane, m.
        yaw: angle label: the dock's yaw from the line fitted over the whole charger face, rad.
        yaw_endpoints: angle label, the papers' way: from the leftmost and rightmost point across marker 2, rad.
        y: lateral label: where the face line crosses marker 2's centre plane, m.
        x_line: depth at that crossing, m (the line's estimate of x, less noisy than one point).
        points: scan points across marker 2.
        span: distance between the outermost points across marker 2, m.
        line_rms: RMS distance of the points across marker 2 from their own line, m.
        centre_offset: distance of the depth point from marker 2's centre plane, m.
        yaw_marker: the dock's yaw from a total-least-squares line through the points across marker 2 only, rad.
        y_marker: where that marker-2 line crosses marker 2's centre plane, m.
        x_line_marker: depth at that crossing, m.
        face_points: scan points on the face line (after outlier rejection).
        face_span: extent of those points along the line, m.
        face_rms: RMS distance of those points from the face line, m.
        face_rejected: points of the face segment the outlier rejection left out.
        reason: why the label is invalid; empty when valid.
    """

    x: float = math.nan
    yaw: float = math.nan
    yaw_endpoints: float = math.nan
    y: float = math.nan
    x_line: float = math.nan
    points: int = 0
    span: float = math.nan
    line_rms: float = math.nan
    centre_offset: float = math.nan
    yaw_marker: float = math.nan
    y_marker: float = math.nan
    x_line_marker: float = math.nan
    face_points: int = 0
    face_span: float = math.nan
    face_rms: float = math.nan
    face_rejected: int = 0
    reason: str = ""

    @property
    def valid(self) -> bool:
        return not self.reason

    def row(self) -> dict[str, object]:
        """The label's dataset columns (LABEL_COLUMNS), angles in degrees."""
        return {
            "label_valid": self.valid,
            "label_reason": self.reason,
            "label_x_m": self.x,
            "label_yaw_deg": math.degrees(self.yaw),
            "label_yaw_endpoints_deg": math.degrees(self.yaw_endpoints),
            "label_y_m": self.y,
            "label_x_line_m": self.x_line,
            "label_points": self.points,
            "label_span_m": self.span,
            "label_line_rms_m": self.line_rms,
            "label_centre_offset_m": self.centre_offset,
            "label_yaw_marker_deg": math.degrees(self.yaw_marker),
            "label_y_marker_m": self.y_marker,
            "label_x_line_marker_m": self.x_line_marker,
            "label_face_points": self.face_points,
            "label_face_span_m": self.face_span,
            "label_face_rms_m": self.face_rms,
            "label_face_rejected": self.face_rejected,
        }


def _ray(camera: CameraModel, pixels: NDArray[np.float64], base_T_optical: NDArray[np.float64]) -> NDArray[np.float64]:
    """Directions in base_link of the rays through pixels (through the lens), shape (N, 3)."""
    n = camera.normalize(pixels)
    d = np.column_stack([n, np.ones(len(n))])
    return np.asarray(d @ base_T_optical[:3, :3].T, dtype=np.float64)


def _plane_normal(a: NDArray[np.float64], b: NDArray[np.float64]) -> NDArray[np.float64]:
    n = np.cross(a, b)
    return np.asarray(n / np.linalg.norm(n), dtype=np.float64)


def _yaw_of_face(direction: NDArray[np.float64]) -> float:
    """The dock's yaw from a direction along the face that points to the robot's left (the dock's +y)."""
    yaw = math.atan2(direction[1], direction[0]) - math.pi / 2
    return (yaw + math.pi) % (2.0 * math.pi) - math.pi


@dataclasses.dataclass(frozen=True)
class _MarkerPlanes:
    """The planes through the camera centre and a marker's left edge, right edge and centre, in base_link."""

    centre: NDArray[np.float64]
    n_left: NDArray[np.float64]
    n_right: NDArray[np.float64]
    n_mid: NDArray[np.float64]
    forward: NDArray[np.float64]

    def across(self, points: NDArray[np.float64]) -> NDArray[np.bool_]:
        """Which points (N, 3) lie between the edge planes, in front of the camera."""
        rel = points - self.centre
        return np.asarray((rel @ self.n_left > 0) & (rel @ self.n_right > 0) & (rel @ self.forward > 0))

    def leftwards(self, direction: NDArray[np.float64]) -> NDArray[np.float64]:
        """A scan-plane direction (2,) along the face, turned to point to the marker's left (the dock's +y)."""
        # n_left points from the left edge into the marker, i.e. to the right.
        return -direction if float(direction @ self.n_left[:2]) > 0 else direction

    def crossing(self, mean: NDArray[np.float64], direction: NDArray[np.float64], z: float) -> tuple[float, float]:
        """(x, y) where a scan line (point, direction) at height z crosses the centre plane; NaN if parallel."""
        a = self.n_mid[:2]
        denom = float(a @ direction)
        if abs(denom) < 1e-9:
            return math.nan, math.nan
        t = float(a @ (self.centre[:2] - mean) + self.n_mid[2] * (self.centre[2] - z)) / denom
        hit = mean + t * direction
        return float(hit[0]), float(hit[1])


def _marker_planes(corners: NDArray[np.float64], camera: CameraModel, robot: RobotConfig) -> _MarkerPlanes:
    base_T_optical = robot.base_T_optical()
    c = np.asarray(corners, dtype=np.float64).reshape(4, 2)
    rays = _ray(camera, np.vstack([c, lens_centre(c, camera)[None, :]]), base_T_optical)
    tl, tr, br, bl, mid = rays
    # Normals oriented so that "inside the marker" is positive for both edge planes.
    n_left = _plane_normal(bl, tl)
    n_right = _plane_normal(tr, br)
    if np.dot(n_left, mid) < 0:
        n_left = -n_left
    if np.dot(n_right, mid) < 0:
        n_right = -n_right
    # The centre plane holds the centre ray and the edges' common direction (vertical on an upright dock).
    n_mid = _plane_normal(mid, np.cross(n_left, n_right))
    return _MarkerPlanes(base_T_optical[:3, 3], n_left, n_right, n_mid, mid)


@dataclasses.dataclass(frozen=True)
class _Returns:
    """A scan's valid returns in beam order: base_link points (N, 3), beam indices, ranges (m)."""

    points: NDArray[np.float64]
    beam: NDArray[np.intp]
    ranges: NDArray[np.float64]
    beams: int
    increment: float
    circular: bool
    origin: tuple[float, float]


def _returns(scan: LaserScan, robot: RobotConfig) -> _Returns:
    """The scan's valid returns, keeping their order and beam indices so that the face can be walked."""
    r = np.asarray(scan.ranges, dtype=np.float64)
    ok = np.isfinite(r) & (r >= scan.range_min) & (r <= scan.range_max)
    beam = np.flatnonzero(ok)
    a = scan.angles()[beam]
    local = np.column_stack([r[ok] * np.cos(a), r[ok] * np.sin(a), np.zeros(beam.size)])
    inc = abs(float(scan.angle_increment))
    # A full turn: the last beam neighbours the first (a face straight behind a 360-degree scanner).
    circular = inc > 0 and r.size * inc >= 2.0 * math.pi - 0.5 * inc
    base_T_laser = robot.base_T_laser()
    origin = (float(base_T_laser[0, 3]), float(base_T_laser[1, 3]))
    return _Returns(transforms.apply(base_T_laser, local), beam, r[ok], int(r.size), inc, circular, origin)


def _tls(xy: NDArray[np.float64]) -> tuple[NDArray[np.float64], NDArray[np.float64], float]:
    """Total-least-squares line through points (N, 2): (mean, unit direction, RMS distance from it).

    Range noise is radial, not along x or y, so neither ordinary regression is right.
    """
    mean = xy.mean(axis=0)
    _, s, vt = np.linalg.svd(xy - mean, full_matrices=False)
    rms = float(s[1] / math.sqrt(len(xy))) if len(s) > 1 else 0.0
    return mean, np.asarray(vt[0], dtype=np.float64), rms


class _LineSums:
    """Running sums of a growing point set: its total-least-squares line in O(1) per added point.

    Plain floats: the growth adds one point at a time, where numpy's cost per call would dominate.
    """

    def __init__(self, xy: NDArray[np.float64]) -> None:
        # Sums relative to the seed's mean: no cancellation when the face is metres from the robot.
        self.ox, self.oy = (float(v) for v in xy.mean(axis=0))
        rel = xy - np.array([self.ox, self.oy])
        self.n = len(rel)
        self.sx, self.sy = (float(v) for v in rel.sum(axis=0))
        self.sxx = float(rel[:, 0] @ rel[:, 0])
        self.sxy = float(rel[:, 0] @ rel[:, 1])
        self.syy = float(rel[:, 1] @ rel[:, 1])

    def add(self, x: float, y: float) -> None:
        dx, dy = x - self.ox, y - self.oy
        self.n += 1
        self.sx += dx
        self.sy += dy
        self.sxx += dx * dx
        self.sxy += dx * dy
        self.syy += dy * dy

    def line(self) -> tuple[float, float, float, float]:
        """(x0, y0, nx, ny): a point on the line and its unit normal."""
        mx, my = self.sx / self.n, self.sy / self.n
        cxx = self.sxx / self.n - mx * mx
        cxy = self.sxy / self.n - mx * my
        cyy = self.syy / self.n - my * my
        theta = 0.5 * math.atan2(2.0 * cxy, cxx - cyy)  # the direction of most spread
        return self.ox + mx, self.oy + my, -math.sin(theta), math.cos(theta)


def _best_pair_line(xy: NDArray[np.float64], tolerance: float) -> tuple[NDArray[np.float64], NDArray[np.float64]]:
    """The line through two of the points (N >= 2, 2) with the least MSAC cost: (a point on it, unit normal).

    Every pair is tried (of a subsample when there are many), so it is deterministic; returns farther
    than ``tolerance`` cost the same however far they are, so a minority of them cannot tilt it as they
    would a least-squares fit.
    """
    n = len(xy)
    cand = xy if n <= _CONSENSUS_CANDIDATES else xy[np.linspace(0, n - 1, _CONSENSUS_CANDIDATES).astype(np.intp)]
    i, j = np.triu_indices(len(cand), 1)
    d = cand[j] - cand[i]
    length = np.linalg.norm(d, axis=1)
    ok = length > 1e-9
    if not ok.any():
        return xy[0], np.array([1.0, 0.0])
    i, d, length = i[ok], d[ok], length[ok]
    normal = np.column_stack([-d[:, 1], d[:, 0]]) / length[:, None]
    res = np.einsum("mk,mnk->mn", normal, xy[None, :, :] - cand[i][:, None, :])
    best = int(np.argmin((np.minimum(np.abs(res), tolerance) ** 2).sum(axis=1)))
    return cand[i[best]], normal[best]


def _consensus(xy: NDArray[np.float64], tolerance: float) -> NDArray[np.bool_]:
    """Which points (N, 2) are within ``tolerance`` of the best line through two of them.

    Seeds the face: an object in front of part of the marker, or a stray return, stays out of it.
    """
    if len(xy) < 3:
        return np.ones(len(xy), dtype=bool)
    p0, normal = _best_pair_line(xy, tolerance)
    return np.asarray(np.abs((xy - p0) @ normal) <= tolerance)


def _grow_once(ret: _Returns, member: NDArray[np.bool_], tolerance: float, gap: float) -> NDArray[np.bool_]:
    """One pass of growing the segment ``member`` along the scan (see _grow_face)."""
    xs, ys = ret.points[:, 0].tolist(), ret.points[:, 1].tolist()
    beam, rng = ret.beam.tolist(), ret.ranges.tolist()
    ox, oy = ret.origin
    n = len(xs)
    member = member.copy()
    sums = _LineSums(ret.points[member, :2])
    x0, y0, nx, ny = sums.line()
    # A walking end: [last accepted, last examined, step, misses in a row].
    ends: list[list[int]] = []
    for k in np.flatnonzero(member).tolist():
        for step in (1, -1):
            nb = (k + step) % n if ret.circular else k + step
            if not (0 <= nb < n and member[nb]):
                ends.append([k, k, step, 0])
    while ends:
        walking = []
        for last, seen, step, misses in ends:
            c = seen + step
            if ret.circular:
                c %= n
            elif not 0 <= c < n:
                continue  # the end of the scan
            if member[c]:
                continue  # met another run of the segment
            beams = (beam[c] - beam[last]) * step
            if ret.circular:
                beams %= ret.beams
            if beams > _MAX_BEAM_STEP:
                continue  # a hole in the scan
            # The gap is measured along the line: across it, range noise alone makes neighbours centimetres
            # apart at close range, and a range jump (wall behind, clutter in front) leaves the line anyway.
            # Beams hitting the face obliquely land farther apart: 1 / cos(incidence).
            bx, by = xs[c] - ox, ys[c] - oy
            cos_inc = max(abs(bx * nx + by * ny) / max(math.hypot(bx, by), 1e-9), _MIN_COS_INCIDENCE)
            allowed = max(gap, _GAP_BEAMS * rng[last] * ret.increment * beams / cos_inc)
            if abs((xs[c] - xs[last]) * ny - (ys[c] - ys[last]) * nx) > allowed:
                continue  # a gap in the face: it ended, or something hides the rest
            if abs((xs[c] - x0) * nx + (ys[c] - y0) * ny) <= tolerance:
                member[c] = True
                sums.add(xs[c], ys[c])
                x0, y0, nx, ny = sums.line()
                walking.append([c, c, step, 0])
            elif misses + 1 < _MAX_MISSES:
                walking.append([last, c, step, misses + 1])
        ends = walking
    return member


def _grow_face(ret: _Returns, seed: NDArray[np.bool_], tolerance: float, gap: float) -> NDArray[np.bool_]:
    """The face segment: the seed grown along the scan to contiguous returns near the refitted line.

    Each end of each run of the segment walks outwards one return at a time, in turn, so that the line
    stays centred on what is known; every accepted return refits the line. An end stops at a gap along the
    line (wider than ``gap`` or a few beam spacings), at a hole of missing beams, at another part of the
    segment, or after two returns in a row farther than ``tolerance`` from the line. A far seed holds a
    handful of returns and its line can be degrees off, so an end may stop early on good returns; the
    passes repeat, with the line of everything found so far, until the segment stops growing.
    """
    member = seed
    for _ in range(_GROW_PASSES):
        grown = _grow_once(ret, member, tolerance, gap)
        if grown.sum() == member.sum():
            break
        member = grown
    return member


def _robust_line(
    xy: NDArray[np.float64], tolerance: float
) -> tuple[NDArray[np.bool_], NDArray[np.float64], NDArray[np.float64], float]:
    """TLS line through points (N >= MIN_FACE_POINTS, 2) with outlier rejection.

    Starts from the best pair line (a least-squares start is already tilted by the outliers it should
    reject: a clutter surface a few centimetres in front of the face's end), then iterates: residual
    scale from the MAD, keep the points within 3 sigma, refit by total least squares. A step that would
    leave fewer than MIN_FACE_POINTS is not taken.

    Returns:
        (kept, mean, unit direction, RMS distance of the kept points from the line).
    """
    p0, normal = _best_pair_line(xy, tolerance)
    keep = np.ones(len(xy), dtype=bool)
    for _ in range(_MAX_REFITS):
        r = (xy - p0) @ normal
        centre = float(np.median(r))
        sigma = max(1.4826 * float(np.median(np.abs(r - centre))), _SIGMA_FLOOR_M)
        new = np.abs(r - centre) <= _REJECT_SIGMAS * sigma
        if new.sum() < MIN_FACE_POINTS or np.array_equal(new, keep):
            break
        keep = new
        p0, direction, _ = _tls(xy[keep])
        normal = np.array([-direction[1], direction[0]])
    mean, direction, rms = _tls(xy[keep])
    return keep, mean, direction, rms


def points_across_marker(
    corners_m2: NDArray[np.float64], points: NDArray[np.float64], camera: CameraModel, robot: RobotConfig
) -> NDArray[np.bool_]:
    """Which base_link points (N, 3) fall across marker 2 as the camera sees it (papers Fig. 9)."""
    return _marker_planes(corners_m2, camera, robot).across(points)


def label_frame(
    corners_m2: NDArray[np.float64],
    scan: LaserScan,
    camera: CameraModel,
    robot: RobotConfig,
    *,
    other_corners: Sequence[NDArray[np.float64]] = (),
    tolerance: float = FACE_TOLERANCE_M,
    gap: float = FACE_GAP_M,
) -> LidarLabel:
    """The LiDAR label of one frame from marker 2's corners (pixels, ArUco order) and the paired scan.

    Args:
        corners_m2: marker 2's detected corners TL, TR, BR, BL, shape (4, 2), pixels through the lens.
        scan: the LiDAR scan paired with the image.
        camera: the camera calibration (intrinsics and distortion).
        robot: the mounts: base_link → camera optical frame and base_link → laser.
        other_corners: corners of the dock's other markers seen in the same image, each (4, 2); the
            returns across them join the seed of the face line.
        tolerance: farthest a return may be from the face line to join the face segment, m.
        gap: distance between neighbouring returns that ends the face segment, m (widened far away to a
            few beam spacings).

    Returns:
        The label; invalid (with a reason) when fewer than MIN_POINTS returns fall across marker 2 or fewer
        than MIN_FACE_POINTS are on the face line.
    """
    c2 = np.asarray(corners_m2, dtype=np.float64).reshape(4, 2)
    if not np.all(np.isfinite(c2)):
        return LidarLabel(reason="marker 2's corners are not finite")
    planes = _marker_planes(c2, camera, robot)
    centre, n_left = planes.centre, planes.n_left
    ret = _returns(scan, robot)
    if len(ret.points) == 0:
        return LidarLabel(reason="scan has no valid returns")
    on_m2 = planes.across(ret.points)
    p = ret.points[on_m2]
    if len(p) < MIN_POINTS:
        return LidarLabel(points=len(p), reason=f"too few LiDAR points across marker 2 ({len(p)}, need {MIN_POINTS})")

    # The papers' depth: the return nearest marker 2's centre plane.
    offset = (p - centre) @ planes.n_mid
    nearest = int(np.argmin(np.abs(offset)))
    # The papers' angle: the outermost points along the face (ordered by their position between the planes).
    side = (p - centre) @ n_left
    left_pt, right_pt = p[int(np.argmin(side))], p[int(np.argmax(side))]
    # The line over marker 2 alone (kept to compare with the face line).
    m_mean, m_dir, m_rms = _tls(p[:, :2])
    m_dir = planes.leftwards(m_dir)
    x_line_marker, y_marker = planes.crossing(m_mean, m_dir, float(p[:, 2].mean()))
    marker = LidarLabel(
        x=float(p[nearest, 0]),
        yaw_endpoints=_yaw_of_face((left_pt - right_pt)[:2]),
        points=len(p),
        span=float(np.linalg.norm(left_pt[:2] - right_pt[:2])),
        line_rms=m_rms,
        centre_offset=float(abs(offset[nearest])),
        yaw_marker=_yaw_of_face(m_dir),
        y_marker=y_marker,
        x_line_marker=x_line_marker,
    )

    # The face: seeded by the returns across every marker seen, grown along the scan, fitted robustly.
    seed = on_m2.copy()
    for corners in other_corners:
        c = np.asarray(corners, dtype=np.float64).reshape(4, 2)
        if np.all(np.isfinite(c)):
            seed |= _marker_planes(c, camera, robot).across(ret.points)
    seed_idx = np.flatnonzero(seed)
    seed[seed_idx[~_consensus(ret.points[seed_idx, :2], tolerance)]] = False
    face = _grow_face(ret, seed, tolerance, gap)
    f = ret.points[face]
    if len(f) < MIN_FACE_POINTS:
        return LidarLabel(
            points=len(p),
            face_points=len(f),
            reason=f"too few LiDAR points on the charger face ({len(f)}, need {MIN_FACE_POINTS})",
        )
    # The rejection never leaves fewer than MIN_FACE_POINTS.
    keep, f_mean, f_dir, f_rms = _robust_line(f[:, :2], tolerance)
    f_dir = planes.leftwards(f_dir)
    x_line, y_line = planes.crossing(f_mean, f_dir, float(f[keep, 2].mean()))
    if not (math.isfinite(x_line) and math.isfinite(y_line)):
        return LidarLabel(points=len(p), reason="the face line does not cross marker 2's centre plane")
    along = (f[keep, :2] - f_mean) @ f_dir
    return dataclasses.replace(
        marker,
        yaw=_yaw_of_face(f_dir),
        y=y_line,
        x_line=x_line,
        face_points=int(keep.sum()),
        face_span=float(np.ptp(along)),
        face_rms=f_rms,
        face_rejected=int((~keep).sum()),
    )
