"""The detector on a real ROS 2 graph over Fast DDS (each graph in a private network namespace).

Three graphs, each run once for the tests below it: monodock_sim's images, board PnP with the camera from
camera_info, started with the shipped params file (its poses against the sim's ground truth and their latency, the
parameters it runs with, its /diagnostics); each kind of bad message, then the sim's frames; bad settings at
start-up, live parameter changes, a camera_info that disagrees with the camera file, and the covariance topic of
the fused method."""

from __future__ import annotations

import math
import re
from pathlib import Path
from typing import Any

import numpy as np
import pytest
import yaml

from private_graph import GraphRun, needs_graph, run_private_graph

HERE = Path(__file__).parent
SHIPPED = HERE.parents[1] / "config" / "monodock_detector.yaml"

pytestmark = needs_graph()


@pytest.fixture(scope="module")
def run() -> GraphRun:
    done = run_private_graph(HERE / "graph_detector.py", "[-1.6, 0.1, 0.05]", str(SHIPPED), timeout=180)
    assert done.returncode == 0, done.stderr
    assert "Traceback" not in done.stderr
    processes = done.first("processes")
    assert processes["sim"] == 0, processes["sim_stderr"]
    assert processes["detector"] == 0, processes["stderr"]  # SIGTERM: a clean exit
    assert "Traceback" not in processes["stderr"]
    return done


def test_detected_poses_match_the_ground_truth_at_the_camera_rate(run: GraphRun) -> None:
    poses = run.first("poses")
    # 9 s of frames at 15 fps. From the first pose to the last, each frame gives a pose or is counted as dropped
    # (the node fell behind: on a busy machine the sim sends late frames in bursts).
    pairs = poses["pairs"]
    stamps = [q["stamp"] for q in pairs]
    frames = 15.0 * (max(stamps) - min(stamps)) * 1e-9 + 1
    assert frames > 90
    dropped = int(run.first("diagnostics")["statuses"][-1]["frames_dropped"])
    assert len(pairs) + dropped > 0.95 * frames
    assert len(pairs) > 0.6 * frames
    assert poses["unpaired"] == 0  # every pose has a truth within 0.1 s of its exposure (standing still)
    err = np.array([[p - t for p, t in zip(q["pose"], q["truth"], strict=True)] for q in pairs])
    mae = np.abs(err).mean(axis=0)
    # Board PnP at 1.4 m from the camera: held-out MAE there is about a centimetre in depth and a degree in yaw.
    assert mae[0] < 0.02
    assert mae[1] < 0.01
    assert math.degrees(mae[2]) < 1.0
    # From the exposure's stamp to the pose's arrival: the camera's 50 ms latency, then transport and estimation
    # (on an idle machine: median 61 ms, p95 69 ms). On a busy one the sim itself sends its frames late, so the
    # detector's share is measured from each image's arrival beside the pose's: median 10 ms idle, ~20 ms busy.
    latency = np.array([q["latency"] for q in pairs])
    assert float(np.median(latency)) > 0.05
    share = np.array([q["detector"] for q in pairs if q["detector"] is not None])
    assert len(share) > 0.8 * len(pairs)
    assert float(np.median(share)) < 0.1


def test_the_params_file_sets_the_parameters_over_the_flags(run: GraphRun) -> None:
    """The shipped file's values hold where nothing overrides them, over the flags (--method pnp --frame-id
    flag_frame --diagnostics-period 2); a second file overrides the first (the paths), and -p both (the period and
    the stamp age limit)."""
    shipped: dict[str, Any] = yaml.safe_load(SHIPPED.read_text())["monodock_detector"]["ros__parameters"]
    parameters = run.first("parameters")["parameters"]
    ours = {k: v for k, v in parameters.items() if k not in ("use_sim_time", "start_type_description_service")}
    assert set(ours) == set(shipped)  # the example names every parameter, and nothing else
    values = {k: v["value"] for k, v in ours.items()}
    assert values["layout"].endswith("/layout.yaml")
    assert values["robot"].endswith("/robot.yaml")
    assert (values["diagnostics_period"], values["max_stamp_age"]) == (0.5, 0.0)
    overridden = ("layout", "robot", "diagnostics_period", "max_stamp_age")
    assert {k: v for k, v in values.items() if k not in overridden} == {
        k: v for k, v in shipped.items() if k not in overridden
    }
    assert (values["method"], values["frame_id"]) == ("board", "base_link")
    assert {q["frame"] for q in run.first("poses")["pairs"]} == {"base_link"}
    # Declared with what they are for; only what can change live is writable; the numbers have their ranges.
    assert all(len(p["description"]) > 20 for p in ours.values())
    assert {k for k, p in ours.items() if not p["read_only"]} == {"frame_id", "max_stamp_age"}
    assert ours["max_stamp_age"]["bounds"] == [[0.0, 3600.0]]
    assert ours["diagnostics_period"]["type"] == "double"


def test_diagnostics_report_rates_latency_and_markers(run: GraphRun) -> None:
    diagnostics = run.first("diagnostics")
    statuses = diagnostics["statuses"]
    estimating = [s for s in statuses if s["t"] < diagnostics["sim_end"] and s["poses_out_hz"] != "0.00"]
    assert len(estimating) > 8  # every 0.5 s (the -p) for several seconds
    steady = estimating[2:-2]
    # OK when each image gave a pose; else only a WARN for frames dropped when it fell behind (a busy machine).
    assert any(s["level"] == 0 for s in steady)
    assert all(s["level"] == 0 or "dropped (falling behind), 0 refused" in s["message"] for s in steady), steady
    rate_in = np.mean([float(s["images_in_hz"]) for s in steady])
    rate_out = np.mean([float(s["poses_out_hz"]) for s in steady])
    assert 10.0 < rate_in < 20.0
    assert rate_out > 0.7 * rate_in
    assert {s["markers_seen"] for s in steady} == {"3"}
    assert {s["method"] for s in steady} == {"board"}  # the file's method, not the flag's
    assert {s["camera"] for s in steady} == {"first camera_info"}
    # The node's latency (stamp to publication) is about the listener's (stamp to arrival).
    listener = float(np.median([q["latency"] for q in run.first("poses")["pairs"]]))
    node = 1e-3 * float(np.median([float(s["latency_median_ms"]) for s in steady]))
    assert node > 0.05
    assert abs(node - listener) < 0.5 * listener
    # Processing (decode and estimate, board PnP at 640x480) is milliseconds: a small part of the latency.
    processing = 1e-3 * float(np.median([float(s["processing_median_ms"]) for s in steady]))
    assert 0.0 < processing < node
    # Once the camera stops: a warning that says so.
    after = [s for s in statuses if s["t"] > diagnostics["sim_end"] + 1.1]  # a whole period after the last image
    assert after
    assert all(s["level"] == 1 and s["message"] == "no images on image" for s in after)


# --- bad messages --------------------------------------------------------------------------------------------

# Each kind of bad message the faults driver sends (its phase) and what the detector's one warning about it says.
WARNINGS = {
    "no calibration": "no camera calibration yet",
    "K all zero": "K is all zero",
    "NaN in K": "NaN or infinite",
    "unknown encoding": "encoding 'yuv422_yuy2' is not supported",
    "short data": "bytes of data, expected step x height",
    "stale": "s old (max_stamp_age",
    "out of order": "is not after the last image's",
    "flood": "falling behind",
}
WARNING_PERIOD = 10.0  # monodock.ros.detector's: a kind's next warning comes no sooner


def warnings_of(stderr: str) -> list[tuple[float, str]]:
    """(time, text) of each warning in a node's log."""
    found = re.findall(r"^\[WARN\] \[(\d+\.\d+)\] \[[^]]*\]: (.*)$", stderr, flags=re.MULTILINE)
    return [(float(t), text) for t, text in found]


@pytest.fixture(scope="module")
def faults() -> GraphRun:
    done = run_private_graph(HERE / "graph_detector_faults.py", "[-1.6, 0.1, 0.05]", timeout=240)
    assert done.returncode == 0, done.stderr
    processes = done.first("processes")
    assert processes["detector"] == 0, processes["stderr"]  # the sim, stopped by the driver, is not under test
    assert "Traceback" not in processes["stderr"] + done.stderr
    return done


@pytest.mark.slow  # the bad-message graph (~25 s): CI runs it with -m slow
def test_each_kind_of_bad_message_gives_one_warning_in_its_phase(faults: GraphRun) -> None:
    phases = {p["name"]: p for p in faults.first("phases")["phases"]}
    warnings = warnings_of(faults.first("processes")["stderr"])
    assert all(any(says in text for says in WARNINGS.values()) for _, text in warnings), warnings
    for name, says in WARNINGS.items():
        times = [t for t, text in warnings if says in text]
        if name == "flood":  # the sim's frames may be dropped too on a busy machine: not sooner than the period
            times = [t for t in times if t < phases[name]["start"] + WARNING_PERIOD]
        assert len(times) == 1, (name, warnings)
        assert phases[name]["start"] <= times[0] <= phases[name]["end"], (name, times, phases[name])


@pytest.mark.slow  # the bad-message graph (~25 s): CI runs it with -m slow
def test_after_bad_messages_the_poses_still_match_the_truth(faults: GraphRun) -> None:
    """Only the good frames gave poses, at the pose they were rendered at; then the sim's frames give poses that
    match its ground truth, as in the test above."""
    driver = faults.first("driver_poses")
    refused = set(faults.first("phases")["refused"])
    assert len(driver["poses"]) >= 2  # the good frame before the out-of-order ones, and the flood's
    assert not refused & {p["stamp"] for p in driver["poses"]}
    for p in driver["poses"]:
        x, y, yaw = (a - b for a, b in zip(p["pose"], driver["rendered"], strict=True))
        assert abs(x) < 0.01
        assert abs(y) < 0.01
        assert abs(math.degrees(yaw)) < 0.5
    sim = faults.first("sim_poses")
    # 7 s of the sim's frames at 15 fps; a slowed-down sim on a busy machine sends fewer.
    assert len(sim["pairs"]) > 20
    assert sim["unpaired"] == 0
    err = np.array([[p - t for p, t in zip(q["pose"], q["truth"], strict=True)] for q in sim["pairs"]])
    mae = np.abs(err).mean(axis=0)
    assert mae[0] < 0.02
    assert mae[1] < 0.01
    assert math.degrees(mae[2]) < 1.0


@pytest.mark.slow  # the bad-message graph (~25 s): CI runs it with -m slow
def test_diagnostics_say_why_there_is_no_estimate(faults: GraphRun) -> None:
    phases = {p["name"]: p for p in faults.first("phases")["phases"]}
    statuses = faults.first("diagnostics")["statuses"]

    def during(name: str) -> list[dict[str, Any]]:
        return [s for s in statuses if phases[name]["start"] < s["t"] <= phases[name]["end"]]

    # ERROR when nothing can be estimated, with the reason; counted refusals and drops.
    assert any(s["level"] == 2 and s["message"] == "no calibration" for s in during("no calibration"))
    bad_images = during("unknown encoding") + during("short data")
    assert any(s["level"] == 2 and s["message"].startswith("bad image: ") for s in bad_images)
    assert any(s["level"] == 2 and s["message"] == "stale stamps" for s in during("stale"))
    assert any(s["level"] == 1 and "dropped (falling behind)" in s["message"] for s in during("flood"))
    last = statuses[-1]
    assert int(last["frames_dropped"]) > 10  # of the flood's 300
    assert int(last["images_refused"]) >= 25  # 20 uncalibrated, 3 + 3 + 3 + 3 bad (best effort may lose one)
    relay = faults.first("phases")["relay"]
    relayed = [s for s in statuses if relay[0] + 1.0 < s["t"] <= relay[1]]
    assert any(s["level"] == 0 and s["markers_seen"] == "3" for s in relayed)


# --- start-up, live parameters, the covariance topic ------------------------------------------------------------


@pytest.fixture(scope="module")
def startup(work: Path) -> GraphRun:
    done = run_private_graph(HERE / "graph_detector_params.py", str(work / "bundle"), timeout=240)
    assert done.returncode == 0, done.stderr
    assert "Traceback" not in done.stderr
    return done


def test_bad_settings_are_one_line_and_exit_2(startup: GraphRun) -> None:
    culprits = {
        "method": "method: 'bogus' is not one of regression, pnp, board, fused",
        "range": "max_stamp_age must be from 0 to 3600, got -1",
        "type": "compressed is true or false, got 'maybe'",
        "range in a params file": "diagnostics_period must be from 0.1 to 60, got 100",
        "missing params file": "missing.yaml",
        "missing robot file": "robot file not found",
        "ROS argument": "--bogus",
    }
    bad = {r["name"]: r for r in startup.records if r["kind"] == "bad"}
    assert set(bad) == set(culprits)
    for name, says in culprits.items():
        assert bad[name]["returncode"] == 2, bad[name]
        lines = bad[name]["stderr"].splitlines()
        assert len(lines) == 1, bad[name]
        assert lines[0].startswith("monodock-ros: error: ")
        assert says in lines[0], (name, lines[0])


def test_live_parameters_and_a_camera_info_that_disagrees(startup: GraphRun) -> None:
    results = startup.first("set")["results"]
    assert results["max_stamp_age=2"]["ok"], results["max_stamp_age=2"]  # an integer serves a real, as at start-up
    assert results["max_stamp_age=2.5"]["ok"]
    assert results["frame_id=odom"]["ok"]
    assert not results["max_stamp_age=-1.0"]["ok"]  # out of its range
    assert "read-only" in results["method=pnp"]["reason"]
    assert "read-only" in results["diagnostics_period=5.0"]["reason"]
    assert startup.first("set")["values"] == {
        "max_stamp_age": 2.5,
        "frame_id": "odom",
        "method": "",
        "diagnostics_period": 1.0,
    }
    poses = startup.first("poses")
    before, after = poses["before"], poses["after"]
    assert (before["frame"], after["frame"]) == ("base_link", "odom")
    assert after["latency"] > 2.0  # 2 s old, taken once max_stamp_age is 2.5 s
    for p in (before, after):
        x, y, yaw = (a - b for a, b in zip(p["pose"], poses["rendered"], strict=True))
        assert abs(x) < 0.01
        assert abs(y) < 0.01
        assert abs(math.degrees(yaw)) < 0.5
    detector = startup.first("detector")
    assert detector["returncode"] == 0
    warnings = warnings_of(detector["stderr"])
    # The camera_info that agrees with the camera file says nothing; of the two that disagree, the first is reported.
    assert len(warnings) == 1, warnings
    t, text = warnings[0]
    assert t > detector["agreed"]
    assert "disagrees with the camera in use, from the camera file (fx 633.45, not 615.00)" in text


def test_a_method_with_a_covariance_publishes_it_beside_the_pose(startup: GraphRun) -> None:
    """Fused, from a model bundle, on image/compressed (compressed:=true; a PNG): the PoseWithCovarianceStamped of a
    frame carries the same stamp, frame and pose as its PoseStamped, the pose matches the one the frame was rendered
    at, and the 6x6 covariance has the (x, y, yaw) block at rows and columns 0, 1 and 5 (monodock.io.nav2), positive
    definite, and zeros elsewhere."""
    fused = startup.first("fused")
    assert fused["returncode"] == 0, fused["stderr"]
    assert fused["board"] == 0  # board PnP gives no covariance: nothing on that topic
    assert len(set(fused["stamps"])) == 1
    assert len(fused["stamps"]) == 2
    assert fused["frames"] == ["base_link", "base_link"]
    assert fused["plain"] == [fused["pose"]]
    rendered = startup.first("poses")["rendered"]
    x, y, yaw = (a - b for a, b in zip(fused["pose"], rendered, strict=True))
    assert abs(x) < 0.01
    assert abs(y) < 0.01
    assert abs(math.degrees(yaw)) < 0.5
    cov = np.array(fused["covariance"]).reshape(6, 6)
    block = cov[np.ix_((0, 1, 5), (0, 1, 5))]
    np.testing.assert_allclose(block, block.T)
    assert np.all(np.linalg.eigvalsh(block) > 0)
    others = np.delete(np.delete(cov, (0, 1, 5), axis=0), (0, 1, 5), axis=1)
    assert not others.any()
    assert not cov[np.ix_((0, 1, 5), (2, 3, 4))].any()
