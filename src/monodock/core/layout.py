"""The dock layout: which ArUco markers the charger carries, how big, and where (docs/architecture.md).

Marker corners follow OpenCV's ArUco order as seen by a robot facing the charger: top-left, top-right,
bottom-right, bottom-left. In the ``dock`` frame (x into the charger, y left, z up) a marker centred at
(0, y, z) with side s has its top-left corner at (0, y + s/2, z + s/2): the robot's left is +y.

A surveyed dock (``monodock calibrate layout``) or a designed one says more per marker, each optional: ``x``
(its centre's distance along the dock's x, metres: > 0 behind the face, < 0 standing off it), its tilt against
the face ``roll``, ``pitch``, ``yaw`` (radians, URDF order, about the dock's axes through the marker's centre:
roll turns it in the face's plane, pitch > 0 leans its top into the charger, yaw > 0 turns it to face the
robot's right) and ``size`` (its own printed side, metres). A file without them means what it always meant.

Beyond the papers' three (left, center, right: required, first), a dock may carry more markers under names of its
own (``far``, ``m4``: lower case, digits and ``_``), each with its own size and place, up to ``MAX_MARKERS`` in all,
from the same dictionary. The papers' regression uses the three; the geometric methods use every marker they see.
"""

from __future__ import annotations

import math
import os
import re
from dataclasses import dataclass
from pathlib import Path
from typing import Any, ClassVar

import cv2
import numpy as np
from numpy.typing import NDArray

from monodock.core import transforms
from monodock.core.config import Fields, load_yaml, write_text_atomic, yaml_text
from monodock.core.settings import Policy, from_fields, from_mapping, setting, to_mapping
from monodock.errors import ConfigError

__all__ = ["FACE_R_MARKER", "MAX_MARKERS", "ROLES", "DockLayout", "MarkerSpec", "dictionary_problem"]

# The papers' markers 1, 2, 3 from the robot's left to its right; marker 2 marks the docking point.
ROLES: tuple[str, str, str] = ("left", "center", "right")
ROLE_NUMBER: dict[str, int] = {"left": 1, "center": 2, "right": 3}
# More markers than the papers' three: how they may be named, and how many a dock may carry in all.
EXTRA_NAME = re.compile(r"^[a-z][a-z0-9_]{0,15}$")
MAX_MARKERS = 16

# What a layout file may hold (docs/user-guide.md, "What every file may hold"): printed markers from 5 mm to 2 m,
# within 5 m of the dock origin.
MARKER_SIZE_RANGE = (0.005, 2.0)
MAX_OFFSET = 5.0
MAX_EDGE_OFFSET_PX = 2.0


def _dictionary_size(name: str) -> int:
    """How many markers an OpenCV predefined dictionary holds."""
    d = cv2.aruco.getPredefinedDictionary(getattr(cv2.aruco, name))
    return int(d.bytesList.shape[0])


# A marker's own frame (x right, y up as seen from the robot, z out of the face towards it) in the dock frame,
# for a marker flat on the face: x -> -y_dock, y -> +z_dock, z -> -x_dock.
FACE_R_MARKER = np.array([[0.0, 0.0, -1.0], [-1.0, 0.0, 0.0], [0.0, 1.0, 0.0]])
# A marker's tilt against the face: beyond this it is not taped onto the face but mounted some other way.
MAX_TILT = math.radians(45.0)
# The optional per-marker keys of its pose.
_POSE_KEYS = ("x", "roll", "pitch", "yaw")
_PLACE = (-MAX_OFFSET, MAX_OFFSET)
_TILT = (-MAX_TILT, MAX_TILT)


def _id_problem(marker_id: int) -> str | None:
    # The dictionary's own range is checked with its name, by DockLayout.
    return f"must be at least 0, got {marker_id!r}" if marker_id < 0 else None


def dictionary_problem(name: str) -> str | None:
    """Why ``name`` is not an OpenCV predefined ArUco dictionary, or None (a settings ``check``)."""
    if name.startswith("DICT_") and hasattr(cv2.aruco, name):
        return None
    return f"unknown ArUco dictionary '{name}' (e.g. DICT_4X4_50)"


@dataclass(frozen=True)
class MarkerSpec:
    """One marker on the charger face: its role, ArUco id, centre (x, y, z) in the dock frame, tilt and side.

    Attributes:
        role: left, center or right (the papers' markers 1, 2, 3), or another marker's own name (``far``).
        id: the ArUco id.
        y, z: its centre across and above the floor, metres.
        x: its centre along the dock's x (0: on the face), metres.
        roll, pitch, yaw: its tilt against the face, radians (URDF order, the dock's axes; the module's docstring).
        size: its own printed side (outer black border), metres; None: the layout's ``marker_size``.

    In the layout file a marker is a mapping under its role (``markers: {left: {id: 1, y: 0.2, z: 0.3}}``) that
    holds its other keys, each optional one only where it is not its default.
    """

    role: str
    id: int = setting(check=_id_problem)
    y: float = setting(range=_PLACE, unit="m")
    z: float = setting(range=_PLACE, unit="m")
    x: float = setting(0.0, range=_PLACE, unit="m", omit_default=True)
    roll: float = setting(0.0, range=_TILT, unit="rad", omit_default=True)
    pitch: float = setting(0.0, range=_TILT, unit="rad", omit_default=True)
    yaw: float = setting(0.0, range=_TILT, unit="rad", omit_default=True)
    size: float | None = setting(None, range=MARKER_SIZE_RANGE, unit="m", omit_default=True)

    @property
    def number(self) -> int | None:
        """The papers' marker number: 1 left, 2 centre, 3 right; None for a marker the papers do not have."""
        return ROLE_NUMBER.get(self.role)

    @property
    def label(self) -> str:
        """A short name for pictures and messages: m1, m2, m3 for the papers' markers, else its own name."""
        return f"m{self.number}" if self.number is not None else self.role

    @property
    def tilted(self) -> bool:
        """Whether it stands off the face or is tilted against it (what a flat face of equal markers is not)."""
        return any(getattr(self, k) != 0.0 for k in _POSE_KEYS)

    def centre(self) -> NDArray[np.float64]:
        """Its centre in the dock frame, shape (3,)."""
        return np.array([self.x, self.y, self.z])


class _ByRole:
    """The layout file's ``markers``: a mapping of role to the marker's keys, the papers' three required and first."""

    def read(self, fields: Fields, key: str) -> tuple[MarkerSpec, ...]:
        mf = fields.child(key)
        missing = [role for role in ROLES if role not in mf.data]
        if missing:
            raise mf.error(missing[0], f"missing: every dock carries the papers' {', '.join(ROLES)}")
        others = [str(k) for k in mf.data if k not in ROLES]
        for name in others:
            if not EXTRA_NAME.match(name):
                raise mf.error(
                    name,
                    f"unknown marker role (expected {', '.join(ROLES)}, or another marker's name: lower-case letters, "
                    "digits and _)",
                )
        return tuple(from_fields(MarkerSpec, mf.child(role), role=role) for role in (*ROLES, *others))

    def write(self, value: tuple[MarkerSpec, ...]) -> dict[str, Any]:
        return {m.role: {k: v for k, v in to_mapping(m).items() if k != "role"} for m in value}


@dataclass(frozen=True)
class DockLayout:
    """Dictionary, marker side (outer black border, metres) and the markers of the charger: the papers' three (left,
    center, right) first, then any others in their file's order.

    The layout file (docs/user-guide.md) is read by ``core.settings.from_mapping`` and written by ``to_mapping``.
    Unknown keys are reported and dropped: nothing a file holds beyond the schema travels into outputs. A survey's
    record (``calibrate layout``) is for people: read past, without a warning.
    """

    SETTINGS: ClassVar[Policy] = Policy(what="layout", ignore=("survey",))

    dictionary: str = setting(check=dictionary_problem)
    marker_size: float = setting(range=MARKER_SIZE_RANGE, unit="m")
    markers: tuple[MarkerSpec, ...] = setting(codec=_ByRole())
    # How far this print's black/white edges look moved towards the white in this camera's images, px (< 0: black
    # thinner; ink, sharpening, processing). Measured by ``calibrate layout``; the geometric methods' corners are
    # corrected by it (``perception.edge_offset``). 0: none.
    edge_offset: float = setting(
        0.0, key="edge_offset_px", range=(-MAX_EDGE_OFFSET_PX, MAX_EDGE_OFFSET_PX), unit="px", omit_default=True
    )

    def __post_init__(self) -> None:
        if not hasattr(cv2.aruco, self.dictionary) or not self.dictionary.startswith("DICT_"):
            raise ConfigError(f"unknown ArUco dictionary '{self.dictionary}'")
        if not self.marker_size > 0:
            raise ConfigError(f"marker_size must be positive, got {self.marker_size}")
        if tuple(m.role for m in self.markers[:3]) != ROLES:
            raise ConfigError(f"layout markers must be {', '.join(ROLES)} in that order, before any others")
        if len(self.markers) > MAX_MARKERS:
            raise ConfigError(f"a dock carries at most {MAX_MARKERS} markers, got {len(self.markers)}")
        names = [m.role for m in self.markers]
        for name in names[3:]:
            if name in ROLES or not EXTRA_NAME.match(name):
                raise ConfigError(
                    f"marker name '{name}': another marker's name is lower-case letters, digits and _ (up to 16, "
                    f"a letter first), not {', '.join(ROLES)}"
                )
        if len(set(names)) != len(names):
            raise ConfigError(f"marker names must be distinct, got {names}")
        ids = [m.id for m in self.markers]
        if len(set(ids)) != len(ids):
            raise ConfigError(f"marker ids must be distinct, got {ids}")
        size = _dictionary_size(self.dictionary)
        for m in self.markers:
            if not 0 <= m.id < size:
                raise ConfigError(f"marker {m.role}: id {m.id} is not in {self.dictionary} (0..{size - 1})")
        for m in self.markers:
            if m.size is not None and not m.size > 0:
                raise ConfigError(f"marker {m.role}: size must be positive, got {m.size}")
        centres = [(m.y, m.z) for m in self.markers]
        for i in range(len(centres)):
            for j in range(i + 1, len(centres)):
                gap = max(abs(centres[i][0] - centres[j][0]), abs(centres[i][1] - centres[j][1]))
                # Tilted markers' outlines on the face are a little narrower than their sides: a gap of the
                # mean half sides, at most 3 % short, is still apart (a survey's ±2° leave 0.06 %).
                need = 0.5 * (self.side(self.markers[i].role) + self.side(self.markers[j].role))
                if gap < 0.97 * need or (gap < need and not (self.markers[i].tilted or self.markers[j].tilted)):
                    raise ConfigError(
                        f"markers {self.markers[i].role} and {self.markers[j].role} overlap "
                        f"(centres {gap:.3f} m apart, sides {need:.3f} m on average)"
                    )

    @classmethod
    def default(cls) -> DockLayout:
        """The papers' charger: marker 2 over the docking point, markers 1 and 3 20 cm either side."""
        return cls(
            dictionary="DICT_4X4_50",
            marker_size=0.10,
            markers=(
                MarkerSpec("left", 1, 0.20, 0.30),
                MarkerSpec("center", 2, 0.0, 0.30),
                MarkerSpec("right", 3, -0.20, 0.30),
            ),
        )

    @classmethod
    def load(cls, path: str | os.PathLike[str]) -> DockLayout:
        """Read a dock layout YAML file."""
        return from_mapping(cls, load_yaml(path, "layout"), str(path))

    def save(self, path: str | os.PathLike[str], *, force: bool = False) -> None:
        """Write the layout YAML atomically."""
        write_text_atomic(Path(path), yaml_text(to_mapping(self)), force=force)

    # --- lookups --------------------------------------------------------------------------------

    @property
    def roles(self) -> tuple[str, ...]:
        """Every marker's role, the papers' three first, then the others in the layout's order."""
        return tuple(m.role for m in self.markers)

    def marker(self, role: str) -> MarkerSpec:
        """The marker with this role."""
        for m in self.markers:
            if m.role == role:
                return m
        raise KeyError(role)

    def role_of(self, marker_id: int) -> str | None:
        """The role of an ArUco id, or None for an id the dock does not carry."""
        for m in self.markers:
            if m.id == marker_id:
                return m.role
        return None

    def aruco_dictionary(self) -> cv2.aruco.Dictionary:
        """The OpenCV dictionary object."""
        return cv2.aruco.getPredefinedDictionary(getattr(cv2.aruco, self.dictionary))

    @property
    def modules(self) -> int:
        """A marker's width in cells, its one-cell black border included (6 for a 4x4 dictionary)."""
        return int(self.aruco_dictionary().markerSize) + 2

    def marker_bits(self, marker_id: int) -> NDArray[np.uint8]:
        """The marker's cells including its one-cell black border: 0 black, 1 white, shape (n+2, n+2)."""
        d = self.aruco_dictionary()
        cells = int(d.markerSize) + 2
        img = cv2.aruco.generateImageMarker(d, marker_id, cells, borderBits=1)
        return (img > 127).astype(np.uint8)

    def side(self, role: str) -> float:
        """A marker's printed side (outer black border), metres: its own ``size``, else ``marker_size``."""
        size = self.marker(role).size
        return self.marker_size if size is None else size

    @property
    def flat(self) -> bool:
        """Whether every marker lies on the face, untilted, at ``marker_size`` (a layout file of three keys each)."""
        return not any(m.tilted or (m.size is not None and m.size != self.marker_size) for m in self.markers)

    def corners_in_marker(self, role: str | None = None) -> NDArray[np.float64]:
        """A marker's corners in its own frame, the order SOLVEPNP_IPPE_SQUARE requires, shape (4, 3).

        ``role`` picks the marker's own side (``side``); without it, the layout's ``marker_size``.
        """
        h = (self.marker_size if role is None else self.side(role)) / 2.0
        return np.array([[-h, h, 0.0], [h, h, 0.0], [h, -h, 0.0], [-h, -h, 0.0]])

    def dock_T_marker(self, role: str) -> NDArray[np.float64]:
        """Pose of a marker's own frame (x right, y up as seen from the robot, z out of the face) in dock."""
        m = self.marker(role)
        # Marker frame axes in dock coordinates: x -> -y_dock, y -> +z_dock, z -> -x_dock (towards the robot),
        # then the marker's tilt about the dock's axes through its centre.
        T = np.eye(4)
        T[:3, :3] = FACE_R_MARKER
        if m.roll or m.pitch or m.yaw:
            T[:3, :3] = transforms.rotation_from_rpy(m.roll, m.pitch, m.yaw) @ FACE_R_MARKER
        T[:3, 3] = (m.x, m.y, m.z)
        return T

    def corners_in_dock(self, role: str) -> NDArray[np.float64]:
        """A marker's four corners in the dock frame, ArUco order (TL, TR, BR, BL), shape (4, 3)."""
        T = self.dock_T_marker(role)
        return self.corners_in_marker(role) @ T[:3, :3].T + T[:3, 3]
