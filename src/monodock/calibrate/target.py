"""The diamond calibration target: a square board turned 45 degrees, with ArUco markers, seen edge-on by the LiDAR.

A board with vertical edges cannot tell the laser's height: the scan's end points slide along the edges. A diamond's
edges are slanted, so where the laser plane crosses them depends on that height, and all six fields of the LiDAR
mount become observable (``calibrate.extrinsics.extrinsics_from_target_views``). Views are an image and a scan each,
from a recording or from a folder of ``NNNN.png`` images and one ``scans.npz``.
"""

from __future__ import annotations

import math
import os
import zipfile
import zlib
from collections.abc import Sequence
from dataclasses import dataclass
from pathlib import Path
from typing import Any, ClassVar

import cv2
import numpy as np
from numpy.typing import NDArray

from monodock.core.config import Fields, load_yaml
from monodock.core.images import encode_png
from monodock.core.layout import dictionary_problem
from monodock.core.scan import LaserScan
from monodock.core.settings import Policy, from_mapping, setting
from monodock.errors import ConfigError, InputError
from monodock.io.frames import read_image

# The most a scans.npz may unpack to.
MAX_NPZ_BYTES = 2_000_000_000

__all__ = ["S_AXIS", "T_AXIS", "DiamondTarget", "TargetMarker", "TargetView", "read_target_views", "write_target_views"]

S_AXIS = np.array([1.0, 1.0, 0.0]) / math.sqrt(2.0)  # board's s axis in the target frame: right and up
T_AXIS = np.array([1.0, -1.0, 0.0]) / math.sqrt(2.0)  # board's t axis: right and down


# The board's side unless its file says otherwise, metres.
_SIDE = 0.5


@dataclass(frozen=True)
class TargetMarker:
    """One marker of the board: its ArUco id and its centre in the board's (s, t) coordinates, metres."""

    id: int
    s: float
    t: float


class _MarkerList:
    """The target file's ``markers``: one list of ``{id, s, t}``, each centre on the board (within its side, which
    is read before the markers)."""

    def read(self, fields: Fields, key: str) -> tuple[TargetMarker, ...]:
        markers = fields.raw(key)
        if not isinstance(markers, list) or not markers:
            raise fields.error(key, "expected a list of {id, s, t}")
        items = [Fields(m, fields.source, f"{fields.prefix}{key}[{k}].") for k, m in enumerate(markers)]
        ids = [m.integer("id", minimum=0) for m in items]
        repeated = sorted({i for i in ids if ids.count(i) > 1})
        if repeated:  # each id places one marker: a second would be found at the first one's corners
            raise fields.error(key, f"marker ids must be distinct, got {repeated[0]} more than once")
        within = (0.0, float(fields.data.get("side", _SIDE)))
        centres = [(m.number("s", within=within, unit="m"), m.number("t", within=within, unit="m")) for m in items]
        return tuple(TargetMarker(i, s, t) for i, (s, t) in zip(ids, centres, strict=True))

    def write(self, value: tuple[TargetMarker, ...]) -> list[dict[str, Any]]:
        return [{"id": m.id, "s": m.s, "t": m.t} for m in value]


@dataclass(frozen=True)
class DiamondTarget:
    """The diamond board: its side, its markers (ids, size, centres in board (s, t) coordinates) and dictionary.

    A target file (``--target``) holds ``{side, marker_size, dictionary, markers: [{id, s, t}, ...]}``, each
    optional; it is read by ``core.settings.from_mapping`` (``load``).

    Attributes:
        side: the square's side, metres.
        marker_size: each marker's side, metres (black border included).
        dictionary: the OpenCV predefined dictionary name.
        markers: the ArUco ids (must not be ids of the dock layout) and each marker's centre in the board's (s, t)
            coordinates, metres: s from the left vertex towards the top vertex, t from the left vertex towards the
            bottom vertex.
    """

    SETTINGS: ClassVar[Policy] = Policy(what="target", error=InputError)

    side: float = setting(_SIDE, range=(0.05, 5.0), unit="m")
    # Big markers: the board's pose from the camera is what locates the edges, and 10 cm markers left the
    # laser's z and pitch 3-4 cm / 2-3 deg off; 16 cm ones (views within 1.3 m) bring them under 0.5 cm / 0.4 deg.
    marker_size: float = setting(0.16, range=(0.005, 2.0), unit="m")
    dictionary: str = setting("DICT_4X4_50", check=dictionary_problem)
    markers: tuple[TargetMarker, ...] = setting(
        (
            TargetMarker(20, 0.13, 0.13),
            TargetMarker(21, 0.37, 0.13),
            TargetMarker(22, 0.37, 0.37),
            TargetMarker(23, 0.13, 0.37),
        ),
        codec=_MarkerList(),
    )

    def __post_init__(self) -> None:
        if not (math.isfinite(self.side) and self.side > 0):
            raise InputError(f"target side must be a positive number of metres, got {self.side}")
        if not self.markers:
            raise InputError("the target needs at least one marker")

    @property
    def marker_ids(self) -> tuple[int, ...]:
        """The markers' ArUco ids."""
        return tuple(m.id for m in self.markers)

    @property
    def marker_centres(self) -> tuple[tuple[float, float], ...]:
        """The markers' centres in board (s, t) coordinates, metres."""
        return tuple((m.s, m.t) for m in self.markers)

    @property
    def half_diagonal(self) -> float:
        """Distance from the centre to each vertex, metres."""
        return self.side / math.sqrt(2.0)

    @classmethod
    def load(cls, path: str | os.PathLike[str]) -> DiamondTarget:
        """Read a target YAML (the class's docstring); an empty file is the default target."""
        p = Path(path)
        if p.is_file() and not p.read_bytes().strip():
            return cls()
        try:
            data = load_yaml(p, "target")
        except ConfigError as exc:
            raise InputError(str(exc)) from None
        return from_mapping(cls, data, str(p))

    def aruco_dictionary(self) -> Any:
        """The OpenCV dictionary object."""

        name = self.dictionary
        if not hasattr(cv2.aruco, name):
            raise InputError(f"unknown ArUco dictionary {name}")
        return cv2.aruco.getPredefinedDictionary(getattr(cv2.aruco, name))

    def board_point(self, s: NDArray[np.float64], t: NDArray[np.float64]) -> NDArray[np.float64]:
        """Target-frame points (N, 3) of board coordinates (s, t), metres from the left vertex."""
        origin = np.array([-self.half_diagonal, 0.0, 0.0])
        return origin + s[:, None] * S_AXIS + t[:, None] * T_AXIS

    def marker_corners_in_target(self, marker_id: int) -> NDArray[np.float64]:
        """A marker's corners in the target frame, ArUco order (TL, TR, BR, BL as printed), shape (4, 3)."""
        if marker_id not in self.marker_ids:
            raise KeyError(marker_id)
        cs, ct = self.marker_centres[self.marker_ids.index(marker_id)]
        h = self.marker_size / 2.0
        s = np.array([cs - h, cs + h, cs + h, cs - h])
        t = np.array([ct - h, ct - h, ct + h, ct + h])
        return self.board_point(s, t)

    def vertices_in_target(self) -> NDArray[np.float64]:
        """The four vertices (top, right, bottom, left) in the target frame, shape (4, 3)."""
        a = self.half_diagonal
        return np.array([[0.0, a, 0.0], [a, 0.0, 0.0], [0.0, -a, 0.0], [-a, 0.0, 0.0]])

    def edges_in_target(self) -> list[tuple[NDArray[np.float64], NDArray[np.float64]]]:
        """The four edges as (start vertex, end vertex) in the target frame: top-right, bottom-right, ..."""
        v = self.vertices_in_target()
        return [(v[k], v[(k + 1) % 4]) for k in range(4)]


@dataclass(frozen=True)
class TargetView:
    """One view of the target: the camera image (mono8), the LiDAR scan, and the true target pose if simulated."""

    image: NDArray[np.uint8]
    scan: LaserScan
    base_T_target: NDArray[np.float64] | None = None


def write_target_views(folder: str | os.PathLike[str], views: Sequence[TargetView]) -> None:
    """Write views as ``NNNN.png`` images and one ``scans.npz`` (ranges row per view, and the beam geometry)."""

    out = Path(folder)
    out.mkdir(parents=True, exist_ok=True)
    for k, v in enumerate(views):
        (out / f"{k:04d}.png").write_bytes(encode_png(v.image))
    s0 = views[0].scan
    np.savez(
        out / "scans.npz",
        ranges=np.stack([v.scan.ranges for v in views]),
        stamps=np.array([v.scan.stamp for v in views]),
        angle_min=s0.angle_min,
        angle_increment=s0.angle_increment,
        range_min=s0.range_min,
        range_max=s0.range_max,
    )


def read_target_views(folder: str | os.PathLike[str]) -> list[TargetView]:
    """Read views written by write_target_views: image ``k`` (sorted PNGs) pairs with scan row ``k``."""

    p = Path(folder)
    if not p.is_dir():
        raise InputError(f"target views folder not found: {p}")
    images = sorted(p.glob("*.png"))
    if not (p / "scans.npz").is_file():
        raise InputError(f"{p}: no scans.npz (the LiDAR scans, one row of ranges per image)")
    npz = p / "scans.npz"
    try:
        # A zip whose members would unpack to more than MAX_NPZ_BYTES is refused before any is read (a zip bomb);
        # object arrays are never unpickled (allow_pickle=False: a pickle in it is a ValueError).
        with zipfile.ZipFile(npz) as z:
            unpacked = sum(info.file_size for info in z.infolist())
        if unpacked > MAX_NPZ_BYTES:
            raise InputError(f"{npz}: unpacks to {unpacked / 1e9:.1f} GB (at most {MAX_NPZ_BYTES / 1e9:.0f} GB)")
        with np.load(npz, allow_pickle=False) as data:
            ranges = np.asarray(data["ranges"], dtype=np.float32)
            stamps = (
                np.asarray(data["stamps"], dtype=np.float64)
                if "stamps" in data
                else np.arange(len(ranges), dtype=float)
            )
            a0, da = float(data["angle_min"]), float(data["angle_increment"])
            rmin, rmax = float(data["range_min"]), float(data["range_max"])
    except (KeyError, ValueError, TypeError, OSError, EOFError, zipfile.BadZipFile, zlib.error) as exc:
        raise InputError(f"{npz}: not a readable scans.npz ({' '.join(str(exc).split())})") from None
    if not all(math.isfinite(v) for v in (a0, da, rmin, rmax)) or da == 0 or not 0 <= rmin < rmax:
        raise InputError(f"{npz}: angle_min, angle_increment, range_min, range_max must be finite, with 0 <= min < max")
    if ranges.ndim != 2 or len(ranges) != len(images):
        raise InputError(f"{p}: {len(images)} images but {len(ranges)} scans; they must pair one to one")
    n = ranges.shape[1]
    views = []
    for k, img in enumerate(images):
        scan = LaserScan(float(stamps[k]), "laser", a0, a0 + da * (n - 1), da, 0.0, 0.0, rmin, rmax, ranges[k])
        views.append(TargetView(read_image(img), scan))
    return views
