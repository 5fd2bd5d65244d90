"""monodock as a ROS 2 package (package.xml, ament_python): a colcon workspace builds it, the ament index finds it,
and its executables are where ``ros2 run monodock NAME`` looks for them (docs/colcon.md).

The build tests need colcon in this venv (requirements/colcon.txt). They skip without it, except where
MONODOCK_REQUIRE_COLCON is set: .ci/run installs colcon and sets it. The ``ros2`` command line is not among the
ROS 2 wheels on PyPI; where it is missing, its lookup (the package's prefix from the ament index, then
``lib/monodock/NAME``) is done with ament_index_python, as ros2pkg does it.
"""

from __future__ import annotations

import os
import re
import shutil
import subprocess
import sys
import tomllib
import xml.etree.ElementTree as ET
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[2]
PROJECT = tomllib.loads((ROOT / "pyproject.toml").read_text(encoding="utf-8"))["project"]
EXECUTABLES = sorted(PROJECT["scripts"])
COLCON = Path(sys.executable).with_name("colcon")
# The environment of one of the workspace's users: its setup script sourced, nothing of another workspace or a
# sourced ROS 2 around it, and no COLCON (colcon sets it for what it runs; setup.py reads it).
FOREIGN = ("AMENT_PREFIX_PATH", "COLCON_PREFIX_PATH", "CMAKE_PREFIX_PATH", "PYTHONPATH", "COLCON", "COLCON_HOME")


def _python() -> str:
    return f"python{sys.version_info[0]}.{sys.version_info[1]}"


def _manifest() -> ET.Element:
    return ET.parse(ROOT / "package.xml").getroot()


def _ros_imports() -> set[str]:
    """The ROS 2 packages monodock's sources import (rclpy and the interface packages)."""
    pattern = re.compile(r"^\s*(?:from|import)\s+(rclpy|rcl_interfaces|std_srvs|bond|\w+_msgs)\b", re.M)
    return {m for path in (ROOT / "src" / "monodock").rglob("*.py") for m in pattern.findall(path.read_text())}


def test_the_manifest_matches_the_project() -> None:
    """Name, version and licence as pyproject.toml says; an ament_python package; every ROS 2 package the sources
    import is an exec_depend (rosdep installs them in a ROS 2 workspace)."""
    package = _manifest()
    assert package.get("format") == "3"
    assert package.findtext("name") == PROJECT["name"]
    assert package.findtext("version") == PROJECT["version"]
    assert package.findtext("license") == PROJECT["license"]
    assert package.findtext("export/build_type") == "ament_python"
    depends = {e.text for e in package.findall("exec_depend")}
    imported = _ros_imports()
    assert {"rclpy", "nav2_msgs", "tf2_msgs"} <= imported  # the scan sees the nodes' imports
    assert imported - depends == set()


def test_setup_cfg_sends_the_scripts_to_lib_monodock() -> None:
    """setup.cfg sends the console scripts to lib/monodock under colcon (pip and uv ignore it in a venv)."""
    text = (ROOT / "setup.cfg").read_text(encoding="utf-8")
    assert "install_scripts=$base/lib/monodock" in text
    assert "script_dir=$base/lib/monodock" in text
    assert (ROOT / "resource" / "monodock").is_file()


def _clean_copy(to: Path) -> None:
    """The repository's files as a user clones them (tracked and new, not ignored: no .venv, no build/)."""
    listed = subprocess.run(
        ["git", "ls-files", "-z", "--cached", "--others", "--exclude-standard"],
        cwd=ROOT,
        capture_output=True,
        check=True,
    ).stdout.decode()
    for name in filter(None, listed.split("\0")):
        source = ROOT / name
        if source.is_file():  # a tracked file deleted in the work tree is not copied
            (to / name).parent.mkdir(parents=True, exist_ok=True)
            shutil.copy2(source, to / name)


def _environment(workspace: Path) -> dict[str, str]:
    env = {k: v for k, v in os.environ.items() if k not in FOREIGN}
    env["COLCON_HOME"] = str(workspace / ".colcon")  # no user's defaults or mixins
    return env


def _sourced(workspace: Path, *command: str, timeout: float = 60) -> subprocess.CompletedProcess[str]:
    """``command`` in a shell that sourced the workspace's install/setup.bash, as a user runs it."""
    return subprocess.run(
        ["bash", "-c", 'source install/setup.bash && exec "$@"', "bash", *command],
        cwd=workspace,
        env=_environment(workspace),
        capture_output=True,
        text=True,
        timeout=timeout,
        check=False,
    )


@pytest.fixture(scope="module")
def workspace(tmp_path_factory: pytest.TempPathFactory) -> Path:
    """A colcon workspace with a clean copy of this repository in src/monodock, built by `colcon build`."""
    if not COLCON.is_file():
        missing = (
            f"colcon is not installed beside {sys.executable}: uv pip install --python {sys.executable} "
            "--no-deps -r requirements/colcon.txt (.ci/run installs it)"
        )
        if os.environ.get("MONODOCK_REQUIRE_COLCON"):  # .ci/run: there a missing colcon is a failure
            pytest.fail(missing)
        pytest.skip(missing)
    if shutil.which("git") is None or not (ROOT / ".git").exists():
        pytest.skip("the clean copy of the repository needs git and a git checkout")
    workspace = tmp_path_factory.mktemp("colcon_ws")
    _clean_copy(workspace / "src" / "monodock")
    built = subprocess.run(
        [str(COLCON), "build", "--event-handlers", "console_cohesion+"],
        cwd=workspace,
        env=_environment(workspace),
        capture_output=True,
        text=True,
        timeout=300,
        check=False,
    )
    assert built.returncode == 0, built.stdout[-4000:] + built.stderr[-4000:]
    # Under colcon, setup.py neither builds the interfaces nor fetches their build requirements into .eggs.
    assert not (workspace / "src" / "monodock" / ".eggs").exists()
    assert not (workspace / "src" / "monodock" / "build").exists()
    return workspace


@pytest.mark.slow
def test_colcon_build_registers_monodock_in_the_ament_index(workspace: Path) -> None:
    from catkin_pkg.package import parse_package  # colcon's own reader of package.xml (requirements/colcon.txt)

    prefix = workspace / "install" / "monodock"
    share = prefix / "share" / "monodock"
    assert (prefix / "share" / "ament_index" / "resource_index" / "packages" / "monodock").is_file()
    assert (share / "package.xml").read_bytes() == (ROOT / "package.xml").read_bytes()
    # The parameter files and the launch description, where `ros2 launch monodock ...` finds them.
    for name in ("config/monodock_docking.yaml", "config/layout.yaml", "launch/monodock_docking.launch.py"):
        assert (share / name).read_bytes() == (ROOT / name).read_bytes(), name
    warnings: list[str] = []
    package = parse_package(str(share / "package.xml"), warnings=warnings)
    package.validate(warnings=warnings)
    assert warnings == []
    found = _sourced(
        workspace,
        sys.executable,
        "-c",
        "from ament_index_python.packages import get_package_prefix, get_package_share_directory as share\n"
        "import monodock\n"
        "print(get_package_prefix('monodock'), share('monodock'), monodock.__file__, sep='\\n')",
    )
    assert found.returncode == 0, found.stderr
    assert found.stdout.splitlines() == [
        str(prefix),
        str(share),
        # The workspace's monodock comes first, before any the venv holds.
        str(prefix / "lib" / _python() / "site-packages" / "monodock" / "__init__.py"),
    ]


@pytest.mark.slow
def test_every_executable_runs_from_lib_monodock(workspace: Path) -> None:
    """ros2run's lookup (ros2pkg's get_executable_paths): the package's prefix from the ament index, then the
    executable files in its lib/<package>. Each is the workspace's console script, and prints its usage."""
    lookup = _sourced(
        workspace,
        sys.executable,
        "-c",
        "import os\n"
        "from importlib.metadata import distribution\n"
        "from ament_index_python.packages import get_package_prefix\n"
        "base = os.path.join(get_package_prefix('monodock'), 'lib', 'monodock')\n"
        "for name in sorted(os.listdir(base)):\n"
        "    path = os.path.join(base, name)\n"
        "    if os.path.isfile(path) and os.access(path, os.X_OK):\n"
        "        print(path)\n"
        "monodock = distribution('monodock')\n"
        "for script in monodock.entry_points.select(group='console_scripts'):\n"
        "    script.load()  # the function it calls imports, without running it\n"
        "print(monodock.locate_file(''))",
    )
    assert lookup.returncode == 0, lookup.stderr
    *lines, location = lookup.stdout.splitlines()
    paths = [Path(line) for line in lines]
    assert [p.name for p in paths] == EXECUTABLES
    assert Path(location) == workspace / "install" / "monodock" / "lib" / _python() / "site-packages"
    for path in paths:
        helped = _sourced(workspace, str(path), "--help", timeout=180)
        assert helped.returncode == 0, f"{path.name}: {helped.stderr[-2000:]}"
        assert helped.stdout.startswith(f"usage: {path.name}"), helped.stdout[:200]


@pytest.mark.slow
def test_ros2_run_finds_monodock(workspace: Path) -> None:
    if _sourced(workspace, "sh", "-c", "command -v ros2").returncode != 0:
        pytest.skip("no ros2 command line here (ros2cli and ros2run are not among the ROS 2 wheels on PyPI)")
    helped = _sourced(workspace, "ros2", "run", "monodock", "monodock", "--help")
    assert helped.returncode == 0, helped.stderr[-2000:]
    assert helped.stdout.startswith("usage: monodock")
