"""The papers' pipeline through the command line: label → train → estimate → evaluate, against the simulator's truth,
and the refusals a user meets with bad input (a foreign bundle, a tampered one, a bag without images)."""

from __future__ import annotations

import csv
import json
import math
import shutil
from pathlib import Path
from typing import Any

import numpy as np
import pytest

from monodock.cli.main import main
from monodock.compute import parallel
from monodock.core.camera import CameraModel
from monodock.core.layout import DockLayout, MarkerSpec
from monodock.core.records import to_record
from monodock.core.robot import Mount, RobotConfig
from monodock.errors import InputError
from monodock.learning import dataset as dataset_module
from monodock.learning.dataset import dataset_columns, label_recording, read_dataset, write_dataset
from monodock.recording import open_recording
from monodock.sim import Nuisances, Simulator
from monodock.sim.drive import DriveConfig, plan_drive
from monodock.sim.recording import write_recording

FAST = Nuisances().updated(supersample=2)


def _record(path: Path, sim: Simulator, stops: int, seed: int, **drive: object) -> None:
    plan = plan_drive(sim, DriveConfig(stops=stops, **drive), np.random.default_rng(seed))  # type: ignore[arg-type]
    write_recording(path, sim, plan, seed=seed, jobs=2, progress=False)


def _truth(root: Path, name: str) -> dict[str, tuple[float, float, float]]:
    with open_recording(root / name) as rec:
        return {f"{t:.6f}": (p.x, p.y, p.yaw_deg) for t, p in rec.ground_truth()}


def test_label_writes_every_image_with_counts_and_truth(work: Path) -> None:
    ds = read_dataset(work / "train.parquet")
    assert len(ds) == 240
    assert list(ds.columns) == list(dataset_columns())
    valid = ds["label_valid"]
    assert valid.sum() > 200
    # Labels against the truth the recording carries: depth within the LiDAR's 1 cm noise.
    dx = (ds["label_x_m"] - ds["truth_x_m"])[valid]
    assert np.mean(np.abs(dx)) < 0.015
    # Every invalid row says why.
    assert all(r for r in ds["label_reason"][~valid])
    assert ds.metadata["counts"]["images"] == 240


def test_labelling_in_worker_processes_gives_the_same_dataset(tmp_path: Path, monkeypatch: pytest.MonkeyPatch) -> None:
    """Images labelled in chunks by two workers: the same rows, labels and counts as one process, in the same
    order, with unpaired images among them (lost scans), and labels that agree with the recording's truth.
    The two workers are asked for on the command line (``monodock label --jobs 2``)."""
    # 30 images are 4 chunks, which label inline unless the workers are asked for from 2 chunks on.
    monkeypatch.setattr(dataset_module, "_LABEL_INLINE_BELOW", 2)
    sim = Simulator(nuisances=FAST, seed=4)
    _record(tmp_path / "rec", sim, 30, 4, scan_loss=0.5)
    pools: list[int] = []
    started = parallel.worker_pool

    def counted(jobs: int, *args: Any) -> Any:
        pools.append(jobs)
        return started(jobs, *args)

    monkeypatch.setattr(parallel, "worker_pool", counted)
    one, run_one, _ = label_recording(tmp_path / "rec", sim.layout, progress=False)
    _, run_two, _ = label_recording(tmp_path / "rec", sim.layout, progress=False, jobs=2)
    assert to_record(run_two) == to_record(run_one)
    sim.layout.save(tmp_path / "layout.yaml")
    argv = ["label", str(tmp_path / "rec"), "--layout", str(tmp_path / "layout.yaml"), "--jobs", "2"]
    assert main([*argv, "--out", str(tmp_path / "two.parquet")]) == 0
    two = read_dataset(tmp_path / "two.parquet")
    write_dataset(tmp_path / "one.parquet", one)  # both as the file holds them (the file adds its schema)
    one = read_dataset(tmp_path / "one.parquet")
    assert run_one.images == 30
    assert 0 < run_one.unpaired < 30
    assert run_one.labelled > 5
    assert two.metadata == one.metadata
    for name in dataset_columns():
        np.testing.assert_array_equal(two[name], one[name], err_msg=name)
    valid = two["label_valid"]
    assert np.mean(np.abs(two["label_x_m"] - two["truth_x_m"])[valid]) < 0.015
    assert list(two["frame"]) == sorted(two["frame"])
    assert pools == [2, 2]  # label_recording(jobs=2) and the command's --jobs 2 ran in workers


def test_dataset_round_trip_and_refusals(work: Path, tmp_path: Path) -> None:
    ds = read_dataset(work / "train.parquet")
    out = tmp_path / "copy.parquet"
    write_dataset(out, ds)
    again = read_dataset(out)
    for name in dataset_columns():
        a, b = ds[name], again[name]
        if a.dtype == object:
            assert list(a) == list(b), name
        else:
            np.testing.assert_array_equal(a, b, err_msg=name)
    assert again.metadata["camera"] == ds.metadata["camera"]
    with pytest.raises(InputError, match="exists"):
        write_dataset(out, ds)
    (tmp_path / "junk.parquet").write_bytes(b"not parquet")
    code = main(["train", str(tmp_path / "junk.parquet"), "--out", str(tmp_path / "b")])
    assert code == 2


def test_estimate_with_the_bundle_against_truth(work: Path) -> None:
    """Regression estimates of the held-out drive, read straight from the recording, against its truth."""
    est = work / "est.csv"
    assert main(["estimate", "--model", str(work / "bundle"), str(work / "test_rec"), "--out", str(est)]) == 0
    truth = _truth(work, "test_rec")
    rows = list(csv.DictReader(est.open()))
    assert len(rows) == 40
    dx, dyaw, dy = [], [], []
    for r in rows:
        if r["valid"] != "true":
            assert r["reason"]
            continue
        t = truth[f"{float(r['stamp']):.6f}"]
        dx.append(float(r["x_m"]) - t[0])
        dy.append(float(r["y_m"]) - t[1])
        dyaw.append(float(r["yaw_deg"]) - t[2])
    assert len(dx) >= 36
    # 240 training frames and one draw per model: a few cm and degrees, far from a guess over 2.5 m and 60 deg.
    assert np.mean(np.abs(dx)) < 0.04
    assert np.mean(np.abs(dy)) < 0.02
    assert np.mean(np.abs(dyaw)) < 8.0


def test_fused_estimates_carry_a_covariance_that_covers_the_truth(work: Path) -> None:
    est = work / "est_fused.csv"
    args = ["estimate", "--model", str(work / "bundle"), "--method", "fused", str(work / "test_rec"), "--out", str(est)]
    assert main(args) == 0
    truth = _truth(work, "test_rec")
    rows = [r for r in csv.DictReader(est.open()) if r["valid"] == "true"]
    assert len(rows) >= 36
    z = []
    for r in rows:
        t = truth[f"{float(r['stamp']):.6f}"]
        assert r["method"] == "fused"
        sd = [math.sqrt(float(r[c])) for c in ("cov_xx", "cov_yy", "cov_yawyaw")]
        assert all(0 < v < 0.05 for v in sd[:2])
        assert 0 < sd[2] < math.radians(5)
        err = (float(r["x_m"]) - t[0], float(r["y_m"]) - t[1], math.radians(float(r["yaw_deg"]) - t[2]))
        z += [e / s for e, s in zip(err, sd, strict=True)]
    # Normalised errors: neither wildly over- nor under-confident (the truth is not what trained the tables).
    assert 0.2 < float(np.sqrt(np.mean(np.square(z)))) < 5.0


def test_evaluate_writes_the_tables_and_compares_every_method(work: Path) -> None:
    out = work / "eval"
    assert main(["evaluate", str(work / "test_rec"), "--model", str(work / "bundle"), "--out", str(out)]) == 0
    for name in (
        "report.html",
        "report.md",
        "summary.json",
        "fig12_depth.png",
        "fig13_angle.png",
        "miscalibration.png",
    ):
        assert (out / name).is_file(), name
    summary = json.loads((out / "summary.json").read_text())
    truth = summary["against_truth"]
    assert set(truth) == {"regression", "pnp", "board", "fused"}
    assert truth["board"]["depth_mae_cm"] < 3.0
    # Bias-free corners and the planar fit: the fused depth and yaw beat board PnP's against the truth.
    assert truth["fused"]["valid"] >= truth["board"]["valid"] - 1
    assert truth["fused"]["depth_mae_cm"] < 0.7 * truth["board"]["depth_mae_cm"]
    assert truth["fused"]["yaw_mae_deg"] < truth["board"]["yaw_mae_deg"]
    # The papers' failure: PnP told a marker 5 % too big reads every depth ~5 % too far.
    study = {(r["quantity"], r["factor"], r["method"]): r for r in summary["miscalibration"]}
    assert study[("marker size", 1.05, "pnp")]["depth_bias_pct"] == pytest.approx(5.0, abs=1.5)
    assert study[("marker size", 1.5, "pnp")]["depth_bias_pct"] == pytest.approx(50.0, abs=5.0)
    assert (
        study[("marker size", 1.5, "regression")]["depth_mae_cm"]
        == study[("marker size", 1.0, "regression")]["depth_mae_cm"]
    )


def test_a_bundle_for_another_layout_is_refused(work: Path, tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    other = DockLayout(
        "DICT_5X5_100",
        0.08,
        (MarkerSpec("left", 10, 0.25, 0.3), MarkerSpec("center", 11, 0.0, 0.3), MarkerSpec("right", 12, -0.25, 0.3)),
    )
    other.save(tmp_path / "other.yaml")
    code = main(
        [
            "estimate",
            "--model",
            str(work / "bundle"),
            "--layout",
            str(tmp_path / "other.yaml"),
            str(work / "test_rec"),
            "--out",
            str(tmp_path / "e.csv"),
        ]
    )
    err = capsys.readouterr().err.strip()
    assert code == 2
    assert "another dock layout" in err
    assert len(err.splitlines()) == 1


def test_a_tampered_bundle_is_refused(work: Path, tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    bundle = tmp_path / "bundle"
    shutil.copytree(work / "bundle", bundle)
    victim = sorted(bundle.glob("*.onnx"))[0]
    data = bytearray(victim.read_bytes())
    data[len(data) // 2] ^= 0xFF
    victim.write_bytes(bytes(data))
    code = main(["estimate", "--model", str(bundle), str(work / "test_rec"), "--out", str(tmp_path / "e.csv")])
    err = capsys.readouterr().err.strip()
    assert code == 2
    assert "checksum" in err
    assert len(err.splitlines()) == 1


def test_regression_without_a_bundle_is_a_usage_error(tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    code = main(["estimate", "--method", "regression", str(tmp_path), "--out", str(tmp_path / "e.csv")])
    assert code == 2
    assert "--model" in capsys.readouterr().err


def test_label_of_a_bag_without_images(work: Path, tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    from rosbags.rosbag2 import StoragePlugin, Writer
    from rosbags.typesys import Stores, get_typestore

    store = get_typestore(Stores.ROS2_HUMBLE)
    bag = tmp_path / "scans_only"
    with Writer(bag, version=8, storage_plugin=StoragePlugin.MCAP) as w:
        w.add_connection("/scan", "sensor_msgs/msg/LaserScan", typestore=store)
    code = main(["label", str(bag), "--layout", str(work / "layout.yaml"), "--out", str(tmp_path / "d.parquet")])
    err = capsys.readouterr().err.strip()
    assert code == 2
    assert "no sensor_msgs/Image" in err
    assert not (tmp_path / "d.parquet").exists()


def test_any_layout_camera_and_mounts(tmp_path: Path) -> None:
    """A user's own charger and robot: other dictionary, ids, size and spacing; a 1280x720 wide lens; a camera
    pitched down and a LiDAR turned sideways. Label, train and estimate must work on them unchanged."""
    layout = DockLayout(
        "DICT_5X5_100",
        0.12,
        (MarkerSpec("left", 40, 0.26, 0.32), MarkerSpec("center", 41, 0.0, 0.32), MarkerSpec("right", 42, -0.26, 0.32)),
    )
    camera = CameraModel.from_intrinsics(
        1280, 720, 820.0, 818.0, 652.0, 361.0, (-0.2, 0.05, 0.0005, -0.0003, 0.0), name="wide"
    )
    robot = RobotConfig(
        camera_mount=Mount(0.20, 0.02, 0.26, 0.0, math.radians(5.0), 0.0),
        laser_mount=Mount(0.10, 0.0, 0.18, 0.0, 0.0, math.radians(90.0)),
        front_offset=0.30,
    )
    sim = Simulator(layout=layout, camera=camera, robot=robot, nuisances=FAST, seed=5)
    _record(tmp_path / "rec", sim, 160, 5, depth=(0.4, 2.0))
    layout.save(tmp_path / "layout.yaml")
    assert (
        main(
            [
                "label",
                str(tmp_path / "rec"),
                "--layout",
                str(tmp_path / "layout.yaml"),
                "--out",
                str(tmp_path / "d.parquet"),
            ]
        )
        == 0
    )
    ds = read_dataset(tmp_path / "d.parquet")
    assert ds["label_valid"].sum() > 130
    assert (
        main(["train", str(tmp_path / "d.parquet"), "--out", str(tmp_path / "b"), "--trials", "1", "--jobs", "2"]) == 0
    )
    test = Simulator(layout=layout, camera=camera, robot=robot, nuisances=FAST, seed=6)
    _record(tmp_path / "held_out", test, 20, 6, depth=(0.5, 1.8))
    est = tmp_path / "est.csv"
    assert main(["estimate", "--model", str(tmp_path / "b"), str(tmp_path / "held_out"), "--out", str(est)]) == 0
    with open_recording(tmp_path / "held_out") as rec:
        truth = {f"{t:.6f}": p for t, p in rec.ground_truth()}
    rows = [r for r in csv.DictReader(est.open()) if r["valid"] == "true"]
    assert len(rows) >= 17
    dx = [abs(float(r["x_m"]) - truth[f"{float(r['stamp']):.6f}"].x) for r in rows]
    dy = [abs(float(r["y_m"]) - truth[f"{float(r['stamp']):.6f}"].y) for r in rows]
    assert np.mean(dx) < 0.05
    assert np.mean(dy) < 0.03


def test_frames_the_regression_must_not_guess(work: Path, tmp_path: Path) -> None:
    """Marker 2 hidden, or the dock farther than anything trained on: no estimate and a reason, never a guess;
    the frames around them are still estimated."""
    import cv2

    from monodock.core.pose import DockPose

    sim = Simulator(seed=9)
    folder = tmp_path / "frames"
    folder.mkdir()
    good = sim.frame(DockPose(1.2, 0.05, 0.1), 0.0, np.random.default_rng(0))
    hidden = good.image.copy()
    c = good.truth.corners["center"]
    lo, hi = np.floor(c.min(axis=0)).astype(int) - 3, np.ceil(c.max(axis=0)).astype(int) + 3
    hidden[lo[1] : hi[1], lo[0] : hi[0]] = 200  # a sticker over marker 2
    far = sim.frame(DockPose(3.3, 0.0, 0.0), 0.0, np.random.default_rng(1)).image
    for name, image in (("a_good.png", good.image), ("b_hidden.png", hidden), ("c_far.png", far)):
        cv2.imwrite(str(folder / name), image)
    est = tmp_path / "e.csv"
    assert main(["estimate", "--model", str(work / "bundle"), str(folder), "--out", str(est)]) == 0
    rows = {r["frame"]: r for r in csv.DictReader(est.open())}
    assert rows["a_good.png"]["valid"] == "true"
    assert abs(float(rows["a_good.png"]["x_m"]) - 1.2) < 0.05
    assert rows["b_hidden.png"]["valid"] == "false"
    assert "marker 2" in rows["b_hidden.png"]["reason"]
    assert rows["c_far.png"]["valid"] == "false"
    assert "outside the trained range" in rows["c_far.png"]["reason"]


def test_a_segment_without_data_gives_no_angle_and_says_why(work: Path, tmp_path: Path) -> None:
    """Trained only on the near half of the range, the bundle still measures depth far out, but has no angle
    model there: the frame gets no estimate and the reason names the segment."""
    import dataclasses

    from monodock.core.pose import DockPose
    from monodock.estimation.bundle import Bundle
    from monodock.estimation.regression import RegressionEstimator
    from monodock.learning.export import save_bundle
    from monodock.learning.pipeline import bundle_metadata, training_sets
    from monodock.learning.tasks import TrainConfig
    from monodock.learning.train import train
    from monodock.perception.detect import MarkerDetector

    ds = read_dataset(work / "train.parquet")
    near = np.asarray(ds["label_x_m"] < 1.2) & np.asarray(ds["label_valid"])
    ds = dataclasses.replace(ds, columns={k: v[near] for k, v in ds.columns.items()})
    result = train(training_sets(ds, ("m2",)), TrainConfig(trials=1, models=("ridge",), jobs=1), progress=False)
    meta = bundle_metadata(ds, depth_label="point", angle_label="line", source="near half")
    bundle = Bundle.load(save_bundle(tmp_path / "near", result, metadata=meta))
    far_segments = [k for k in range(45) if not bundle.has_angle_model("m2", k)]
    assert far_segments
    assert min(far_segments) * 0.05 + 0.25 < 2.0  # the far end of the table has no angle model
    sim = Simulator(seed=12)
    frame = sim.frame(DockPose(2.2, 0.0, 0.0), 0.0, np.random.default_rng(0))
    est = RegressionEstimator(bundle, sim.camera, sim.robot).estimate(MarkerDetector(sim.layout).detect(frame.image))
    assert est.pose is None
    assert "no angle model for the" in est.reason
