"""Camera-LiDAR extrinsics from LiDAR point / pixel pairs (the papers' way): PnP, its uncertainty, and the
pairs CSV file."""

from __future__ import annotations

import csv
import dataclasses
import math
import os
from pathlib import Path
from typing import TYPE_CHECKING

import cv2
import numpy as np
from numpy.typing import ArrayLike, NDArray

from monodock.core import transforms
from monodock.core.atomic import write_text_atomic
from monodock.core.robot import Mount
from monodock.errors import InputError

if TYPE_CHECKING:
    from monodock.core.camera import CameraModel
from monodock.calibrate.extrinsics.result import ExtrinsicsResult, covariance, line_spread

MIN_PAIRS = 6
# The laser points' spread across their best line, metres (RMS): below it the pairs are one line.
COLLINEAR_SPREAD_M = 0.01


# --- (a) pairs: PnP from LiDAR points to pixels -------------------------------------------------------


def _check_pairs(points_laser: ArrayLike, pixels: ArrayLike) -> tuple[NDArray[np.float64], NDArray[np.float64]]:
    p = np.asarray(points_laser, dtype=np.float64)
    px = np.asarray(pixels, dtype=np.float64)
    if p.ndim != 2 or p.shape[1] not in (2, 3):
        raise InputError(f"LiDAR points must have shape (N, 2) or (N, 3), got {p.shape}")
    if px.ndim != 2 or px.shape[1] != 2:
        raise InputError(f"pixels must have shape (N, 2), got {px.shape}")
    if len(p) != len(px):
        raise InputError(f"{len(p)} LiDAR points but {len(px)} pixels; they must pair one to one")
    bad = ~(np.all(np.isfinite(p), axis=1) & np.all(np.isfinite(px), axis=1))
    if bad.any():
        raise InputError(f"pair {int(np.flatnonzero(bad)[0]) + 1} holds NaN or infinity; every value must be a number")
    if len(p) < MIN_PAIRS:
        raise InputError(f"{len(p)} pairs is too few: need at least {MIN_PAIRS}, spread over several target positions")
    if p.shape[1] == 2:
        p = np.column_stack([p, np.zeros(len(p))])
    p, px = np.ascontiguousarray(p), np.ascontiguousarray(px)
    spread, _, _ = line_spread(p[:, :2])
    if spread < COLLINEAR_SPREAD_M:
        raise InputError(
            f"the LiDAR points lie on one line in the scan plane (spread {spread * 1000:.1f} mm): "
            "add pairs from other target positions or angles"
        )
    return p, px


def extrinsics_from_pairs(
    points_laser: ArrayLike,
    pixels: ArrayLike,
    camera: CameraModel,
    base_T_optical: NDArray[np.float64],
    *,
    prior: Mount | None = None,
) -> ExtrinsicsResult:
    """The LiDAR mount from LiDAR points matched to their pixels (SolvePnP, then Levenberg-Marquardt).

    Args:
        points_laser: the LiDAR returns in the laser frame, metres, shape (N, 2) (the scan plane, z = 0) or (N, 3).
        pixels: where each return hits the target in the image, pixels through the lens, shape (N, 2).
        camera: the camera's intrinsics and distortion.
        base_T_optical: the camera optical frame in base_link (the known camera mount).
        prior: the mount to report the change from (default: the solved one).

    Returns:
        The calibration; the residual is the RMS reprojection error in pixels.

    Raises:
        InputError: fewer than MIN_PAIRS pairs, NaN, mismatched shapes, collinear LiDAR points, or no solution
            with the points in front of the camera.
    """

    obj, img = _check_pairs(points_laser, pixels)
    K, D = camera.matrix, camera.dist
    criteria = (cv2.TERM_CRITERIA_COUNT | cv2.TERM_CRITERIA_EPS, 100, 1e-12)
    starts: list[tuple[NDArray[np.float64], NDArray[np.float64]]] = []
    if prior is not None:
        guess = transforms.invert(base_T_optical) @ prior.matrix()
        rv, _ = cv2.Rodrigues(guess[:3, :3])
        starts.append((np.asarray(rv, dtype=np.float64), guess[:3, 3].reshape(3, 1).copy()))
    found, rvec, tvec = cv2.solvePnP(obj, img, K, D, flags=cv2.SOLVEPNP_ITERATIVE)
    if found:
        starts.append((np.asarray(rvec, dtype=np.float64), np.asarray(tvec, dtype=np.float64)))
    count, rvecs, tvecs, _ = cv2.solvePnPGeneric(obj, img, K, D, flags=cv2.SOLVEPNP_IPPE)
    if count:
        starts += [
            (np.asarray(r, dtype=np.float64), np.asarray(t, dtype=np.float64))
            for r, t in zip(rvecs, tvecs, strict=True)
        ]
    best: tuple[float, NDArray[np.float64]] | None = None
    for r0, t0 in starts:
        r, t = cv2.solvePnPRefineLM(obj, img, K, D, r0.copy(), t0.copy(), criteria)
        R, _ = cv2.Rodrigues(r)
        optical_T_laser = transforms.transform(R, np.asarray(t).ravel())
        if not np.all(transforms.apply(optical_T_laser, obj)[:, 2] > 0):
            continue
        proj, _ = cv2.projectPoints(obj, r, t, K, D)
        rms = float(np.sqrt(np.mean(np.sum((proj.reshape(-1, 2) - img) ** 2, axis=1))))
        if best is None or rms < best[0]:
            best = (rms, optical_T_laser)
    if best is None:
        raise InputError("no LiDAR pose puts the pairs in front of the camera: check the pairs' columns and units")
    rms, optical_T_laser = best
    mount = Mount.from_matrix(base_T_optical @ optical_T_laser)
    notes = []
    if rms > 3.0:
        notes.append(f"reprojection RMS {rms:.1f} px is large: check for mismatched pairs")
    std, cond = _pnp_uncertainty(obj, optical_T_laser, camera, base_T_optical, rms)
    return ExtrinsicsResult(
        method="pairs",
        laser_mount=mount,
        optical_T_laser=optical_T_laser,
        prior_mount=prior or mount,
        rms=rms,
        residual_unit="px",
        count=len(obj),
        points=len(obj),
        std=std,
        condition=cond,
        notes=tuple(notes),
    )


def _pnp_uncertainty(
    obj: NDArray[np.float64],
    optical_T_laser: NDArray[np.float64],
    camera: CameraModel,
    base_T_optical: NDArray[np.float64],
    rms: float,
) -> tuple[dict[str, float], float]:
    """1-sigma of the mount's six fields by numerical Jacobian of the reprojection, and its condition."""

    base = Mount.from_matrix(base_T_optical @ optical_T_laser)
    optical_T_base = transforms.invert(base_T_optical)
    keys = ("x", "y", "z", "roll", "pitch", "yaw")
    steps = (1e-4, 1e-4, 1e-4, 1e-5, 1e-5, 1e-5)

    def project(m: Mount) -> NDArray[np.float64]:
        p = transforms.apply(optical_T_base @ m.matrix(), obj)
        px, _ = cv2.projectPoints(p, np.zeros(3), np.zeros(3), camera.matrix, camera.dist)
        return np.asarray(px, dtype=np.float64).ravel()

    p0 = project(base)
    J = np.column_stack(
        [
            (project(dataclasses.replace(base, **{k: getattr(base, k) + h})) - p0) / h
            for k, h in zip(keys, steps, strict=True)
        ]
    )
    return covariance(J, rms * math.sqrt(2.0), keys)


# --- pairs files --------------------------------------------------------------------------------------


def read_pairs_csv(path: str | os.PathLike[str]) -> tuple[NDArray[np.float64], NDArray[np.float64]]:
    """LiDAR point / pixel pairs from a CSV with the header ``x,y,u,v`` (optionally ``z``).

    x, y (z) are metres in the laser frame; u, v are pixels through the lens (as the image shows them).

    Returns:
        points (N, 3) in the laser frame (z = 0 when the column is absent) and pixels (N, 2).

    Raises:
        InputError: missing file or column, a value that is not a number, no rows.
    """
    p = Path(path)
    if not p.is_file():
        raise InputError(f"pairs file not found: {p}")
    with p.open(newline="", encoding="utf-8") as fh:
        reader = csv.DictReader(fh)
        header = [h.strip().lower() for h in (reader.fieldnames or [])]
        missing = [c for c in ("x", "y", "u", "v") if c not in header]
        if missing:
            raise InputError(f"{p}: missing column {', '.join(missing)} (the header must be x,y,u,v with optional z)")
        reader.fieldnames = header
        rows = []
        for line, row in enumerate(reader, start=2):
            try:
                vals = [float(row.get(c) or "nan") for c in ("x", "y", "z", "u", "v")] if "z" in header else None
                if vals is None:
                    vals = [float(row[c] or "nan") for c in ("x", "y")] + [0.0]
                    vals += [float(row[c] or "nan") for c in ("u", "v")]
            except (TypeError, ValueError):
                raise InputError(f"{p}: line {line}: every value must be a number") from None
            rows.append(vals)
    if not rows:
        raise InputError(f"{p}: no pairs below the header")
    a = np.asarray(rows, dtype=np.float64)
    return np.ascontiguousarray(a[:, :3]), np.ascontiguousarray(a[:, 3:])


def write_pairs_csv(
    path: str | os.PathLike[str],
    points_laser: NDArray[np.float64],
    pixels: NDArray[np.float64],
    *,
    force: bool = False,
) -> None:
    """Write pairs as the CSV that read_pairs_csv reads (x, y metres in the laser frame; u, v pixels)."""

    lines = ["x,y,u,v"] + [
        f"{p[0]:.6f},{p[1]:.6f},{q[0]:.4f},{q[1]:.4f}" for p, q in zip(points_laser, pixels, strict=True)
    ]
    write_text_atomic(path, "\n".join(lines) + "\n", force=force)
