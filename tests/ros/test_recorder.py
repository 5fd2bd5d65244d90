"""monodock-record-ros: its options and bag writer here (no ROS 2 in this process), and on a real ROS 2 graph
(Fast DDS, private network namespace) the bag it records of monodock_sim driven by cmd_vel, read back and checked
against the sim's ground truth in the same bag."""

from __future__ import annotations

import itertools
from pathlib import Path
from typing import Any

import numpy as np
import pytest
import yaml
from rosbags.highlevel import AnyReader
from rosbags.interfaces import QosDurability, QosReliability
from rosbags.rosbag2 import Reader
from rosbags.typesys import Stores, get_typestore

from monodock.cli.ros_record import main, record_options
from monodock.core.camera import CameraModel
from monodock.core.settings import to_argv
from monodock.errors import InputError
from monodock.recording import messages as m
from monodock.recording.write import RELIABLE, SENSOR
from monodock.ros.recorder import (
    DEFAULT_TOPICS,
    RawBagWriter,
    RecorderOptions,
    TopicSpec,
    header_stamp_ns,
    parse_topic,
    subscription_qos,
)
from private_graph import needs_graph, run_private_graph

HERE = Path(__file__).parent


# --- without ROS 2 ------------------------------------------------------------------------------


def test_topic_names_and_types_parse_and_bad_ones_are_refused() -> None:
    assert parse_topic("odom") == TopicSpec("odom")
    assert parse_topic("/monodock_dock/result") == TopicSpec("/monodock_dock/result")
    assert parse_topic("~/state:std_msgs/String") == TopicSpec("~/state", "std_msgs/msg/String")
    assert parse_topic("image:sensor_msgs/msg/Image") == TopicSpec("image", "sensor_msgs/msg/Image")
    for bad in ("", "bad topic", "1image", "/odom/", "odom:", "odom:nav_msgs", "odom:nav_msgs/msg/", "a//b"):
        with pytest.raises(InputError):
            parse_topic(bad)


def test_the_subscription_matches_every_publisher() -> None:
    # (reliable, transient_local) of each publisher -> of the subscription that matches them all.
    assert subscription_qos([(True, False)]) == (True, False)
    assert subscription_qos([(False, False)]) == (False, False)  # a camera: sensor data
    assert subscription_qos([(True, True)]) == (True, True)  # a latched result
    assert subscription_qos([(True, True), (True, False)]) == (True, False)
    assert subscription_qos([(True, False), (False, False)]) == (False, False)


def test_the_default_topics_are_a_docking_run() -> None:
    options = RecorderOptions("bag")
    assert [t.name for t in options.topics] == list(DEFAULT_TOPICS)
    for name in ("image", "camera_info", "odom", "cmd_vel", "ground_truth", "detected_dock_pose"):
        assert name in DEFAULT_TOPICS
    assert "monodock_dock/result" in DEFAULT_TOPICS  # the docking node in the recorder's namespace
    assert {"/diagnostics", "/tf", "/tf_static"} <= set(DEFAULT_TOPICS)  # absolute in every ROS 2 system
    absolute = {t for t in DEFAULT_TOPICS if t.startswith("/")}
    assert absolute == {"/diagnostics", "/tf", "/tf_static"}


def test_options_survive_the_command_line(tmp_path: Path) -> None:
    """What RecorderProcess passes to the child process is what the child parses."""
    options = RecorderOptions(
        str(tmp_path / "bag"),
        topics=(TopicSpec("odom"), TopicSpec("/cmd_vel", "geometry_msgs/msg/Twist")),
        all_topics=True,
        timestamps="header",
        distro="humble",
        duration=2.5,
        poll_period=0.1,
    )
    assert record_options(to_argv(options)) == options
    assert record_options([str(tmp_path / "b"), "--ros-args", "-r", "__ns:=/robot", "--", "--force"]).force


@pytest.mark.parametrize(
    ("args", "says"),
    [
        (["--topics", "bad topic"], "not a ROS topic name"),
        (["--topics", "odom:nav_msgs"], "not a message type"),
        (["--topics", ","], "no topic to record"),
        (["--duration", "-1"], "positive number of seconds"),
        (["--duration", "nan"], "positive number of seconds"),
        (["--distro", "noetic"], "invalid choice"),
        (["--timestamps", "publish"], "invalid choice"),
    ],
)
def test_bad_input_is_one_line_and_exit_2(
    args: list[str], says: str, tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    try:
        code = main([str(tmp_path / "bag"), *args])
    except SystemExit as exc:  # argparse's usage errors exit; ours return the code
        code = int(exc.code or 0)
    assert code == 2
    err = capsys.readouterr().err
    assert len(err.strip().splitlines()) == 1
    assert says in err
    assert not (tmp_path / "bag").exists()


def test_an_existing_output_is_refused_without_force(tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    (tmp_path / "bag").mkdir()
    (tmp_path / "bag" / "keep.txt").write_text("mine")
    assert main([str(tmp_path / "bag")]) == 2
    err = capsys.readouterr().err
    assert err.count("\n") == 1
    assert "exists" in err
    assert "--force" in err
    assert (tmp_path / "bag" / "keep.txt").read_text() == "mine"
    (tmp_path / "file").write_text("x")
    with pytest.raises(InputError, match="is a file"):
        record_options([str(tmp_path / "file" / "bag")])


def test_raw_messages_round_trip_with_kilted_definitions(tmp_path: Path) -> None:
    """CDR bytes as DDS delivers them go into the bag unchanged; the bag's definitions are Kilted's (Range has
    ``variance``, which Humble's has not) and readers decode them; header log times come from the bytes."""
    kilted = get_typestore(Stores.ROS2_KILTED)
    types = kilted.types
    stamp = types["builtin_interfaces/msg/Time"](sec=1_700_000_000, nanosec=250_000_000)
    header = types["std_msgs/msg/Header"](stamp=stamp, frame_id="rear_range")
    rng = types["sensor_msgs/msg/Range"](
        header=header, radiation_type=0, field_of_view=0.5, min_range=0.0, max_range=2.0, range=1.25, variance=0.01
    )
    twist = types["geometry_msgs/msg/Twist"](
        linear=types["geometry_msgs/msg/Vector3"](x=0.1, y=0.0, z=0.0),
        angular=types["geometry_msgs/msg/Vector3"](x=0.0, y=0.0, z=-0.2),
    )
    raw_range = bytes(kilted.serialize_cdr(rng, "sensor_msgs/msg/Range"))
    raw_twist = bytes(kilted.serialize_cdr(twist, "geometry_msgs/msg/Twist"))
    out = tmp_path / "bag"
    with RawBagWriter(out, distro="kilted") as bag:
        assert bag.has_header("sensor_msgs/msg/Range")
        assert not bag.has_header("geometry_msgs/msg/Twist")
        assert not bag.knows("my_msgs/msg/Thing")
        c_range = bag.connect("/rear_range", "sensor_msgs/msg/Range", SENSOR)
        c_twist = bag.connect("/cmd_vel", "geometry_msgs/msg/Twist", RELIABLE)
        header_ns = header_stamp_ns(raw_range)
        assert header_ns == 1_700_000_000_250_000_000
        assert header_stamp_ns(raw_range[:8]) is None
        bag.write_raw(c_range, raw_range, header_ns)
        bag.write_raw(c_twist, raw_twist, header_ns + 5_000_000)
    assert sorted(p.name for p in tmp_path.iterdir()) == ["bag"]  # no temporary folder left beside it
    assert sorted(p.name for p in out.iterdir()) == ["bag.mcap", "metadata.yaml"]
    with AnyReader([out]) as reader:
        got = {c.topic: (t, reader.deserialize(raw, c.msgtype), raw) for c, t, raw in reader.messages()}
    t, msg, raw = got["/rear_range"]
    assert bytes(raw) == raw_range
    assert t == 1_700_000_000_250_000_000
    assert msg.variance == pytest.approx(0.01)
    assert msg.range == pytest.approx(1.25)
    assert got["/cmd_vel"][1].angular.z == pytest.approx(-0.2)


def test_an_error_while_recording_leaves_no_partial_bag(tmp_path: Path) -> None:
    with pytest.raises(RuntimeError, match="boom"), RawBagWriter(tmp_path / "bag"):
        raise RuntimeError("boom")
    assert list(tmp_path.iterdir()) == []


# --- on a real ROS 2 graph ----------------------------------------------------------------------


def _read(bag: Path) -> tuple[dict[str, list[tuple[float, Any]]], dict[str, Any]]:
    """Every message of a bag by topic, as (log time in seconds, message), and each topic's connection."""
    out: dict[str, list[tuple[float, Any]]] = {}
    with AnyReader([bag]) as reader:
        connections = {c.topic: c for c in reader.connections}
        for c, t, raw in reader.messages():
            out.setdefault(c.topic, []).append((t * 1e-9, reader.deserialize(raw, c.msgtype)))
    return out, connections


def _spacing(stamps: list[float]) -> float:
    """The typical time between consecutive messages (the median: robust to a lost one)."""
    return float(np.median(np.diff(stamps)))


def _expected(stamps: list[float], rate: float) -> float:
    """How many messages a topic at ``rate`` Hz has between its first and last stamp."""
    return (stamps[-1] - stamps[0]) * rate + 1


@needs_graph()
def test_a_recorded_drive_matches_the_sims_ground_truth(tmp_path: Path) -> None:
    bag = tmp_path / "drive"
    run = run_private_graph(HERE / "graph_recorder.py", str(bag), "drive", timeout=180)
    assert run.returncode == 0, run.stderr
    assert run.first("ready")["ready"], run.stderr
    recorder = run.first("recorder")
    assert recorder["returncode"] == 0, recorder["log"]
    assert "Traceback" not in recorder["log"]
    # The sim was stopped by SIGTERM after the recorder: how it exits then is tests/ros/test_sim_node.py's business.
    sim_log = run.first("sim")["stderr"]
    # Closed by SIGINT into a complete bag, renamed into place: nothing left beside it.
    assert sorted(p.name for p in tmp_path.iterdir()) == ["drive"]
    messages, connections = _read(bag)
    for topic in ("/image", "/camera_info", "/odom", "/ground_truth", "/cmd_vel", "/battery_state", "/contact"):
        assert messages.get(topic), f"{topic} not recorded; the sim said: {sim_log}"
    # The metadata says what the bag holds.
    info = yaml.safe_load((bag / "metadata.yaml").read_text())["rosbag2_bagfile_information"]
    assert info["storage_identifier"] == "mcap"
    assert info["message_count"] == sum(len(v) for v in messages.values())
    counted = {t["topic_metadata"]["name"]: t["message_count"] for t in info["topics_with_message_count"]}
    assert counted == {k: len(v) for k, v in messages.items() if k in counted}
    assert counted.keys() == messages.keys()
    assert f"{len(messages)} topics" in recorder["summary"]
    # QoS as the publishers offer it: the camera best effort, odometry reliable.
    assert connections["/image"].ext.offered_qos_profiles[0].reliability == QosReliability.BEST_EFFORT
    assert connections["/odom"].ext.offered_qos_profiles[0].reliability == QosReliability.RELIABLE

    # Images decode to the sim camera's size, as its camera_info says; at the camera's 15 Hz.
    width, height = CameraModel.default().size
    images = messages["/image"]
    for _, msg in images[:: max(1, len(images) // 10)]:
        assert m.decode_image(msg, m.IMAGE).shape == (height, width)
    info_msg = messages["/camera_info"][0][1]
    assert (info_msg.width, info_msg.height) == (width, height)
    image_stamps = [m.header_stamp(msg) for _, msg in images]
    assert _spacing(image_stamps) == pytest.approx(1 / 15, abs=0.002)
    assert len(images) >= 0.85 * _expected(image_stamps, 15.0)  # best effort may lose a few on a busy machine
    assert images[-1][0] - images[0][0] > 4.5  # the whole drive: 1 s still, 2 s driving, 2 s stopping
    assert abs(len(messages["/camera_info"]) - len(images)) <= 0.1 * len(images)
    # The log times are the recorder's receive times, not the header stamps: they follow the stamps by at least
    # the camera's 50 ms latency (by more on a busy machine, where the sim falls behind the wall clock).
    lags = np.array([t - s for (t, _), s in zip(images, image_stamps, strict=True)])
    assert 0.04 < float(np.median(lags)) < 10.0
    odom = messages["/odom"]
    odom_stamps = [m.header_stamp(msg) for _, msg in odom]
    assert _spacing(odom_stamps) == pytest.approx(0.02, abs=0.001)
    assert len(odom) >= 0.95 * _expected(odom_stamps, 50.0)  # reliable
    assert all(b > a for a, b in itertools.pairwise(odom_stamps))

    # cmd_vel: what the driver sent, in the bag.
    sent = run.first("sent")
    cmd = messages["/cmd_vel"]
    assert 0.9 * sent["count"] <= len(cmd) <= sent["count"]
    assert all(msg.twist.linear.x == pytest.approx(0.1) for _, msg in cmd)
    first_cmd, last_cmd = cmd[0][0], cmd[-1][0]
    assert abs(first_cmd - sent["first"]) < 0.2
    assert abs(last_cmd - sent["last"]) < 0.2

    # The robot moved as commanded: at the commanded 0.1 m/s, straight ahead, about 0.2 m in the 2 s of the sim's
    # time the driver commanded (timed by the odometry's stamps, so on a busy machine too), and no farther once
    # cmd_vel stopped; odometry and the ground truth in the same bag agree on how far.
    x = np.array([msg.pose.pose.position.x for _, msg in odom])
    y = np.array([msg.pose.pose.position.y for _, msg in odom])
    speed = np.array([msg.twist.twist.linear.x for _, msg in odom])
    assert float(np.median(speed[speed > 0.05])) == pytest.approx(0.1, abs=0.01)
    moved = float(x[-1] - x[0])
    assert 0.15 < moved < 0.3
    assert abs(float(y[-1] - y[0])) < 0.02
    truth = messages["/ground_truth"]
    closer = truth[0][1].pose.position.x - truth[-1][1].pose.position.x  # the dock's distance ahead shrinks
    assert abs(closer - moved) < 0.02
    # It moved only while commanded, plus the base's latency and its 0.5 s cmd_vel time-out. Timed on the
    # recorder's clock (the log times of cmd_vel and odom), where a command comes before its effect.
    odom_log = np.array([t for t, _ in odom])
    moving = odom_log[np.flatnonzero(np.abs(np.diff(x)) > 1e-5) + 1]
    assert first_cmd < moving[0] < first_cmd + 1.0
    assert last_cmd < moving[-1] < last_cmd + 2.0
    assert moving[-1] < odom_log[-1] - 0.5  # then it stood still
    assert np.all(x[odom_log < first_cmd] == x[0])


@needs_graph()
def test_a_latched_result_is_recorded_and_sigterm_closes_the_bag(tmp_path: Path) -> None:
    bag = tmp_path / "latched"
    run = run_private_graph(HERE / "graph_recorder.py", str(bag), "latched", timeout=120)
    assert run.returncode == 0, run.stderr
    assert run.first("ready")["ready"], run.stderr
    assert run.first("recorder")["returncode"] == 0, run.first("recorder")["log"]
    messages, connections = _read(bag)
    # Published before the recorder started, and still recorded: transient local, stored as such for replay.
    ((_, result),) = messages["/monodock_dock/result"]
    assert result.message == "docked"
    assert {v.key for v in result.values} == {"lateral_cm", "gap_cm", "heading_deg", "retries"}
    qos = connections["/monodock_dock/result"].ext.offered_qos_profiles[0]
    assert qos.durability == QosDurability.TRANSIENT_LOCAL
    assert qos.reliability == QosReliability.RELIABLE
    # A volatile topic has only what was published after the recorder subscribed.
    assert [msg.data for _, msg in messages["/monodock_dock/state"]] == ["DOCKED"]
    with Reader(bag) as reader:  # rosbag2's own layout: metadata.yaml and one MCAP file
        assert reader.message_count == 2
