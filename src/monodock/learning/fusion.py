"""Learning the fused method's tables (``estimation.fused.FusionTables``) from a bundle's held-out rows.

The rows the regression never trained on are run through both methods, the geometry (planar fit on the
refined corners) and the regression, and compared with their LiDAR labels: first the camera mount's pitch,
height and roll as the images see them (4-DoF fits), then the corner noise, the calibration residual
(``fit_correction``), and per marker set and 25 cm band the error covariances of both methods with the labels'
own noise removed (``three_cornered_hat``: with three independent instruments, the cross-covariance of two
methods' residuals against the third is that third one's covariance).
"""

from __future__ import annotations

import math
from dataclasses import dataclass, replace
from pathlib import Path

import numpy as np
from numpy.typing import NDArray

from monodock.core.camera import CameraModel
from monodock.core.layout import DockLayout
from monodock.core.robot import RobotConfig
from monodock.errors import InputError
from monodock.estimation.bundle import load_bundle
from monodock.estimation.fused import (
    BAND_EDGES_M,
    DISAGREE_CHI2,
    Correction,
    FusedEstimator,
    FusionTables,
    band_index,
    marker_set_key,
    pose_difference,
    pose_vector,
    psd_floor,
)
from monodock.estimation.regression import RegressionEstimator
from monodock.learning.dataset import Dataset
from monodock.learning.export import update_bundle_metadata
from monodock.perception.features import detection_from_features, refined_detection_from_row

__all__ = [
    "FUSION_FRACTION",
    "FUSION_LABELS",
    "FUSION_LEARNING",
    "TrainingRows",
    "corner_sigma_from_residuals",
    "fit_correction",
    "fit_mount_offsets",
    "fit_mount_roll",
    "fusion_holdout",
    "learn_fusion",
    "learn_fusion_from",
    "learn_mount",
    "learn_tables",
    "three_cornered_hat",
    "train_fusion",
    "training_rows",
]

# What the tables are learned with, for caches of self-trained bundles (2: the mount's roll; the geometry's
# excess variance from depth and yaw only). Tables of an earlier revision still read.
FUSION_LEARNING = 2


def three_cornered_hat(
    residual_a: NDArray[np.float64], residual_b: NDArray[np.float64]
) -> tuple[NDArray[np.float64], NDArray[np.float64], NDArray[np.float64]]:
    """The error covariances of two methods and of their common reference from residuals against it.

    ``residual_a = a - ref`` and ``residual_b = b - ref`` (rows, 3). With independent errors,
    Cov(r_a, r_b) = Cov(ref), so Cov(a) = Cov(r_a) - Cov(ref) and likewise for b. Rows far out (chi-square
    3 dof beyond 99.9 % on a first pass) are left out, so a mislabelled row does not inflate every variance.
    Returns (cov_a, cov_b, cov_ref), each projected onto a positive-definite matrix above a small floor.
    """
    joint = np.hstack([residual_a, residual_b])
    keep = np.all(np.isfinite(joint), axis=1)
    joint = joint[keep]
    if len(joint) < 8:
        raise ValueError(f"three-cornered hat needs at least 8 rows, got {len(joint)}")
    for _ in range(2):
        c = np.cov(joint, rowvar=False)
        centred = joint - joint.mean(axis=0)
        d2 = np.einsum("ij,jk,ik->i", centred, np.linalg.pinv(c), centred)
        inliers = d2 <= 2 * DISAGREE_CHI2  # 6 dof
        if inliers.sum() >= 8:
            joint = joint[inliers]
    c = np.cov(joint, rowvar=False)
    cross = 0.5 * (c[:3, 3:] + c[3:, :3])
    return psd_floor(c[:3, :3] - cross), psd_floor(c[3:, 3:] - cross), psd_floor(cross)


# A calibration residual smaller than these is left alone: the LiDAR labels themselves carry biases of a few
# hundredths of a degree and a millimetre or two (bench/label_accuracy.py), which a correction would import into
# a geometry far more accurate than they are. Real miscalibrations (a 1 degree mount, a 3 % focal length, a 5 %
# marker size) are many times larger.
MIN_YAW_OFFSET = math.radians(0.1)
MIN_SCALE_ERROR = 0.002
MIN_OFFSET_M = 0.002


def fit_correction(
    geometry: NDArray[np.float64], labels: NDArray[np.float64], pivot: tuple[float, float] = (0.0, 0.0)
) -> Correction:
    """The yaw offset (median), then the depth scale and offset (least squares), three times over, each time
    leaving out rows beyond 4 robust sigmas; a term that is not both significant (3 standard errors) and
    above the labels' own bias (MIN_*) stays at the identity. Fewer than 20 rows: the identity."""
    ok = np.all(np.isfinite(geometry), axis=1) & np.all(np.isfinite(labels), axis=1)
    g, lab = geometry[ok], labels[ok]
    c = Correction(pivot_x=pivot[0], pivot_y=pivot[1])
    if len(g) < 20:
        return c
    keep = np.ones(len(g), dtype=bool)
    for _ in range(3):
        n = int(keep.sum())
        dyaw = pose_difference(lab[keep], g[keep])[:, 2]
        yaw_off = float(np.median(dyaw))
        se_yaw = 1.253 * float(np.std(dyaw)) / math.sqrt(n)
        if abs(yaw_off) < max(3 * se_yaw, MIN_YAW_OFFSET):
            yaw_off = 0.0
        turned = Correction(yaw_offset=yaw_off, pivot_x=pivot[0], pivot_y=pivot[1]).apply(g[keep])
        a = np.column_stack([turned[:, 0] - pivot[0], np.ones(n)])
        coef, *_ = np.linalg.lstsq(a, lab[keep, 0] - turned[:, 0], rcond=None)
        resid = lab[keep, 0] - turned[:, 0] - a @ coef
        cov = np.linalg.inv(a.T @ a) * float(np.var(resid))
        scale_err, offset = float(coef[0]), float(coef[1])
        depth = float(np.median(a[:, 0]))
        shift = scale_err * depth + offset  # what the depth term changes at a typical depth
        se_shift = math.sqrt(max(float(np.array([depth, 1.0]) @ cov @ np.array([depth, 1.0])), 0.0))
        big = abs(scale_err) >= max(3 * math.sqrt(cov[0, 0]), MIN_SCALE_ERROR)
        big = big or abs(shift) >= max(3 * se_shift, MIN_OFFSET_M)
        if not big:
            scale_err, offset = 0.0, 0.0
        c = Correction(1.0 + scale_err, offset, yaw_off, *pivot)
        r = pose_difference(lab, c.apply(g))
        mad = np.median(np.abs(r - np.median(r, axis=0)), axis=0) * 1.4826 + 1e-12
        keep = (np.abs(r[:, 0]) <= 4 * mad[0]) & (np.abs(r[:, 2]) <= 4 * mad[2])
    return c


MIN_CELL_ROWS = 30


@dataclass
class TrainingRows:
    """Per held-out row: both methods' answers, the LiDAR label and what the tables are keyed by.

    Poses are (n, 3) x m, y m, yaw rad, NaN where a method had no answer or the label is invalid.
    ``geometry_cov`` is each geometric fit's Jacobian covariance at unit corner sigma scaled by the
    corner sigma model; ``residual_sigma`` the per-axis corner sigma its residuals imply, and ``side_px``
    the mean marker side of the fit, which together estimate the corner sigma model.
    """

    geometry: NDArray[np.float64]
    geometry_cov: NDArray[np.float64]
    geometry_set: list[str]
    residual_sigma: NDArray[np.float64]
    side_px: NDArray[np.float64]
    regression: NDArray[np.float64]
    regression_set: list[str]
    labels: NDArray[np.float64]
    depth_from_camera: NDArray[np.float64]
    pitch_offset: NDArray[np.float64] | None = None
    roll_offset: NDArray[np.float64] | None = None


def corner_sigma_from_residuals(residual_sigma: NDArray[np.float64], side_px: NDArray[np.float64]) -> float:
    """The corner sigma model's constant c (sigma_px = c / sqrt(side px)) from the fits' residuals."""
    ok = np.isfinite(residual_sigma) & np.isfinite(side_px) & (side_px > 0)
    if ok.sum() < 10:
        raise InputError(f"only {int(ok.sum())} geometric fits to learn the corner noise from (need 10)")
    return float(np.median(residual_sigma[ok] * np.sqrt(side_px[ok])))


def _excess(z_geo: NDArray[np.float64], z_reg: NDArray[np.float64], draws: int = 100) -> float:
    """How many times its Jacobian variance the geometry's error variance is, at least (>= 1).

    The labels are often far noisier than the geometry, and then the hat's estimate of the geometry's
    variance is mostly sampling noise: the bootstrap's lower bound (mean minus two standard errors) is
    kept, so that noise never inflates the geometry's covariance. Depth and yaw only: the regression's
    lateral and the label's both come from marker 2's centre ray, so their errors correlate, which the hat
    reads as geometry variance (the demo's held-out rows: 86x the Jacobian variance in lateral, 1.0x true).
    """
    rng = np.random.default_rng(0)
    n = len(z_geo)
    values = []
    for k in range(draws + 1):
        pick = np.arange(n) if k == 0 else rng.integers(0, n, n)
        cov_g, _, _ = three_cornered_hat(z_geo[pick], z_reg[pick])
        values.append(float(np.mean(np.diag(cov_g)[[0, 2]])))
    low = values[0] - 2.0 * float(np.std(values[1:]))
    return float(np.clip(low, 1.0, 1e4))


def learn_tables(rows: TrainingRows, corner_sigma: float, pivot: tuple[float, float] = (0.0, 0.0)) -> FusionTables:
    """The fusion tables from held-out rows (see the module docstring); ``pivot`` is the camera's position
    in base_link, about which a calibration error turns and scales what the camera sees."""
    bands = np.array([band_index(float(d)) if math.isfinite(d) else -1 for d in rows.depth_from_camera])
    labelled = np.all(np.isfinite(rows.labels), axis=1)
    geo_ok = np.all(np.isfinite(rows.geometry), axis=1) & labelled
    reg_ok = np.all(np.isfinite(rows.regression), axis=1) & labelled
    correction = fit_correction(rows.geometry[geo_ok], rows.labels[geo_ok], pivot)
    geometry = correction.apply(rows.geometry)
    cj = correction.jacobian()
    gcov = np.einsum("ij,njk,lk->nil", cj, rows.geometry_cov, cj)
    r_geo = pose_difference(geometry, rows.labels)
    r_reg = pose_difference(rows.regression, rows.labels)
    both = geo_ok & reg_ok
    nb = len(BAND_EDGES_M) - 1
    gset = np.asarray(rows.geometry_set, dtype=object)
    rset = np.asarray(rows.regression_set, dtype=object)

    # The geometry's excess over its Jacobian covariance, one factor per marker set pooled over the bands:
    # residuals divided by the Jacobian sd of their row (both methods' alike, so the hat still separates the
    # labels' share), so that every held-out row counts, whatever its depth.
    sd_j = np.sqrt(np.diagonal(gcov, axis1=1, axis2=2))
    geometry_scale: dict[str, list[float]] = {}
    pooled: dict[str, float] = {}
    keys = sorted({s for s, ok in zip(rows.geometry_set, both, strict=True) if ok and s})
    for key in [*keys, ""]:
        sel = both & ((gset == key) if key else True)
        if sel.sum() < MIN_CELL_ROWS:
            continue
        pooled[key] = _excess(r_geo[sel] / sd_j[sel], r_reg[sel] / sd_j[sel])
    for key in keys:
        geometry_scale[key] = [pooled.get(key, pooled.get("", 1.0))] * nb

    # The regression's covariance per marker set and band, from the band's rows, widened to the neighbouring
    # bands until there are enough.
    regression_cov: dict[str, list[NDArray[np.float64] | None]] = {}
    label_cov: list[NDArray[np.float64] | None] = [None] * nb
    counts: dict[str, int] = {}
    for key in sorted({s for s, ok in zip(rows.regression_set, both, strict=True) if ok and s}):
        cells: list[NDArray[np.float64] | None] = []
        mine = both & (rset == key)
        counts[key] = int(mine.sum())
        for b in range(nb):
            sel = np.zeros_like(mine)
            for reach in range(nb):
                sel = mine & (np.abs(bands - b) <= reach)
                if sel.sum() >= MIN_CELL_ROWS:
                    break
            if sel.sum() < MIN_CELL_ROWS:
                cells.append(None)
                continue
            _, cov_r, cov_l = three_cornered_hat(r_geo[sel], r_reg[sel])
            cells.append(cov_r)
            if label_cov[b] is None or key == "m1m2m3":
                label_cov[b] = cov_l
        regression_cov[key] = cells
    return FusionTables(corner_sigma, correction, geometry_scale, regression_cov, label_cov, counts)


# The share of a dataset's rows kept out of the regression's training to learn the fusion tables from.
FUSION_FRACTION = 0.1
# The labels the tables are learned against: the whole-face line's depth and lateral at marker 2's centre
# plane, and its angle (the best the LiDAR gives; the papers' nearest-point depth is noisier).
FUSION_LABELS = ("label_x_line_m", "label_y_m", "label_yaw_deg")
# Before anything is learned: corner sigma 1 px * sqrt(px), i.e. 0.14 px on a 50 px marker, and a broad
# regression covariance (5 cm, 5 cm, 10 degrees) to choose among a lone marker's minima.
_GUESS_SIGMA = 1.0
_GUESS_PRIOR_COV = np.diag([0.05**2, 0.05**2, math.radians(10.0) ** 2])


def fusion_holdout(rows: int, fraction: float = FUSION_FRACTION, seed: int = 0) -> NDArray[np.bool_]:
    """Which rows to keep out of the regression's training for the fusion tables (seeded)."""
    if not 0.0 < fraction < 1.0:
        raise InputError(f"the fusion hold-out must be a fraction between 0 and 1, got {fraction}")
    rng = np.random.default_rng([seed, 0xF05E])
    mask = np.zeros(rows, dtype=bool)
    mask[rng.choice(rows, size=max(1, round(fraction * rows)), replace=False)] = True
    return mask


def training_rows(
    dataset: Dataset,
    regression: RegressionEstimator | None,
    camera: CameraModel,
    layout: DockLayout,
    robot: RobotConfig,
    rows: NDArray[np.int64],
    *,
    pitch_sd: float | None = None,
    roll_sd: float | None = None,
    mount_offsets: tuple[float, float, float] = (0.0, 0.0, 0.0),
) -> TrainingRows:
    """Both methods on the given rows of a labelled dataset (its stored OpenCV and refined corners).

    ``pitch_sd`` or ``roll_sd`` fits the camera's pitch or roll offset too (``planar.solve_planar``);
    ``mount_offsets`` (pitch rad, height m, roll rad) corrects the camera mount the geometry fits with.
    """
    raw = dataset.raw_features()
    refined = dataset.refined_corners()
    labels = np.column_stack([np.asarray(dataset[c], dtype=np.float64) for c in FUSION_LABELS])
    labels[:, 2] = np.radians(labels[:, 2])
    labels[~np.asarray(dataset["label_valid"], dtype=bool)] = np.nan
    guess = learn_mount(FusionTables(_GUESS_SIGMA), mount_offsets)
    probe = FusedEstimator(camera, layout, robot, guess, None)
    n = len(rows)
    geo = np.full((n, 3), np.nan)
    gcov = np.tile(np.eye(3), (n, 1, 1))
    reg = np.full((n, 3), np.nan)
    gset, rset = [""] * n, [""] * n
    resid = np.full(n, np.nan)
    side = np.full(n, np.nan)
    pitch = np.full(n, np.nan)
    roll = np.full(n, np.nan)
    for k, i in enumerate(rows):
        det = detection_from_features(raw[i], layout, camera.size)
        ref = refined_detection_from_row(raw[i], refined[i], layout, camera.size)
        r = regression.estimate_raw(raw[i], det.roles_seen) if regression is not None else None
        if r is not None and r.pose is not None:
            reg[k] = pose_vector(r.pose)
            rset[k] = marker_set_key(r.markers_seen)
        g = probe.geometry(
            det, ref, r.pose if r is not None else None, _GUESS_PRIOR_COV, pitch_sd=pitch_sd, roll_sd=roll_sd
        )
        if g is not None:
            pitch[k], roll[k] = g.pitch_offset, g.roll_offset
            geo[k], gcov[k], gset[k] = g.pose, g.covariance, marker_set_key(g.roles)
            side[k] = g.side_px
            resid[k] = g.noise_scale * _GUESS_SIGMA / math.sqrt(max(g.side_px, 4.0))
    depth = labels[rows, 0] - robot.camera_mount.x
    return TrainingRows(geo, gcov, gset, resid, side, reg, rset, labels[rows], depth, pitch, roll)


# A mount pitch or height error smaller than these is left alone (what a few hundred frames cannot tell apart
# from the corners' noise and the floor's unevenness).
MIN_PITCH_OFFSET = math.radians(0.05)
MIN_HEIGHT_OFFSET = 0.002
MIN_ROLL_OFFSET = math.radians(0.05)
TRAINING_PITCH_SD = math.radians(3.0)


def fit_mount_offsets(rows: TrainingRows, camera_x: float) -> tuple[float, float]:
    """The camera mount's pitch (rad) and height (m) errors from the pitch offsets the 4-DoF fits found.

    A pitch error tilts every view by the same angle; a height error by (error / depth from the camera),
    opposite in sign: delta = pitch_error - height_error / depth. Robust least squares over the rows; a term
    that is not significant (3 standard errors) and above MIN_* stays 0.
    """
    if rows.pitch_offset is None:
        return 0.0, 0.0
    ok = np.isfinite(rows.pitch_offset) & np.all(np.isfinite(rows.geometry), axis=1)
    if ok.sum() < 20:
        return 0.0, 0.0
    delta = rows.pitch_offset[ok]
    inv_depth = 1.0 / np.maximum(rows.geometry[ok, 0] - camera_x, 0.2)
    a = np.column_stack([np.ones(len(delta)), -inv_depth])
    keep = np.ones(len(delta), dtype=bool)
    coef = np.zeros(2)
    cov = np.eye(2)
    for _ in range(3):
        coef, *_ = np.linalg.lstsq(a[keep], delta[keep], rcond=None)
        r = delta - a @ coef
        scale = 1.4826 * float(np.median(np.abs(r[keep]))) + 1e-9
        keep = np.abs(r) <= 4 * scale
        cov = np.linalg.inv(a[keep].T @ a[keep]) * float(np.var(r[keep]))
    pitch, height = float(coef[0]), float(coef[1])
    if abs(pitch) < max(3 * math.sqrt(cov[0, 0]), MIN_PITCH_OFFSET):
        pitch = 0.0
    if abs(height) < max(3 * math.sqrt(cov[1, 1]), MIN_HEIGHT_OFFSET):
        height = 0.0
    return pitch, height


def learn_mount(tables: FusionTables, mount_offsets: tuple[float, float, float]) -> FusionTables:
    """The tables with the camera mount's (pitch rad, height m, roll rad) offsets."""
    pitch, height, roll = mount_offsets
    return replace(tables, mount_pitch_offset=pitch, mount_z_offset=height, mount_roll_offset=roll)


def fit_mount_roll(rows: TrainingRows) -> float:
    """The camera mount's roll error (rad) from the roll offsets the 4-DoF fits found.

    A roll error turns every view by the same angle about the optical axis, the opposite way (the image turns
    against the camera): a robust mean, 0 unless significant (3 standard errors) and above MIN_ROLL_OFFSET.
    """
    if rows.roll_offset is None:
        return 0.0
    rho = rows.roll_offset[np.isfinite(rows.roll_offset)]
    if len(rho) < 20:
        return 0.0
    keep = np.ones(len(rho), dtype=bool)
    for _ in range(3):
        centre = float(np.median(rho[keep]))
        scale = 1.4826 * float(np.median(np.abs(rho[keep] - centre))) + 1e-12
        keep = np.abs(rho - centre) <= 4 * scale
    mean = float(np.mean(rho[keep]))
    se = float(np.std(rho[keep])) / math.sqrt(keep.sum())
    return -mean if abs(mean) >= max(3 * se, MIN_ROLL_OFFSET) else 0.0


def learn_fusion(
    rows: TrainingRows, robot: RobotConfig, mount_offsets: tuple[float, float, float] = (0.0, 0.0, 0.0)
) -> FusionTables:
    """The tables from held-out rows (fitted with ``mount_offsets``): the corner noise first, then everything that
    depends on it."""
    c = corner_sigma_from_residuals(rows.residual_sigma, rows.side_px)
    scaled = TrainingRows(**{**rows.__dict__, "geometry_cov": rows.geometry_cov * (c / _GUESS_SIGMA) ** 2})
    tables = learn_tables(scaled, c, (robot.camera_mount.x, robot.camera_mount.y))
    return learn_mount(tables, mount_offsets)


def learn_fusion_from(
    dataset: Dataset,
    regression: RegressionEstimator | None,
    camera: CameraModel,
    layout: DockLayout,
    robot: RobotConfig,
    rows: NDArray[np.int64],
) -> FusionTables:
    """Everything the fused method learns from held-out rows: first the camera mount's pitch and height, then its
    roll, as the images see them (4-DoF fits), then, with those, the corner noise, the variances and the
    calibration residual."""
    first = training_rows(dataset, regression, camera, layout, robot, rows, pitch_sd=TRAINING_PITCH_SD)
    pitch, height = fit_mount_offsets(first, robot.camera_mount.x)
    turned = training_rows(
        dataset, regression, camera, layout, robot, rows, roll_sd=TRAINING_PITCH_SD, mount_offsets=(pitch, height, 0.0)
    )
    offsets = (pitch, height, fit_mount_roll(turned))
    second = training_rows(dataset, regression, camera, layout, robot, rows, mount_offsets=offsets)
    return learn_fusion(second, robot, offsets)


def train_fusion(
    bundle_path: str | Path, dataset: Dataset, holdout: NDArray[np.bool_], *, camera: CameraModel | None = None
) -> FusionTables:
    """Learn the fusion tables on a trained bundle's held-out rows and store them in the bundle.

    ``holdout`` marks the rows the regression never trained on (``fusion_holdout``); ``camera`` overrides
    the dataset's, as it did for the regression's training.
    """
    bundle = load_bundle(bundle_path)
    camera = camera or dataset.camera()
    layout, robot = dataset.layout(), dataset.robot()
    regression = RegressionEstimator(bundle, camera, robot)
    tables = learn_fusion_from(dataset, regression, camera, layout, robot, np.flatnonzero(holdout))
    update_bundle_metadata(bundle_path, "fusion", tables.to_dict())
    return tables
