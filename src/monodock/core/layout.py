"""The dock layout: which ArUco markers the charger carries, how big, and where (docs/architecture.md).

Marker corners follow OpenCV's ArUco order as seen by a robot facing the charger: top-left, top-right,
bottom-right, bottom-left. In the ``dock`` frame (x into the charger, y left, z up) a marker centred at
(0, y, z) with side s has its top-left corner at (0, y + s/2, z + s/2): the robot's left is +y.
"""

from __future__ import annotations

import os
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import cv2
import numpy as np
from numpy.typing import NDArray

from monodock.core.config import Fields, load_yaml, write_text_atomic, yaml_text
from monodock.errors import ConfigError

__all__ = ["ROLES", "DockLayout", "MarkerSpec"]

# The papers' markers 1, 2, 3 from the robot's left to its right; marker 2 marks the docking point.
ROLES: tuple[str, str, str] = ("left", "center", "right")
ROLE_NUMBER: dict[str, int] = {"left": 1, "center": 2, "right": 3}

# What a layout file may hold (docs/user-guide.md, "What every file may hold"): printed markers from 5 mm to 2 m,
# within 5 m of the dock origin.
MARKER_SIZE_RANGE = (0.005, 2.0)
MAX_OFFSET = 5.0


def _dictionary_size(name: str) -> int:
    """How many markers an OpenCV predefined dictionary holds."""
    d = cv2.aruco.getPredefinedDictionary(getattr(cv2.aruco, name))
    return int(d.bytesList.shape[0])


@dataclass(frozen=True)
class MarkerSpec:
    """One marker on the charger face: its role, ArUco id, and centre (0, y, z) in the dock frame."""

    role: str
    id: int
    y: float
    z: float

    @property
    def number(self) -> int:
        """The papers' marker number: 1 left, 2 centre, 3 right."""
        return ROLE_NUMBER[self.role]


@dataclass(frozen=True)
class DockLayout:
    """Dictionary, marker side (outer black border, metres) and the three markers of the charger."""

    dictionary: str
    marker_size: float
    markers: tuple[MarkerSpec, MarkerSpec, MarkerSpec]

    def __post_init__(self) -> None:
        if not hasattr(cv2.aruco, self.dictionary) or not self.dictionary.startswith("DICT_"):
            raise ConfigError(f"unknown ArUco dictionary '{self.dictionary}'")
        if not self.marker_size > 0:
            raise ConfigError(f"marker_size must be positive, got {self.marker_size}")
        if tuple(m.role for m in self.markers) != ROLES:
            raise ConfigError(f"layout markers must be {', '.join(ROLES)} in that order")
        ids = [m.id for m in self.markers]
        if len(set(ids)) != len(ids):
            raise ConfigError(f"marker ids must be distinct, got {ids}")
        size = _dictionary_size(self.dictionary)
        for m in self.markers:
            if not 0 <= m.id < size:
                raise ConfigError(f"marker {m.role}: id {m.id} is not in {self.dictionary} (0..{size - 1})")
        centres = [(m.y, m.z) for m in self.markers]
        for i in range(3):
            for j in range(i + 1, 3):
                gap = max(abs(centres[i][0] - centres[j][0]), abs(centres[i][1] - centres[j][1]))
                if gap < self.marker_size:
                    raise ConfigError(
                        f"markers {self.markers[i].role} and {self.markers[j].role} overlap "
                        f"(centres {gap:.3f} m apart, marker_size {self.marker_size} m)"
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
    def from_dict(cls, data: dict[str, Any], source: str = "layout") -> DockLayout:
        """Build from the layout YAML mapping (docs/user-guide.md); errors name the field."""
        f = Fields(data, source)
        dictionary = f.string("dictionary")
        if not dictionary.startswith("DICT_") or not hasattr(cv2.aruco, dictionary):
            raise f.error("dictionary", f"unknown ArUco dictionary '{dictionary}' (e.g. DICT_4X4_50)")
        marker_size = f.number("marker_size", within=MARKER_SIZE_RANGE, unit="m")
        mf = f.child("markers")
        unknown = sorted(str(k) for k in set(mf.data) - set(ROLES))
        if unknown:
            raise mf.error(unknown[0], f"unknown marker role (expected {', '.join(ROLES)})")
        specs = []
        for role in ROLES:
            m = mf.child(role)
            marker_id = m.integer("id", minimum=0)  # the dictionary's range is checked with its name below
            y = m.number("y", within=(-MAX_OFFSET, MAX_OFFSET), unit="m")
            z = m.number("z", within=(-MAX_OFFSET, MAX_OFFSET), unit="m")
            m.warn_unknown(("id", "y", "z"))
            specs.append(MarkerSpec(role, marker_id, y, z))
        # Unknown keys are reported and dropped: nothing a file holds beyond the schema travels into outputs.
        f.warn_unknown(("dictionary", "marker_size", "markers"))
        try:
            return cls(dictionary, marker_size, (specs[0], specs[1], specs[2]))
        except ConfigError as exc:
            raise ConfigError(f"{source}: {exc}") from None

    @classmethod
    def load(cls, path: str | os.PathLike[str]) -> DockLayout:
        """Read a dock layout YAML file."""
        return cls.from_dict(load_yaml(path, "layout"), str(path))

    def to_dict(self) -> dict[str, Any]:
        """The layout YAML mapping (docs/user-guide.md)."""
        out: dict[str, Any] = {"dictionary": self.dictionary, "marker_size": self.marker_size}
        out["markers"] = {m.role: {"id": m.id, "y": m.y, "z": m.z} for m in self.markers}
        return out

    def save(self, path: str | os.PathLike[str], *, force: bool = False) -> None:
        """Write the layout YAML atomically."""
        write_text_atomic(Path(path), yaml_text(self.to_dict()), force=force)

    # --- lookups --------------------------------------------------------------------------------

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

    def corners_in_marker(self) -> NDArray[np.float64]:
        """A marker's corners in its own frame, the order SOLVEPNP_IPPE_SQUARE requires, shape (4, 3)."""
        h = self.marker_size / 2.0
        return np.array([[-h, h, 0.0], [h, h, 0.0], [h, -h, 0.0], [-h, -h, 0.0]])

    def dock_T_marker(self, role: str) -> NDArray[np.float64]:
        """Pose of a marker's own frame (x right, y up as seen from the robot, z out of the face) in dock."""
        m = self.marker(role)
        # Marker frame axes in dock coordinates: x -> -y_dock, y -> +z_dock, z -> -x_dock (towards the robot).
        T = np.eye(4)
        T[:3, :3] = np.array([[0.0, 0.0, -1.0], [-1.0, 0.0, 0.0], [0.0, 1.0, 0.0]])
        T[:3, 3] = (0.0, m.y, m.z)
        return T

    def corners_in_dock(self, role: str) -> NDArray[np.float64]:
        """A marker's four corners in the dock frame, ArUco order (TL, TR, BR, BL), shape (4, 3)."""
        T = self.dock_T_marker(role)
        return self.corners_in_marker() @ T[:3, :3].T + T[:3, 3]
