"""Fixtures several test folders share: a labelled, trained model bundle from a simulated drive (built once)."""

from __future__ import annotations

import fcntl
import hashlib
import json
import os
import shutil
import sys
import tempfile
from collections.abc import Callable, Iterator
from pathlib import Path

import cv2
import numpy as np
import pytest

from monodock.cli.main import main
from monodock.core.pose import DockPose
from monodock.learning.export import save_bundle
from monodock.learning.tasks import TrainConfig, TrainingSet
from monodock.learning.train import TrainingResult, train
from monodock.sim import Nuisances, PoseDistribution, Simulator
from monodock.sim.drive import DriveConfig, plan_drive
from monodock.sim.recording import write_recording
from shared import BLACK, FRAMES, META, synthetic_set

FAST = Nuisances().updated(supersample=2)

# DDS discovers peers by multicast on every interface. No test here starts a DDS participant (the ROS tests run
# the nodes against stand-ins for rclpy); should one ever, it and every process it starts stay on loopback.
os.environ["ROS_AUTOMATIC_DISCOVERY_RANGE"] = "LOCALHOST"
os.environ.setdefault("ROS_DOMAIN_ID", "117")


@pytest.fixture(scope="session", autouse=True)
def _no_dds_participant() -> Iterator[None]:
    """The ROS tests use stand-ins: at the end no real rclpy (one loaded from a file) may be in this process."""
    yield
    rclpy = sys.modules.get("rclpy")
    assert rclpy is None or getattr(rclpy, "__file__", None) is None, (
        "a test imported the real rclpy: run ROS 2 graphs in a private network namespace (issue 17)"
    )


def built_once(tmp_path_factory: pytest.TempPathFactory, name: str, build: Callable[[Path], None]) -> Path:
    """A folder that ``build`` fills, made once per test run even when pytest-xdist runs it in several workers.

    Without xdist it is a fresh temporary folder. With xdist, the workers share the run's base temporary folder
    (pytest's own for this run): the first worker to get the lock builds, the others wait for it and reuse the
    result. A build that failed leaves no ``.done`` mark: the next worker tries again (and fails the same way).
    The folder is the tests' to read, not to change.

    With ``MONODOCK_TEST_CACHE`` set (.ci/run sets it), the folder is kept there across runs, keyed by the source
    of monodock and of the tests' builders: CI's default tier builds it and its slow tier reuses it, and any change
    to the code builds it afresh.
    """
    cache = os.environ.get("MONODOCK_TEST_CACHE")
    if cache:
        root = Path(cache) / f"{name}-{_source_key()}"
    elif os.environ.get("PYTEST_XDIST_WORKER") is None:
        root = tmp_path_factory.mktemp(name)
        build(root)
        return root
    else:
        root = tmp_path_factory.getbasetemp().parent / f"shared-{name}"
    root.parent.mkdir(parents=True, exist_ok=True)
    with (root.parent / f"shared-{name}.lock").open("w") as lock:
        fcntl.flock(lock, fcntl.LOCK_EX)
        if not (root / ".done").exists():
            shutil.rmtree(root, ignore_errors=True)
            root.mkdir()
            build(root)
            (root / ".done").touch()
    return root


def _source_key() -> str:
    """A digest of monodock's sources and of this file and tests/shared.py (what builds the fixtures)."""
    here = Path(__file__).resolve().parent
    digest = hashlib.sha256()
    for path in sorted([*(here.parent / "src" / "monodock").rglob("*.py"), here / "conftest.py", here / "shared.py"]):
        digest.update(str(path.relative_to(here.parent)).encode())
        digest.update(path.read_bytes())
    return digest.hexdigest()[:16]


def _record(path: Path, sim: Simulator, stops: int, seed: int) -> None:
    plan = plan_drive(sim, DriveConfig(stops=stops), np.random.default_rng(seed))
    write_recording(path, sim, plan, seed=seed, jobs=2, progress=False)


@pytest.fixture(scope="session")
def work(tmp_path_factory: pytest.TempPathFactory) -> Path:
    """A training drive (labelled, trained with one draw per model) and a held-out drive of another seed."""
    return built_once(tmp_path_factory, "pipeline", _build_work)


def _build_work(root: Path) -> None:
    _record(root / "train_rec", Simulator(nuisances=FAST, seed=1), 240, 1)
    _record(root / "test_rec", Simulator(nuisances=FAST, seed=2), 40, 2)
    Simulator().layout.save(root / "layout.yaml")
    layout = str(root / "layout.yaml")
    assert main(["label", str(root / "train_rec"), "--layout", layout, "--out", str(root / "train.parquet")]) == 0
    code = main(["train", str(root / "train.parquet"), "--out", str(root / "bundle"), "--trials", "1", "--jobs", "2"])
    assert code == 0


@pytest.fixture(scope="session")
def drive(tmp_path_factory: pytest.TempPathFactory) -> tuple[Simulator, list[DockPose], Path, Path]:
    """A 10 fps MJPG video of simulated frames with one black frame, the poses, and the calibration folder."""
    folder = tmp_path_factory.mktemp("drive")
    sim = Simulator(nuisances=Nuisances(supersample=4), seed=5)  # 4x4 edge samples: fast enough for a test
    poses = [sim.sample_pose(PoseDistribution(depth=(0.4, 1.2))) for _ in range(FRAMES)]
    video = folder / "drive.avi"
    writer = cv2.VideoWriter(str(video), cv2.VideoWriter_fourcc(*"MJPG"), 10.0, sim.camera.size)
    assert writer.isOpened()
    rng = np.random.default_rng(0)
    for i, pose in enumerate(poses):
        image = sim.frame(pose, 0.1 * i, rng).image
        if i == BLACK:
            image = np.zeros_like(image)
        writer.write(cv2.cvtColor(image, cv2.COLOR_GRAY2BGR))
    writer.release()
    sim.camera.save(folder / "camera.yaml")
    sim.layout.save(folder / "layout.yaml")
    sim.robot.save(folder / "robot.yaml")
    return sim, poses, video, folder


@pytest.fixture(scope="session")
def data() -> TrainingSet:
    return synthetic_set()


@pytest.fixture(scope="session")
def result(data: TrainingSet) -> TrainingResult:
    return train([data], TrainConfig(trials=2, jobs=1, seed=3), progress=False)


@pytest.fixture(scope="session")
def saved(result: TrainingResult, tmp_path_factory: pytest.TempPathFactory) -> Path:
    return save_bundle(tmp_path_factory.mktemp("b") / "bundle", result, metadata=META)


@pytest.fixture
def bundle_copy(saved: Path, tmp_path: Path) -> Path:
    out = tmp_path / "bundle"
    shutil.copytree(saved, out)
    return out


# --- parallel runs (pytest-xdist; pyproject's addopts: -n 2 --dist loadgroup --no-loadscope-reorder) ----------
#
# Tests are handed to the workers one at a time, longest first, so that the short ones fill in around the long
# ones and no worker is left with a long test at the end while the other idles. Tests that share a fixture of
# module scope, or one of the session fixtures below, go to one worker together (a group), so that the fixture is
# built once, not once per worker. ``work`` (a minute of simulation and training) is shared across the workers
# through ``built_once`` instead and needs no group; the fuzz ``world`` (~7 s) is built per worker.
#
# xdist's own loadgroup reads ``xdist_group`` marks by renaming the items, which pytest 9 no longer lets it do
# (its groups are silently ignored). So the workers write the groups they computed at collection (the same in
# each) to a file the controller named, and the controller's scheduler reads it: one unit per group.

_GROUPED_SESSION_FIXTURES = ("drive", "result")
# The modules that start ROS 2 graphs (sim, detector, dock nodes in real time, in private network namespaces): the
# tests/ros/test_*_graph.py modules and these.
_ROS_GRAPH_MODULES = frozenset(f"tests/ros/{name}.py" for name in ("test_graph", "test_sim_node", "test_recorder"))


def _starts_ros_graphs(module: str) -> bool:
    return module in _ROS_GRAPH_MODULES or (module.startswith("tests/ros/test_") and module.endswith("_graph.py"))


_GROUPS_FILE = "MONODOCK_XDIST_GROUPS"

# The tests of a minute or more (on a quiet 2-core machine), first: the slow tier's end-to-end runs, ROS 2 graphs
# and long fuzz profiles, then the default tier's longest modules and tests.
# The ROS 2 graphs are one group (below) and go to one worker as a unit, where its first test would be: right
# after the longest CPU-bound runs, so that the group (about ten minutes, mostly real time) starts early.
_FIRST = (
    "tests/cli/test_end_to_end.py::test_demo",
    "tests/evaluation/test_dock_sim.py::",
    "tests/ros/test_dock_graph.py::test_docking_over_dds_",
    "tests/ros/test_dock_action_graph.py::",
    "tests/ros/test_dock_graph.py::",
    "tests/ros/test_detector_graph.py::",
    "tests/fuzz/test_properties.py::",
    "tests/evaluation/test_robustness.py::",
    "tests/learning/test_pipeline.py::test_any_layout",
    "tests/cli/test_commission.py::test_commission_a_wrong_world",
    "tests/dock/test_mission.py::test_dock_sim_writes",
    "tests/ros/",
)


def _rank(item: pytest.Item) -> int:
    slow = item.get_closest_marker("slow") is not None
    for i, prefix in enumerate(_FIRST):
        if item.nodeid.startswith(prefix) and (slow or "test_properties" not in prefix):
            return i
    return len(_FIRST)


def _groups(items: list[pytest.Item]) -> dict[str, str]:
    """Each item's group (nodeid -> name) when it shares a costly fixture instance or has an xdist_group mark."""
    parent: dict[str, str] = {}

    def find(key: str) -> str:
        while parent.setdefault(key, key) != key:
            key = parent[key]
        return key

    keys: dict[str, list[str]] = {}
    for item in items:
        info = getattr(item, "_fixtureinfo", None)
        defs = info.name2fixturedefs if info is not None else {}
        module = item.nodeid.split("::")[0]
        mine = [f"{module}:{name}" for name, d in defs.items() if d and d[-1].scope == "module"]
        mine += [name for name in _GROUPED_SESSION_FIXTURES if name in defs]
        mine += [
            str(m.args[0] if m.args else m.kwargs.get("name", "default")) for m in item.iter_markers("xdist_group")
        ]
        if _starts_ros_graphs(module):  # real-time graphs: one after another, never two beside each other
            mine.append("ros-graph")
        keys[item.nodeid] = mine
        for k in mine[1:]:
            parent[find(k)] = find(mine[0])
    return {nodeid: find(mine[0]) for nodeid, mine in keys.items() if mine}


def pytest_configure(config: pytest.Config) -> None:
    controller = not hasattr(config, "workerinput")  # the controller, before it starts the workers
    if controller and config.pluginmanager.hasplugin("xdist") and config.getoption("dist", "no") == "loadgroup":
        handle, name = tempfile.mkstemp(prefix="monodock-xdist-groups-", suffix=".json")
        os.close(handle)
        os.environ[_GROUPS_FILE] = name


def pytest_unconfigure(config: pytest.Config) -> None:
    if not hasattr(config, "workerinput") and _GROUPS_FILE in os.environ:
        Path(os.environ.pop(_GROUPS_FILE)).unlink(missing_ok=True)


@pytest.hookimpl(tryfirst=True)
def pytest_collection_modifyitems(config: pytest.Config, items: list[pytest.Item]) -> None:
    items.sort(key=_rank)  # stable: within a rank, pytest's order
    if hasattr(config, "workerinput") and _GROUPS_FILE in os.environ:
        target = Path(os.environ[_GROUPS_FILE])
        partial = target.with_name(f"{target.name}.{os.environ.get('PYTEST_XDIST_WORKER', '')}")
        partial.write_text(json.dumps(_groups(items)))
        partial.replace(target)  # each worker writes the same groups; whole files only


@pytest.hookimpl(optionalhook=True)  # xdist's hook: pytest -p no:xdist still loads this file
def pytest_xdist_make_scheduler(config: pytest.Config, log: object) -> object:
    """loadgroup with the groups of ``_groups`` (see above); units handed out in collection order."""
    if config.getoption("dist", "no") != "loadgroup" or _GROUPS_FILE not in os.environ:
        return None
    from xdist.scheduler import LoadScopeScheduling

    class Grouped(LoadScopeScheduling):
        _map: dict[str, str] | None = None

        def _split_scope(self, nodeid: str) -> str:
            if self._map is None:  # read once every worker has collected (xdist schedules only then)
                self._map = json.loads(Path(os.environ[_GROUPS_FILE]).read_text() or "{}")
            return self._map.get(nodeid, nodeid)

    return Grouped(config, log)
