"""monodock's build: the package (pyproject.toml says the rest) and the ROS 2 interfaces it speaks with Nav2 and tf2.

nav2_msgs (DockRobot, UndockRobot) and tf2_msgs (TFMessage) are not among the ros-kilted-* wheels on PyPI, so the
install builds them from their upstream definitions with those wheels' own generators (interfaces/build.py,
interfaces/README.md): the build's requirements are interfaces/build-requirements.txt, every version pinned, and
the generated packages install beside monodock, with their type-support libraries inside them. A machine that
cannot build them (no C compiler) still gets monodock, with a warning: everything but the Nav2 action servers and
TF then works.

A colcon workspace builds monodock too (package.xml, ament_python: docs/colcon.md). colcon runs this file itself,
outside any build environment, so there it builds no interfaces and asks for no build requirements (setuptools would
fetch them into .eggs): the workspace's ROS 2 provides nav2_msgs and tf2_msgs.
"""

from __future__ import annotations

import importlib.util
import os
import sys
from pathlib import Path

from setuptools import setup
from setuptools.dist import Distribution

ROOT = Path(__file__).resolve().parent
GENERATED = ROOT / "build" / "ros_interfaces"
INTERFACE_PACKAGES = {
    "tf2_msgs": ("tf2_msgs", "tf2_msgs.msg"),
    "nav2_msgs": ("nav2_msgs", "nav2_msgs.action", "nav2_msgs.srv"),
    "bond": ("bond", "bond.msg"),
}
BINARIES = ["*.so", "type_description/*.json", "LICENSE*"]
# colcon sets COLCON=1 in the environment of everything it runs.
COLCON = os.environ.get("COLCON") == "1"


def _requirements() -> list[str]:
    lines = (ROOT / "interfaces" / "build-requirements.txt").read_text(encoding="utf-8").splitlines()
    return [line.strip() for line in lines if line.strip() and not line.startswith("#")]


def _build_interfaces() -> tuple[str, ...]:
    """The interface packages built into GENERATED; none before the build requirements are installed (pip and uv
    first ask setup.py what to install), and none, with a warning, where they cannot be built."""
    if COLCON or importlib.util.find_spec("ament_package") is None:
        return ()
    try:
        sys.path.insert(0, str(ROOT / "interfaces"))
        from build import build_interfaces  # noqa: PLC0415 - interfaces/build.py, on the path just above

        return build_interfaces(GENERATED)
    except Exception as exc:  # any failure: monodock installs without them, and says so in one line
        why = str(exc).splitlines()[0] if str(exc) else type(exc).__name__
        print(f"warning: monodock's ROS 2 interfaces were not built ({why}; {GENERATED / 'build.log'} says more); "
              "the Nav2 action servers and TF will be unavailable (interfaces/README.md)", file=sys.stderr)  # fmt: skip
        return ()


class ColconDistribution(Distribution):
    """pyproject.toml's requires-python as a string, not a SpecifierSet: colcon reads the configured distribution
    back through its repr and ast.literal_eval (colcon-python-setup-py), which a SpecifierSet's repr fails."""

    def parse_config_files(self, filenames: list[str] | None = None, ignore_option_errors: bool = False) -> None:
        super().parse_config_files(filenames, ignore_option_errors)
        for holder in (self, self.metadata):
            if getattr(holder, "python_requires", None) is not None:
                holder.python_requires = str(holder.python_requires)


class BinaryDistribution(Distribution):
    """The interface packages hold compiled extension modules: the wheel is for this platform."""

    def has_ext_modules(self) -> bool:
        return True


def _monodock_packages() -> list[str]:
    src = ROOT / "src"
    return sorted(".".join(init.parent.relative_to(src).parts) for init in (src / "monodock").rglob("__init__.py"))


built = _build_interfaces()
setup(
    packages=[*_monodock_packages(), *(p for name in built for p in INTERFACE_PACKAGES[name])],
    package_dir={"": "src", **{name: str((GENERATED / name).relative_to(ROOT)) for name in built}},
    package_data={"monodock": ["py.typed"], **dict.fromkeys(built, BINARIES)},
    # A ROS 2 package's marker in the ament index and its manifest (package.xml), where colcon and ros2 look; its
    # parameter files and launch description where `ros2 launch monodock ...` and get_package_share_directory do.
    data_files=[
        ("share/ament_index/resource_index/packages", ["resource/monodock"]),
        ("share/monodock", ["package.xml"]),
        ("share/monodock/config", sorted(str(p.relative_to(ROOT)) for p in (ROOT / "config").glob("*.yaml"))),
        ("share/monodock/launch", sorted(str(p.relative_to(ROOT)) for p in (ROOT / "launch").glob("*.launch.py"))),
    ],
    setup_requires=[] if COLCON else _requirements(),
    distclass=BinaryDistribution if built else ColconDistribution if COLCON else Distribution,
)
