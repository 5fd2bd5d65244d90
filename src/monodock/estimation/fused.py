"""The fused estimator (``--method fused``): planar PnP on bias-free corners, combined with the regression.

Two estimators with opposite weaknesses see the same frame:

- **geometry**: the maximum-likelihood planar pose (x, y, yaw) of every visible marker's refined corners
  (``perception.refine``, ``estimation.planar``). It is as good as the pixels allow, but only as right as the
  calibration; a lone small marker has two near-equal minima (the sign of yaw).
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
from monodock.estimation.corner_noise import CornerNoise
from monodock.estimation.planar import FIT_ITERATIONS, FIT_TOLERANCE, planar_model, solve_planar
from monodock.estimation.planar_starts import _board_lm, board_fit, board_fit_stacked, planar_candidates
from monodock.estimation.pnp import PoseEstimate
from monodock.perception.detect import Detection
from monodock.perception.features import choose_marker_set, side_lengths

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
    "pose_difference",
    "pose_vector",
    "psd_floor",
]

FUSION_SCHEMA = "monodock.fusion/3"
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


def pose_vector(pose: DockPose) -> NDArray[np.float64]:
    return np.array([pose.x, pose.y, pose.yaw])


def pose_difference(a: NDArray[np.float64], b: NDArray[np.float64]) -> NDArray[np.float64]:
    d = np.asarray(a, dtype=np.float64) - np.asarray(b, dtype=np.float64)
    d[..., 2] = (d[..., 2] + math.pi) % (2 * math.pi) - math.pi
    return d


def psd_floor(cov: NDArray[np.float64], floor_sd: NDArray[np.float64] = _FLOOR_SD) -> NDArray[np.float64]:
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
        vec += w @ pose_difference(m, ref)
    cov = np.linalg.inv(info)
    mean = ref + cov @ vec
    mean[2] = wrap_angle(float(mean[2]))
    return mean, 0.5 * (cov + cov.T)


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


@kernel
def _corner_sigma(
    c: NDArray[np.float64], law: tuple[float, float, float, float], factor: NDArray[np.float64]
) -> NDArray[np.float64] | None:  # pragma: no cover - compiled
    """``CornerNoise.sigma_of_sides`` of markers' corners stacked (4M, 2), compiled, each marker's times its
    ``factor`` (M,); None where a corner is not finite. ``law``: the CornerNoise's (c, floor_px,
    small_side_px, small_sigma_px). The same arithmetic in the same order (tests/estimation/test_fused.py)."""
    cc, floor, small_side, small_sigma = law
    small = 1.0 / small_side if small_side > 0 else np.inf
    m = c.shape[0] // 4
    sides = np.empty(4)
    out = np.empty(4 * m)
    for i in range(m):
        for k in range(4):
            p, q = 4 * i + k, 4 * i + (k + 1) % 4
            if not (np.isfinite(c[p, 0]) and np.isfinite(c[p, 1])):
                return None
            sides[k] = math.hypot(c[q, 0] - c[p, 0], c[q, 1] - c[p, 1])
        for k in range(4):
            before, after = sides[k - 1], sides[k]  # corner k's edges: sides k - 1 and k
            inverse = 0.5 * (1.0 / max(before, 1e-9) + 1.0 / max(after, 1e-9))
            sd = max(cc * math.sqrt(inverse), floor)
            out[4 * i + k] = (max(sd, small_sigma) if inverse > small else sd) * factor[i]
    return out


_QUICK_CLEAN, _QUICK_NOT_CLEAN, _QUICK_UNDECIDED = 0, 1, 2
_NOT_CLEAN = object()
_BANDS = len(BAND_EDGES_M) - 2  # the last band's index


@kernel
def _board_answer(
    corners: Any, factor: Any, law: Any, Z: Any, T: Any, lens: Any, correction: Any, scales: Any
) -> tuple[int, Any, Any, float]:  # pragma: no cover - compiled
    """``FusedEstimator._quick_board``: the corner sigmas (``_corner_sigma``), the board fit
    (``planar_starts.board_fit_stacked``), its clean check, the correction (``Correction.apply``, its Jacobian) and the
    covariance scaled by its band's ``scales`` and floored (``psd_floor``). Returns a status (_QUICK_*), the
    corrected (x, y, yaw), its covariance and the RMS residual (px)."""
    nan3 = np.full(3, np.nan)
    sig = _corner_sigma(corners, law, factor)
    if sig is None:
        return _QUICK_UNDECIDED, nan3, np.full((3, 3), np.nan), np.nan
    rows = np.empty(2 * sig.size)
    for i in range(sig.size):
        rows[2 * i] = rows[2 * i + 1] = 1.0 / sig[i]
    problem = (Z, T, corners, 1, 1.0, rows, np.zeros((0, 2, 2)), lens, False, np.zeros((3, 3)), np.zeros(3))
    started, th, ok, cost, cov, _, scale, rms, _, converged = _board_lm(problem, FIT_ITERATIONS, FIT_TOLERANCE)
    if not (started and ok and converged):
        return _QUICK_UNDECIDED, nan3, np.full((3, 3), np.nan), np.nan
    if not (np.isfinite(cost) and scale < 3.0):
        return _QUICK_NOT_CLEAN, nan3, np.full((3, 3), np.nan), np.nan
    (x_scale, x_offset, yaw_offset, pivot_x, pivot_y, mount_x), identity, cj = correction
    g = np.array([th[0], th[1], (th[2] + math.pi) % (2.0 * math.pi) - math.pi])  # DockPose's wrap_angle
    if not identity:
        c, s = math.cos(yaw_offset), math.sin(yaw_offset)
        dx, dy = g[0] - pivot_x, g[1] - pivot_y
        g[0], g[1] = pivot_x + x_scale * (c * dx - s * dy) + x_offset, pivot_y + s * dx + c * dy
        g[2] = (g[2] + yaw_offset + math.pi) % (2 * math.pi) - math.pi
    band = min(max(int(math.floor((g[0] - mount_x - BAND_EDGES_M[0]) / 0.25)), 0), _BANDS)
    f = scales[min(band, scales.size - 1)]
    scaled = cov * f if identity else cj @ cov @ cj.T * f
    return _QUICK_CLEAN, g, _floored(scaled, _FLOOR_OUTER), rms


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
        self.corner_noise = CornerNoise.edge_fit(tables.corner_sigma)  # the bias-free corners' noise
        self._model = planar_model(camera, layout, self.geometry_robot)
        n = self.corner_noise
        self._noise_law = (float(n.c), float(n.floor_px), float(n.small_side_px), float(n.small_sigma_px))
        c = tables.correction
        cj = c.jacobian()
        self._correction = (
            (c.x_scale, c.x_offset, c.yaw_offset, c.pivot_x, c.pivot_y, float(robot.camera_mount.x)),
            c.identity,
            cj,
        )
        self._fixed: dict[tuple[str, ...], tuple[Any, Any, Any]] = {}

    def estimate(
        self,
        detection: Detection,
        refined: Detection | None = None,
        reg: PoseEstimate | None = None,
        *,
        raw: NDArray[np.float64] | None = None,
    ) -> PoseEstimate:
        """The fused DockPose of a frame from its OpenCV detection and its refined corners.

        With two or more markers the planar fit starts from the board's IPPE solution (``_board_fit``), and
        the regression is used only where it can improve that answer (``_regression_helps``); ``reg`` is its
        answer when the caller has it already (the result is the same either way), else it runs when needed, on
        ``raw`` (the raw features as a dataset stores them) when given, else on the detection.
        The board fit is reused by the combination, not done again.
        """
        quick = self._quick_board(detection, refined)
        if isinstance(quick, tuple):
            g, g_cov, roles, rms = quick
            if not self._regression_helps(roles, g, g_cov):
                return self._answer(g, g_cov, roles, rms)
        fit = self._board_fit(detection, refined) if quick is not _NOT_CLEAN else None
        if fit is not None:
            g, g_cov = self._corrected(pose_vector(fit.pose), fit.covariance, fit.roles)
            if not self._regression_helps(fit.roles, g, g_cov):
                return self._answer(g, g_cov, fit.roles, fit.rms_px)
        if reg is None and self.regression is not None:
            reg = (
                self.regression.estimate(detection)
                if raw is None
                else self.regression.estimate_raw(raw, detection.roles_seen)
            )
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
                d = pose_difference(pose_vector(f.pose), pose_vector(prior))
                s += float(d @ np.linalg.solve(prior_cov + f.covariance, d))
            return s

        best = min(fits, key=score)
        return GeometryAnswer(
            pose_vector(best.pose),
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
        if not roles:
            return roles, corners, np.zeros(0), np.zeros(0)
        marker_sides = [side_lengths(corners[r]) for r in roles]
        sides = np.array([0.25 * sum(s) for s in marker_sides])
        sig = self.corner_noise.sigma_of_sides(marker_sides)
        unrefined = set(getattr(source, "unrefined", ())) if refined is not None else set(roles)
        for i, r in enumerate(roles):
            if r in unrefined:
                sig[4 * i : 4 * i + 4] *= UNREFINED_SIGMA_FACTOR
        return roles, corners, sig, sides

    def _quick_board(self, detection: Detection, refined: Detection | None) -> Any:
        """``_board_fit`` and ``_corrected`` of two or more markers in one compiled call (``_board_answer``): the
        corrected pose and covariance, the roles and the RMS; ``_NOT_CLEAN`` where that fit is not clean; None
        where this cannot tell (fewer than two markers, corners not finite, the floor start failed): then
        ``_board_fit`` decides. The same arithmetic as those two, in the same order: every frame with two or more
        markers ends here, where a dozen Python calls after the detection cost as much as the fit."""
        stack = _stacked_corners(detection, refined)
        if stack is None:
            return None
        roles, stacked, factor = stack
        if stacked.shape != (4 * len(roles), 2):
            return None
        fixed = self._fixed.get(roles)
        if fixed is None:
            parts = self._model.parts(roles)
            key = marker_set_key(roles)
            scales = np.array([self.tables.geometry_factor(key, b) for b in range(len(BAND_EDGES_M) - 1)])
            fixed = self._fixed[roles] = (parts.Z, parts.T, scales)
        status, g, g_cov, rms = _board_answer(
            stacked, factor, self._noise_law, fixed[0], fixed[1], self._model.lens, self._correction, fixed[2]
        )
        if status == _QUICK_CLEAN:
            return g, g_cov, roles, rms
        return _NOT_CLEAN if status == _QUICK_NOT_CLEAN else None

    def _board_fit(self, detection: Detection, refined: Detection | None) -> PlanarFit | None:
        """The planar fit of two or more markers (``planar_starts.board_fit``), if it is clean (converged, its residuals
        within 3x the corner noise); None for a lone marker (its yaw sign needs the regression).

        Every frame with two or more markers ends here: the corners are stacked once, their sides measured in
        one compiled call, and the fit gets them as arrays (``planar_starts.board_fit_stacked``).
        """
        stack = _stacked_corners(detection, refined)
        if stack is None:
            return None
        roles, stacked, factor = stack
        sig = _corner_sigma(stacked, self._noise_law, factor) if stacked.shape == (4 * len(roles), 2) else None
        if sig is None:  # not four finite corners each: the checked path says what is wrong
            _, corners, sig, _ = self._corners(detection, refined)
            fit = board_fit(corners, self.camera, self.layout, self.geometry_robot, corner_sigma=sig)
        else:
            fit = board_fit_stacked(self._model, roles, stacked, sig)
        return fit if fit is not None and fit.converged and math.isfinite(fit.cost) and fit.noise_scale < 3.0 else None

    def _regression_helps(self, roles: Sequence[str], g: NDArray[np.float64], g_cov: NDArray[np.float64]) -> bool:
        """Whether the regression's learned covariance for these markers and band could make some component of
        the answer's standard deviation ~10 % smaller (``REGRESSION_GAIN``); not if it would not answer at all
        (marker 2 unseen, no model or table for the markers)."""

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
        correction = self.tables.correction
        g = correction.apply(pose)
        band = band_index(g[0] - self.robot.camera_mount.x)
        factor = self.tables.geometry_factor(marker_set_key(roles), band)
        if correction.identity:  # its Jacobian is the identity
            return g, psd_floor(covariance * factor)
        cj = correction.jacobian()
        return g, psd_floor(cj @ covariance @ cj.T * factor)

    def combine(
        self, detection: Detection, refined: Detection | None, reg: PoseEstimate | None, fit: PlanarFit | None = None
    ) -> PoseEstimate:
        """Geometry and regression (either may be missing) into one estimate with its covariance; ``fit`` as in
        ``geometry``."""
        reg_vec = pose_vector(reg.pose) if reg is not None and reg.pose is not None else None
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
        d = pose_difference(g, reg_vec)
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


def _stacked_corners(
    detection: Detection, refined: Detection | None
) -> tuple[tuple[str, ...], NDArray[np.float64], NDArray[np.float64]] | None:
    """The seen roles, their corners stacked in that order and each marker's corner-sigma factor (unrefined
    corners count ``UNREFINED_SIGMA_FACTOR`` times the law's noise); None for fewer than two markers."""
    source = refined if refined is not None else detection
    roles = source.roles_seen
    if len(roles) < 2:
        return None
    obs = source.observations
    stacked = np.concatenate([obs[r].corners for r in roles], dtype=np.float64)
    unrefined = source.unrefined if refined is not None else roles
    factor = np.array([UNREFINED_SIGMA_FACTOR if r in unrefined else 1.0 for r in roles])
    return roles, stacked, factor
