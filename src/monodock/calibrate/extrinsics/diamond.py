"""Camera-LiDAR extrinsics from a diamond target: the LiDAR segment's ends on the board's slanted edges."""

from __future__ import annotations

import dataclasses
import math
import os
from collections.abc import Sequence
from dataclasses import dataclass
from typing import TYPE_CHECKING, Any

import cv2
import numpy as np
from numpy.typing import NDArray

from monodock.calibrate.target import DiamondTarget, TargetView
from monodock.core import transforms
from monodock.core.robot import Mount
from monodock.errors import InputError
from monodock.perception.detect import as_gray
from monodock.recording import open_recording, pair_nearest

if TYPE_CHECKING:
    from monodock.calibrate.target import DiamondTarget, TargetView
    from monodock.core.camera import CameraModel
    from monodock.core.scan import LaserScan
from monodock.calibrate.extrinsics.pairs import MIN_PAIRS, extrinsics_from_pairs
from monodock.calibrate.extrinsics.result import MAX_LINE_RMS_M, ExtrinsicsResult, covariance, line_spread

# --- (c) diamond target: LiDAR segment ends on the board's slanted edges ------------------------------

MIN_TARGET_VIEWS = 6
MIN_SEGMENT_BEAMS = 6
# Scan points this far from the board's plane / outside the diamond (under the prior mount) are not on it.
TARGET_PLANE_GATE_M = 0.10
TARGET_EDGE_MARGIN_M = 0.10
# Consecutive beams on one surface differ in range by less than this, metres.
RANGE_JUMP_M = 0.06


@dataclass(frozen=True)
class EdgeFit:
    """The diamond target's LiDAR point / pixel pairs and the point-to-line fit that matched them.

    Attributes:
        points: (N, 3) segment ends in the laser frame.
        pixels: (N, 2) the pixel of each end's closest point on its edge.
        views: views used (board and segment found).
        skipped: views or ends left out, reason -> count.
        mount: the point-to-line solution for the laser mount.
        rms_m: the ends' RMS distance to their edges, metres.
        std: the mount fields' 1-sigma (x, y, z, roll, pitch, yaw).
        condition: the condition of the fit's normalised J^T J.
    """

    points: NDArray[np.float64]
    pixels: NDArray[np.float64]
    views: int
    skipped: dict[str, int]
    mount: Mount
    rms_m: float
    std: dict[str, float]
    condition: float


@dataclass(frozen=True)
class _EdgeEnd:
    """One end of a view's LiDAR segment on the target: the point (laser frame) and the view's board pose."""

    view: int
    point: NDArray[np.float64]
    base_T_target: NDArray[np.float64]
    optical_T_target: NDArray[np.float64]


def _target_board_pose(
    image: NDArray[np.generic], camera: CameraModel, target: DiamondTarget, detector: Any
) -> NDArray[np.float64] | None:
    """optical_T_target from the target's markers in an image (two markers at least), or None."""

    corners, ids, _ = detector.detectMarkers(as_gray(image))
    if ids is None:
        return None
    obj, img = [], []
    for quad, mid in zip(corners, ids.ravel(), strict=True):
        if int(mid) in target.marker_ids:
            obj.append(target.marker_corners_in_target(int(mid)))
            img.append(np.asarray(quad, dtype=np.float64).reshape(4, 2))
    if len(obj) < 2:
        return None
    o, p = np.ascontiguousarray(np.vstack(obj)), np.ascontiguousarray(np.vstack(img))
    count, rvecs, tvecs, errs = cv2.solvePnPGeneric(o, p, camera.matrix, camera.dist, flags=cv2.SOLVEPNP_IPPE)
    if not count:
        return None
    k = int(np.argmin(np.asarray(errs).ravel()))
    criteria = (cv2.TERM_CRITERIA_COUNT | cv2.TERM_CRITERIA_EPS, 100, 1e-12)
    r, t = cv2.solvePnPRefineLM(o, p, camera.matrix, camera.dist, rvecs[k].copy(), tvecs[k].copy(), criteria)
    R, _ = cv2.Rodrigues(r)
    T = transforms.transform(R, np.asarray(t).ravel())
    return T if T[2, 3] > 0 else None


def _segment_ends(
    scan: LaserScan, target_T_laser: NDArray[np.float64], half_diagonal: float
) -> list[NDArray[np.float64]] | None:
    """The LiDAR segment on the board and its ends (laser frame, z = 0), or None when no segment is found.

    The segment is the run of consecutive beams without a range jump that holds the most returns near the board
    (under the prior mount). Each end whose outside neighbour lies farther (a true edge, not an occlusion) is
    refined: the segment's fitted line cut by the bisector of the last beam on and the first beam off.
    """
    r = scan.ranges.astype(np.float64)
    a = scan.angles()
    valid = np.isfinite(r) & (r >= scan.range_min) & (r <= scan.range_max)
    rr = np.where(valid, r, np.inf)
    xyz = np.stack([rr * np.cos(a), rr * np.sin(a), np.zeros_like(a)], axis=1)
    with np.errstate(invalid="ignore"):
        pt = transforms.apply(target_T_laser, np.where(valid[:, None], xyz, 0.0))
    near = (
        valid
        & (np.abs(pt[:, 2]) < TARGET_PLANE_GATE_M)
        & (np.abs(pt[:, 0]) + np.abs(pt[:, 1]) < half_diagonal + TARGET_EDGE_MARGIN_M)
    )
    if near.sum() < MIN_SEGMENT_BEAMS:
        return None
    n = len(r)
    # Runs of returns without a range jump; a single dropped beam (NaN) inside a run does not split it.
    idx = np.flatnonzero(valid)
    best: tuple[int, int, int] | None = None
    start = 0
    for q in range(1, len(idx) + 1):
        if q < len(idx):
            gap = idx[q] - idx[q - 1]
            same = (gap == 1 or (gap == 2 and np.isnan(r[idx[q] - 1]))) and abs(
                rr[idx[q]] - rr[idx[q - 1]]
            ) < RANGE_JUMP_M
            if same:
                continue
        i, j = int(idx[start]), int(idx[q - 1])
        hits = int(near[i : j + 1].sum())
        if best is None or hits > best[0]:
            best = (hits, i, j)
        start = q
    if best is None or best[0] < MIN_SEGMENT_BEAMS or best[2] - best[1] + 1 < MIN_SEGMENT_BEAMS:
        return None
    _, i0, i1 = best
    seg = xyz[i0 : i1 + 1, :2][valid[i0 : i1 + 1]]
    spread, c, d = line_spread(seg)
    if spread > MAX_LINE_RMS_M:
        return None
    ends = []
    for last, off in ((i0, i0 - 1), (i1, i1 + 1)):
        if off < 0 or off >= n or np.isnan(r[off]) or (valid[off] and rr[off] < rr[last] + RANGE_JUMP_M):
            continue  # the scan's border, a dropped beam, or something nearer hides the board's edge
        phi = 0.5 * (a[last] + a[off])
        u = np.array([math.cos(phi), math.sin(phi)])
        A = np.column_stack([u, -d])
        if abs(np.linalg.det(A)) < 1e-9:
            continue
        lam, _ = np.linalg.solve(A, c)
        if lam <= 0:
            continue
        ends.append(np.array([lam * u[0], lam * u[1], 0.0]))
    return ends


def _edge_frames(target: DiamondTarget) -> tuple[NDArray[np.float64], NDArray[np.float64], NDArray[np.float64]]:
    """The edges' start vertices, unit directions and in-plane unit normals, each shape (4, 3)."""
    edges = target.edges_in_target()
    v0 = np.array([e[0] for e in edges])
    d = np.array([e[1] - e[0] for e in edges])
    d /= np.linalg.norm(d, axis=1, keepdims=True)
    nrm = np.cross(np.array([0.0, 0.0, 1.0]), d)
    return v0, d, nrm


def _ends_in_target(ends: Sequence[_EdgeEnd], mount: NDArray[np.float64]) -> NDArray[np.float64]:
    """Each end point in its view's target frame under a mount (x y z roll pitch yaw), shape (N, 3)."""
    M = transforms.transform(transforms.rotation_from_rpy(*mount[3:]), mount[:3])
    return np.array([transforms.apply(transforms.invert(e.base_T_target) @ M, e.point[None])[0] for e in ends])


def _assign_edges(p_target: NDArray[np.float64], target: DiamondTarget) -> NDArray[np.intp]:
    """The nearest edge (as a segment, in the board plane) to each point."""
    edges = target.edges_in_target()
    dist = np.empty((len(p_target), 4))
    for k, (a, b) in enumerate(edges):
        ab = b - a
        s = np.clip((p_target[:, :2] - a[:2]) @ ab[:2] / (ab[:2] @ ab[:2]), 0.0, 1.0)
        dist[:, k] = np.linalg.norm(p_target[:, :2] - (a[:2] + s[:, None] * ab[:2]), axis=1)
    return np.asarray(np.argmin(dist, axis=1), dtype=np.intp)


def _edge_residuals(
    ends: Sequence[_EdgeEnd], mount: NDArray[np.float64], edge: NDArray[np.intp], target: DiamondTarget
) -> NDArray[np.float64]:
    """Point-to-line residuals: each end's offset from its edge across the board and out of its plane, (2N,)."""
    v0, _, nrm = _edge_frames(target)
    p = _ends_in_target(ends, mount)
    across = np.einsum("ij,ij->i", p - v0[edge], nrm[edge])
    return np.column_stack([across, p[:, 2]]).ravel()


def _solve_edge_mount(
    ends: Sequence[_EdgeEnd], prior: Mount, target: DiamondTarget
) -> tuple[NDArray[np.float64], NDArray[np.intp], NDArray[np.float64], NDArray[np.float64]]:
    """Levenberg-Marquardt on the six mount fields from the prior, re-assigning edges between rounds.

    Returns the mount vector, each end's edge, the final residuals and the Jacobian there.
    """
    x = np.array([prior.x, prior.y, prior.z, prior.roll, prior.pitch, prior.yaw], dtype=np.float64)
    steps = np.array([1e-6, 1e-6, 1e-6, 1e-7, 1e-7, 1e-7])
    edge = _assign_edges(_ends_in_target(ends, x), target)
    J = np.zeros((2 * len(ends), 6))
    res = _edge_residuals(ends, x, edge, target)
    for _ in range(3):
        lam = 1e-3
        for _ in range(50):
            res = _edge_residuals(ends, x, edge, target)
            J = np.column_stack(
                [(_edge_residuals(ends, x + h * np.eye(6)[i], edge, target) - res) / h for i, h in enumerate(steps)]
            )
            A = J.T @ J
            g = J.T @ res
            improved = False
            while lam < 1e8:
                dx = -np.linalg.solve(A + lam * np.diag(np.diag(A) + 1e-12), g)
                new = _edge_residuals(ends, x + dx, edge, target)
                if new @ new < res @ res:
                    x, lam, improved = x + dx, lam * 0.3, True
                    break
                lam *= 10.0
            if not improved or np.max(np.abs(dx)) < 1e-9:
                break
        new_edge = _assign_edges(_ends_in_target(ends, x), target)
        if np.array_equal(new_edge, edge):
            break
        edge = new_edge
    res = _edge_residuals(ends, x, edge, target)
    return x, edge, res, J


def edge_pairs_from_views(
    views: Sequence[TargetView],
    camera: CameraModel,
    base_T_optical: NDArray[np.float64],
    target: DiamondTarget,
    prior_mount: Mount,
) -> EdgeFit:
    """LiDAR point / pixel pairs from views of the diamond target: segment ends matched to the board's edges.

    Per view the camera gives the board's pose (its markers, PnP) and the scan its segment on the board, whose
    two ends lie on two slanted edges. The 6-DoF laser mount that puts the ends on their edges is found by
    point-to-line least squares from ``prior_mount``; each end is then paired with the pixel of its closest
    point on its edge.

    Returns:
        The pairs and the facts for the result's notes (views used, skipped, the point-to-line mount and RMS).

    Raises:
        InputError: fewer than MIN_TARGET_VIEWS views with the board and its segment found.
    """

    params = cv2.aruco.DetectorParameters()
    params.cornerRefinementMethod = cv2.aruco.CORNER_REFINE_SUBPIX
    params.cornerRefinementMinAccuracy = 0.01
    params.cornerRefinementMaxIterations = 50
    detector = cv2.aruco.ArucoDetector(target.aruco_dictionary(), params)
    prior_T = prior_mount.matrix()
    skipped: dict[str, int] = {}
    ends: list[_EdgeEnd] = []
    used = 0
    for k, view in enumerate(views):
        optical_T_target = _target_board_pose(view.image, camera, target, detector)
        if optical_T_target is None:
            skipped["board not found"] = skipped.get("board not found", 0) + 1
            continue
        base_T_target = base_T_optical @ optical_T_target
        found = _segment_ends(view.scan, transforms.invert(base_T_target) @ prior_T, target.half_diagonal)
        if not found:
            skipped["no LiDAR segment on the board"] = skipped.get("no LiDAR segment on the board", 0) + 1
            continue
        used += 1
        ends += [_EdgeEnd(k, p, base_T_target, optical_T_target) for p in found]
    if used < MIN_TARGET_VIEWS or len(ends) < MIN_PAIRS:
        why = ", ".join(f"{n} {r}" for r, n in skipped.items()) or "no views"
        raise InputError(
            f"only {used} of {len(views)} target views are usable ({why}); need at least {MIN_TARGET_VIEWS}"
        )
    x, edge, res, J = _solve_edge_mount(ends, prior_mount, target)
    # Drop ends far off their edge (a mis-found segment end), then solve again from the first solution.
    dist = np.hypot(res[0::2], res[1::2])
    keep = dist < max(3.0 * float(np.median(dist)) * 1.4826, 0.01)
    if not keep.all() and keep.sum() >= MIN_PAIRS:
        skipped["segment ends off their edge"] = int((~keep).sum())
        ends = [e for e, k in zip(ends, keep, strict=True) if k]
        x, edge, res, J = _solve_edge_mount(ends, Mount(*(float(v) for v in x)), target)
    v0, d, _ = _edge_frames(target)
    p_t = _ends_in_target(ends, x)
    q_t = v0[edge] + np.einsum("ij,ij->i", p_t - v0[edge], d[edge])[:, None] * d[edge]
    q_opt = np.array([transforms.apply(e.optical_T_target, q[None])[0] for e, q in zip(ends, q_t, strict=True)])
    pixels = camera.project(q_opt)
    points = np.array([e.point for e in ends])
    rms = float(np.sqrt(np.mean(res**2)))
    std, cond = covariance(J, rms, ("x", "y", "z", "roll", "pitch", "yaw"))
    return EdgeFit(points, pixels, used, skipped, Mount(*(float(v) for v in x)), rms, std, cond)


def extrinsics_from_target_views(
    views: Sequence[TargetView],
    camera: CameraModel,
    base_T_optical: NDArray[np.float64],
    prior_mount: Mount,
    target: DiamondTarget | None = None,
) -> ExtrinsicsResult:
    """The full 6-DoF LiDAR mount from views of the diamond target: edge pairs, then SolvePnP on them."""

    tgt = target or DiamondTarget()
    fit = edge_pairs_from_views(views, camera, base_T_optical, tgt, prior_mount)
    result = extrinsics_from_pairs(fit.points, fit.pixels, camera, base_T_optical, prior=prior_mount)
    m = fit.mount
    notes = [
        f"point-to-line solution: x {m.x:+.4f} y {m.y:+.4f} z {m.z:+.4f} m, roll {math.degrees(m.roll):+.3f} "
        f"pitch {math.degrees(m.pitch):+.3f} yaw {math.degrees(m.yaw):+.3f} deg, RMS {fit.rms_m * 100:.2f} cm",
        *result.notes,
    ]
    if fit.skipped:
        notes.append("views skipped: " + ", ".join(f"{n} {r}" for r, n in fit.skipped.items()))
    return dataclasses.replace(
        result, method="target pairs (SolvePnP)", count=fit.views, points=len(fit.points), notes=tuple(notes)
    )


def target_views_from_recording(
    path: str | os.PathLike[str], *, tolerance_s: float = 0.05
) -> tuple[list[TargetView], CameraModel | None, list[str]]:
    """Views of the diamond target from a recording: each image with the scan nearest in stamp (within
    ``tolerance_s``), the recording's camera (CameraInfo) if it has one, and the reader's warnings."""

    with open_recording(path) as rec:
        if rec.scan_topic is None:
            raise InputError(f"{path}: no sensor_msgs/LaserScan topic; the target's ends come from the LiDAR")
        scans = rec.scans()
        frames = [f for f in rec.images() if f.image is not None]
        camera = rec.camera()
        warnings = list(rec.warnings)
    pairing = pair_nearest([f.stamp for f in frames], [s.stamp for s in scans], tolerance_s)
    views = [
        TargetView(f.image, scans[int(j)])
        for f, j in zip(frames, pairing, strict=True)
        if j >= 0 and f.image is not None
    ]
    if not views:
        raise InputError(f"{path}: no image has a scan within {tolerance_s * 1000:.0f} ms")
    return views, camera, warnings
