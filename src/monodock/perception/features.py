"""The papers' marker features (Fig. 4, 9): side lengths, corners and centres, as named columns.

Markers are numbered as in the papers: m1 left, m2 centre (the docking point), m3 right. Corners follow
ArUco order: tl, tr, br, bl. A marker not seen has NaN features and ``m{i}_seen`` = 0.

Two layers: the *raw* features (``FEATURE_NAMES``, pixels, what the dataset stores and the papers list) and the
*model inputs* of each marker set (``model_features``): the same geometry through the lens, in normalised image
coordinates, with the inverse sizes, side ratios and centre separations that make depth and yaw nearly linear.
"""

from __future__ import annotations

import functools
import math
from dataclasses import dataclass

import numpy as np
from numpy.typing import ArrayLike, NDArray

from monodock.core.camera import CameraModel
from monodock.core.layout import ROLE_NUMBER, ROLES, DockLayout
from monodock.perception.detect import Detection, MarkerObservation

__all__ = [
    "DEFAULT_MARKER_SETS",
    "FEATURE_NAMES",
    "MARKER_SETS",
    "MODEL_FEATURE_SCHEMA",
    "REFINED_CORNER_NAMES",
    "MarkerFeatures",
    "choose_marker_set",
    "detection_from_features",
    "feature_vector",
    "lens_centre",
    "marker_features",
    "model_feature_names",
    "model_features",
    "refined_detection_from_row",
    "refined_vector",
    "side_lengths",
]

CORNER_NAMES = ("tl", "tr", "br", "bl")
SIDE_NAMES = ("top", "bottom", "left", "right")


@dataclass(frozen=True)
class MarkerFeatures:
    """One marker's geometry in pixels: side lengths, corners (4, 2) and centre (2,)."""

    top: float
    bottom: float
    left: float
    right: float
    corners: NDArray[np.float64]
    centre: NDArray[np.float64]


def _centre(c: NDArray[np.float64]) -> NDArray[np.float64]:
    """Intersection of the diagonals: the image of the marker's centre under perspective (mean is not)."""
    p, r = c[0], c[2] - c[0]
    q, s = c[1], c[3] - c[1]
    denom = r[0] * s[1] - r[1] * s[0]
    if abs(denom) < 1e-12:
        return np.asarray(c.mean(axis=0), dtype=np.float64)
    t = ((q - p)[0] * s[1] - (q - p)[1] * s[0]) / denom
    return np.asarray(p + t * r, dtype=np.float64)


def side_lengths(corners: ArrayLike) -> tuple[float, float, float, float]:
    """A marker's four sides in pixels, in ArUco order: top (TL-TR), right (TR-BR), bottom (BR-BL), left (BL-TL).

    The one place a side length is measured: the papers' features, the fused method's corner noise and the
    Cramér–Rao bound's all read it here. Plain floats: it runs per marker on every frame.
    """
    (x0, y0), (x1, y1), (x2, y2), (x3, y3) = np.asarray(corners, dtype=np.float64).reshape(4, 2).tolist()
    return (
        math.hypot(x1 - x0, y1 - y0),
        math.hypot(x2 - x1, y2 - y1),
        math.hypot(x3 - x2, y3 - y2),
        math.hypot(x0 - x3, y0 - y3),
    )


def marker_features(corners: NDArray[np.float64]) -> MarkerFeatures:
    """Side lengths (top TL-TR, bottom BR-BL, left BL-TL, right TR-BR), corners and centre of a marker."""
    c = np.asarray(corners, dtype=np.float64).reshape(4, 2)
    top, right, bottom, left = side_lengths(c)
    return MarkerFeatures(top, bottom, left, right, c, _centre(c))


def _names() -> tuple[str, ...]:
    names: list[str] = []
    for role in ROLES:
        m = f"m{ROLE_NUMBER[role]}"
        names.append(f"{m}_seen")
        names += [f"{m}_{s}" for s in SIDE_NAMES]
        names += [f"{m}_{c}_{a}" for c in CORNER_NAMES for a in ("u", "v")]
        names += [f"{m}_centre_u", f"{m}_centre_v"]
    names += ["m2_offset_u", "m2_offset_v"]
    return tuple(names)


FEATURE_NAMES: tuple[str, ...] = _names()


def lens_centre(corners: NDArray[np.float64], camera: CameraModel) -> NDArray[np.float64]:
    """The pixel of a marker's centre through the lens: diagonals intersected in undistorted coordinates.

    Lens distortion bends the diagonals, so intersecting them in raw pixels is off by a few tenths of a
    pixel away from the image centre; undistorting first makes it exact for exact corners.
    """
    n = camera.normalize(corners)
    c = _centre(n)
    return np.asarray(camera.project(np.array([[c[0], c[1], 1.0]]))[0], dtype=np.float64)


def feature_vector(detection: Detection, camera: CameraModel) -> NDArray[np.float64]:
    """Features of one image in the order of FEATURE_NAMES.

    ``m2_offset_u`` is the papers' P: marker 2's centre (through the lens, see lens_centre) minus the
    principal point, pixels (+ right); ``m2_offset_v`` the same downwards.
    """
    out = np.full(len(FEATURE_NAMES), np.nan)
    i = 0
    for role in ROLES:
        obs = detection.observations.get(role)
        out[i] = 1.0 if obs is not None else 0.0
        if obs is not None:
            f = marker_features(obs.corners)
            out[i + 1 : i + 5] = (f.top, f.bottom, f.left, f.right)
            out[i + 5 : i + 13] = f.corners.ravel()
            out[i + 13 : i + 15] = f.centre
        i += 15
    centre = detection.observations.get("center")
    if centre is not None:
        c = lens_centre(centre.corners, camera)
        out[i : i + 2] = (c[0] - camera.cx, c[1] - camera.cy)
    return out


def detection_from_features(raw: NDArray[np.float64], layout: DockLayout, image_size: tuple[int, int]) -> Detection:
    """The Detection a raw feature vector was made from (its corners), so a dataset row can feed PnP too."""
    obs = {}
    for role in ROLES:
        m = f"m{ROLE_NUMBER[role]}"
        if raw[FEATURE_NAMES.index(f"{m}_seen")] == 1.0:
            cols = [FEATURE_NAMES.index(f"{m}_{c}_{a}") for c in CORNER_NAMES for a in ("u", "v")]
            obs[role] = MarkerObservation(
                role, layout.marker(role).id, np.asarray(raw[cols], dtype=np.float64).reshape(4, 2)
            )
    return Detection(obs, (), image_size)


# Corners from monodock.perception.refine (bias-free edge fits), stored beside OpenCV's: NaN where the marker was
# not seen or could not be refined. The regression keeps OpenCV's corners (it was trained on them, and learned
# their bias).
REFINED_CORNER_NAMES = tuple(
    f"m{ROLE_NUMBER[role]}_{c}_{a}_refined" for role in ROLES for c in CORNER_NAMES for a in ("u", "v")
)


def refined_vector(refined: Detection) -> NDArray[np.float64]:
    """The refined corners of a detection in REFINED_CORNER_NAMES order (NaN: not seen or not refined)."""
    out = np.full(len(REFINED_CORNER_NAMES), np.nan)
    for k, role in enumerate(ROLES):
        obs = refined.observations.get(role)
        if obs is not None and role not in refined.unrefined:
            out[8 * k : 8 * k + 8] = obs.corners.ravel()
    return out


def refined_detection_from_row(
    raw: NDArray[np.float64], refined: NDArray[np.float64], layout: DockLayout, image_size: tuple[int, int]
) -> Detection:
    """The refined Detection of a dataset row: refined corners where there are some, OpenCV's (listed in
    ``unrefined``) for a marker seen but not refined."""
    base = detection_from_features(raw, layout, image_size)
    obs = dict(base.observations)
    unrefined = []
    for k, role in enumerate(ROLES):
        if role not in obs:
            continue
        c = np.asarray(refined[8 * k : 8 * k + 8], dtype=np.float64)
        if np.all(np.isfinite(c)):
            obs[role] = MarkerObservation(role, obs[role].marker_id, c.reshape(4, 2))
        else:
            unrefined.append(role)
    return Detection(obs, (), image_size, tuple(unrefined))


# --- model inputs ---------------------------------------------------------------------------------

# Bumped whenever model_features changes: a bundle trained on another schema must refuse to load.
MODEL_FEATURE_SCHEMA = "monodock.model_features/1"

# Which markers each model sees. Near the charger the side markers leave the view, so besides the papers'
# three-marker model there is one per subset, trained on the same rows with the other markers masked.
MARKER_SETS: dict[str, tuple[str, ...]] = {
    "m1m2m3": ("left", "center", "right"),
    "m1m2": ("left", "center"),
    "m2m3": ("center", "right"),
    "m2": ("center",),
}
DEFAULT_MARKER_SETS: tuple[str, ...] = ("m1m2m3", "m2")

_PER_MARKER = ("u", "v", "top", "bottom", "left", "right", "inv_size", "log_lr", "log_tb")


def model_feature_names(set_name: str) -> tuple[str, ...]:
    """The model input columns of a marker set, in order."""
    roles = _roles(set_name)
    names = [f"m{ROLE_NUMBER[r]}_{f}" for r in roles for f in _PER_MARKER]
    names += [f"m2_shape_{c}_{a}" for c in CORNER_NAMES for a in ("x", "y")]
    for r in roles:
        if r != "center":
            m = f"m{ROLE_NUMBER[r]}"
            names += [f"{m}_du", f"{m}_dv", f"{m}_inv_sep"]
    if "left" in roles and "right" in roles:
        names += ["log_sep_ratio", "log_size_ratio"]
    return tuple(names)


def _roles(set_name: str) -> tuple[str, ...]:
    if set_name not in MARKER_SETS:
        raise ValueError(f"unknown marker set '{set_name}' (one of {', '.join(MARKER_SETS)})")
    return MARKER_SETS[set_name]


@functools.lru_cache(maxsize=8)
def _corner_columns(roles: tuple[str, ...]) -> NDArray[np.int64]:
    """Column indices of the roles' corners (tl, tr, br, bl; u, v) in FEATURE_NAMES."""
    names = [f"m{ROLE_NUMBER[r]}_{c}_{a}" for r in roles for c in CORNER_NAMES for a in ("u", "v")]
    return np.array([FEATURE_NAMES.index(n) for n in names], dtype=np.int64)


def _normalised_markers(
    rows: NDArray[np.float64], roles: tuple[str, ...], camera: CameraModel
) -> dict[str, NDArray[np.float64]]:
    """Per row and marker, the geometry in normalised image coordinates, arrays of shape (n, markers[, ...]).

    One undistortion call for every corner of every row: this runs on each frame at run time.
    """
    px = rows[:, _corner_columns(roles)].reshape(len(rows), len(roles), 4, 2)
    n = np.full_like(px, np.nan)
    ok = np.all(np.isfinite(px), axis=(2, 3))
    if ok.any():
        n[ok] = camera.normalize(px[ok].reshape(-1, 2)).reshape(-1, 4, 2)
    c0, c1, c2, c3 = n[..., 0, :], n[..., 1, :], n[..., 2, :], n[..., 3, :]
    top = np.linalg.norm(c0 - c1, axis=-1)
    bottom = np.linalg.norm(c2 - c3, axis=-1)
    left = np.linalg.norm(c3 - c0, axis=-1)
    right = np.linalg.norm(c1 - c2, axis=-1)
    # The centre is where the diagonals cross: the image of the marker's centre under perspective.
    r, d = c2 - c0, c3 - c1
    q = c1 - c0
    with np.errstate(divide="ignore", invalid="ignore"):
        t = (q[..., 0] * d[..., 1] - q[..., 1] * d[..., 0]) / (r[..., 0] * d[..., 1] - r[..., 1] * d[..., 0])
        centre = c0 + t[..., None] * r
        size = (top + bottom + left + right) / 4.0
        # The quadrilateral's shape independent of its size and place: what perspective does to a square.
        shape = (n - centre[..., None, :]) / size[..., None, None]
        return {
            "shape": shape.reshape(len(rows), len(roles), 8),
            "u": centre[..., 0],
            "v": centre[..., 1],
            "top": top,
            "bottom": bottom,
            "left": left,
            "right": right,
            "inv_size": 1.0 / size,
            "log_lr": np.log(left / right),
            "log_tb": np.log(top / bottom),
        }


def model_features(raw: NDArray[np.float64], camera: CameraModel, set_name: str) -> NDArray[np.float64]:
    """The model inputs of a marker set for rows of raw features, shape (n, len(model_feature_names(set_name))).

    Args:
        raw: raw features in the order of FEATURE_NAMES, shape (n, len(FEATURE_NAMES)) or (len(FEATURE_NAMES),).
        camera: the calibration the corners were measured with; the inputs are undistorted and normalised
            (x/z, y/z), so a model does not depend on the pixel grid.
        set_name: one of MARKER_SETS.

    Rows where a marker of the set was not seen come out NaN; the caller drops or refuses them.
    """
    roles = _roles(set_name)
    rows = np.atleast_2d(np.asarray(raw, dtype=np.float64))
    n = len(rows)
    geo = _normalised_markers(rows, roles, camera)
    k = {r: i for i, r in enumerate(roles)}
    # Per marker, in the order of _PER_MARKER: one (n, markers * 9) block.
    blocks = [np.stack([geo[f] for f in _PER_MARKER], axis=-1).reshape(n, -1)]
    # Marker 2's full shape: with marker 2 alone, the yaw is in the perspective of one square.
    blocks.append(geo["shape"][:, k["center"]])
    sides = [r for r in roles if r != "center"]
    if sides:
        idx = [k[r] for r in sides]
        du = geo["u"][:, idx] - geo["u"][:, k["center"], None]
        dv = geo["v"][:, idx] - geo["v"][:, k["center"], None]
        sep = np.hypot(du, dv)
        with np.errstate(divide="ignore", invalid="ignore"):
            blocks.append(np.stack([du, dv, 1.0 / sep], axis=-1).reshape(n, -1))
            if len(sides) == 2:  # left and right: how the face turns shows in their asymmetry
                inv = geo["inv_size"]
                ratios = [np.log(sep[:, 0] / sep[:, 1]), np.log(inv[:, k["left"]] / inv[:, k["right"]])]
                blocks.append(np.stack(ratios, axis=-1))
    return np.concatenate(blocks, axis=1)


def choose_marker_set(seen: tuple[str, ...] | set[str], available: tuple[str, ...]) -> str | None:
    """The most informative available marker set whose markers were all seen (None without marker 2)."""
    ok = [s for s in available if set(MARKER_SETS[s]) <= set(seen)]
    return max(ok, key=lambda s: len(MARKER_SETS[s]), default=None)
