"""Driver (tests/ros/test_recorder.py, inside a private network namespace): monodock-record-ros on a live graph.

``graph_recorder.py OUT drive``: start monodock_sim and the recorder, stand still 1 s, drive by cmd_vel at
0.1 m/s for 2 s, fall silent 2 s (both in the sim's time, by its odometry's stamps), stop the recorder with SIGINT,
then the sim.
``graph_recorder.py OUT latched``: publish a transient-local result and a volatile state before the recorder
starts, one more state once it records, then stop it with SIGTERM.
Prints what happened as JSON lines; the test reads the bag.
"""

from __future__ import annotations

import json
import signal
import subprocess
import sys
import time
from collections.abc import Callable
from typing import Any

import rclpy
from diagnostic_msgs.msg import DiagnosticStatus, KeyValue
from geometry_msgs.msg import TwistStamped
from nav_msgs.msg import Odometry
from rclpy.qos import DurabilityPolicy, QoSProfile, ReliabilityPolicy, qos_profile_sensor_data
from sensor_msgs.msg import Image
from std_msgs.msg import String

from monodock.ros.recorder import RecorderOptions, RecorderProcess

out, mode = sys.argv[1], sys.argv[2]
SIM = "from monodock.ros.sim_node import run_sim; import sys; run_sim(sys.argv, duration=60.0)"
SENSORS = ["/image", "/camera_info", "/odom", "/ground_truth", "/battery_state", "/contact", "/cmd_vel"]


def report(kind: str, **values: Any) -> None:
    print(json.dumps({"kind": kind, **values}), flush=True)


def spin_for(node: Any, seconds: float) -> None:
    until = time.monotonic() + seconds
    while time.monotonic() < until:
        rclpy.spin_once(node, timeout_sec=0.02)


def spin_for_sim(node: Any, seconds: float, clock: list[float], then: Callable[[], None] | None = None) -> None:
    """Spin until ``seconds`` of the sim's time have passed by its odometry stamps (``clock``, the newest last),
    calling ``then()`` every 50 ms meanwhile: on a busy machine the sim runs slower than the wall clock, and the
    drive must last as long in the world it moves in. No odometry, or too little of it within 30 s of the wall
    clock, ends the driver with that one line (the test shows it) rather than a bag that puzzles the test."""
    give_up = time.monotonic() + 30.0
    start: float | None = None
    while True:
        if time.monotonic() > give_up:
            got = 0.0 if start is None else clock[-1] - start
            raise SystemExit(f"graph_recorder: {got:.2f} s of the sim's odometry in 30 s, waiting for {seconds:g} s")
        if start is None and clock:
            start = clock[-1]
        if start is not None and clock[-1] - start >= seconds:
            return
        if then is not None:
            then()
        spin_for(node, 0.05)


def stop(process: subprocess.Popen[str]) -> tuple[int, str]:
    process.send_signal(signal.SIGTERM)
    try:
        _, err = process.communicate(timeout=20)
    except subprocess.TimeoutExpired:
        process.kill()
        _, err = process.communicate()
    return process.returncode, err


def drive(node: Any) -> None:
    sim = subprocess.Popen(
        [sys.executable, "-c", SIM, "--ros-args", "-p", "start:=[-1.5, 0.05, 0.0]", "-p", "seed:=3"],
        stderr=subprocess.PIPE,
        text=True,
    )
    cmd = node.create_publisher(TwistStamped, "cmd_vel", 10)  # before the recorder looks: it records what is published
    images: list[float] = []
    node.create_subscription(Image, "image", lambda _: images.append(time.time()), qos_profile_sensor_data)
    sent: list[float] = []
    clock: list[float] = []  # the sim's time, from its odometry's stamps
    stamp = lambda msg: msg.header.stamp.sec + msg.header.stamp.nanosec * 1e-9  # noqa: E731
    node.create_subscription(Odometry, "odom", lambda msg: clock.append(stamp(msg)), 10)

    def send() -> None:
        twist = TwistStamped()  # the sim's default, as the docking node sends it
        twist.twist.linear.x = 0.1
        cmd.publish(twist)
        sent.append(time.time())

    with RecorderProcess(RecorderOptions(out)) as recorder:
        ready = recorder.wait_for(SENSORS, timeout=60)
        waited = time.monotonic()
        while ready and not images and time.monotonic() - waited < 60:  # the camera runs once the sim warmed up
            rclpy.spin_once(node, timeout_sec=0.05)
        report("ready", ready=ready and bool(images), recording=sorted(recorder.recording))
        spin_for(node, 1.0)
        if ready:
            spin_for_sim(node, 2.0, clock, then=send)  # 2 s of driving in the sim's time
            spin_for_sim(node, 2.0, clock)  # the base stops on its cmd_vel time-out
        code = recorder.stop()
        report("recorder", returncode=code, summary=recorder.summary, log=recorder.log[-3000:])
    report("sent", count=len(sent), first=sent[0] if sent else None, last=sent[-1] if sent else None)
    code, err = stop(sim)
    report("sim", returncode=code, stderr=err[-2000:])


def latched(node: Any) -> None:
    keep = QoSProfile(depth=1, reliability=ReliabilityPolicy.RELIABLE, durability=DurabilityPolicy.TRANSIENT_LOCAL)
    result = node.create_publisher(DiagnosticStatus, "/monodock_dock/result", keep)
    state = node.create_publisher(String, "/monodock_dock/state", 10)
    values = {"lateral_cm": "0.4", "gap_cm": "0.1", "heading_deg": "0.3", "retries": "0"}
    result.publish(
        DiagnosticStatus(
            level=DiagnosticStatus.OK,
            name="monodock_dock",
            message="docked",
            values=[KeyValue(key=k, value=v) for k, v in values.items()],
        )
    )
    state.publish(String(data="BEFORE"))  # volatile, before the recorder exists: not in the bag
    with RecorderProcess(RecorderOptions(out)) as recorder:
        ready = recorder.wait_for(["/monodock_dock/result", "/monodock_dock/state"], timeout=30)
        report("ready", ready=ready, recording=sorted(recorder.recording))
        spin_for(node, 0.5)  # the state subscription matches the publisher
        state.publish(String(data="DOCKED"))
        spin_for(node, 1.0)
        code = recorder.stop(sig=signal.SIGTERM)
        report("recorder", returncode=code, summary=recorder.summary, log=recorder.log[-3000:])


rclpy.init()
driver = rclpy.create_node("driver")
{"drive": drive, "latched": latched}[mode](driver)
driver.destroy_node()
rclpy.shutdown()
