"""The dock designer: which markers a charger face needs so that a robot sees the dock across a start envelope.

The envelope is every robot pose 0.5 m to ``max_distance`` from the face centre (base_link's distance) within
±``max_bearing`` of the dock's axis, the robot facing the face centre (a far approach turns to face the dock
first). At each pose a marker counts as detectable when it is fully in the image and its pixels per code cell
(``design.detection_model``, measured against the simulator) meet the budget; the pose's accuracy is the
Cramér–Rao bound (``estimation.crlb``'s model, ``CornerNoise``'s corners) of the detectable markers.

The search is a small grid, smallest face first: dictionary (DICT_4X4_50, DICT_5X5_100), the papers' three
markers' side and spacing, no far-field marker or one of 14-80 cm above the row and to its left (its centre over
the left marker's outer edge) or beside the row on its left, bottoms level (not symmetric with the others, so its
pose is not mirrored by theirs), and no middle marker or one of 14-22 cm beside the row on its right (nested sizes,
for heavy blur, where the far marker has left the image and the near ones are still too small). The first
candidate that fits the face and meets every constraint is the proposal:

- coverage: at every envelope pose at least one marker is detectable;
- near the dock: the three papers' markers are all detectable on the axis from ``NEAR_ALL_THREE`` (1 m) in to
  ``NEAR_THREE_FROM`` (0.7 m), and the centre marker's blind gap (``core.projection.blind_gap``) is no larger
  than the papers' dock's on the same camera;
- tolerance: the bound's σ of x, y and yaw at the near-field poses (on the axis and ±10° off, ``NEAR_ALL_THREE``
  to ``NEAR_FIELD``) is within the tolerance;
- print: no marker larger than ``MAX_PRINTED`` (A0 paper).

``check_in_sim`` renders the simulator at envelope poses and compares what it detects and how far the fused
estimate is off with the prediction.
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from dataclasses import dataclass

import numpy as np
from numpy.typing import NDArray

from monodock.core import transforms
from monodock.core.camera import CameraModel
from monodock.core.layout import DockLayout, MarkerSpec
from monodock.core.pose import DockPose
from monodock.core.projection import blind_gap
from monodock.core.robot import RobotConfig
from monodock.design.detection_model import DetectionModel, pixels_per_cell
from monodock.errors import ConfigError, InputError
from monodock.estimation.corner_noise import CornerNoise
from monodock.estimation.factory import make_estimator
from monodock.estimation.planar import planar_model
from monodock.sim import Nuisances, Simulator
from monodock.sim.world import ChargerGeometry

__all__ = [
    "DICTIONARIES",
    "Design",
    "Envelope",
    "PoseMap",
    "SimCheck",
    "Tolerance",
    "candidate_layout",
    "check_in_sim",
    "check_poses",
    "design",
    "face_size",
    "facing_pose",
    "predict_map",
]

DICTIONARIES = ("DICT_4X4_50", "DICT_5X5_100")
NEAR_SIZES = (0.08, 0.10, 0.12)
SPACINGS = (0.15, 0.20, 0.25)  # centre to centre, centre marker to each side marker
FAR_SIZES = (0.0, *(round(0.14 + 0.02 * k, 2) for k in range(34)))  # 0: no far marker; 14-80 cm
FAR_PLACES = ("above", "beside")
NEAR_Z = 0.30  # the papers' marker height (centres above the floor)
FAR_ID = 7
# A middle marker, for where the far one has left the image and the near ones are still too small (heavy blur).
MID_SIZES = (0.0, 0.14, 0.18, 0.22)
MID_ID = 8
# Near the dock: all three papers' markers detectable on the axis from NEAR_ALL_THREE in to NEAR_THREE_FROM (base_link
# to face centre; the final manoeuvre's estimates), and the tolerance met from NEAR_ALL_THREE out to NEAR_FIELD.
NEAR_THREE_FROM = 0.7
NEAR_ALL_THREE = 1.0
NEAR_FIELD = 1.5
NEAR_BEARINGS_DEG = (-10.0, 0.0, 10.0)
# The largest marker the kit prints: A0's card box (report.dock_kit's margins).
MAX_PRINTED = 0.80
MIN_DISTANCE = 0.5


@dataclass(frozen=True)
class Envelope:
    """Start poses: ``min_distance``..``max_distance`` (m, base_link from the face centre), bearing within
    ±``max_bearing`` (rad) of the dock's axis, the robot facing the face centre."""

    max_distance: float
    max_bearing: float
    min_distance: float = MIN_DISTANCE

    def __post_init__(self) -> None:
        if not (math.isfinite(self.max_distance) and self.min_distance < self.max_distance <= 20.0):
            raise InputError(
                f"max distance must be between {self.min_distance:g} and 20 m, got {self.max_distance:g} m"
            )
        if not (math.isfinite(self.max_bearing) and 0.0 <= self.max_bearing < math.radians(90.0)):
            raise InputError(f"max bearing must be 0 to under 90 degrees, got {math.degrees(self.max_bearing):g}")

    def grid(self, step_m: float = 0.25, step_deg: float = 5.0) -> tuple[NDArray[np.float64], NDArray[np.float64]]:
        """Distances (m) and bearings (rad) of the map: end points included."""
        nd = max(2, math.ceil((self.max_distance - self.min_distance) / step_m) + 1)
        nb = max(1, 2 * math.ceil(math.degrees(self.max_bearing) / step_deg) + 1)
        return np.linspace(self.min_distance, self.max_distance, nd), np.linspace(
            -self.max_bearing, self.max_bearing, nb
        )


@dataclass(frozen=True)
class Tolerance:
    """The final pose accuracy wanted: σ of x and y (m) and of yaw (rad)."""

    xy: float
    yaw: float

    def __post_init__(self) -> None:
        if not (self.xy > 0 and self.yaw > 0 and math.isfinite(self.xy) and math.isfinite(self.yaw)):
            raise InputError(f"tolerance must be positive, got {self.xy * 100:g} cm and {math.degrees(self.yaw):g} deg")


def facing_pose(distance: float, bearing: float) -> DockPose:
    """The DockPose of a robot whose base_link is ``distance`` from the face centre, ``bearing`` (rad, > 0 to the
    dock's left as the robot sees it) off the dock's axis, facing the face centre."""
    dock_T_base = transforms.planar(-distance * math.cos(bearing), distance * math.sin(bearing), -bearing)
    return DockPose.from_matrix(transforms.invert(dock_T_base))


def candidate_layout(
    dictionary: str,
    near_size: float,
    spacing: float,
    far_size: float,
    far_place: str = "above",
    mid_size: float = 0.0,
) -> DockLayout:
    """The papers' three markers (ids 1, 2, 3; side ``near_size``; side markers ``spacing`` from the centre, at the
    papers' height) and, when ``far_size`` > 0, a far marker (id 7) off to the left, where it is not symmetric
    with the others: ``above`` the row, its centre over the left marker's outer edge, or ``beside`` it, left of the
    left marker, their bottom edges level (lower, so that it stays in view nearer the dock); a quiet zone of both
    markers between them. When ``mid_size`` > 0, a middle marker (``mid``, id 8) right of the right marker, bottoms
    level.

    Raises:
        ConfigError: markers that overlap, or an unknown ``far_place``.
    """
    markers = [
        MarkerSpec("left", 1, spacing, NEAR_Z),
        MarkerSpec("center", 2, 0.0, NEAR_Z),
        MarkerSpec("right", 3, -spacing, NEAR_Z),
    ]
    if far_size > 0:
        modules = DockLayout(dictionary, near_size, tuple(markers)).modules
        gap = (near_size + far_size) / modules
        if far_place == "above":
            y, z = spacing + near_size / 2, NEAR_Z + near_size / 2 + gap + far_size / 2
        elif far_place == "beside":
            y, z = spacing + near_size / 2 + gap + far_size / 2, NEAR_Z + (far_size - near_size) / 2
        else:
            raise ConfigError(f"far_place must be above or beside, got {far_place!r}")
        markers.append(MarkerSpec("far", FAR_ID, round(y, 3), round(z, 3), size=far_size))
    if mid_size > 0:
        modules = DockLayout(dictionary, near_size, tuple(markers[:3])).modules
        y = -(spacing + near_size / 2 + (near_size + mid_size) / modules + mid_size / 2)
        z = NEAR_Z + (mid_size - near_size) / 2
        markers.append(MarkerSpec("mid", MID_ID, round(y, 3), round(z, 3), size=mid_size))
    return DockLayout(dictionary, near_size, tuple(markers))


def face_size(layout: DockLayout) -> tuple[float, float]:
    """The charger face the layout needs: width (m) across every marker and its one-cell white margin, and height
    from the floor to the top of the highest margin."""
    lo, hi, top = math.inf, -math.inf, 0.0
    for m in layout.markers:
        half = layout.side(m.role) / 2 * (1 + 2 / layout.modules)
        lo, hi, top = min(lo, m.y - half), max(hi, m.y + half), max(top, m.z + half)
    return hi - lo, top


@dataclass(frozen=True)
class PoseMap:
    """The prediction over the envelope's grid.

    Attributes:
        distances, bearings: the grid (m, rad).
        roles: the layout's markers.
        px_per_cell: shape (D, B, R): each marker's px/cell (0: not fully in view).
        detectable: shape (D, B, R): budgeted as decoded.
        sigma: shape (D, B, 3): the bound's σ of x (m), y (m), yaw (rad) from the detectable markers; NaN where
            none is.
    """

    distances: NDArray[np.float64]
    bearings: NDArray[np.float64]
    roles: tuple[str, ...]
    px_per_cell: NDArray[np.float64]
    detectable: NDArray[np.bool_]
    sigma: NDArray[np.float64]

    @property
    def covered(self) -> NDArray[np.bool_]:
        """Shape (D, B): at least one marker detectable."""
        return np.asarray(self.detectable.any(axis=2), dtype=bool)

    def detection_range(self, role: str) -> float:
        """The largest grid distance (m) at which the marker is budgeted as decoded at some bearing (0: never)."""
        k = self.roles.index(role)
        rows = np.flatnonzero(self.detectable[:, :, k].any(axis=1))
        return float(self.distances[rows[-1]]) if rows.size else 0.0


def bound_sigma(
    pose: DockPose,
    camera: CameraModel,
    layout: DockLayout,
    robot: RobotConfig,
    roles: Sequence[str],
    noise: CornerNoise | None = None,
) -> NDArray[np.float64]:
    """The Cramér–Rao σ (x m, y m, yaw rad) from these markers' corners, each with ``CornerNoise``'s σ at its
    pixel size (as ``evaluation.what_if``); NaN without markers, inf where unobservable."""
    if not roles:
        return np.full(3, np.nan)
    px, J = planar_model(camera, layout, robot).jacobian(pose, tuple(roles))
    Jw = J / np.repeat((noise or CornerNoise()).sigma(px), 2)[:, None]
    try:
        cov = np.linalg.inv(Jw.T @ Jw)
    except np.linalg.LinAlgError:
        return np.full(3, np.inf)
    return np.asarray(np.sqrt(np.clip(np.diag(cov), 0.0, None)), dtype=np.float64)


def predict_map(
    layout: DockLayout,
    camera: CameraModel,
    robot: RobotConfig,
    envelope: Envelope,
    *,
    blur: bool,
    sigma: bool = True,
    step_m: float = 0.25,
    step_deg: float = 5.0,
) -> PoseMap:
    """Which markers are detectable, and the bound's σ (``sigma``), at every pose of the envelope's grid."""
    model = DetectionModel.budget(layout.dictionary, blur=blur)
    ds, bs = envelope.grid(step_m, step_deg)
    roles = layout.roles
    ppc = np.zeros((len(ds), len(bs), len(roles)))
    sig = np.full((len(ds), len(bs), 3), np.nan)
    for i, d in enumerate(ds):
        for j, b in enumerate(bs):
            pose = facing_pose(float(d), float(b))
            ppc[i, j] = pixels_per_cell(pose, camera, layout, robot)
    det = model.detectable(ppc)
    if sigma:
        for i, d in enumerate(ds):
            for j, b in enumerate(bs):
                seen = [r for r, ok in zip(roles, det[i, j], strict=True) if ok]
                if seen:
                    sig[i, j] = bound_sigma(facing_pose(float(d), float(b)), camera, layout, robot, seen)
    return PoseMap(ds, bs, roles, ppc, det, sig)


@dataclass(frozen=True)
class Design:
    """The proposal and what it is predicted to do.

    Attributes:
        layout: the proposed dock layout.
        face: width and height (m) of the charger face it needs.
        blur: whether it budgets for heavy motion blur.
        px_per_cell: the detection budget (px a code cell).
        map: the prediction over the envelope.
        blind_gap: the centre marker's blind gap (m, front edge to face) and the papers' dock's on this camera.
        near_sigma: the worst bound σ (x m, y m, yaw rad) at the near-field poses.
        tried: candidates checked, smallest face first, the proposal the last.
        envelope, tolerance, max_face: the request.
        papers_covered, papers_range: the papers' dock (three 10 cm DICT_4X4_50 markers) by the same model: the
            share of the envelope's grid where a marker is budgeted as decoded, and how far out (m).
    """

    layout: DockLayout
    face: tuple[float, float]
    blur: bool
    px_per_cell: float
    map: PoseMap
    near_sigma: NDArray[np.float64]
    blind_gap: tuple[float, float]
    tried: int
    envelope: Envelope
    tolerance: Tolerance
    max_face: tuple[float, float]
    papers_covered: float = math.nan
    papers_range: float = math.nan


def _near_poses() -> list[DockPose]:
    ds = np.arange(NEAR_ALL_THREE, NEAR_FIELD + 1e-9, 0.25)
    return [facing_pose(float(d), math.radians(b)) for d in ds for b in NEAR_BEARINGS_DEG]


def _near_ok(
    layout: DockLayout, camera: CameraModel, robot: RobotConfig, model: DetectionModel, tolerance: Tolerance
) -> tuple[str | None, NDArray[np.float64]]:
    """Why the near field fails (or None), and the worst bound σ there."""
    three = ("left", "center", "right")
    for d in np.arange(NEAR_THREE_FROM, NEAR_ALL_THREE + 1e-9, 0.1):
        if not model.detectable(pixels_per_cell(facing_pose(float(d), 0.0), camera, layout, robot, three)).all():
            return f"the three near markers are not all detectable on the axis at {d:.1f} m", np.full(3, np.inf)
    worst = np.zeros(3)
    for pose in _near_poses():
        ppc = pixels_per_cell(pose, camera, layout, robot)
        seen = [r for r, ok in zip(layout.roles, model.detectable(ppc), strict=True) if ok]
        if not seen:
            return f"no marker detectable at the near pose {pose}", np.full(3, np.inf)
        worst = np.maximum(worst, bound_sigma(pose, camera, layout, robot, seen))
    if worst[0] > tolerance.xy or worst[1] > tolerance.xy or worst[2] > tolerance.yaw:
        return (
            f"near-field bound σ {worst[0] * 100:.2f} / {worst[1] * 100:.2f} cm, {math.degrees(worst[2]):.2f} deg "
            "exceeds the tolerance"
        ), worst
    return None, worst


def _safe_blind_gap(camera: CameraModel, layout: DockLayout, robot: RobotConfig) -> float:
    try:
        return blind_gap(camera, layout, robot)
    except ConfigError:
        return math.inf


def design(
    camera: CameraModel,
    robot: RobotConfig,
    envelope: Envelope,
    tolerance: Tolerance,
    *,
    max_width: float,
    max_height: float,
    blur: bool = False,
) -> Design:
    """The smallest face (area, then the fewest and smallest markers) that meets every constraint (module doc).

    Raises:
        InputError: no candidate fits the face and meets the constraints (one line saying what fell short).
    """
    if not (0 < max_width <= 10 and 0 < max_height <= 10):
        raise InputError(f"the face must be 0-10 m wide and high, got {max_width:g} x {max_height:g} m")
    papers_gap = _safe_blind_gap(camera, DockLayout.default(), robot)
    cands = []
    for dictionary in DICTIONARIES:
        for near in NEAR_SIZES:
            for spacing in SPACINGS:
                for far in FAR_SIZES:
                    for place in FAR_PLACES if far > 0 else FAR_PLACES[:1]:
                        for mid in MID_SIZES:
                            if spacing < near * (1 + 2 / 6) or far > MAX_PRINTED:
                                continue
                            try:
                                lay = candidate_layout(dictionary, near, spacing, far, place, mid)
                            except ConfigError:
                                continue
                            w, h = face_size(lay)
                            key = (w * h, len(lay.markers), far, mid, near, DICTIONARIES.index(dictionary), spacing)
                            cands.append((key, lay, (w, h)))
    cands.sort(key=lambda c: c[0])
    fits = [c for c in cands if c[2][0] <= max_width + 1e-9 and c[2][1] <= max_height + 1e-9]
    if not fits:
        smallest = cands[0][2]
        raise InputError(
            f"no layout fits a {max_width:g} x {max_height:g} m face: the smallest candidate needs "
            f"{smallest[0]:.2f} x {smallest[1]:.2f} m"
        )
    why: dict[str, tuple[int, str]] = {}  # a constraint -> how many candidates it refused, the largest's reason

    def refuse(kind: str, reason: str) -> None:
        why[kind] = (why.get(kind, (0, ""))[0] + 1, reason)

    for tried, (_, lay, wh) in enumerate(fits, start=1):
        model = DetectionModel.budget(lay.dictionary, blur=blur)
        hard = [(envelope.max_distance, b) for b in (-envelope.max_bearing, 0.0, envelope.max_bearing)]
        if not all(model.detectable(pixels_per_cell(facing_pose(d, b), camera, lay, robot)).any() for d, b in hard):
            refuse(
                "coverage",
                f"no marker detectable at {envelope.max_distance:.1f} m (on the axis or at the bearing's edge)",
            )
            continue
        coverage = predict_map(lay, camera, robot, envelope, blur=blur, sigma=False)
        if not coverage.covered.all():
            i, j = np.argwhere(~coverage.covered)[-1]
            d, b = coverage.distances[i], math.degrees(coverage.bearings[j])
            refuse("coverage", f"no marker detectable at {d:.1f} m, {b:.0f} deg")
            continue
        gap = _safe_blind_gap(camera, lay, robot)
        if gap > papers_gap + 1e-6:
            refuse(
                "blind",
                f"the centre marker's blind gap {gap * 100:.0f} cm exceeds the papers' {papers_gap * 100:.0f} cm",
            )
            continue
        reason, worst = _near_ok(lay, camera, robot, model, tolerance)
        if reason is not None:
            refuse("near", reason)
            continue
        full = predict_map(lay, camera, robot, envelope, blur=blur)
        papers = predict_map(DockLayout.default(), camera, robot, envelope, blur=blur, sigma=False)
        return Design(
            lay,
            wh,
            blur,
            model.px_per_cell,
            full,
            worst,
            (gap, papers_gap),
            tried,
            envelope,
            tolerance,
            (max_width, max_height),
            float(papers.covered.mean()),
            max(papers.detection_range(r) for r in papers.roles),
        )
    summary = "; ".join(f"{n} by {kind} (e.g. {reason})" for kind, (n, reason) in why.items())
    raise InputError(
        f"no layout within a {max_width:g} x {max_height:g} m face meets the constraints: of {len(fits)} that fit, "
        f"{summary}"
    )


@dataclass(frozen=True)
class SimCheck:
    """One rendered envelope pose: the prediction and what the simulator's frame gave.

    Attributes:
        distance, bearing: the pose (m, rad).
        predicted: the markers budgeted as detectable.
        detected: the markers the detector decoded.
        sigma: the bound's σ (x m, y m, yaw rad) from the predicted markers; NaN without any.
        error: the fused estimate minus the truth (x m, y m, yaw rad); NaN without a pose.
        px_per_cell: each marker's px/cell, layout order.
        sigma_detected: the bound's σ from the markers the detector actually decoded (the stricter yardstick
            for the error: the estimate uses them all); NaN without any.
    """

    distance: float
    bearing: float
    predicted: tuple[str, ...]
    detected: tuple[str, ...]
    sigma: tuple[float, float, float]
    error: tuple[float, float, float]
    px_per_cell: tuple[float, ...]
    sigma_detected: tuple[float, float, float] = (math.nan, math.nan, math.nan)

    @property
    def z_scores(self) -> tuple[float, float, float]:
        """|error| / the predicted σ, per axis."""
        x, y, a = (abs(e) / s if s > 0 else math.inf for e, s in zip(self.error, self.sigma, strict=True))
        return x, y, a

    @property
    def z_detected(self) -> tuple[float, float, float]:
        """|error| / the σ of the markers decoded, per axis."""
        x, y, a = (abs(e) / s if s > 0 else math.inf for e, s in zip(self.error, self.sigma_detected, strict=True))
        return x, y, a


def check_in_sim(
    layout: DockLayout,
    camera: CameraModel,
    robot: RobotConfig,
    poses: Sequence[tuple[float, float]],
    *,
    blur: bool,
    face: tuple[float, float] | None = None,
    supersample: int | None = None,
    seed: int = 0,
    method: str = "fused",
) -> list[SimCheck]:
    """Render the simulator (default nuisances, and a 6 px motion blur when ``blur``; ``supersample``: the renderer's
    S x S, default the nuisances') at (distance m, bearing rad) poses on ``layout`` (the charger face ``face`` when
    given), detect and estimate with ``method``."""
    nuisances = Nuisances().updated(**({"motion_blur_px": 6.0} if blur else {}))
    if supersample is not None:
        nuisances = nuisances.updated(supersample=supersample)
    charger = ChargerGeometry(width=max(face[0], 0.60), height=max(face[1], 0.45)) if face else ChargerGeometry()
    sim = Simulator(layout=layout, camera=camera, robot=robot, nuisances=nuisances, charger=charger, seed=seed)
    estimator = make_estimator(method=method, camera=camera, layout=layout, robot=robot)
    model = DetectionModel.budget(layout.dictionary, blur=blur)
    out = []
    for k, (d, b) in enumerate(poses):
        truth = facing_pose(d, b)
        ppc = pixels_per_cell(truth, camera, layout, robot)
        predicted = tuple(r for r, ok in zip(layout.roles, model.detectable(ppc), strict=True) if ok)
        sig = bound_sigma(truth, camera, layout, robot, predicted)
        frame = sim.frame(truth, rng=np.random.default_rng([seed, k]))
        result = estimator.estimate(f"{k}", 0.0, frame.image)
        detected = result.detection.roles_seen if result.detection is not None else ()
        est = result.estimates[method].pose
        err = (
            (est.x - truth.x, est.y - truth.y, math.remainder(est.yaw - truth.yaw, math.tau))
            if est is not None
            else (math.nan, math.nan, math.nan)
        )
        known = tuple(r for r in detected if r in layout.roles)
        sd = bound_sigma(truth, camera, layout, robot, known) if known else np.full(3, np.nan)
        out.append(
            SimCheck(
                d,
                b,
                predicted,
                tuple(detected),
                (float(sig[0]), float(sig[1]), float(sig[2])),
                err,
                tuple(float(v) for v in ppc),
                (float(sd[0]), float(sd[1]), float(sd[2])),
            )
        )
    return out


def check_poses(envelope: Envelope, n: int, seed: int = 0) -> list[tuple[float, float]]:
    """``n`` (distance m, bearing rad) poses to render: the envelope's far corners and far centre, a near one on the
    axis, then uniform draws over distance and bearing (seeded)."""
    d_max, b_max = envelope.max_distance, envelope.max_bearing
    fixed = [(d_max, -b_max), (d_max, 0.0), (d_max, b_max), (min(NEAR_ALL_THREE, d_max), 0.0)]
    rng = np.random.default_rng(seed)
    drawn = [
        (float(rng.uniform(envelope.min_distance, d_max)), float(rng.uniform(-b_max, b_max)))
        for _ in range(max(0, n - len(fixed)))
    ]
    return (fixed + drawn)[:n]
