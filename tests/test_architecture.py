"""The package's shape, as a robot sees it: what the robot side loads, in a fresh interpreter.

import-linter (``.importlinter``, run by CI) checks the import graph statically; this test checks what really
gets loaded at run time, including what is imported inside functions (the fused method's warm-up, a bundle's
ONNX sessions), which a static graph can miss.
"""

from __future__ import annotations

import ast
import json
import subprocess
import sys
import textwrap
from pathlib import Path

from shared import RCLPY_STAND_INS

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

_SCRIPT = RCLPY_STAND_INS + textwrap.dedent(
    """
    import json

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
    allowed = (
        "monodock.errors",
        "monodock.cli",
        "monodock.cli.options",
        "monodock.cli.parser",
        "monodock.cli.ros_nodes",
    )
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


SRC = Path(__file__).resolve().parents[1] / "src"
SUBPACKAGES = sorted(p.parent.name for p in (SRC / "monodock").glob("*/__init__.py"))
# Re-exports kept on purpose: pyplot through report.plotting (which picks the Agg backend before pyplot loads),
# and core.config's write_text_atomic until the settings schema (issue 40) retires core.config's readers.
KEPT_REEXPORTS = {("monodock.report.plotting", "plt"), ("monodock.core.config", "write_text_atomic")}


def test_no_module_but_a_face_re_exports() -> None:
    """A name a module imports is not in its ``__all__`` unless the module is its subpackage's ``__init__``: one
    path to each name, the one where it is defined."""
    found = set()
    for path in (SRC / "monodock").rglob("*.py"):
        if path.name == "__init__.py":
            continue
        module = ".".join(path.relative_to(SRC).with_suffix("").parts)
        tree = ast.parse(path.read_text(encoding="utf-8"))
        imported = {
            a.asname or a.name.split(".")[0]
            for n in tree.body
            if isinstance(n, (ast.Import, ast.ImportFrom))
            for a in n.names
        }
        for n in tree.body:
            if isinstance(n, ast.Assign) and any(isinstance(t, ast.Name) and t.id == "__all__" for t in n.targets):
                found |= {
                    (module, e.value) for e in n.value.elts if isinstance(e, ast.Constant) and e.value in imported
                }
    assert found <= KEPT_REEXPORTS


def test_each_subpackage_has_a_face_of_its_own_names() -> None:
    """Each subpackage's ``__init__`` is its face: an ``__all__`` (empty for cli, which nothing imports) whose names
    resolve to what the subpackage itself defines (none named as one of its modules); a lazy face loads none of its
    modules until a name is used."""
    script = textwrap.dedent(
        f"""
        import importlib, inspect, json, pkgutil, sys
        out = {{}}
        for name in {SUBPACKAGES!r}:
            before = set(sys.modules)
            package = importlib.import_module("monodock." + name)
            loaded = sorted(m for m in set(sys.modules) - before if m.startswith("monodock." + name + "."))
            lazy = "lazy_face" in vars(package)
            foreign = []
            for attr in package.__all__:
                value = getattr(package, attr)
                own = inspect.isclass(value) or inspect.isfunction(value)
                if own and not value.__module__.startswith("monodock." + name + "."):
                    foreign.append(attr)
            # A name that is also a submodule's would change meaning once the submodule is imported.
            foreign += sorted(set(package.__all__) & {{m.name for m in pkgutil.iter_modules(package.__path__)}})
            out[name] = {{"all": list(package.__all__), "lazy": lazy, "loaded": loaded, "foreign": foreign}}
        print(json.dumps(out))
        """
    )
    done = subprocess.run([sys.executable, "-c", script], capture_output=True, text=True, timeout=300, check=False)
    assert done.returncode == 0, done.stderr
    faces = json.loads(done.stdout.strip().splitlines()[-1])
    for name, face in faces.items():
        assert face["foreign"] == [], name
        assert face["all"] or name == "cli", name
        if face["lazy"]:
            assert face["loaded"] in ([], ["monodock.core.face"]), name
