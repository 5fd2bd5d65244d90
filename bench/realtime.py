"""Whether the simulated robot keeps up with the wall clock: real-time mode on one core.

Runs ``monodock.sim.realtime.RealTimeRunner`` on the default robot (640x480 camera at 15 fps, 50 ms camera
latency, default nuisances): the robot creeps towards the charger from 2.4 m at 0.1 m/s for ``--seconds``
simulated seconds, paced by the wall clock, every frame rendered as it is exposed and handed over when due
(what ``monodock-sim-ros`` publishes). Pinned to one CPU with OpenCV limited to one thread. Prints how many
frames were late and by how much, the rendering time against the camera period, and how busy the core was.

Run from the repo root:

    python bench/realtime.py [--seconds 20] [--rate 15] [--camera CAMERA.yaml] [--layout L.yaml] [--robot R.yaml]
        [--out FILE.md]
"""

from __future__ import annotations

import os

for _var in ("OMP_NUM_THREADS", "OPENBLAS_NUM_THREADS", "MKL_NUM_THREADS", "NUMEXPR_NUM_THREADS"):
    os.environ[_var] = "1"

import argparse  # noqa: E402
import dataclasses  # noqa: E402
import math  # noqa: E402
import sys  # noqa: E402

import numpy as np  # noqa: E402

from _common import emit, environment, fmt, markdown_table, pin_one_cpu  # noqa: E402
from monodock.core.camera import CameraModel  # noqa: E402
from monodock.core.layout import DockLayout  # noqa: E402
from monodock.core.pose2d import Pose2D  # noqa: E402
from monodock.core.robot import RobotConfig  # noqa: E402
from monodock.sim import Simulator  # noqa: E402
from monodock.sim.diffdrive import DiffDriveConfig, SimulatedRobot  # noqa: E402
from monodock.sim.realtime import RealTimeRunner, drive_arc  # noqa: E402


def main(argv: list[str] | None = None) -> int:
    p = argparse.ArgumentParser(description=__doc__.split("\n\n", maxsplit=1)[0])
    p.add_argument("--seconds", type=float, default=20.0, help="simulated seconds (20)")
    p.add_argument("--rate", type=float, default=15.0, help="camera frames per second (15)")
    p.add_argument("--camera", help="camera_info YAML (default: the simulator's 640x480 camera)")
    p.add_argument("--layout", help="dock layout YAML (default: the papers')")
    p.add_argument("--robot", help="robot YAML: mounts, front offset (default: the papers')")
    p.add_argument("--seed", type=int, default=0)
    p.add_argument("--out", help="also write the markdown here, and the raw numbers as JSON beside it")
    args = p.parse_args(argv)
    for flag, value in (("--seconds", args.seconds), ("--rate", args.rate)):
        if not (math.isfinite(value) and value > 0):
            p.error(f"{flag} must be a positive number, got {value}")
    pinned = pin_one_cpu()

    camera = CameraModel.load(args.camera) if args.camera else CameraModel.default()
    layout = DockLayout.load(args.layout) if args.layout else DockLayout.default()
    robot_config = RobotConfig.load(args.robot) if args.robot else RobotConfig.default()
    sim = Simulator(layout=layout, camera=camera, robot=robot_config, seed=args.seed)
    sim.render(sim.sample_pose())  # warm-up: compiles or loads the kernels, caches the camera's rays
    config = DiffDriveConfig(camera_rate=args.rate)
    robot = SimulatedRobot(sim, Pose2D(-2.4, 0.05, 0.03), config, np.random.default_rng(args.seed))
    report = RealTimeRunner(robot).run(args.seconds, command=drive_arc(0.1, 0.0))
    period_ms = 1e3 / args.rate
    env = environment()
    table = markdown_table(
        [
            "camera",
            "fps",
            "frames",
            "simulated s",
            "wall s",
            "late frames",
            "late mean ms",
            "late p95 ms",
            "render ms",
            "render / period",
            "core busy",
        ],
        [
            [
                f"{camera.width}x{camera.height}",
                fmt(args.rate, 0),
                str(report.frames),
                fmt(report.simulated_s, 1),
                fmt(report.wall_s, 1),
                str(report.late_frames),
                fmt(report.late_mean_ms),
                fmt(report.late_p95_ms),
                fmt(report.render_mean_ms, 1),
                fmt(report.render_mean_ms / period_ms),
                f"{report.busy:.0%}",
            ]
        ],
    )
    text = (
        f"### Real-time simulated robot\n\n`python bench/realtime.py --seconds {args.seconds:g} --rate {args.rate:g}"
        f"{' --camera ' + args.camera if args.camera else ''}{' --layout ' + args.layout if args.layout else ''}"
        f"{' --robot ' + args.robot if args.robot else ''}` "
        f"— {env['date_utc']} UTC, {env['machine']}, pinned: {pinned}. The robot drives at 0.1 m/s towards the "
        f"charger from 2.4 m; a frame is late when its rendering ends after its exposure plus the camera's "
        f"{1e3 * config.camera_latency:.0f} ms latency.\n\n{table}"
    )
    emit(text, {"environment": env, "pinned": pinned, "report": dataclasses.asdict(report)}, args.out)
    return 0


if __name__ == "__main__":
    sys.exit(main())
