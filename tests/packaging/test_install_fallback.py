"""An install where the ROS 2 interfaces cannot be built (no working C compiler): monodock still installs, says so in
one line, and its nodes run without the Nav2 actions and TF, saying what is missing (setup.py, interfaces/build.py).
"""

from __future__ import annotations

import os
import shutil
import subprocess
import sys
import zipfile
from pathlib import Path

import pytest

from private_graph import needs_graph, run_private_graph

ROOT = Path(__file__).resolve().parents[2]
UV = Path(sys.executable).with_name("uv")


def _clean_copy(into: Path) -> Path:
    """The repository's tracked files (no venv, no earlier build), as a fresh clone has them."""
    listed = subprocess.run(["git", "ls-files", "-z"], cwd=ROOT, capture_output=True, check=True).stdout
    for name in listed.decode().split("\0"):
        if name and (ROOT / name).is_file():
            (into / name).parent.mkdir(parents=True, exist_ok=True)
            shutil.copy2(ROOT / name, into / name)
    return into


@pytest.mark.slow
@pytest.mark.skipif(not UV.is_file(), reason="uv is not installed beside this Python (requirements/tools.txt)")
def test_without_a_compiler_monodock_installs_without_the_interfaces_and_says_so(tmp_path: Path) -> None:
    tree = _clean_copy(tmp_path / "src")
    env = {**os.environ, "CC": "/bin/false", "CXX": "/bin/false"}
    env.pop("COLCON", None)
    built = subprocess.run(
        [str(UV), "build", "--wheel", "-v", "--out-dir", str(tmp_path / "dist"), str(tree)],
        capture_output=True,
        text=True,
        env=env,
        timeout=600,
        check=False,
    )
    assert built.returncode == 0, built.stderr[-3000:]
    said = [line for line in built.stderr.splitlines() if "interfaces were not built" in line]
    assert len(said) == 1, built.stderr[-3000:]
    assert said[0].startswith("warning: monodock's ROS 2 interfaces were not built (")
    assert "the Nav2 action servers and TF will be unavailable" in said[0]
    # The build's own account is in the log it names: the compiler CMake could not use.
    log = tree / "build" / "ros_interfaces" / "build.log"
    assert str(log) in said[0]
    assert "/bin/false" in log.read_text(encoding="utf-8")
    (wheel,) = (tmp_path / "dist").glob("*.whl")
    assert wheel.name.endswith("-py3-none-any.whl")  # no compiled interfaces: a pure wheel
    names = zipfile.ZipFile(wheel).namelist()
    assert any(n.startswith("monodock/ros/") for n in names)
    assert not any(n.startswith(("nav2_msgs/", "tf2_msgs/")) for n in names)


@pytest.mark.slow
@needs_graph()
def test_without_the_interfaces_the_nodes_run_and_say_what_is_missing() -> None:
    run = run_private_graph(ROOT / "tests" / "ros" / "graph_without_interfaces.py", timeout=180)
    assert run.returncode == 0, run.stderr
    graph = run.first("graph")
    # The services remain; the actions and TF do not exist.
    assert {"/monodock_dock/dock", "/monodock_dock/undock", "/monodock_detector/toggle"} <= set(graph["services"])
    assert not any("dock_robot" in s for s in graph["services"]), graph["services"]
    assert "/tf" not in graph["topics"]
    assert "/tf_static" not in graph["topics"]
    assert "/detected_dock_pose" in graph["topics"]
    nodes = {r["name"]: r for r in run.records if r["kind"] == "node"}
    for name, node in nodes.items():
        assert node["returncode"] == 0, (name, node["stderr"])
        assert "Traceback" not in node["stderr"], (name, node["stderr"])
    missing = "No module named 'nav2_msgs'"
    assert nodes["dock"]["stderr"].count("no dock_robot/undock_robot action servers") == 1
    assert missing in nodes["dock"]["stderr"]
    for name in ("dock", "detector"):
        assert nodes[name]["stderr"].count("camera mount from the robot file only: no /tf_static") == 1, name
    assert nodes["sim"]["stderr"].count("no /tf:") == 1
