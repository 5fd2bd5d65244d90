"""``monodock-record-ros`` (node ``monodock_recorder``): a rosbag2 recorder that writes MCAP, without ``ros2 bag``.

The ROS 2 wheels on PyPI bring rclpy and the messages but not rosbag2, so this node records with the ``rosbags``
library instead. It subscribes to each topic in its list once a publisher of it appears on the graph, with the
QoS the publishers offer (best effort when any of them is, transient local when all of them are: images stay
sensor-data, a latched result is still received when the recorder comes late), and takes every message as the
serialised CDR that DDS delivered (``raw=True``: nothing is deserialised). Each message is logged at its receive
time on the node's clock (as ``ros2 bag record`` does), or at its header stamp with ``timestamps="header"``.

The bag is written in a temporary folder beside the output and renamed into place when the recorder stops: on
SIGINT, SIGTERM, the end of ``duration`` or a shutdown of rclpy. Its MCAP channels carry the ``ros2msg`` schemas
of the chosen ROS distribution's message definitions (rosbags' typestore, Kilted by default: the wheels' types),
so ``rosbags``' AnyReader, Foxglove and ``ros2 bag play`` open it; ``metadata.yaml`` sits beside it.

This module imports rclpy only when a recorder starts: its options, the bag writer and ``RecorderProcess``
(the recorder in a child process, for test drivers) work without ROS 2.
"""

from __future__ import annotations

import importlib
import math
import os
import re
import signal
import struct
import subprocess
import sys
import threading
import time
from collections.abc import Iterable, Sequence
from dataclasses import dataclass
from pathlib import Path
from types import FrameType, TracebackType
from typing import Any

from rosbags.interfaces import Connection, Nodetype, Qos, QosReliability
from rosbags.typesys import Stores, get_typestore
from rosbags.typesys.store import Typestore

from monodock.core.settings import setting, to_argv
from monodock.errors import InputError
from monodock.recording.messages import normalize_msgtype
from monodock.recording.write import LATCHED, RELIABLE, SENSOR, STORAGES, BagWriter

__all__ = [
    "DEFAULT_TOPICS",
    "DISTROS",
    "NODE_NAME",
    "TIMESTAMPS",
    "RawBagWriter",
    "Recorder",
    "RecorderOptions",
    "RecorderProcess",
    "TopicSpec",
    "header_stamp_ns",
    "parse_topic",
    "run_recorder",
    "subscription_qos",
]

NODE_NAME = "monodock_recorder"

# What a docking run on the graph is made of (docs/ros2.md, the contract); relative names resolve in the
# recorder's namespace, as the nodes' do in theirs (the docking node's own topics under its name), so a recorder
# started in a robot's namespace records that robot. /diagnostics and TF are absolute in every ROS 2 system.
DEFAULT_TOPICS = (
    "image",
    "camera_info",
    "odom",
    "cmd_vel",
    "ground_truth",
    "detected_dock_pose",
    "detected_dock_pose_with_covariance",
    "monodock_dock/state",
    "monodock_dock/result",
    "battery_state",
    "contact",
    "rear_range",
    "/diagnostics",
    "/tf",
    "/tf_static",
)

DISTROS = {"kilted": Stores.ROS2_KILTED, "jazzy": Stores.ROS2_JAZZY, "humble": Stores.ROS2_HUMBLE}
TIMESTAMPS = ("receive", "header")

# What --all leaves out: every node's logging and parameter chatter.
_GRAPH_NOISE = ("/rosout", "/parameter_events")

_NAME = re.compile(r"^(~/|/)?[A-Za-z_][A-Za-z0-9_]*(/[A-Za-z_][A-Za-z0-9_]*)*$")
_TYPE = re.compile(r"^[A-Za-z_][A-Za-z0-9_]*/(msg/)?[A-Za-z][A-Za-z0-9_]*$")
_HEADER = (Nodetype.NAME, "std_msgs/msg/Header")


@dataclass(frozen=True)
class TopicSpec:
    """A topic to record: its name (relative names resolve in the recorder's namespace) and, optionally, the type
    its publishers must have (``pkg/msg/Type``); without one the type is the graph's."""

    name: str
    msgtype: str | None = None

    def __str__(self) -> str:
        return self.name if self.msgtype is None else f"{self.name}:{self.msgtype}"


def parse_topic(text: str) -> TopicSpec:
    """``name`` or ``name:pkg/msg/Type`` (``pkg/Type`` too) as a TopicSpec.

    Raises:
        InputError: the name is not a ROS topic name, or the type is not a message type's name.
    """
    name, colon, msgtype = text.strip().partition(":")
    if not _NAME.match(name):
        raise InputError(f"topic '{text}' is not a ROS topic name (letters, digits, _ and /; no digit first)")
    if not colon:
        return TopicSpec(name)
    if not _TYPE.match(msgtype):
        raise InputError(f"topic '{text}': '{msgtype}' is not a message type (pkg/msg/Type)")
    return TopicSpec(name, normalize_msgtype(msgtype))


def _topics(value: str) -> tuple[TopicSpec, ...]:
    """Comma-separated topic names (``NAME`` or ``NAME:pkg/msg/Type``) as TopicSpecs."""
    return tuple(parse_topic(t) for t in value.split(",") if t.strip())


def _seconds(value: str) -> float:
    """A positive, finite number of seconds from a word."""
    try:
        seconds = float(value)
    except ValueError:
        seconds = math.nan
    if not (math.isfinite(seconds) and seconds > 0):
        raise InputError(f"'{value}' is not a positive number of seconds")
    return seconds


@dataclass(frozen=True)
class RecorderOptions:
    """What the recorder records and how (``monodock-record-ros``'s flags).

    Attributes:
        output: the bag folder to write (refused when it exists, unless ``force``).
        topics: the topics to record, each once a publisher of it appears.
        all_topics: also record every other topic that appears (not /rosout and /parameter_events).
        force: replace an existing ``output``.
        storage: "mcap" or "sqlite3".
        distro: whose message definitions go in the bag: kilted (the PyPI wheels), jazzy or humble.
        timestamps: a message's log time: "receive" (the recorder's clock on arrival) or "header" (its header
            stamp; messages without a header keep their receive time).
        duration: stop after this many seconds (wall clock); infinite by default.
        poll_period: seconds between looks at the graph for new topics.
    """

    output: str = setting(flag="output", help="the bag folder to write (refused if it exists, unless --force)")
    topics: tuple[TopicSpec, ...] = setting(
        default_factory=lambda: tuple(TopicSpec(t) for t in DEFAULT_TOPICS),
        parse=_topics,
        show=lambda topics: ",".join(str(t) for t in topics),
        help="comma-separated topics, each NAME or NAME:pkg/msg/Type (default: a docking run's: "
        + ",".join(DEFAULT_TOPICS)
        + ")",
    )
    all_topics: bool = setting(False, flag="--all", help="also record every other topic that appears")
    force: bool = setting(False, help="replace an existing output")
    storage: str = setting("mcap", choices=tuple(STORAGES))
    distro: str = setting("kilted", choices=DISTROS, help="whose message definitions to store")
    timestamps: str = setting(
        "receive",
        choices=TIMESTAMPS,
        help="log time of a message: its receive time, or its header stamp (when it has a header)",
    )
    duration: float = setting(math.inf, parse=_seconds, help="stop after this many seconds")
    poll_period: float = setting(0.2, parse=_seconds, help="seconds between looks for new topics")

    def __post_init__(self) -> None:
        if self.distro not in DISTROS:
            raise InputError(f"distro '{self.distro}' is unknown ({', '.join(DISTROS)})")
        if self.timestamps not in TIMESTAMPS:
            raise InputError(f"timestamps '{self.timestamps}' is unknown ({', '.join(TIMESTAMPS)})")
        if not self.duration > 0:
            raise InputError(f"duration must be positive, got {self.duration}")
        if not (math.isfinite(self.poll_period) and self.poll_period > 0):
            raise InputError(f"poll period must be a positive number of seconds, got {self.poll_period}")
        if not self.topics and not self.all_topics:
            raise InputError("no topic to record (name some, or record them all)")


def subscription_qos(offers: Iterable[tuple[bool, bool]]) -> tuple[bool, bool]:
    """The (reliable, transient_local) of a subscription that every publisher's offer matches.

    Args:
        offers: each publisher's (reliable, transient_local).

    Returns:
        Reliable only when every publisher is (a reliable subscription does not match a best-effort publisher);
        transient local only when every publisher is (else it would not match the volatile ones).
    """
    listed = list(offers)
    return all(r for r, _ in listed), bool(listed) and all(t for _, t in listed)


def _bag_qos(reliable: bool, transient_local: bool) -> Qos:
    """The offered QoS stored for a topic, so that a replay offers what the publishers did."""
    if transient_local:
        return LATCHED if reliable else LATCHED._replace(reliability=QosReliability.BEST_EFFORT)
    return RELIABLE if reliable else SENSOR


def header_stamp_ns(data: bytes | memoryview) -> int | None:
    """The header stamp in nanoseconds of a ROS 2 CDR message that starts with a std_msgs/Header; None if too short.

    Exact, unlike ``recording.messages.raw_header_stamp``'s float seconds (which lose the last ~100 ns).
    """
    if len(data) < 12:
        return None
    order = "<" if data[1] & 1 else ">"  # the encapsulation's byte order: CDR_LE is 0x0001
    sec, nanosec = struct.unpack_from(f"{order}iI", data, 4)
    return int(sec) * 1_000_000_000 + int(nanosec)


_TYPESTORES: dict[str, Typestore] = {}


def _typestore(distro: str) -> Typestore:
    if distro not in _TYPESTORES:  # building one takes a while; one per process is enough
        _TYPESTORES[distro] = get_typestore(DISTROS[distro])
    return _TYPESTORES[distro]


class RawBagWriter(BagWriter):
    """A BagWriter for messages that arrive serialised (CDR as DDS delivered them), with the message definitions
    of a ROS distribution; a context manager (written beside its path, renamed into place at the end).

    Args:
        path: the bag folder to write.
        distro: kilted, jazzy or humble: the typestore whose definitions (and type hashes) describe the topics.
        storage: "mcap" or "sqlite3".
        force: replace an existing ``path``.
    """

    def __init__(
        self, path: str | os.PathLike[str], *, distro: str = "kilted", storage: str = "mcap", force: bool = False
    ) -> None:
        super().__init__(path, storage=storage, force=force)
        self.typestore = _typestore(distro)

    def knows(self, msgtype: str) -> bool:
        """Whether the typestore has ``msgtype``'s definition (a topic of another type cannot be described)."""
        return msgtype in self.typestore.fielddefs

    def has_header(self, msgtype: str) -> bool:
        """Whether ``msgtype`` starts with a std_msgs/Header (its stamp can be read without decoding)."""
        fields = self.typestore.fielddefs[msgtype][1]
        return bool(fields) and tuple(fields[0][1]) == _HEADER

    def write_raw(self, connection: Connection, data: bytes | memoryview, log_time_ns: int) -> None:
        """One serialised message, logged at ``log_time_ns`` (nanoseconds of ROS time)."""
        if self._writer is None:
            raise RuntimeError("RawBagWriter.write_raw outside its with block")
        self._writer.write(connection, log_time_ns, data)
        self.written += 1


@dataclass
class _Topic:
    name: str
    msgtype: str
    connection: Connection
    header: bool
    count: int = 0


class Recorder:
    """The recorder node and its bag: call ``poll`` to pick up new topics, spin the node, ``close`` at the end.

    Args:
        options: what to record, and where.
        node_name: the node's name (rclpy must be initialised; its ROS arguments, such as ``-r __ns:=/robot``,
            apply to the node).
    """

    def __init__(self, options: RecorderOptions, node_name: str = NODE_NAME) -> None:
        self.options = options
        self.bag = RawBagWriter(options.output, distro=options.distro, storage=options.storage, force=options.force)
        self.node = _create_node(node_name)
        self.wanted = {self.node.resolve_topic_name(t.name): t.msgtype for t in options.topics}
        self.topics: dict[str, _Topic] = {}
        self._refused: set[str] = set()
        self._subscriptions: list[Any] = []
        self._open = False

    def __enter__(self) -> Recorder:
        self.bag.__enter__()
        self._open = True
        self.node.create_timer(self.options.poll_period, self.poll)
        self.poll()
        return self

    @property
    def written(self) -> int:
        """Messages written so far."""
        return self.bag.written

    def _refuse(self, topic: str, reason: str) -> None:
        if topic not in self._refused:
            self._refused.add(topic)
            self.node.get_logger().warning(f"{topic} not recorded: {reason}")

    def poll(self) -> None:
        """Subscribe to every wanted topic that now has a publisher (the graph tells its type and QoS)."""
        if not self._open:
            return
        for name, types in self.node.get_topic_names_and_types():
            if name in self.topics or name in self._refused:
                continue
            if name not in self.wanted and not (self.options.all_topics and name not in _GRAPH_NOISE):
                continue
            publishers = self.node.get_publishers_info_by_topic(name)
            if not publishers:
                continue  # only subscribers so far: their QoS says nothing about what will be published
            required = self.wanted.get(name)
            if len(types) != 1:
                self._refuse(name, f"published with several types ({', '.join(types)})")
            elif required is not None and types[0] != required:
                self._refuse(name, f"its type is {types[0]}, not {required}")
            elif not self.bag.knows(types[0]):
                self._refuse(name, f"{types[0]} is not a {self.options.distro} message type that rosbags knows")
            else:
                self._subscribe(name, types[0], publishers)

    def _subscribe(self, name: str, msgtype: str, publishers: Sequence[Any]) -> None:
        reliable, latched = subscription_qos(_offers(publishers))
        try:
            msg_class = _message_class(msgtype)
        except (ImportError, AttributeError):
            self._refuse(name, f"its message package ({msgtype}) is not installed")
            return
        connection = self.bag.connect(name, msgtype, _bag_qos(reliable, latched))
        topic = _Topic(name, msgtype, connection, self.bag.has_header(msgtype))
        self.topics[name] = topic
        self._subscriptions.append(
            self.node.create_subscription(
                msg_class,
                name,
                lambda data: self._on_message(topic, data),
                _profile(reliable, latched),
                raw=True,
                event_callbacks=self._events(name),
            )
        )
        mode = f"{'reliable' if reliable else 'best-effort'} {'transient-local' if latched else 'volatile'}"
        print(f"recording {name} {msgtype} {mode}", flush=True)  # RecorderProcess waits for these lines

    def _events(self, name: str) -> Any:
        """A warning when a publisher that came later offers a QoS this subscription does not match."""
        from rclpy.event_handler import SubscriptionEventCallbacks  # type: ignore[import-not-found, unused-ignore]

        def incompatible(event: Any) -> None:
            self.node.get_logger().warning(
                f"{name}: a publisher offers a QoS the recording does not match ({event.last_policy_kind}); "
                "its messages are not recorded"
            )

        return SubscriptionEventCallbacks(incompatible_qos=incompatible)

    def _on_message(self, topic: _Topic, data: bytes) -> None:
        if not self._open:
            return
        log_time = self.node.get_clock().now().nanoseconds
        if topic.header and self.options.timestamps == "header":
            log_time = header_stamp_ns(data) or log_time  # a zero (unset) stamp keeps the receive time
        self.bag.write_raw(topic.connection, data, log_time)
        topic.count += 1

    def close(self) -> None:
        """Stop taking messages and finish the bag (renamed into place)."""
        if self._open:
            self._open = False
            self.bag.__exit__(None, None, None)

    def __exit__(
        self, exc_type: type[BaseException] | None, exc: BaseException | None, tb: TracebackType | None
    ) -> None:
        # What was recorded before an error is still a good bag: keep it.
        try:
            self.close()
        finally:
            self.node.destroy_node()


def _offers(publishers: Sequence[Any]) -> list[tuple[bool, bool]]:
    """Each publisher's (reliable, transient_local), from the graph's endpoint information."""
    from rclpy.qos import DurabilityPolicy, ReliabilityPolicy  # type: ignore[import-not-found, unused-ignore]

    return [
        (
            p.qos_profile.reliability == ReliabilityPolicy.RELIABLE,
            p.qos_profile.durability == DurabilityPolicy.TRANSIENT_LOCAL,
        )
        for p in publishers
    ]


def _profile(reliable: bool, transient_local: bool) -> Any:
    """The recorder's subscription QoS."""
    from rclpy.qos import (  # type: ignore[import-not-found, unused-ignore]
        DurabilityPolicy,
        HistoryPolicy,
        QoSProfile,
        ReliabilityPolicy,
    )

    return QoSProfile(
        history=HistoryPolicy.KEEP_LAST,
        depth=100,  # room for a burst while the bag writes: raw messages cost nothing to keep
        reliability=ReliabilityPolicy.RELIABLE if reliable else ReliabilityPolicy.BEST_EFFORT,
        durability=DurabilityPolicy.TRANSIENT_LOCAL if transient_local else DurabilityPolicy.VOLATILE,
    )


def _create_node(name: str) -> Any:
    from rclpy import create_node  # type: ignore[import-not-found, unused-ignore]

    return create_node(name)


def _message_class(msgtype: str) -> Any:
    """The installed Python class of ``pkg/msg/Type`` (what rclpy needs to know the type; not to decode it)."""
    package, kind, name = msgtype.split("/")
    return getattr(importlib.import_module(f"{package}.{kind}"), name)


def run_recorder(options: RecorderOptions, argv: Sequence[str] = ()) -> int:
    """Record until SIGINT, SIGTERM, ``options.duration`` or a shutdown of rclpy; the bag is complete after each.

    Prints ``recording TOPIC TYPE QOS`` for every topic as its recording starts, and a summary at the end.

    Args:
        options: what to record, and where.
        argv: the command line, program name first, for rclpy (``--ros-args`` remappings, ``use_sim_time``).

    Returns:
        0 (a bag was written, perhaps empty).
    """
    import rclpy  # type: ignore[import-not-found, unused-ignore]
    from rclpy.executors import SingleThreadedExecutor  # type: ignore[import-not-found, unused-ignore]
    from rclpy.signals import SignalHandlerOptions  # type: ignore[import-not-found, unused-ignore]

    stop = threading.Event()

    def on_signal(_signum: int, _frame: FrameType | None) -> None:
        stop.set()

    # Our own handlers: rclpy's would shut the context down mid-write; ours let the loop finish the bag.
    rclpy.init(args=list(argv) or None, signal_handler_options=SignalHandlerOptions.NO)
    previous = {s: signal.signal(s, on_signal) for s in (signal.SIGINT, signal.SIGTERM)}
    started = time.monotonic()
    try:
        with Recorder(options) as recorder:
            executor = SingleThreadedExecutor()
            executor.add_node(recorder.node)
            deadline = started + options.duration
            while not stop.is_set() and rclpy.ok() and time.monotonic() < deadline:
                executor.spin_once(timeout_sec=0.05)
            executor.remove_node(recorder.node)
            topics = {t.name: t.count for t in recorder.topics.values()}
    finally:
        for s, handler in previous.items():
            signal.signal(s, handler)
        if rclpy.ok():
            rclpy.shutdown()
    total = sum(topics.values())
    print(
        f"wrote {total} messages on {len(topics)} topics in {time.monotonic() - started:.1f} s to {options.output}",
        flush=True,
    )
    if total == 0:
        print(f"monodock-record-ros: warning: nothing was published on {len(options.topics)} topics", file=sys.stderr)
    return 0


class RecorderProcess:
    """``monodock-record-ros`` in a child process: a context manager for test drivers and scripts.

    Started on entry; ``wait_for`` blocks until it records the topics named; stopped with SIGINT on exit (or by
    ``stop``), which completes the bag. The child inherits this process's environment and network namespace.

    Args:
        options: what to record, and where.
        ros_args: ROS arguments for the recorder (remappings, ``-r __ns:=/robot``).
        stderr: where the child's log goes (default: kept, the last lines are in ``log``).
    """

    def __init__(self, options: RecorderOptions, *, ros_args: Sequence[str] = (), stderr: Any = None) -> None:
        self.options = options
        self.command = [sys.executable, "-m", "monodock.cli.ros_record", *to_argv(options)]
        if ros_args:
            self.command += ["--ros-args", *[a for a in ros_args if a != "--ros-args"]]
        self._stderr = stderr
        self.recording: dict[str, str] = {}  # topic -> its type, as the child announced them
        self.summary = ""
        self._log: list[str] = []
        self._changed = threading.Condition()
        self.process: subprocess.Popen[str] | None = None
        self.returncode: int | None = None

    @property
    def log(self) -> str:
        """The last lines the child wrote to stderr (when not sent elsewhere)."""
        return "".join(self._log[-40:])

    def start(self) -> RecorderProcess:
        """Start the recorder (it subscribes to each topic once that topic has a publisher)."""
        self.process = subprocess.Popen(
            self.command,
            stdout=subprocess.PIPE,
            stderr=subprocess.PIPE if self._stderr is None else self._stderr,
            text=True,
        )
        threading.Thread(target=self._read_stdout, daemon=True).start()
        if self._stderr is None:
            threading.Thread(target=self._read_stderr, daemon=True).start()
        return self

    def _read_stdout(self) -> None:
        assert self.process is not None
        assert self.process.stdout is not None
        for line in self.process.stdout:
            words = line.split()
            with self._changed:
                if len(words) >= 3 and words[0] == "recording":
                    self.recording[words[1]] = words[2]
                elif words[:1] == ["wrote"]:
                    self.summary = line.strip()
                self._changed.notify_all()

    def _read_stderr(self) -> None:
        assert self.process is not None
        assert self.process.stderr is not None
        for line in self.process.stderr:
            self._log.append(line)
            del self._log[:-200]

    def wait_for(self, topics: Iterable[str], timeout: float = 30.0) -> bool:
        """Wait until the recorder records every topic of ``topics`` (absolute names); False on timeout or exit."""
        wanted = set(topics)
        deadline = time.monotonic() + timeout
        with self._changed:
            while not wanted <= self.recording.keys():
                left = deadline - time.monotonic()
                if left <= 0 or self.process is None or self.process.poll() is not None:
                    return False
                self._changed.wait(min(left, 0.2))
        return True

    def stop(self, timeout: float = 30.0, sig: int = signal.SIGINT) -> int:
        """Send ``sig`` (SIGINT: what Ctrl-C sends), wait for the bag to be finished; the exit code."""
        if self.process is None:
            raise RuntimeError("RecorderProcess.stop before start")
        if self.process.poll() is None:
            self.process.send_signal(sig)
            try:
                self.process.wait(timeout=timeout)
            except subprocess.TimeoutExpired:
                self.process.kill()
                self.process.wait()
        self.returncode = self.process.returncode
        time.sleep(0.05)  # let the readers take the last lines
        return self.returncode

    def __enter__(self) -> RecorderProcess:
        return self.start()

    def __exit__(
        self, exc_type: type[BaseException] | None, exc: BaseException | None, tb: TracebackType | None
    ) -> None:
        if self.process is not None and self.returncode is None:
            self.stop()

    @property
    def path(self) -> Path:
        """The bag folder (there once the recorder has stopped cleanly)."""
        return Path(self.options.output)
