"""The ROS 2 interfaces monodock builds at install time (interfaces/): nav2_msgs' docking interfaces, tf2_msgs and
bond's messages (nav2_lifecycle_manager's bonds).

Ground truth: the RIHS01 type hashes that rosbags (its own pure-Python implementation, not rosidl's) computes from
the upstream definitions' text in interfaces/upstream/, and the hash of tf2_msgs/msg/TFMessage that ROS 2 Jazzy
and Kilted installs report (``ros2 topic info -v /tf``). A type whose text or build differed from upstream's would
not talk to a real Nav2: DDS matches endpoints by type name and hash.
"""

from __future__ import annotations

import importlib.util
import json
import os
import subprocess
import sys
from pathlib import Path

import pytest
from rosbags.typesys import Stores, get_types_from_msg, get_typestore

UPSTREAM = Path(__file__).resolve().parents[2] / "interfaces" / "upstream"
# What a ROS 2 Jazzy or Kilted graph reports for /tf (rosidl's own golden tests carry the same value).
TFMESSAGE_RIHS01 = "RIHS01_e369d0f05a23ae52508854b66f6aa0437f3449d652e8cbf22d5abe85d020f087"


def _package_dir(name: str) -> Path:
    spec = importlib.util.find_spec(name)  # finds, does not import (importing sets LD_LIBRARY_PATH)
    if spec is None or not spec.submodule_search_locations:
        if os.environ.get("MONODOCK_REQUIRE_ROS_GRAPH"):
            pytest.fail(f"{name} was not built at install time (interfaces/README.md)")
        pytest.skip(f"{name} was not built at install time on this machine")
    return Path(next(iter(spec.submodule_search_locations)))


def _installed_hashes(name: str) -> dict[str, str]:
    """Every type's hash as the build wrote it (rosidl_generator_type_description; compiled into the type support)."""
    out = {}
    for path in sorted((_package_dir(name) / "type_description").glob("*.json")):
        for entry in json.loads(path.read_text(encoding="utf-8"))["type_hashes"]:
            out[entry["type_name"]] = entry["hash_string"]
    return out


def _action_types(name: str) -> dict[str, object]:
    """An action's parts as rosidl expands them (goal, result, feedback, and the service and feedback wrappers),
    from the upstream .action text, as rosbags message definitions."""
    text = (UPSTREAM / "nav2_msgs" / "action" / f"{name}.action").read_text(encoding="utf-8")
    goal, result, feedback = (part.strip() + "\n" for part in text.split("\n---"))
    base = f"nav2_msgs/action/{name}"
    types: dict[str, object] = {}
    for suffix, body in (("_Goal", goal), ("_Result", result), ("_Feedback", feedback)):
        types.update(get_types_from_msg(body, base + suffix))
    wrappers = {
        "_FeedbackMessage": f"unique_identifier_msgs/UUID goal_id\n{base}_Feedback feedback\n",
        "_SendGoal_Request": f"unique_identifier_msgs/UUID goal_id\n{base}_Goal goal\n",
        "_SendGoal_Response": "bool accepted\nbuiltin_interfaces/Time stamp\n",
        "_GetResult_Request": "unique_identifier_msgs/UUID goal_id\n",
        "_GetResult_Response": f"int8 status\n{base}_Result result\n",
    }
    for suffix, body in wrappers.items():
        types.update(get_types_from_msg(body, base + suffix))
    return types


def test_the_built_types_hash_as_upstream_s_definitions() -> None:
    # rosbags' Kilted store has tf2_msgs (and what every type here is built of); registering the upstream text of
    # TFMessage and TF2Error again would raise if it differed from rosbags' own.
    store = get_typestore(Stores.ROS2_KILTED)
    types: dict[str, object] = {}
    for n in ("TFMessage", "TF2Error"):
        types.update(
            get_types_from_msg(
                (UPSTREAM / "tf2_msgs" / "msg" / f"{n}.msg").read_text(encoding="utf-8"), f"tf2_msgs/msg/{n}"
            )
        )
    for action in ("DockRobot", "UndockRobot", "NavigateToPose"):
        types.update(_action_types(action))
    # (rosbags names no service types, so ReloadDockDatabase is checked by its blob and by loading it, below.)
    types.update(get_types_from_msg((UPSTREAM / "bond" / "msg" / "Status.msg").read_text(), "bond/msg/Status"))
    store.register(types)
    installed = {**_installed_hashes("tf2_msgs"), **_installed_hashes("nav2_msgs"), **_installed_hashes("bond")}
    assert installed["tf2_msgs/msg/TFMessage"] == TFMESSAGE_RIHS01
    checked = 0
    for type_name in types:
        assert store.hash_rihs01(type_name) == installed[type_name], type_name
        checked += 1
    assert checked >= 2 + 3 * 8 + 1


def test_the_built_types_load_their_type_support_in_a_fresh_process() -> None:
    """Imported as a node would (rclpy stays out of this test process): the C type support loads, and the goal's
    defaults are the upstream text's."""
    _package_dir("nav2_msgs")
    code = (
        "from nav2_msgs.action import DockRobot, NavigateToPose, UndockRobot\n"
        "from nav2_msgs.srv import ReloadDockDatabase\n"
        "from tf2_msgs.msg import TFMessage\n"
        "from bond.msg import Constants, Status\n"
        "for t in (DockRobot, UndockRobot, NavigateToPose, ReloadDockDatabase, TFMessage, Status, Constants):\n"
        "    type(t).__import_type_support__()\n"
        "    assert t._TYPE_SUPPORT is not None, t\n"
        "g = DockRobot.Goal()\n"
        "print(g.use_dock_id, g.navigate_to_staging_pose, g.max_staging_time, DockRobot.Result.FAILED_TO_CHARGE)\n"
        "print(Constants.DISABLE_HEARTBEAT_TIMEOUT_PARAM, NavigateToPose.Result.TIMEOUT)\n"
    )
    done = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, timeout=120, check=False)
    assert done.returncode == 0, done.stderr
    assert done.stdout.split() == ["True", "True", "1000.0", "906", "/bond_disable_heartbeat_timeout", "9003"]


def test_the_upstream_files_are_the_upstream_commits_blobs() -> None:
    """interfaces/upstream/ holds the upstream text byte for byte: each file's git blob id is the one recorded from
    the upstream commit (SOURCES.md), so the hashes above are upstream's, not a copy's."""
    import hashlib

    recorded = [line.split() for line in (UPSTREAM / "BLOBS.txt").read_text(encoding="utf-8").splitlines() if line]
    assert {path for _, path in recorded} >= {
        "tf2_msgs/msg/TFMessage.msg",
        "tf2_msgs/msg/TF2Error.msg",
        "nav2_msgs/action/DockRobot.action",
        "nav2_msgs/action/UndockRobot.action",
        "nav2_msgs/action/NavigateToPose.action",
        "nav2_msgs/srv/ReloadDockDatabase.srv",
        "bond/msg/Status.msg",
        "bond/msg/Constants.msg",
    }
    for blob, path in recorded:
        data = (UPSTREAM / path).read_bytes()
        assert hashlib.sha1(b"blob %d\0" % len(data) + data).hexdigest() == blob, path
