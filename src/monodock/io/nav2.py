"""Nav2-ready output: the estimates as geometry_msgs/PoseStamped on ``detected_dock_pose`` in a rosbag2.

Nav2's docking server (opennav_docking) takes the dock's pose from an external detector on the topic
``detected_dock_pose``: a PoseStamped in the robot's frame whose header stamp is the stamp of the image it was
seen in. The bag written here holds exactly that, one message per valid estimate, so it can be replayed into a
docking server (``ros2 bag play``) or compared with its own detector.

When an estimate has a covariance (the EST.csv columns ``cov_xx ... cov_yawyaw``), the same pose is also
written as geometry_msgs/PoseWithCovarianceStamped on ``detected_dock_pose_with_covariance``, for consumers
that weigh it (robot_localization, a tracking filter). Its covariance is the message's 6x6 row-major matrix
over (x, y, z, rotation about x, about y, about z): our (x, y, yaw) block sits at rows and columns 0, 1 and 5.
Convention for the rest: the pose is planar, its z, roll and pitch fixed by the floor (both frames stand on
it) rather than measured, so their rows and columns are zero, as amcl's ``amcl_pose`` does for a 2D pose.
"""

from __future__ import annotations

import math
import os
from collections.abc import Iterable, Mapping, Sequence
from dataclasses import dataclass
from pathlib import Path
from types import TracebackType
from typing import Any

import numpy as np
from numpy.typing import NDArray
from rosbags.interfaces import Connection
from rosbags.rosbag2 import Reader, ReaderError

from monodock.core import transforms
from monodock.core.pose import DockPose
from monodock.errors import ConfigError, InputError
from monodock.io.rows import COVARIANCE_COLUMNS
from monodock.recording import messages as m
from monodock.recording.write import BASE_FRAME, RELIABLE, BagWriter

__all__ = [
    "DOCK_POSE_COVARIANCE_TOPIC",
    "DOCK_POSE_TOPIC",
    "PLANAR_INDEX",
    "POSE_WITH_COVARIANCE_STAMPED",
    "PoseStampedBagWriter",
    "PoseStampedRecord",
    "covariance_of_row",
    "planar_covariance",
    "pose_covariance_6x6",
    "pose_of_row",
    "read_pose_bag",
    "write_pose_bag",
]

# Relative, as opennav_docking subscribes to it: it resolves inside the docking server's namespace.
DOCK_POSE_TOPIC = "detected_dock_pose"
DOCK_POSE_COVARIANCE_TOPIC = "detected_dock_pose_with_covariance"
POSE_WITH_COVARIANCE_STAMPED = "geometry_msgs/msg/PoseWithCovarianceStamped"
# Where (x, y, yaw) sit among the 6x6 covariance's (x, y, z, rot x, rot y, rot z).
PLANAR_INDEX = (0, 1, 5)
_COVARIANCE_CELLS = ((0, 0), (0, 1), (0, 2), (1, 1), (1, 2), (2, 2))  # the order of COVARIANCE_COLUMNS


def pose_covariance_6x6(covariance: NDArray[np.float64]) -> list[float]:
    """The 36 row-major floats of a PoseWithCovariance from a 3x3 (x m, y m, yaw rad) covariance.

    The (x, y, yaw) block goes to rows and columns (0, 1, 5); z, roll and pitch (fixed by the floor, not
    measured) are zero, as in amcl's 2D poses.
    """
    cov = np.asarray(covariance, dtype=np.float64)
    if cov.shape != (3, 3):
        raise ValueError(f"pose covariance must be 3x3, got shape {cov.shape}")
    out = np.zeros((6, 6))
    out[np.ix_(PLANAR_INDEX, PLANAR_INDEX)] = cov
    return [float(v) for v in out.ravel()]


def planar_covariance(covariance: Sequence[float]) -> NDArray[np.float64]:
    """The 3x3 (x, y, yaw) block of a PoseWithCovariance's 36 row-major floats."""
    full = np.asarray(covariance, dtype=np.float64)
    if full.size != 36:
        raise ValueError(f"a pose covariance has 36 entries, got {full.size}")
    out: NDArray[np.float64] = full.reshape(6, 6)[np.ix_(PLANAR_INDEX, PLANAR_INDEX)].copy()
    return out


def _number(value: object) -> float:
    """A row's cell as a float: NaN for empty cells and None."""
    if value is None or value == "":
        return math.nan
    return float(value)  # type: ignore[arg-type]


# Image files carry no time stamp (their rows' stamp is NaN); a bag of poses without times is no use to Nav2.
UNSTAMPED_BAG = "--bag needs time-stamped frames and image files have none: give a video or a recording"


def pose_of_row(row: Mapping[str, object]) -> tuple[float, DockPose] | None:
    """(stamp, DockPose) of a valid EST.csv row (as read by csv.DictReader, or the typed rows of a live run).

    Returns:
        None when the row is not valid, or has no finite stamp or pose (nothing a docking server could use).
    """
    if row.get("valid") not in (True, "true"):
        return None
    stamp = _number(row.get("stamp"))
    x, y, yaw_deg = (_number(row.get(k)) for k in ("x_m", "y_m", "yaw_deg"))
    if not all(math.isfinite(v) for v in (stamp, x, y, yaw_deg)):
        return None
    return stamp, DockPose(x, y, math.radians(yaw_deg))


def covariance_of_row(row: Mapping[str, object]) -> NDArray[np.float64] | None:
    """The 3x3 (x, y, yaw) covariance of an EST.csv row, or None when its covariance cells are empty.

    Raises:
        InputError: the cells are present but not a covariance (not numbers, or not positive semi-definite).
    """
    cells = [_number(row.get(k)) for k in COVARIANCE_COLUMNS]
    if all(math.isnan(v) for v in cells):
        return None
    if not all(math.isfinite(v) for v in cells):
        raise InputError(f"row of frame {row.get('frame', '?')}: covariance cells {cells} are not all numbers")
    cov = np.zeros((3, 3))
    for (i, j), v in zip(_COVARIANCE_CELLS, cells, strict=True):
        cov[i, j] = cov[j, i] = v
    if np.linalg.eigvalsh(cov).min() < -1e-12 * max(1.0, float(np.abs(cov).max())):
        raise InputError(f"row of frame {row.get('frame', '?')}: covariance is not positive semi-definite")
    return cov


class PoseStampedBagWriter:
    """A rosbag2 being written with the dock poses for Nav2; a context manager.

    The bag appears at ``path`` only when the ``with`` block ends without an error (written in a temporary
    folder beside it, then renamed); an existing bag is replaced only with ``force``. Poses that come with a
    covariance are also written as PoseWithCovarianceStamped on ``covariance_topic`` (the topic appears with
    the first of them).

    Args:
        path: the bag folder to write.
        force: replace an existing ``path``.
        storage: "mcap" (default) or "sqlite3".
        frame_id: the header frame of the poses (base_link: the dock in the robot's frame).
        topic: the topic (``detected_dock_pose``, what opennav_docking reads).
        covariance_topic: the topic of the poses with their covariance.

    Attributes:
        written: PoseStamped messages written.
        written_with_covariance: PoseWithCovarianceStamped messages written.
    """

    def __init__(
        self,
        path: str | os.PathLike[str],
        *,
        force: bool = False,
        storage: str = "mcap",
        frame_id: str = BASE_FRAME,
        topic: str = DOCK_POSE_TOPIC,
        covariance_topic: str = DOCK_POSE_COVARIANCE_TOPIC,
    ) -> None:
        try:
            self._bag = BagWriter(path, storage=storage, force=force)
        except ConfigError as exc:
            raise InputError(f"bag {exc}") from None
        self.path = Path(path)
        self.frame_id, self.topic, self.covariance_topic = frame_id, topic, covariance_topic
        self.written = 0
        self.written_with_covariance = 0
        self._open = False
        self._conn: Connection | None = None
        self._cov_conn: Connection | None = None

    def __enter__(self) -> PoseStampedBagWriter:
        self._bag.__enter__()
        self._open = True
        self._conn = self._bag.connect(self.topic, m.POSE_STAMPED, RELIABLE)
        return self

    def write(self, stamp: float, pose: DockPose, covariance: NDArray[np.float64] | None = None) -> None:
        """Add one PoseStamped: header stamp ``stamp`` (the image's, seconds), position (x, y, 0), yaw about z.

        With a 3x3 ``covariance`` (x m, y m, yaw rad), also the PoseWithCovarianceStamped of the same pose.
        """
        if not self._open or self._conn is None:
            raise RuntimeError("PoseStampedBagWriter.write outside its with block")
        if not math.isfinite(stamp):
            raise ValueError(f"stamp {stamp} is not a time")
        msg = m.pose_msg(pose, stamp, self.frame_id)
        self._bag.write(self._conn, msg, stamp)
        self.written += 1
        if covariance is None:
            return
        if self._cov_conn is None:
            self._cov_conn = self._bag.connect(self.covariance_topic, POSE_WITH_COVARIANCE_STAMPED, RELIABLE)
        types = self._bag.typestore.types
        with_cov = types[POSE_WITH_COVARIANCE_STAMPED](
            header=msg.header,
            pose=types["geometry_msgs/msg/PoseWithCovariance"](
                pose=msg.pose, covariance=np.array(pose_covariance_6x6(covariance), dtype=np.float64)
            ),
        )
        self._bag.write(self._cov_conn, with_cov, stamp)
        self.written_with_covariance += 1

    def write_row(self, row: Mapping[str, object]) -> bool:
        """Add an EST.csv row's pose if it is valid (see pose_of_row), with its covariance when it has one."""
        got = pose_of_row(row)
        if got is None:
            return False
        self.write(*got, covariance_of_row(row))
        return True

    def __exit__(
        self, exc_type: type[BaseException] | None, exc: BaseException | None, tb: TracebackType | None
    ) -> None:
        if self._open:
            self._open = False
            self._bag.__exit__(exc_type, exc, tb)


def write_pose_bag(
    path: str | os.PathLike[str], rows: Iterable[Mapping[str, object]], *, force: bool = False, storage: str = "mcap"
) -> int:
    """Write the valid rows of an estimate run (EST.csv rows) as a Nav2 ``detected_dock_pose`` bag.

    Rows with a covariance are also written on ``detected_dock_pose_with_covariance`` (PoseStampedBagWriter).

    Returns:
        The number of poses written (rows that are invalid or without a stamp are left out).
    """
    with PoseStampedBagWriter(path, force=force, storage=storage) as bag:
        for row in rows:
            bag.write_row(row)
    return bag.written


@dataclass(frozen=True)
class PoseStampedRecord:
    """One PoseStamped or PoseWithCovarianceStamped read back from a bag.

    Attributes:
        topic, msgtype: where it was and what it is.
        stamp, frame_id: its header.
        position, orientation: its pose.
        covariance: the 36 row-major floats of a PoseWithCovarianceStamped; None for a PoseStamped.
    """

    topic: str
    msgtype: str
    stamp: float
    frame_id: str
    position: tuple[float, float, float]
    orientation: tuple[float, float, float, float]
    covariance: tuple[float, ...] | None = None

    @property
    def pose_covariance(self) -> NDArray[np.float64] | None:
        """The 3x3 (x, y, yaw) block of the covariance, or None."""
        return None if self.covariance is None else planar_covariance(self.covariance)

    @property
    def pose(self) -> DockPose:
        """The floor-plane pose (yaw from the quaternion)."""
        x, y, z = self.position
        return DockPose.from_matrix(transforms.transform(m.matrix_from_quaternion(*self.orientation), (x, y, z)))


def read_pose_bag(path: str | os.PathLike[str], topic: str = DOCK_POSE_TOPIC) -> list[PoseStampedRecord]:
    """The PoseStamped or PoseWithCovarianceStamped messages of a bag's ``topic``, in log order.

    Raises:
        InputError: the bag cannot be read, has no such topic, or the topic holds another type.
    """

    ts = m.humble_typestore()
    try:
        with Reader(Path(path)) as reader:
            conns = [c for c in reader.connections if c.topic == topic]
            if not conns:
                raise InputError(f"{path}: no topic {topic}")
            for c in conns:
                if c.msgtype not in (m.POSE_STAMPED, POSE_WITH_COVARIANCE_STAMPED):
                    raise InputError(f"{path}: topic {topic} holds {c.msgtype}, not a stamped pose")
            out = []
            for conn, _, raw in reader.messages(connections=conns):
                msg: Any = ts.deserialize_cdr(raw, conn.msgtype)
                covariance = None
                pose = msg.pose
                if conn.msgtype == POSE_WITH_COVARIANCE_STAMPED:
                    covariance = tuple(float(v) for v in pose.covariance)
                    pose = pose.pose
                p, q = pose.position, pose.orientation
                out.append(
                    PoseStampedRecord(
                        conn.topic,
                        conn.msgtype,
                        m.header_stamp(msg),
                        str(msg.header.frame_id),
                        (float(p.x), float(p.y), float(p.z)),
                        (float(q.x), float(q.y), float(q.z), float(q.w)),
                        covariance,
                    )
                )
            return out
    except ReaderError as exc:
        raise InputError(f"cannot read bag {path}: {exc}") from exc
