"""The fused estimator (``--method fused``): planar PnP on bias-free corners, combined with the regression.

Two estimators with opposite weaknesses see the same frame:

- **geometry**: the maximum-likelihood planar pose (x, y, yaw) of every visible marker's refined corners
  (``refine.py``, ``planar.py``). It is as good as the pixels allow, but only as right as the calibration;
  a lone small marker has two near-equal minima (the sign of yaw).
- **regression** (the papers'): learned from LiDAR labels, so it carries no calibration error, but no better
  than its labels, and blind outside its training range.

Per frame, every local minimum of the geometry is scored by its reprojection error and by its distance from
the regression (which settles a lone marker's yaw sign); the chosen one is corrected by the calibration
residual learned from the LiDAR labels at training time, and the two are combined by inverse-variance
(information) weighting. With two or more markers and a clean fit the regression is not even run where its
learned covariance could not make the answer measurably better (``REGRESSION_GAIN``): near the dock, and
with three markers almost everywhere, the pixels alone are the answer.

The variances come from training: the rows held out of the regression's training, per marker set and 25 cm
depth band, as the error covariance of each method against the LiDAR labels with the
labels' own noise removed (the three-cornered hat: with three independent instruments, the cross-covariance
of two methods' residuals against the third is that third one's covariance). The geometry's per-frame
covariance is its Jacobian covariance from the corner noise, scaled up where training found it optimistic.
"""

from __future__ import annotations

import math
from collections.abc import Mapping, Sequence
from dataclasses import dataclass, field, replace
from typing import TYPE_CHECKING, Any

import numpy as np
from numpy.typing import NDArray

from monodock.core.camera import CameraModel
from monodock.core.compiled import kernel
from monodock.core.layout import ROLE_NUMBER, ROLES, DockLayout
from monodock.core.pose import DockPose, wrap_angle
from monodock.core.robot import RobotConfig
from monodock.errors import InputError
from monodock.estimation.pnp import PoseEstimate
from monodock.perception.detect import Detection

if TYPE_CHECKING:
    from monodock.estimation.planar import PlanarFit

__all__ = [
    "BAND_EDGES_M",
    "FUSION_SCHEMA",
    "Correction",
    "FusedEstimator",
    "FusionTables",
    "band_index",
    "fuse_gaussians",
    "marker_set_key",
    "three_cornered_hat",
]

FUSION_SCHEMA = "monodock.fusion/3"
# What the tables are learned with, for caches of self-trained bundles (2: the mount's roll; the geometry's
# excess variance from depth and yaw only). Tables of an earlier revision still read.
FUSION_LEARNING = 2
# 25 cm bands of the papers' depth (from the camera) over 25-250 cm; depths outside use the end bands.
BAND_EDGES_M = tuple(0.25 + 0.25 * k for k in range(10))
# Chi-square, 3 dof, 99.9 %: beyond this the geometry and the regression disagree and are not averaged.
DISAGREE_CHI2 = 16.27
# Floors that keep a covariance invertible: 0.1 mm, 0.1 mm, 0.005 degrees (standard deviations).
_FLOOR_SD = np.array([1e-4, 1e-4, math.radians(0.005)])
_FLOOR_OUTER = np.outer(_FLOOR_SD, _FLOOR_SD)


def band_index(depth_from_camera: float) -> int:
    """The 25 cm band of a depth measured from the camera (clamped to the first and last band)."""
    k = int(math.floor((depth_from_camera - BAND_EDGES_M[0]) / 0.25))
    return min(max(k, 0), len(BAND_EDGES_M) - 2)


def marker_set_key(roles: Sequence[str]) -> str:
    """ "m1m2m3", "m2", ... for the roles seen (the regression's marker-set names)."""
    return "".join(f"m{ROLE_NUMBER[r]}" for r in ROLES if r in roles)


def _as_vector(pose: DockPose) -> NDArray[np.float64]:
    return np.array([pose.x, pose.y, pose.yaw])


def _difference(a: NDArray[np.float64], b: NDArray[np.float64]) -> NDArray[np.float64]:
    d = np.asarray(a, dtype=np.float64) - np.asarray(b, dtype=np.float64)
    d[..., 2] = (d[..., 2] + math.pi) % (2 * math.pi) - math.pi
    return d


def _psd_floor(cov: NDArray[np.float64], floor_sd: NDArray[np.float64] = _FLOOR_SD) -> NDArray[np.float64]:
    """The nearest symmetric matrix whose eigenvalues are at least the floor (scaled per component)."""
    ss = _FLOOR_OUTER if floor_sd is _FLOOR_SD else np.outer(floor_sd, floor_sd)
    return _floored(np.asarray(cov, dtype=np.float64), ss)


@kernel
def _floored(cov: NDArray[np.float64], ss: NDArray[np.float64]) -> NDArray[np.float64]:  # pragma: no cover
    """``_psd_floor`` in the floor's units ss: c = sym(cov) / ss with its eigenvalues raised to at least 1.

    Compiled: it runs on every frame, and the floor is usually reached (on the fused lateral).
    """
    sym = 0.5 * (cov + cov.T)
    c = sym / ss
    # c − I positive definite (Sylvester: its leading minors are positive): nothing below the floor.
    a, b, d = c[0, 0] - 1.0, c[0, 1], c[0, 2]
    e, f, i = c[1, 1] - 1.0, c[1, 2], c[2, 2] - 1.0
    if a > 0 and a * e - b * b > 0 and a * (e * i - f * f) - b * (b * i - f * d) + d * (b * f - e * d) > 0:
        return sym
    w, v = np.linalg.eigh(c)
    out: NDArray[np.float64] = ((v * np.maximum(w, 1.0)) @ v.T) * ss
    return out


def fuse_gaussians(
    means: Sequence[NDArray[np.float64]], covariances: Sequence[NDArray[np.float64]]
) -> tuple[NDArray[np.float64], NDArray[np.float64]]:
    """Inverse-variance (information-form) combination of independent Gaussian estimates of (x, y, yaw).

    Yaws are combined as offsets from the first estimate, so that +179 and -179 degrees average to 180.
    """
    ref = means[0]
    info = np.zeros((3, 3))
    vec = np.zeros(3)
    for m, c in zip(means, covariances, strict=True):
        w = np.linalg.inv(c)
        info += w
        vec += w @ _difference(m, ref)
    cov = np.linalg.inv(info)
    mean = ref + cov @ vec
    mean[2] = wrap_angle(float(mean[2]))
    return mean, 0.5 * (cov + cov.T)


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
    return _psd_floor(c[:3, :3] - cross), _psd_floor(c[3:, 3:] - cross), _psd_floor(cross)


# A calibration residual smaller than these is left alone: the LiDAR labels themselves carry biases of a few
# hundredths of a degree and a millimetre or two (bench/label_accuracy.py), which a correction would import into
# a geometry far more accurate than they are. Real miscalibrations (a 1 degree mount, a 3 % focal length, a 5 %
# marker size) are many times larger.
MIN_YAW_OFFSET = math.radians(0.1)
MIN_SCALE_ERROR = 0.002
MIN_OFFSET_M = 0.002


@dataclass(frozen=True)
class Correction:
    """The geometry's calibration residual, learned from the LiDAR labels (identity when calibrated).

    A physical model about the camera's position (pivot_x, pivot_y) in base_link: a camera mount off in yaw
    turns everything the camera sees about the camera, and a marker size or focal length that is off scales the
    distance along the view:

        (x, y) <- pivot + R(yaw_offset) (x - pivot, y - pivot);  yaw <- yaw + yaw_offset
        x <- pivot_x + x_scale (x - pivot_x) + x_offset

    Only what a 2D LiDAR measures without the camera is learned: depth and the face's angle. Its lateral
    reference (where the face line crosses marker 2's centre ray) goes through the camera and would only echo
    the camera's own error back.
    """

    x_scale: float = 1.0
    x_offset: float = 0.0
    yaw_offset: float = 0.0
    pivot_x: float = 0.0
    pivot_y: float = 0.0

    @property
    def identity(self) -> bool:
        return self.x_scale == 1.0 and self.x_offset == 0.0 and self.yaw_offset == 0.0

    def apply(self, v: NDArray[np.float64]) -> NDArray[np.float64]:
        """Corrected (x, y, yaw) rows (or one row)."""
        v = np.asarray(v, dtype=np.float64)
        if self.identity:
            return v.copy()
        c, s = math.cos(self.yaw_offset), math.sin(self.yaw_offset)
        out = np.array(v, dtype=np.float64, copy=True)
        dx, dy = v[..., 0] - self.pivot_x, v[..., 1] - self.pivot_y
        out[..., 0] = self.pivot_x + self.x_scale * (c * dx - s * dy) + self.x_offset
        out[..., 1] = self.pivot_y + s * dx + c * dy
        out[..., 2] = (v[..., 2] + self.yaw_offset + math.pi) % (2 * math.pi) - math.pi
        return out

    def jacobian(self) -> NDArray[np.float64]:
        """d(corrected)/d(estimate), to carry a covariance through the correction."""
        c, s = math.cos(self.yaw_offset), math.sin(self.yaw_offset)
        return np.array([[self.x_scale * c, -self.x_scale * s, 0.0], [s, c, 0.0], [0.0, 0.0, 1.0]])

    @classmethod
    def fit(
        cls, geometry: NDArray[np.float64], labels: NDArray[np.float64], pivot: tuple[float, float] = (0.0, 0.0)
    ) -> Correction:
        """The yaw offset (median), then the depth scale and offset (least squares), three times over, each time
        leaving out rows beyond 4 robust sigmas; a term that is not both significant (3 standard errors) and
        above the labels' own bias (MIN_*) stays at the identity. Fewer than 20 rows: the identity."""
        ok = np.all(np.isfinite(geometry), axis=1) & np.all(np.isfinite(labels), axis=1)
        g, lab = geometry[ok], labels[ok]
        c = cls(pivot_x=pivot[0], pivot_y=pivot[1])
        if len(g) < 20:
            return c
        keep = np.ones(len(g), dtype=bool)
        for _ in range(3):
            n = int(keep.sum())
            dyaw = _difference(lab[keep], g[keep])[:, 2]
            yaw_off = float(np.median(dyaw))
            se_yaw = 1.253 * float(np.std(dyaw)) / math.sqrt(n)
            if abs(yaw_off) < max(3 * se_yaw, MIN_YAW_OFFSET):
                yaw_off = 0.0
            turned = cls(yaw_offset=yaw_off, pivot_x=pivot[0], pivot_y=pivot[1]).apply(g[keep])
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
            c = cls(1.0 + scale_err, offset, yaw_off, *pivot)
            r = _difference(lab, c.apply(g))
            mad = np.median(np.abs(r - np.median(r, axis=0)), axis=0) * 1.4826 + 1e-12
            keep = (np.abs(r[:, 0]) <= 4 * mad[0]) & (np.abs(r[:, 2]) <= 4 * mad[2])
        return c


@dataclass(frozen=True)
class FusionTables:
    """What the fused estimator learned at training time (kept in the bundle, ``metadata.fusion``).

    Attributes:
        corner_sigma: refined-corner noise model, sigma_px = corner_sigma / sqrt(marker side in px).
        correction: the geometry's calibration residual.
        geometry_scale: per marker set, per band: how much larger the geometry's error is than its
            Jacobian covariance says (>= 1).
        regression_cov: per marker set, per band: the regression's 3x3 error covariance (x m, y m, yaw rad).
        label_cov: per band: the LiDAR labels' own error covariance, as the hat measured it.
        rows: rows the tables were learned from, per marker set.
        mount_pitch_offset, mount_z_offset, mount_roll_offset: what the training images say the camera mount's
            pitch (rad), height (m) and roll (rad) are off by (0 when within what they can tell).
    """

    corner_sigma: float
    correction: Correction = field(default_factory=Correction)
    geometry_scale: Mapping[str, Sequence[float]] = field(default_factory=dict)
    regression_cov: Mapping[str, Sequence[NDArray[np.float64] | None]] = field(default_factory=dict)
    label_cov: Sequence[NDArray[np.float64] | None] = ()
    rows: Mapping[str, int] = field(default_factory=dict)
    mount_pitch_offset: float = 0.0
    mount_z_offset: float = 0.0
    mount_roll_offset: float = 0.0

    def geometry_robot(self, robot: RobotConfig) -> RobotConfig:
        """The mounts the geometry fits with: the camera's pitch, height and roll as the training images saw them."""
        if self.mount_pitch_offset == 0.0 and self.mount_z_offset == 0.0 and self.mount_roll_offset == 0.0:
            return robot
        m = robot.camera_mount
        mount = replace(
            m,
            pitch=m.pitch + self.mount_pitch_offset,
            z=m.z + self.mount_z_offset,
            roll=m.roll + self.mount_roll_offset,
        )
        return replace(robot, camera_mount=mount)

    def regression_covariance(self, set_key: str, band: int) -> NDArray[np.float64] | None:
        """The regression's covariance for a marker set and band (the nearest band that has one)."""
        bands = self.regression_cov.get(set_key)
        if not bands:
            return None
        order = sorted(range(len(bands)), key=lambda k: abs(k - band))
        for k in order:
            c = bands[k]
            if c is not None:
                return c
        return None

    def geometry_factor(self, set_key: str, band: int) -> float:
        scales = self.geometry_scale.get(set_key)
        if not scales:
            scales = self.geometry_scale.get("m2") or [1.0]
        return float(scales[min(band, len(scales) - 1)])

    def to_dict(self) -> dict[str, Any]:
        def mat(c: NDArray[np.float64] | None) -> list[list[float]] | None:
            return None if c is None else [[float(v) for v in row] for row in c]

        return {
            "schema": FUSION_SCHEMA,
            "bands_m": list(BAND_EDGES_M),
            "corner_sigma": self.corner_sigma,
            "correction": dict(self.correction.__dict__),
            "geometry_scale": {k: [float(v) for v in s] for k, s in self.geometry_scale.items()},
            "regression_cov": {k: [mat(c) for c in s] for k, s in self.regression_cov.items()},
            "label_cov": [mat(c) for c in self.label_cov],
            "rows": dict(self.rows),
            "mount_pitch_offset": self.mount_pitch_offset,
            "mount_z_offset": self.mount_z_offset,
            "mount_roll_offset": self.mount_roll_offset,
        }

    @classmethod
    def from_dict(cls, d: Any, where: str) -> FusionTables:
        """Parse and check; one-line InputError on anything malformed."""
        try:
            if not isinstance(d, dict) or d.get("schema") != FUSION_SCHEMA:
                found = d.get("schema") if isinstance(d, dict) else type(d).__name__
                raise InputError(f"{where}: fusion tables of schema {found}; this monodock reads {FUSION_SCHEMA}")
            if list(d["bands_m"]) != list(BAND_EDGES_M):
                raise InputError(f"{where}: fusion tables use other depth bands")

            def mat(c: Any) -> NDArray[np.float64] | None:
                if c is None:
                    return None
                a = np.asarray(c, dtype=np.float64)
                if a.shape != (3, 3) or not np.all(np.isfinite(a)):
                    raise ValueError("a covariance is not a finite 3x3 matrix")
                # Every frame inverts it: a singular or indefinite one must fail here, not on the robot.
                if not np.allclose(a, a.T, rtol=1e-9, atol=0.0) or np.any(np.linalg.eigvalsh(a) <= 0.0):
                    raise ValueError("a covariance is not symmetric positive definite")
                return a

            nb = len(BAND_EDGES_M) - 1
            reg = {str(k): [mat(c) for c in s] for k, s in d["regression_cov"].items()}
            geo = {str(k): [float(v) for v in s] for k, s in d["geometry_scale"].items()}
            if any(len(s) != nb for s in reg.values()) or any(len(s) != nb for s in geo.values()):
                raise ValueError(f"every marker set needs {nb} bands")
            sigma = float(d["corner_sigma"])
            if not (sigma > 0 and math.isfinite(sigma)):
                raise ValueError("corner_sigma must be positive")
            return cls(
                corner_sigma=sigma,
                correction=Correction(**{k: float(v) for k, v in d["correction"].items()}),
                geometry_scale=geo,
                regression_cov=reg,
                label_cov=[mat(c) for c in d["label_cov"]],
                rows={str(k): int(v) for k, v in d["rows"].items()},
                mount_pitch_offset=float(d["mount_pitch_offset"]),
                mount_z_offset=float(d["mount_z_offset"]),
                mount_roll_offset=float(d.get("mount_roll_offset", 0.0)),  # added within schema 3: absent is 0
            )
        except InputError:
            raise
        except (KeyError, TypeError, ValueError) as exc:
            raise InputError(f"{where}: malformed fusion tables ({exc})") from None


def side_lengths(corners: Mapping[str, NDArray[np.float64]]) -> NDArray[np.float64]:
    """Each marker's mean side in pixels, for the roles in ``corners`` in ROLES order."""
    out = []
    for role in ROLES:
        if role in corners:
            (x0, y0), (x1, y1), (x2, y2), (x3, y3) = np.asarray(corners[role], dtype=np.float64).tolist()
            sides = math.hypot(x1 - x0, y1 - y0) + math.hypot(x2 - x1, y2 - y1) + math.hypot(x3 - x2, y3 - y2)
            out.append(0.25 * (sides + math.hypot(x0 - x3, y0 - y3)))
    return np.array(out, dtype=np.float64)


def corner_sigmas(
    corners: Mapping[str, NDArray[np.float64]], corner_sigma: float, sides: NDArray[np.float64] | None = None
) -> NDArray[np.float64]:
    """Per-corner noise sd (px) for the roles in ``corners`` (in ROLES order): c / sqrt(mean side px).

    ``sides``: the markers' ``side_lengths``, when the caller has them already.
    """
    side = side_lengths(corners) if sides is None else sides
    return np.repeat(corner_sigma / np.sqrt(np.maximum(side, 4.0)), 4)


# --- learning the tables --------------------------------------------------------------------------------------

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
    correction = Correction.fit(rows.geometry[geo_ok], rows.labels[geo_ok], pivot)
    geometry = correction.apply(rows.geometry)
    cj = correction.jacobian()
    gcov = np.einsum("ij,njk,lk->nil", cj, rows.geometry_cov, cj)
    r_geo = _difference(geometry, rows.labels)
    r_reg = _difference(rows.regression, rows.labels)
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


# --- run time -------------------------------------------------------------------------------------------------

# The regression runs on a frame only if it could make some component of the fused answer's standard deviation
# at least ~1 % smaller: sqrt(1 + gain) with gain = tr(R⁻¹G) >= λmax(G R⁻¹), R and G the regression's and the
# geometry's covariances (information adds: the fused variance along any direction is G / (1 + λ) at best).
REGRESSION_GAIN = 0.25


def _gain(g_cov: NDArray[np.float64], reg_cov: NDArray[np.float64]) -> float:
    """tr(R⁻¹ G): a bound on how much of the geometry's variance the regression could take away."""
    return _trace_solve(reg_cov, g_cov)


@kernel
def _trace_solve(a: NDArray[np.float64], b: NDArray[np.float64]) -> float:  # pragma: no cover - compiled
    """tr(a⁻¹ b)."""
    return float(np.trace(np.linalg.solve(a, b)))


# An unrefined marker keeps OpenCV's corners: inset by ~0.2-0.4 px, so they count as this much noisier.
UNREFINED_SIGMA_FACTOR = 3.0


@dataclass(frozen=True)
class GeometryAnswer:
    """The chosen planar fit, before the calibration correction: pose row, Jacobian covariance and fit quality."""

    pose: NDArray[np.float64]
    covariance: NDArray[np.float64]
    roles: tuple[str, ...]
    rms_px: float
    noise_scale: float
    side_px: float
    candidates: int
    pitch_offset: float = 0.0
    roll_offset: float = 0.0


class FusedEstimator:
    """The ``fused`` method: see the module docstring.

    Args:
        camera, layout, robot: the calibration (the same every method gets).
        tables: what training learned (``FusionTables``).
        regression: the papers' regression (``RegressionEstimator``), or None for geometry alone.
    """

    method = "fused"

    def __init__(
        self,
        camera: CameraModel,
        layout: DockLayout,
        robot: RobotConfig,
        tables: FusionTables,
        regression: Any | None = None,
    ) -> None:
        self.camera, self.layout, self.robot = camera, layout, robot
        self.tables = tables
        self.regression = regression
        self.geometry_robot = tables.geometry_robot(robot)

    def estimate(
        self, detection: Detection, refined: Detection | None = None, reg: PoseEstimate | None = None
    ) -> PoseEstimate:
        """The fused DockPose of a frame from its OpenCV detection and its refined corners.

        With two or more markers the planar fit starts from the board's IPPE solution (``_board_fit``), and
        the regression is used only where it can improve that answer (``_regression_helps``); ``reg`` is its
        answer when the caller has it already (the result is the same either way), else it runs when needed.
        The board fit is reused by the combination, not done again.
        """
        fit = self._board_fit(detection, refined)
        if fit is not None:
            g, g_cov = self._corrected(_as_vector(fit.pose), fit.covariance, fit.roles)
            if not self._regression_helps(fit.roles, g, g_cov):
                return self._answer(g, g_cov, fit.roles, fit.rms_px)
        if reg is None and self.regression is not None:
            reg = self.regression.estimate(detection)
        return self.combine(detection, refined, reg, fit)

    def geometry(
        self,
        detection: Detection,
        refined: Detection | None,
        prior: DockPose | None = None,
        prior_cov: NDArray[np.float64] | None = None,
        *,
        pitch_sd: float | None = None,
        roll_sd: float | None = None,
        fit: PlanarFit | None = None,
    ) -> GeometryAnswer | None:
        """The planar fit to the refined corners (OpenCV's where a marker could not be refined).

        ``pitch_sd`` or ``roll_sd`` also fit a camera pitch or roll offset (``planar.solve_planar``).
        ``fit``: a clean fit of two or more markers already made (``_board_fit``), which stands for the one
        from the prior.

        With ``prior`` (the regression's pose) a fit starts there; every IPPE start joins it when fewer than two
        markers are seen or that fit is poor, and the minimum with the lowest cost plus distance from the prior
        (in the prior's covariance) wins.
        """
        from monodock.estimation.planar import planar_candidates, solve_planar

        roles, corners, sig, sides = self._corners(detection, refined)
        if not roles:
            return None
        fits = [fit] if fit is not None else []
        if prior is not None and not fits:
            fit = solve_planar(
                corners,
                self.camera,
                self.layout,
                self.geometry_robot,
                start=prior,
                corner_sigma=sig,
                pitch_sd=pitch_sd,
                roll_sd=roll_sd,
            )
            if fit.converged and math.isfinite(fit.cost):
                fits.append(fit)
        good = bool(fits) and len(roles) >= 2 and fits[0].noise_scale < 3.0
        if not good:
            starts = (prior,) if prior is not None else ()
            fits += planar_candidates(
                corners,
                self.camera,
                self.layout,
                self.geometry_robot,
                corner_sigma=sig,
                starts=starts,
                pitch_sd=pitch_sd,
                roll_sd=roll_sd,
            )
        if not fits:
            return None

        def score(f: Any) -> float:
            s = float(f.cost)
            if prior is not None and prior_cov is not None:
                d = _difference(_as_vector(f.pose), _as_vector(prior))
                s += float(d @ np.linalg.solve(prior_cov + f.covariance, d))
            return s

        best = min(fits, key=score)
        return GeometryAnswer(
            _as_vector(best.pose),
            best.covariance,
            best.roles,
            best.rms_px,
            best.noise_scale,
            float(sides.mean()),
            len(fits),
            best.pitch_offset,
            best.roll_offset,
        )

    def _corners(
        self, detection: Detection, refined: Detection | None
    ) -> tuple[tuple[str, ...], dict[str, NDArray[np.float64]], NDArray[np.float64], NDArray[np.float64]]:
        """The roles the geometry fits, their corners (refined where they could be), per-corner sigmas and
        each marker's mean side (px)."""
        source = refined if refined is not None else detection
        roles = source.roles_seen
        corners = {r: source.observations[r].corners for r in roles}
        sides = side_lengths(corners)
        sig = corner_sigmas(corners, self.tables.corner_sigma, sides)
        unrefined = set(getattr(source, "unrefined", ())) if refined is not None else set(roles)
        for i, r in enumerate(roles):
            if r in unrefined:
                sig[4 * i : 4 * i + 4] *= UNREFINED_SIGMA_FACTOR
        return roles, corners, sig, sides

    def _board_fit(self, detection: Detection, refined: Detection | None) -> PlanarFit | None:
        """The planar fit of two or more markers from the board's IPPE solution, if it is clean (converged, its
        residuals within 3x the corner noise); None for a lone marker (its yaw sign needs the regression)."""
        from monodock.estimation.planar import board_fit

        roles, corners, sig, _ = self._corners(detection, refined)
        if len(roles) < 2:
            return None
        fit = board_fit(corners, self.camera, self.layout, self.geometry_robot, corner_sigma=sig)
        return fit if fit is not None and fit.converged and math.isfinite(fit.cost) and fit.noise_scale < 3.0 else None

    def _regression_helps(self, roles: Sequence[str], g: NDArray[np.float64], g_cov: NDArray[np.float64]) -> bool:
        """Whether the regression's learned covariance for these markers and band could make some component of
        the answer's standard deviation ~10 % smaller (``REGRESSION_GAIN``); not if it would not answer at all
        (marker 2 unseen, no model or table for the markers)."""
        from monodock.perception.features import choose_marker_set

        if "center" not in roles or self.regression is None:
            return False
        reg_set = choose_marker_set(tuple(roles), self.regression.bundle.sets)
        if reg_set is None:
            return False
        reg_cov = self.tables.regression_covariance(reg_set, band_index(g[0] - self.robot.camera_mount.x))
        return reg_cov is not None and _gain(g_cov, reg_cov) >= REGRESSION_GAIN

    def _corrected(
        self, pose: NDArray[np.float64], covariance: NDArray[np.float64], roles: Sequence[str]
    ) -> tuple[NDArray[np.float64], NDArray[np.float64]]:
        """A planar fit with the learned calibration correction, and its covariance scaled as training found."""
        g = self.tables.correction.apply(pose)
        cj = self.tables.correction.jacobian()
        band = band_index(g[0] - self.robot.camera_mount.x)
        return g, _psd_floor(cj @ covariance @ cj.T * self.tables.geometry_factor(marker_set_key(roles), band))

    def combine(
        self, detection: Detection, refined: Detection | None, reg: PoseEstimate | None, fit: PlanarFit | None = None
    ) -> PoseEstimate:
        """Geometry and regression (either may be missing) into one estimate with its covariance; ``fit`` as in
        ``geometry``."""
        reg_vec = _as_vector(reg.pose) if reg is not None and reg.pose is not None else None
        reg_cov = None
        if reg_vec is not None and reg is not None:
            reg_cov = self.tables.regression_covariance(
                marker_set_key(reg.markers_seen), band_index(reg_vec[0] - self.robot.camera_mount.x)
            )
        geo = self.geometry(detection, refined, reg.pose if reg is not None else None, reg_cov, fit=fit)
        if geo is None:
            if reg_vec is None or reg_cov is None:
                why = reg.reason if reg is not None and reg.reason else "no dock marker seen"
                return PoseEstimate(self.method, None, why, detection.roles_seen)
            return self._answer(reg_vec, reg_cov, reg.markers_seen if reg else (), math.nan)
        g, g_cov = self._corrected(geo.pose, geo.covariance, geo.roles)
        if reg_vec is None or reg_cov is None:
            return self._answer(g, g_cov, geo.roles, geo.rms_px)
        d = _difference(g, reg_vec)
        if float(d @ np.linalg.solve(g_cov + reg_cov, d)) > DISAGREE_CHI2:
            # They disagree beyond chance: an average would be wrong for both; the pixels win.
            return self._answer(g, g_cov, geo.roles, geo.rms_px)
        mean, cov = fuse_gaussians([g, reg_vec], [g_cov, reg_cov])
        return self._answer(mean, cov, geo.roles, geo.rms_px)

    def _answer(
        self, v: NDArray[np.float64], cov: NDArray[np.float64], roles: Sequence[str], rms: float
    ) -> PoseEstimate:
        return PoseEstimate(
            self.method,
            DockPose(float(v[0]), float(v[1]), wrap_angle(float(v[2]))),
            "",
            tuple(roles),
            rms,
            0.0,
            None,
            cov,
        )


# --- training time: the held-out rows -------------------------------------------------------------------------

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
    dataset: Any,
    regression: Any,
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
    from monodock.perception.features import detection_from_features, refined_detection_from_row

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
            reg[k] = _as_vector(r.pose)
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
    dataset: Any, regression: Any, camera: CameraModel, layout: DockLayout, robot: RobotConfig, rows: NDArray[np.int64]
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
    bundle_path: Any, dataset: Any, holdout: NDArray[np.bool_], *, camera: CameraModel | None = None
) -> FusionTables:
    """Learn the fusion tables on a trained bundle's held-out rows and store them in the bundle.

    ``holdout`` marks the rows the regression never trained on (``fusion_holdout``); ``camera`` overrides
    the dataset's, as it did for the regression's training.
    """
    from monodock.estimation.bundle import update_bundle_metadata
    from monodock.estimation.regression import RegressionEstimator
    from monodock.evaluation.selftrain import load_bundle

    bundle = load_bundle(bundle_path)
    camera = camera or dataset.camera()
    layout, robot = dataset.layout(), dataset.robot()
    regression = RegressionEstimator(bundle, camera, robot)
    tables = learn_fusion_from(dataset, regression, camera, layout, robot, np.flatnonzero(holdout))
    update_bundle_metadata(bundle_path, "fusion", tables.to_dict())
    return tables


def fusion_tables_of(bundle: Any) -> FusionTables:
    """The fusion tables a bundle carries; one-line InputError for a bundle trained without them."""
    meta = bundle.manifest.get("metadata", {})
    if "fusion" not in meta:
        raise InputError(
            f"{bundle.path}: this bundle has no fusion tables (trained before the fused method); retrain it"
        )
    return FusionTables.from_dict(meta["fusion"], str(bundle.path))
