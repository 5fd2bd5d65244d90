"""The detector node over DDS: end-to-end latency, output rate against the camera's, and the offline cost of the
same method on the same frames, from one run.

Starts, in a private network namespace (only loopback, ROS_AUTOMATIC_DISCOVERY_RANGE=LOCALHOST, a ROS_DOMAIN_ID
of its own, as the ROS tests do), monodock_sim standing still in front of the dock and monodock-ros (board PnP by
default, the camera from camera_info), and listens for ``--seconds``: each image's stamp and arrival, each pose's
arrival, the detector's /diagnostics. Then, with the graph stopped, it estimates the same images with the same
method in this process (monodock.estimation, as the node runs it). Reports:

- latency from the image's stamp (the middle of its exposure) to the pose's arrival, median and p95; the camera's
  own latency (the sim's 50 ms from exposure to publication) is part of it;
- the detector's share: from the image's arrival here to its pose's arrival here (transport both ways, decoding,
  estimation, publication);
- images and poses per second, and the frames the detector dropped (it keeps only the newest when behind);
- the offline cost per frame (``Estimator.estimate``: detection and the method), and the ratio of the detector's
  share to it.

Run from the repo root:

    python bench/ros_latency.py [--seconds 20] [--method board|pnp|regression|fused] [--model BUNDLE]
        [--start "[-1.6, 0.1, 0.05]"] [--out FILE.md]
"""

from __future__ import annotations

import argparse
import json
import math
import subprocess
import sys
import tempfile
import time
from pathlib import Path
from typing import Any

import numpy as np

from _common import emit, environment, fmt, markdown_table

sys.path.insert(0, str(Path(__file__).resolve().parents[1] / "tests"))
from private_graph import rerun_in_private_network

# Each node's process gets SIGTERM when its parent ends, however it ends (PR_SET_PDEATHSIG): none outlives its run.
_ORPHANS_END = "import ctypes, signal; ctypes.CDLL(None).prctl(1, signal.SIGTERM); "
DETECTOR = (
    _ORPHANS_END + "from monodock.cli.ros_nodes import detector_main; import sys; sys.exit(detector_main(sys.argv[1:]))"
)
SIM = _ORPHANS_END + "from monodock.ros.sim_node import run_sim; import sys; run_sim(sys.argv, duration={duration})"
WARM_UP = 3.0  # s of the graph's first frames left out: discovery, the estimator's first call


def listen(args: argparse.Namespace) -> dict[str, Any]:
    """Run the graph for ``args.seconds``; what was heard (images kept for the offline run)."""
    import rclpy
    from diagnostic_msgs.msg import DiagnosticArray
    from geometry_msgs.msg import PoseStamped
    from rclpy.qos import qos_profile_sensor_data
    from sensor_msgs.msg import Image

    from monodock.core.layout import DockLayout
    from monodock.core.robot import RobotConfig
    from monodock.recording import messages as m

    folder = Path(tempfile.mkdtemp())
    DockLayout.default().save(folder / "layout.yaml")
    RobotConfig.default().save(folder / "robot.yaml")
    heard: dict[str, Any] = {"images": {}, "poses": {}, "diagnostics": [], "reasons": set()}

    def on_image(msg: Any) -> None:
        heard["images"][m.header_stamp(msg)] = (time.time(), m.decode_image(msg, m.IMAGE))

    def on_pose(msg: Any) -> None:
        heard["poses"][m.header_stamp(msg)] = time.time()

    def on_diagnostics(msg: Any) -> None:
        for s in msg.status:
            if s.name.startswith("monodock_detector"):
                values = {v.key: v.value for v in s.values}
                heard["diagnostics"].append(values)
                if values["images_in_hz"] != "0.00":  # the reason of a frame, not of waiting for one
                    heard["reasons"].add(values["no_estimate_reason"])

    rclpy.init()
    node = rclpy.create_node("ros_latency")
    node.create_subscription(Image, "image", on_image, qos_profile_sensor_data)
    node.create_subscription(PoseStamped, "detected_dock_pose", on_pose, 100)
    node.create_subscription(DiagnosticArray, "/diagnostics", on_diagnostics, 10)
    estimator = ["--model", args.model] if args.model else ["--layout", str(folder / "layout.yaml")]
    estimator += ["--robot", str(folder / "robot.yaml")] if not args.model else []
    method = ["--method", args.method] if args.method else []
    detector = subprocess.Popen([sys.executable, "-c", DETECTOR, *estimator, *method])
    end = time.monotonic() + 120.0  # the detector subscribes once its estimator is ready: then the sim starts
    while node.count_subscribers("image") < 2 and time.monotonic() < end:
        rclpy.spin_once(node, timeout_sec=0.1)
    duration = args.seconds + WARM_UP
    sim_command = [sys.executable, "-c", SIM.format(duration=duration), "--ros-args", "-p", f"start:={args.start}"]
    sim = subprocess.Popen(sim_command)
    while sim.poll() is None:
        rclpy.spin_once(node, timeout_sec=0.05)
    end = time.monotonic() + 1.0  # the last poses
    while time.monotonic() < end:
        rclpy.spin_once(node, timeout_sec=0.05)
    detector.terminate()
    detector.wait(timeout=20)
    rclpy.shutdown()
    return heard


def offline(args: argparse.Namespace, images: list[np.ndarray]) -> tuple[list[float], str, int]:
    """Seconds per frame of the same method on the same images in this process, the method's name, and how many of
    the images it gave a pose for."""
    from monodock.core.camera import CameraModel
    from monodock.core.layout import DockLayout
    from monodock.core.robot import RobotConfig
    from monodock.estimation.factory import make_estimator

    if args.model:
        estimator = make_estimator(bundle=args.model, method=args.method, camera=CameraModel.default())
    else:
        calibration = {"camera": CameraModel.default(), "layout": DockLayout.default(), "robot": RobotConfig.default()}
        estimator = make_estimator(method=args.method, **calibration)
    estimator.warm_up()
    estimator.estimate("warm-up", 0.0, images[0])  # the first call loads OpenCV's code paths
    costs, valid = [], 0
    for i, image in enumerate(images):
        start = time.perf_counter()
        result = estimator.estimate(str(i), float(i), image)
        costs.append(time.perf_counter() - start)
        valid += result.estimates[estimator.method].pose is not None
    return costs, estimator.method, valid


def report(args: argparse.Namespace, heard: dict[str, Any]) -> tuple[str, dict[str, Any]]:
    stamps = sorted(heard["images"])
    first = stamps[0] + WARM_UP if stamps else 0.0
    measured = [s for s in stamps if s >= first]
    seen = {s: heard["images"][s][0] for s in measured}
    poses = {s: t for s, t in heard["poses"].items() if s >= first}
    latency = np.array([t - s for s, t in poses.items()])
    share = np.array([t - seen[s] for s, t in poses.items() if s in seen])
    camera_side = np.array([t - s for s, t in seen.items()])
    span = (measured[-1] - measured[0]) if len(measured) > 1 else math.nan
    images_hz = (len(measured) - 1) / span
    poses_hz = (len(poses) - 1) / span
    costs, method, valid = offline(args, [heard["images"][s][1] for s in measured])
    cost = float(np.median(costs))
    last = heard["diagnostics"][-1] if heard["diagnostics"] else {}
    dropped, refused = int(last.get("frames_dropped", -1)), int(last.get("images_refused", -1))

    def row(what: str, seconds: Any) -> list[str]:
        return [what, fmt(1e3 * float(np.median(seconds)), 1), fmt(1e3 * float(np.percentile(seconds, 95)), 1)]

    rows = [
        row("image stamp → pose arrival (end to end)", latency),
        row("image stamp → image arrival (the camera's 50 ms, and the sim)", camera_side),
        row("image arrival → pose arrival (the detector's share)", share),
        row(f"offline estimate(), {method}, the same frames, this process", costs),
    ]
    text = "\n".join(
        [
            f"monodock-ros over Fast DDS (loopback, private network namespace): {method}, camera from "
            f"{'the model bundle' if args.model else 'camera_info'}, "
            f"{len(measured)} frames in {span:.1f} s after {WARM_UP:g} s of warm-up",
            "",
            markdown_table(["", "median ms", "p95 ms"], rows),
            "",
            f"rate: {poses_hz:.2f} poses/s out for {images_hz:.2f} images/s in ({len(poses)} poses, "
            f"{len(measured)} images; over the whole run the detector dropped {dropped} frame(s) when behind and "
            f"refused {refused} image(s): stale, or before camera_info); why a frame gave no pose: "
            f"{'; '.join(sorted(r for r in heard['reasons'] if r)) or '-'}; offline, the same images gave "
            f"{valid} poses",
            f"ratio: the detector's share is {np.median(share) / cost:.2f}x the offline estimate; end to end, "
            f"{np.median(latency) / cost:.1f}x",
            f"environment: {json.dumps(environment())}",
        ]
    )
    raw = {
        "method": method,
        "frames": len(measured),
        "poses": len(poses),
        "offline_poses": valid,
        "images_hz": images_hz,
        "poses_hz": poses_hz,
        "frames_dropped": dropped,
        "images_refused": refused,
        "latency_s": latency,
        "camera_side_s": camera_side,
        "detector_share_s": share,
        "offline_cost_s": costs,
    }
    return text, raw


def main() -> int:
    p = argparse.ArgumentParser(description=(__doc__ or "").split("\n\n", maxsplit=1)[0])
    p.add_argument("--seconds", type=float, default=20.0, help="seconds measured, after the warm-up (20)")
    p.add_argument("--method", help="regression, pnp, board or fused (default: board, regression with --model)")
    p.add_argument("--model", help="model bundle (for regression or fused)")
    p.add_argument("--start", default="[-1.6, 0.1, 0.05]", help="the robot's [x, y, yaw] in the dock frame")
    p.add_argument("--out", help="also write the markdown here, and the raw numbers as JSON beside it")
    p.add_argument("--inside", action="store_true", help=argparse.SUPPRESS)  # already in the private network
    args = p.parse_args()
    if not (math.isfinite(args.seconds) and args.seconds > 0):
        p.error(f"--seconds must be a positive number, got {args.seconds}")
    if not args.inside:
        return rerun_in_private_network(__file__, sys.argv[1:])
    heard = listen(args)
    if len(heard["images"]) < 10 or not heard["poses"]:
        print("ros_latency: the graph gave too few images or no pose; see the nodes' messages above", file=sys.stderr)
        return 1
    text, raw = report(args, heard)
    emit(text, raw, args.out)
    return 0


if __name__ == "__main__":
    sys.exit(main())
