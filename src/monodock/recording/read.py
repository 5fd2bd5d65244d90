"""Reading any robot's recording: rosbag2 (MCAP or sqlite3) or ROS 1 bags, complete or cut short.

Topics are found by message type when the bag has exactly one of a kind (Image and CompressedImage both count
as images), or named by the caller. Stamps come from the messages' ``header.stamp``, never from the bag's
receive time. A bag cut short is read up to the cut, with a warning; a frame that cannot be decoded becomes a
Frame with the reason and the rest carry on.
"""

from __future__ import annotations

import dataclasses
import os
from collections import deque
from collections.abc import Collection, Iterator, Sequence
from pathlib import Path
from typing import Any, Protocol

import numpy as np
from numpy.typing import ArrayLike, NDArray
from rosbags.highlevel import AnyReader

from monodock.core import transforms
from monodock.core.camera import CameraModel
from monodock.core.closing import Closing
from monodock.core.frame import Frame
from monodock.core.pose import DockPose
from monodock.core.robot import Mount, RobotConfig
from monodock.core.scan import LaserScan
from monodock.errors import InputError
from monodock.recording import messages as m
from monodock.recording.salvage import Salvage, SalvageError, sniff

__all__ = ["RECORDING_SUFFIXES", "Recording", "is_recording", "open_recording", "pair_nearest"]

RECORDING_SUFFIXES = (".mcap", ".db3", ".bag")
_SUFFIX = {"mcap": ".mcap", "sqlite3": ".db3", "ros1": ".bag"}
_STORAGE_SUFFIXES = (".mcap", ".db3")


def is_recording(path: str | os.PathLike[str]) -> bool:
    """Whether a path looks like a recording: a rosbag2 folder (with metadata.yaml), an .mcap, .db3 or .bag file."""
    p = Path(path)
    if p.is_dir():
        return (p / "metadata.yaml").is_file()
    return p.suffix.lower() in RECORDING_SUFFIXES


def pair_nearest(image_stamps: ArrayLike, scan_stamps: ArrayLike, tolerance_s: float) -> NDArray[np.int64]:
    """For each image stamp the index of the scan nearest in time, or -1 when none is within ``tolerance_s``.

    Args:
        image_stamps: shape (N,), seconds.
        scan_stamps: shape (M,), seconds, in any order.
        tolerance_s: the largest time difference that still pairs, seconds.

    Returns:
        Indices into ``scan_stamps``, shape (N,); on a tie the earlier scan.
    """
    img = np.asarray(image_stamps, dtype=np.float64).ravel()
    scans = np.asarray(scan_stamps, dtype=np.float64).ravel()
    out = np.full(img.shape, -1, dtype=np.int64)
    if scans.size == 0 or img.size == 0:
        return out
    order = np.argsort(scans, kind="stable")
    s = scans[order]
    right = np.clip(np.searchsorted(s, img, side="left"), 0, s.size - 1)
    left = np.clip(right - 1, 0, s.size - 1)
    d_left, d_right = np.abs(img - s[left]), np.abs(s[right] - img)
    best = np.where(d_left <= d_right, left, right)
    ok = np.minimum(d_left, d_right) <= tolerance_s
    out[ok] = order[best[ok]]
    return out


# --- sources: rosbags' reader for sound files, the salvage scanner for damaged ones -------------------


RawMessage = tuple[str, int, bytes]  # topic, receive time (ns), serialised message


class _Source(Protocol):
    ros1: bool
    topics: dict[str, tuple[str, int]]

    def messages(self, topics: Collection[str]) -> Iterator[RawMessage]: ...

    def deserialize(self, raw: bytes, msgtype: str) -> Any: ...

    def close(self) -> None: ...


class _ReaderSource:
    """A sound bag, through rosbags' AnyReader (indexes, footers, metadata)."""

    def __init__(self, path: Path) -> None:
        self.reader = AnyReader([path], default_typestore=m.humble_typestore())
        self.reader.open()
        self.ros1 = not self.reader.is2
        self.topics: dict[str, tuple[str, int]] = {}
        self.connections: dict[str, list[Any]] = {}
        for name, info in self.reader.topics.items():
            msgtype = info.msgtype or (info.connections[0].msgtype if info.connections else "")
            self.topics[name] = (m.normalize_msgtype(msgtype), int(info.msgcount))
            self.connections[name] = list(info.connections)

    def messages(self, topics: Collection[str]) -> Iterator[RawMessage]:
        conns = [c for t in topics for c in self.connections.get(t, [])]
        if not conns:  # AnyReader reads every topic when given none
            return
        for conn, stamp, raw in self.reader.messages(connections=conns):
            yield conn.topic, int(stamp), bytes(raw)

    def deserialize(self, raw: bytes, msgtype: str) -> Any:
        return self.reader.deserialize(raw, msgtype)

    def close(self) -> None:
        self.reader.close()


class _SalvageSource:
    """A damaged bag (or a bag rosbags cannot open), scanned record by record from the start of each file."""

    def __init__(self, paths: Sequence[Path], kind: str) -> None:
        self.parts = [Salvage(p, kind) for p in paths]
        self.ros1 = kind == "ros1"
        self.topics: dict[str, tuple[str, int]] = {}
        for part in self.parts:
            for cid, c in part.connections.items():
                _, n = self.topics.get(c.topic, (c.msgtype, 0))
                self.topics[c.topic] = (c.msgtype, n + part.counts.get(cid, 0))
        self.typestores = [p.typestore() for p in self.parts]
        self.reason = next((p.reason for p in self.parts if p.reason), None)
        self.total = sum(p.total for p in self.parts)

    def messages(self, topics: Collection[str]) -> Iterator[RawMessage]:
        for part in self.parts:
            ids = {cid: c.topic for cid, c in part.connections.items() if c.topic in topics}
            for cid, stamp, raw in part.messages(ids):
                yield ids[cid], stamp, raw

    def deserialize(self, raw: bytes, msgtype: str) -> Any:
        last: Exception | None = None
        for store in self.typestores:
            try:
                return store.deserialize_ros1(raw, msgtype) if self.ros1 else store.deserialize_cdr(raw, msgtype)
            except Exception as exc:  # a definition that does not fit: try the next file's
                last = exc
        raise m.DecodeError(str(last))

    def close(self) -> None:
        pass


def _storage_files(folder: Path) -> list[Path]:
    return sorted(p for p in folder.iterdir() if p.is_file() and p.suffix.lower() in _STORAGE_SUFFIXES)


def _describe(exc: BaseException) -> str:
    text = " ".join(str(exc).split()) or type(exc).__name__
    return text.rstrip(".")


def _open_source(p: Path, warnings: list[str]) -> _Source:
    """The readable source of a path: rosbags for a sound bag, the salvage scanner when rosbags refuses it."""
    if p.is_dir():
        if (p / "metadata.yaml").is_file():
            try:
                return _ReaderSource(p)
            except Exception as exc:  # rosbags, sqlite and the OS each raise their own; all mean "unreadable"
                files = _storage_files(p)
                if not files:
                    raise InputError(f"{p}: cannot read the recording: {_describe(exc)}") from None
                return _salvaged(p, files, exc, warnings)
        files = _storage_files(p)
        if not files:
            raise InputError(f"{p}: not a recording: it has no metadata.yaml (nor an .mcap or .db3 file)")
        warnings.append(f"{p}: no metadata.yaml; reading {', '.join(f.name for f in files)} directly")
        if len(files) > 1:
            return _salvaged(p, files, None, warnings)
        p = files[0]
    kind = sniff(p)
    if kind is None:
        raise InputError(
            f"{p}: not a recording (expected a rosbag2 folder with metadata.yaml, or an .mcap, .db3 or ROS 1 .bag file)"
        )
    if p.suffix.lower() != _SUFFIX[kind]:
        # rosbags picks its reader by the file's suffix; the scanner reads by content.
        return _salvaged(p, [p], None, warnings)
    try:
        return _ReaderSource(p)
    except Exception as exc:  # as above
        return _salvaged(p, [p], exc, warnings)


def _salvaged(p: Path, files: list[Path], cause: Exception | None, warnings: list[str]) -> _SalvageSource:
    kinds = {sniff(f) for f in files}
    kind = kinds.pop() if len(kinds) == 1 else None
    if kind is None:
        raise InputError(f"{p}: not a recording (its files are not all MCAP, sqlite3 or ROS 1 bags)")
    try:
        src = _SalvageSource(files, kind)
    except (SalvageError, OSError) as exc:
        if cause is None:
            raise InputError(f"{p}: cannot read the recording: {_describe(exc)}") from None
        raise InputError(
            f"{p}: cannot read the recording ({_describe(cause)}), and nothing is readable from its start "
            f"({_describe(exc)})"
        ) from None
    if src.reason:
        warnings.append(f"{p}: recording cut short after {src.total} messages: {src.reason}")
    elif cause is not None:
        warnings.append(f"{p}: read record by record, as rosbags could not open it: {_describe(cause)}")
    return src


# --- the recording ------------------------------------------------------------------------------------


def _listing(topics: dict[str, tuple[str, int]]) -> str:
    if not topics:
        return "no topics"
    return "topics: " + ", ".join(f"{t} [{_short(mt)}]" for t, (mt, _) in sorted(topics.items()))


def _short(msgtype: str) -> str:
    """The type name as people write it, the same in ROS 1 and 2: sensor_msgs/msg/Image -> sensor_msgs/Image."""
    return msgtype.replace("/msg/", "/")


class Recording(Closing):
    """An open recording: its topics, camera model, sensor mounts, images, scans and ground truth.

    Opened by ``open_recording`` (this class under the name its callers use): a rosbag2 folder, a bare .mcap or
    .db3 file, or a ROS 1 .bag; a context manager (``with open_recording(path) as rec:``). ``warnings`` collects
    what the caller should tell the user (a bag cut short, a frame missing from tf); nothing here prints.

    Raises:
        InputError: not found, not a recording, unreadable, no image topic, an ambiguous or unknown topic.
    """

    def __init__(
        self,
        path: str | os.PathLike[str],
        *,
        image_topic: str | None = None,
        camera_info_topic: str | None = None,
        scan_topic: str | None = None,
        truth_topic: str | None = "/monodock/ground_truth",
        odometry_topic: str | None = None,
    ) -> None:
        path = Path(path)
        if not path.exists():
            raise InputError(f"recording not found: {path}")
        self.path = path
        self.warnings: list[str] = []
        self._edges: dict[tuple[str, str], NDArray[np.float64]] | None = None
        self._edges_read = False
        self._frame_ids: dict[str, str | None] = {}
        self._source = _open_source(path, self.warnings)
        try:
            self.topics: dict[str, tuple[str, int]] = dict(self._source.topics)
            self.image_topic: str = self._pick(m.IMAGE_TYPES, image_topic, "--image-topic", required=True) or ""
            self.camera_info_topic = self._pick((m.CAMERA_INFO,), camera_info_topic, "--camera-info-topic")
            self.scan_topic = self._pick((m.LASER_SCAN,), scan_topic, "--scan-topic")
            self.odometry_topic = self._pick((m.ODOMETRY,), odometry_topic, "--odometry-topic")
            self.battery_topic = self._pick((m.BATTERY_STATE,), None, "--battery-topic")
            self.truth_topic = truth_topic if truth_topic in self.topics else None
            if self.truth_topic is not None and self.topics[self.truth_topic][0] != m.POSE_STAMPED:
                raise InputError(
                    f"{path}: ground truth topic {self.truth_topic} is {_short(self.topics[self.truth_topic][0])}, "
                    f"not {_short(m.POSE_STAMPED)}"
                )
        except BaseException:
            self._source.close()
            raise

    # --- plumbing -------------------------------------------------------------------------------

    def close(self) -> None:
        """Close the bag's files."""
        self._source.close()

    def _warn(self, text: str) -> None:
        if text not in self.warnings:
            self.warnings.append(text)

    def _pick(self, types: tuple[str, ...], requested: str | None, flag: str, *, required: bool = False) -> str | None:
        names = " or ".join(t.split("/")[-1] if i else _short(t) for i, t in enumerate(types))
        if requested is not None:
            if requested not in self.topics:
                raise InputError(f"{self.path}: {flag} {requested}: no such topic ({_listing(self.topics)})")
            if self.topics[requested][0] not in types:
                raise InputError(f"{self.path}: {flag} {requested} is {_short(self.topics[requested][0])}, not {names}")
            return requested
        found = sorted(t for t, (mt, _) in self.topics.items() if mt in types)
        if len(found) > 1:
            found = [t for t in found if self.topics[t][1] > 0] or found
        if len(found) > 1:
            raise InputError(f"{self.path}: several {names} topics ({', '.join(found)}); choose one with {flag}")
        if found:
            return found[0]
        if required:
            raise InputError(f"{self.path}: no {names} topic ({_listing(self.topics)})")
        return None

    def _raw(self, topic: str, *, label: str = "") -> Iterator[RawMessage]:
        """The topic's messages in bag order; a read error ends them with a warning instead of an exception."""
        n = 0
        try:
            for item in self._source.messages([topic]):
                n += 1
                yield item
        except Exception as exc:  # each storage library has its own errors; all mean the data ends here
            self._warn(f"{self.path}: recording cut short after {n} {label or topic} messages: {_describe(exc)}")

    def _decoded(self, topic: str) -> Iterator[tuple[Any, int]]:
        """The topic's messages, deserialised; one that does not deserialise is skipped with a warning."""
        msgtype = self.topics[topic][0]
        for _, receive, raw in self._raw(topic):
            try:
                yield self._source.deserialize(raw, msgtype), receive
            except Exception as exc:  # rosbags' deserialisers raise several kinds on bad bytes
                self._warn(f"{self.path}: {topic}: skipped a message that does not decode: {_describe(exc)}")

    def _first(self, topic: str | None) -> Any | None:
        if topic is None:
            return None
        return next((msg for msg, _ in self._decoded(topic)), None)

    # --- contents -------------------------------------------------------------------------------

    def camera(self) -> CameraModel | None:
        """The camera model of the first CameraInfo; None without a camera_info topic or with an uncalibrated one.

        Raises:
            InputError: the CameraInfo holds an invalid calibration.
        """
        msg = self._first(self.camera_info_topic)
        if msg is None:
            return None
        name = (self.camera_info_topic or "").strip("/").split("/")[0] or "camera"
        try:
            camera = m.camera_from_msg(msg, name)
        except m.DecodeError as exc:
            raise InputError(f"{self.path}: {self.camera_info_topic}: {exc}") from None
        if camera is None:
            self._warn(f"{self.path}: {self.camera_info_topic} is uncalibrated (K is all zero)")
        return camera

    def _tf_edges(self) -> dict[tuple[str, str], NDArray[np.float64]] | None:
        """parent_T_child of every static transform, or None when the recording has no /tf_static (cached)."""
        if not self._edges_read:
            self._edges = self._read_tf_edges()
            self._edges_read = True
        return self._edges

    def _read_tf_edges(self) -> dict[tuple[str, str], NDArray[np.float64]] | None:
        topics = [t for t, (mt, _) in self.topics.items() if mt == m.TF_MESSAGE and t.rstrip("/").endswith("tf_static")]
        if not topics:
            return None
        topic = "/tf_static" if "/tf_static" in topics else sorted(topics)[0]
        edges: dict[tuple[str, str], NDArray[np.float64]] = {}
        for msg, _ in self._decoded(topic):
            for t in msg.transforms:
                try:
                    edges[(t.header.frame_id.strip("/"), t.child_frame_id.strip("/"))] = m.transform_of(t)
                except m.DecodeError as exc:
                    self._warn(f"{self.path}: {topic}: {t.header.frame_id} -> {t.child_frame_id}: {exc}")
        return edges

    @staticmethod
    def _lookup(edges: dict[tuple[str, str], NDArray[np.float64]], base: str, frame: str) -> NDArray[np.float64] | None:
        """base_T_frame through any chain of transforms (each usable both ways), or None when not connected."""
        links: dict[str, list[tuple[str, NDArray[np.float64]]]] = {}
        for (parent, child), T in edges.items():
            links.setdefault(parent, []).append((child, T))
            links.setdefault(child, []).append((parent, transforms.invert(T)))
        seen = {base: np.eye(4)}
        queue = deque([base])
        while queue:
            a = queue.popleft()
            if a == frame:
                return seen[a]
            for b, a_T_b in links.get(a, []):
                if b not in seen:
                    seen[b] = seen[a] @ a_T_b
                    queue.append(b)
        return None

    def _frame_id(self, topic: str | None) -> str | None:
        """The header.frame_id of the topic's first message (cached)."""
        if topic is None:
            return None
        if topic not in self._frame_ids:
            msg = self._first(topic)
            self._frame_ids[topic] = None if msg is None else str(msg.header.frame_id).strip("/")
        return self._frame_ids[topic]

    def has_mounts(self, base_frame: str = "base_link") -> bool:
        """Whether /tf_static places both the image's and the scan's frames relative to ``base_frame``."""
        edges = self._tf_edges()
        if edges is None:
            return False
        frames = (self._frame_id(self.image_topic), self._frame_id(self.scan_topic))
        return all(f and self._lookup(edges, base_frame, f) is not None for f in frames)

    def robot(self, base: RobotConfig, *, base_frame: str = "base_link") -> RobotConfig:
        """The robot with its sensor mounts from /tf_static, the rest (front_offset, speeds) from ``base``.

        The image's and the scan's ``header.frame_id`` are looked up relative to ``base_frame``, through any
        chain of static transforms. The image frame is an optical frame (z forward), so the camera mount
        (camera_link) is base_T_optical with the optical rotation taken off. A frame the tf tree does not
        reach keeps ``base``'s mount, with a warning.
        """
        edges = self._tf_edges()
        if edges is None:
            self._warn(f"{self.path}: no /tf_static; sensor mounts come from the robot description")
            return base
        robot = base
        image_frame = self._frame_id(self.image_topic)
        T = self._mount_lookup(edges, base_frame, image_frame, "camera")
        if T is not None:
            link = T.copy()
            if T[2, 2] > 0.7:
                # The frame's z points up: a body frame (camera_link), not an optical one (REP 103).
                self._warn(f"{self.path}: image frame {image_frame} is not an optical frame (its z is up)")
            else:
                link[:3, :3] = T[:3, :3] @ transforms.LINK_R_OPTICAL.T
            robot = dataclasses.replace(robot, camera_mount=Mount.from_matrix(link))
        T = self._mount_lookup(edges, base_frame, self._frame_id(self.scan_topic), "LiDAR")
        if T is not None:
            robot = dataclasses.replace(robot, laser_mount=Mount.from_matrix(T))
        return robot

    def _mount_lookup(
        self, edges: dict[tuple[str, str], NDArray[np.float64]], base_frame: str, frame: str | None, sensor: str
    ) -> NDArray[np.float64] | None:
        """base_frame_T_frame for ``robot``; None for a topic without a frame, or (with a warning that the
        ``sensor``'s mount stays the robot description's) a frame the tf tree does not reach."""
        if not frame:
            return None
        T = self._lookup(edges, base_frame, frame)
        if T is None:
            self._warn(f"{self.path}: /tf_static has no {base_frame} -> {frame}; {sensor} mount from the robot")
        return T

    def _image_stamps(self) -> list[float]:
        stamps = []
        for _, receive, raw in self._raw(self.image_topic):
            s = m.raw_header_stamp(raw, ros1=self._source.ros1)
            stamps.append(s if s is not None else receive * 1e-9)
        return stamps

    def _frame(self, index: int, stamp: float, raw: bytes) -> Frame:
        msgtype = self.topics[self.image_topic][0]
        name = str(index)
        try:
            msg = self._source.deserialize(raw, msgtype)
            return Frame(name, m.header_stamp(msg), m.decode_image(msg, msgtype))
        except Exception as exc:  # a bad message costs its frame, not the recording
            return Frame(name, stamp, None, f"{self.path}: frame {index}: {_describe(exc)}")

    def images(self) -> Iterator[Frame]:
        """The images in stamp order: Frame(name=index, stamp=header stamp, mono or BGR uint8 pixels).

        A message that cannot be decoded gives a Frame without pixels and with the reason. Two passes over
        the topic: the first reads only the stamps, the second decodes in stamp order, holding back only the
        few messages that arrived out of order, so memory does not grow with the recording.
        """
        stamps = self._image_stamps()
        order = np.argsort(np.asarray(stamps, dtype=np.float64), kind="stable")
        pending: dict[int, bytes] = {}
        position = 0
        for ordinal, (_, _, raw) in enumerate(self._raw(self.image_topic)):
            if ordinal >= len(stamps):
                break
            pending[ordinal] = raw
            while position < len(order) and int(order[position]) in pending:
                j = int(order[position])
                yield self._frame(position, stamps[j], pending.pop(j))
                position += 1

    def scans(self) -> list[LaserScan]:
        """All scans of the scan topic in stamp order (header stamps; NaN and +-inf ranges kept)."""
        if self.scan_topic is None:
            return []
        out = [m.scan_from_msg(msg) for msg, _ in self._decoded(self.scan_topic)]
        return sorted(out, key=lambda s: s.stamp)

    def odometry(self) -> NDArray[np.float64]:
        """Every nav_msgs/Odometry pose of the odometry topic in stamp order, rows (stamp, x, y, yaw); (0, 4) when
        the recording has none."""
        if self.odometry_topic is None:
            return np.zeros((0, 4))
        rows = [m.odometry_from_msg(msg) for msg, _ in self._decoded(self.odometry_topic)]
        out = np.array(sorted(rows), dtype=np.float64).reshape(-1, 4)
        return out[np.all(np.isfinite(out), axis=1)]

    def charging(self) -> list[tuple[float, bool]]:
        """(stamp, charging) of each sensor_msgs/BatteryState in stamp order; empty without the topic."""
        if self.battery_topic is None:
            return []
        return sorted(m.charging_from_msg(msg) for msg, _ in self._decoded(self.battery_topic))

    def ground_truth(self) -> list[tuple[float, DockPose]]:
        """(header stamp, DockPose) of each ground-truth message in stamp order; empty without the topic."""
        if self.truth_topic is None:
            return []
        out = []
        for msg, _ in self._decoded(self.truth_topic):
            try:
                out.append((m.header_stamp(msg), m.pose_from_msg(msg)))
            except m.DecodeError as exc:
                self._warn(f"{self.path}: {self.truth_topic}: skipped a pose: {exc}")
        return sorted(out, key=lambda item: item[0])


# Opening a recording is making a Recording; callers say what they do: ``with open_recording(path) as rec:``.
open_recording = Recording
