"""Nav2-ready output: the estimates as geometry_msgs/PoseStamped on ``detected_dock_pose`` in a rosbag2.

Nav2's docking server (opennav_docking) takes the dock's pose from an external detector on the topic
``detected_dock_pose``: a PoseStamped in the robot's frame whose header stamp is the stamp of the image it was
seen in. The bag written here holds exactly that, one message per valid estimate, so it can be replayed into a
docking server (``ros2 bag play``) or compared with its own detector.
"""

from __future__ import annotations

import math
import os
from collections.abc import Iterable, Mapping
from contextlib import ExitStack
from dataclasses import dataclass
from pathlib import Path
from types import TracebackType
from typing import Any

from monodock import transforms
from monodock.atomic import atomic_directory
from monodock.errors import InputError
from monodock.pose import DockPose
from monodock.recording import messages as m
from monodock.recording.write import _RELIABLE, BASE_FRAME, STORAGES, _lift_bag

__all__ = [
    "DOCK_POSE_TOPIC",
    "PoseStampedBagWriter",
    "PoseStampedRecord",
    "pose_of_row",
    "read_pose_bag",
    "write_pose_bag",
]

# Relative, as opennav_docking subscribes to it: it resolves inside the docking server's namespace.
DOCK_POSE_TOPIC = "detected_dock_pose"


def _number(value: object) -> float:
    """A row's cell as a float: NaN for empty cells and None."""
    if value is None or value == "":
        return math.nan
    return float(value)  # type: ignore[arg-type]


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


class PoseStampedBagWriter:
    """A rosbag2 being written with the dock poses for Nav2; a context manager.

    The bag appears at ``path`` only when the ``with`` block ends without an error (written in a temporary
    folder beside it, then renamed); an existing bag is replaced only with ``force``.

    Args:
        path: the bag folder to write.
        force: replace an existing ``path``.
        storage: "mcap" (default) or "sqlite3".
        frame_id: the header frame of the poses (base_link: the dock in the robot's frame).
        topic: the topic (``detected_dock_pose``, what opennav_docking reads).
    """

    def __init__(
        self,
        path: str | os.PathLike[str],
        *,
        force: bool = False,
        storage: str = "mcap",
        frame_id: str = BASE_FRAME,
        topic: str = DOCK_POSE_TOPIC,
    ) -> None:
        if storage not in STORAGES:
            raise InputError(f"bag storage '{storage}' is unknown ({', '.join(STORAGES)})")
        self.path = Path(path)
        self.force, self.storage, self.frame_id, self.topic = force, storage, frame_id, topic
        self.written = 0
        self._stack: ExitStack | None = None
        self._writer: Any = None
        self._conn: Any = None
        self._tmp: Path | None = None

    def __enter__(self) -> PoseStampedBagWriter:
        from rosbags.rosbag2 import Writer

        stack = ExitStack()
        try:
            self._tmp = stack.enter_context(atomic_directory(self.path, force=self.force))
            # Version 8 stores QoS as the integers Humble's rosbag2 reads (as recording.write_recording does).
            writer = Writer(self._tmp / self.path.name, version=8, storage_plugin=STORAGES[self.storage])
            writer.open()
            self._conn = writer.add_connection(
                self.topic, m.POSE_STAMPED, typestore=m.humble_typestore(), offered_qos_profiles=[_RELIABLE]
            )
        except BaseException:
            stack.close()
            raise
        self._writer, self._stack = writer, stack
        return self

    def write(self, stamp: float, pose: DockPose) -> None:
        """Add one PoseStamped: header stamp ``stamp`` (the image's, seconds), position (x, y, 0), yaw about z."""
        if self._writer is None:
            raise RuntimeError("PoseStampedBagWriter.write outside its with block")
        if not math.isfinite(stamp):
            raise ValueError(f"stamp {stamp} is not a time")
        msg = m.pose_msg(pose, stamp, self.frame_id)
        self._writer.write(self._conn, round(stamp * 1e9), m.humble_typestore().serialize_cdr(msg, m.POSE_STAMPED))
        self.written += 1

    def write_row(self, row: Mapping[str, object]) -> bool:
        """Add an EST.csv row's pose if it is valid (see pose_of_row); whether it was written."""
        got = pose_of_row(row)
        if got is None:
            return False
        self.write(*got)
        return True

    def __exit__(
        self, exc_type: type[BaseException] | None, exc: BaseException | None, tb: TracebackType | None
    ) -> None:
        stack, writer, tmp = self._stack, self._writer, self._tmp
        self._stack = self._writer = None
        if stack is None or tmp is None:
            return
        try:
            writer.close()
            if exc is None:
                bag = tmp / self.path.name
                tmp.chmod(bag.stat().st_mode & 0o777)
                _lift_bag(tmp, bag)
        except BaseException as err:
            stack.__exit__(type(err), err, err.__traceback__)
            raise
        # Renames the folder into place, or (after an error in the with block) removes it.
        stack.__exit__(exc_type, exc, tb)


def write_pose_bag(
    path: str | os.PathLike[str], rows: Iterable[Mapping[str, object]], *, force: bool = False, storage: str = "mcap"
) -> int:
    """Write the valid rows of an estimate run (EST.csv rows) as a Nav2 ``detected_dock_pose`` bag.

    Returns:
        The number of poses written (rows that are invalid or without a stamp are left out).
    """
    with PoseStampedBagWriter(path, force=force, storage=storage) as bag:
        for row in rows:
            bag.write_row(row)
    return bag.written


@dataclass(frozen=True)
class PoseStampedRecord:
    """One PoseStamped read back from a bag: topic, type, header stamp and frame, position and orientation."""

    topic: str
    msgtype: str
    stamp: float
    frame_id: str
    position: tuple[float, float, float]
    orientation: tuple[float, float, float, float]

    @property
    def pose(self) -> DockPose:
        """The floor-plane pose (yaw from the quaternion)."""
        x, y, z = self.position
        return DockPose.from_matrix(transforms.transform(m.matrix_from_quaternion(*self.orientation), (x, y, z)))


def read_pose_bag(path: str | os.PathLike[str], topic: str = DOCK_POSE_TOPIC) -> list[PoseStampedRecord]:
    """The PoseStamped messages of a bag's ``topic``, in log order.

    Raises:
        InputError: the bag cannot be read, or has no such topic.
    """
    from rosbags.rosbag2 import Reader, ReaderError

    ts = m.humble_typestore()
    try:
        with Reader(Path(path)) as reader:
            conns = [c for c in reader.connections if c.topic == topic]
            if not conns:
                raise InputError(f"{path}: no topic {topic}")
            out = []
            for conn, _, raw in reader.messages(connections=conns):
                msg: Any = ts.deserialize_cdr(raw, conn.msgtype)
                p, q = msg.pose.position, msg.pose.orientation
                out.append(
                    PoseStampedRecord(
                        conn.topic,
                        conn.msgtype,
                        m.header_stamp(msg),
                        str(msg.header.frame_id),
                        (float(p.x), float(p.y), float(p.z)),
                        (float(q.x), float(q.y), float(q.z), float(q.w)),
                    )
                )
            return out
    except ReaderError as exc:
        raise InputError(f"cannot read bag {path}: {exc}") from exc
