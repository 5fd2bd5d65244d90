"""The package's shape, as a robot sees it: what the robot side loads, in a fresh interpreter.

import-linter (``.importlinter``, run by CI) checks the import graph statically; this test checks what really
gets loaded at run time, including what is imported inside functions (the fused method's warm-up, a bundle's
ONNX sessions), which a static graph can miss.
"""

from __future__ import annotations

import json
import subprocess
import sys
import textwrap

# What the robot must never load: the simulator, training, evaluation, the designer, the sweeps' executor (local
# pools, the Dask cluster), reports, the command line, and the heavy libraries only they need.
FORBIDDEN_MONODOCK = (
    "monodock.sim",
    "monodock.learning",
    "monodock.evaluation",
    "monodock.design",
    "monodock.compute",
    "monodock.report",
)
FORBIDDEN_THIRD_PARTY = ("matplotlib", "sklearn", "skl2onnx", "pyarrow", "joblib", "dask", "distributed")
ROBOT_SIDE = (
    "monodock.core",
    "monodock.perception",
    "monodock.estimation",
    "monodock.dock",
    "monodock.io",
    "monodock.recording",
    "monodock.ros",
)

_SCRIPT = textwrap.dedent(
    """
    import json, sys, types

    # Stand-ins for rclpy and the message packages, so that the nodes' modules import in full without ROS 2.
    class Node:
        def __init__(self, *args, **kwargs):
            pass
    for name in ("rclpy", "rclpy.node", "rclpy.lifecycle", "rclpy.utilities"):
        sys.modules[name] = types.ModuleType(name)
    sys.modules["rclpy.node"].Node = Node
    sys.modules["rclpy.lifecycle"].LifecycleNode = Node
    sys.modules["rclpy.utilities"].remove_ros_args = lambda args: args

    import monodock.dock
    import monodock.estimation
    import monodock.io.frames
    import monodock.io.live
    import monodock.cli.ros_nodes  # the entry points of monodock-ros and monodock-dock-ros
    import monodock.ros.detector
    import monodock.ros.dock_node
    from monodock.core.camera import CameraModel
    from monodock.core.layout import DockLayout
    from monodock.core.robot import RobotConfig
    from monodock.estimation.estimator import Estimator
    from monodock.estimation.fused import FusionTables
    from monodock.estimation.methods import MethodSetup, build_methods

    # Run what runs first on a robot: the fused method's warm-up (two synthetic views through every kernel).
    camera, layout, robot = CameraModel.default(), DockLayout.default(), RobotConfig.default()
    fused = build_methods(("fused",), MethodSetup(camera, layout, robot, tables=FusionTables(0.22)))
    Estimator(camera, layout, robot, fused).warm_up()
    print(json.dumps(sorted(sys.modules)))
    """
)


def test_the_robot_side_loads_no_simulator_training_report_or_their_libraries() -> None:
    done = subprocess.run([sys.executable, "-c", _SCRIPT], capture_output=True, text=True, timeout=300, check=False)
    assert done.returncode == 0, done.stderr
    loaded = json.loads(done.stdout.strip().splitlines()[-1])
    ours = [m for m in loaded if m.startswith("monodock.")]
    assert "monodock.ros.detector" in ours  # the stand-ins let the nodes import in full
    assert "monodock.perception.refine" in ours  # the warm-up ran the fused method
    wrong = [m for m in ours if m.startswith(FORBIDDEN_MONODOCK)]
    assert wrong == []
    # Beside the robot side, only the nodes' command line (their entry points) and the errors.
    allowed = ("monodock.errors", "monodock.cli", "monodock.cli.options", "monodock.cli.ros_nodes")
    outside = [m for m in ours if not m.startswith(ROBOT_SIDE) and m not in allowed]
    assert outside == []
    heavy = sorted({m.split(".")[0] for m in loaded} & set(FORBIDDEN_THIRD_PARTY))
    assert heavy == []


def test_import_monodock_is_cheap_and_names_the_public_api() -> None:
    """``import monodock`` loads nothing but the errors; each public name loads its module on first use."""
    script = textwrap.dedent(
        """
        import json, sys
        import monodock
        before = sorted(m for m in sys.modules if m.startswith("monodock"))
        names = {name: type(getattr(monodock, name)).__name__ for name in monodock.__all__}
        print(json.dumps([before, names]))
        """
    )
    done = subprocess.run([sys.executable, "-c", script], capture_output=True, text=True, timeout=120, check=False)
    assert done.returncode == 0, done.stderr
    before, names = json.loads(done.stdout.strip().splitlines()[-1])
    assert before == ["monodock", "monodock.errors"]
    assert names["make_estimator"] == "function"
    assert names["load_bundle"] == "function"
    assert names["DockPose"] == "type"
