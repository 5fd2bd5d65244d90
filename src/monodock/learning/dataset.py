"""The training dataset: one row per camera frame of a recording, with its features, LiDAR label and truth.

A Parquet file (docs/user-guide.md, Dataset). Columns, in order (``dataset_columns()``):

- ``frame`` (int): the image's index in the recording; ``image_stamp`` (s); ``scan_stamp`` (s, NaN when no scan
  was within the pairing tolerance); ``paired`` (bool); ``markers_seen`` ("m1 m2 m3").
- every raw feature of ``features.FEATURE_NAMES`` (pixels; NaN for a marker not seen).
- the bias-free corners of ``monodock.perception.refine`` (``features.REFINED_CORNER_NAMES``, pixels; NaN for a
  marker not seen or not refined). Datasets of schema 1 have none; they read with these columns NaN.
- the label columns of ``label.LABEL_COLUMNS`` (metres, degrees; ``label_valid`` false with ``label_reason``).
- ``truth_x_m``, ``truth_y_m``, ``truth_yaw_deg``: the simulator's DockPose when the recording has it, else NaN.

The file's metadata (key ``monodock``) holds the camera, robot mounts and layout the features were measured
with, the source recording, the pairing tolerance and the counts of the labelling run, so that training
needs nothing but this file.
"""

from __future__ import annotations

import io
import json
import math
import os
from collections import Counter
from collections.abc import Callable, Iterator
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np
import pyarrow as pa
import pyarrow.parquet as pq
from numpy.typing import NDArray
from tqdm import tqdm

from monodock import __version__
from monodock.compute import map_stream
from monodock.core.atomic import write_bytes_atomic
from monodock.core.camera import CameraModel
from monodock.core.config import parse_json
from monodock.core.frame import Frame
from monodock.core.layout import DockLayout
from monodock.core.records import to_record
from monodock.core.robot import RobotConfig
from monodock.core.settings import to_mapping
from monodock.errors import ConfigError, InputError
from monodock.estimation.calibration_records import CalibrationRecords
from monodock.learning.label import LABEL_COLUMNS, LidarLabel, label_frame
from monodock.perception.detect import MarkerDetector, as_gray
from monodock.perception.features import FEATURE_NAMES, REFINED_CORNER_NAMES, feature_vector, refined_vector
from monodock.perception.refine import refine_detection
from monodock.recording import open_recording, pair_nearest

__all__ = [
    "DATASET_SCHEMA",
    "Dataset",
    "LabelError",
    "LabelRun",
    "dataset_columns",
    "label_error_table",
    "label_errors",
    "label_frames",
    "label_recording",
    "read_dataset",
    "write_dataset",
]

DATASET_SCHEMA = "monodock.learning.dataset/2"
# Schema 1 lacked the refined corners and the whole-face line (its label_yaw_deg is the marker-2 line's); it
# reads with those columns NaN.
_READABLE_SCHEMAS = ("monodock.learning.dataset/1", DATASET_SCHEMA)
# The label columns from the marker-2 line's onwards are the face line's additions.
_NEW_IN_SCHEMA_2 = (*REFINED_CORNER_NAMES, *LABEL_COLUMNS[LABEL_COLUMNS.index("label_yaw_marker_deg") :])
TRUTH_COLUMNS = ("truth_x_m", "truth_y_m", "truth_yaw_deg")
_FRAME_COLUMNS = ("frame", "image_stamp", "scan_stamp", "paired", "markers_seen")


def dataset_columns() -> tuple[str, ...]:
    """Every column of a dataset file, in order."""
    return _FRAME_COLUMNS + FEATURE_NAMES + REFINED_CORNER_NAMES + LABEL_COLUMNS + TRUTH_COLUMNS


# Stamps are seconds since 1970 (~1.8e9); pixels, metres and degrees are far smaller.
MAX_DATASET_VALUE = 1e11

_BOOL = {"paired", "label_valid"}
_INT = {"frame", "label_points", "label_face_points", "label_face_rejected"}
_STR = {"markers_seen", "label_reason"}


def _arrow_type(name: str) -> pa.DataType:
    if name in _BOOL:
        return pa.bool_()
    if name in _INT:
        return pa.int64()
    if name in _STR:
        return pa.string()
    return pa.float64()


@dataclass
class Dataset(CalibrationRecords):
    """A dataset in memory: columns by name (numpy arrays) and the metadata of its labelling run."""

    columns: dict[str, NDArray[Any]]
    metadata: dict[str, Any]
    source: str = "dataset"  # the file it was read from, for messages

    def __len__(self) -> int:
        return len(self.columns["frame"])

    def __getitem__(self, name: str) -> NDArray[Any]:
        return self.columns[name]

    def raw_features(self) -> NDArray[np.float64]:
        """The raw features of every row, shape (rows, len(FEATURE_NAMES))."""
        return np.column_stack([self.columns[n] for n in FEATURE_NAMES]).astype(np.float64)

    def refined_corners(self) -> NDArray[np.float64]:
        """The refined corners of every row, shape (rows, len(REFINED_CORNER_NAMES)); NaN where none."""
        return np.column_stack([self.columns[n] for n in REFINED_CORNER_NAMES]).astype(np.float64)

    def subset(self, rows: NDArray[Any]) -> Dataset:
        """The dataset of some rows (a boolean mask or indices), with the same metadata."""
        return Dataset({n: np.asarray(v)[rows] for n, v in self.columns.items()}, dict(self.metadata), self.source)

    # camera(), layout() and robot(): CalibrationRecords, from these two.
    def _meta(self, key: str) -> Any:
        if key not in self.metadata:
            raise InputError(f"{self.source}: its metadata has no '{key}'")
        return self.metadata[key]

    def _record_name(self, key: str) -> str:
        return f"{self.source}: metadata {key}"


def write_dataset(path: str | os.PathLike[str], dataset: Dataset, *, force: bool = False) -> None:
    """Write the Parquet file atomically; the metadata travels in the file's schema."""
    names = dataset_columns()
    missing = [n for n in names if n not in dataset.columns]
    if missing:
        raise ValueError(f"dataset lacks columns {missing}")
    arrays = [pa.array(np.asarray(dataset.columns[n]).tolist(), type=_arrow_type(n)) for n in names]
    meta = {**dataset.metadata, "schema": DATASET_SCHEMA}
    schema = pa.schema([pa.field(n, _arrow_type(n)) for n in names], metadata={"monodock": json.dumps(meta)})
    table = pa.Table.from_arrays(arrays, schema=schema)
    buf = io.BytesIO()
    pq.write_table(table, buf, compression="zstd")
    write_bytes_atomic(path, buf.getvalue(), force=force)


def _read_table(p: Path) -> pa.Table:
    """The Parquet table of a dataset file; InputError when there is no file or it is not Parquet."""
    if not p.is_file():
        raise InputError(f"dataset not found: {p}")
    try:
        return pq.read_table(p)
    except (pa.ArrowException, OSError) as exc:
        raise InputError(f"{p}: not a Parquet file ({str(exc).splitlines()[0]})") from None


def _read_metadata(p: Path, table: pa.Table) -> dict[str, Any]:
    """The table's ``monodock`` metadata, checked to be a JSON object of a schema this monodock reads."""
    raw_meta = (table.schema.metadata or {}).get(b"monodock")
    if raw_meta is None:
        raise InputError(f"{p}: not a monodock dataset (no 'monodock' metadata; write it with monodock label)")
    try:
        meta = parse_json(raw_meta, f"{p}: metadata")
    except ConfigError as exc:
        raise InputError(str(exc)) from None
    if not isinstance(meta, dict):
        raise InputError(f"{p}: metadata: expected a JSON object, got {type(meta).__name__}")
    if meta.get("schema") not in _READABLE_SCHEMAS:
        raise InputError(f"{p}: dataset schema {meta.get('schema')!r}, this monodock reads {DATASET_SCHEMA!r}")
    return meta


def _check_columns(p: Path, table: pa.Table, meta: dict[str, Any]) -> None:
    """Refuse a table lacking a column its schema must have, or without rows."""
    # An older schema lacks the columns added since; they read as NaN.
    optional = _NEW_IN_SCHEMA_2 if meta.get("schema") != DATASET_SCHEMA else ()
    missing = [n for n in dataset_columns() if n not in table.column_names and n not in optional]
    if missing:
        raise InputError(f"{p}: dataset lacks columns {', '.join(missing[:5])}{' …' if len(missing) > 5 else ''}")
    if table.num_rows == 0:
        raise InputError(f"{p}: the dataset has no rows")


def _column_values(p: Path, table: pa.Table, n: str) -> NDArray[Any]:
    """Column ``n`` as a numpy array of its type; -1 or NaN throughout when the file (an older schema) lacks it."""
    if n not in table.column_names:
        return np.full(table.num_rows, -1 if n in _INT else np.nan, dtype=np.int64 if n in _INT else np.float64)
    col = table.column(n)
    want = _arrow_type(n)
    if col.type != want:
        try:
            col = col.cast(want)
        except (pa.ArrowInvalid, pa.ArrowNotImplementedError):
            raise InputError(f"{p}: column {n} holds {col.type}, expected {want}") from None
    if n in _STR:
        return np.array(col.to_pylist(), dtype=object)
    if n in _BOOL:
        return np.asarray(col.to_numpy(zero_copy_only=False), dtype=bool)
    if n in _INT:
        return np.asarray(col.to_numpy(zero_copy_only=False), dtype=np.int64)
    values = np.asarray(col.to_numpy(zero_copy_only=False), dtype=np.float64)
    # NaN is "none" (a marker not seen, a row without a label); anything else is pixels, metres, degrees or
    # seconds, and far beyond MAX_DATASET_VALUE is a damaged file, not a measurement.
    bad = np.flatnonzero(~np.isnan(values) & ~(np.abs(values) <= MAX_DATASET_VALUE))
    if bad.size:
        raise InputError(f"{p}: column {n}, row {bad[0]}: {values[bad[0]]:g} is not a plausible value")
    return values


def read_dataset(path: str | os.PathLike[str]) -> Dataset:
    """Read a dataset written by ``monodock label``; InputError when it is not one."""
    p = Path(path)
    table = _read_table(p)
    meta = _read_metadata(p, table)
    _check_columns(p, table, meta)
    cols = {n: _column_values(p, table, n) for n in dataset_columns()}
    dataset = Dataset(cols, meta, str(p))
    # The calibration the features were measured with is checked as its files would be, before any work.
    dataset.camera(), dataset.robot(), dataset.layout()
    return dataset


@dataclass
class LabelRun:
    """Counts of a labelling run, for the summary line and the dataset's metadata (``core.records`` writes it)."""

    images: int = 0
    unreadable: int = 0
    paired: int = 0
    unpaired: int = 0
    no_marker2: int = 0
    labelled: int = 0
    invalid_labels: Counter[str] = field(default_factory=Counter)

    def add(self, other: LabelRun) -> None:
        """Add another run's counts to these (the parts of one recording labelled in chunks)."""
        self.images += other.images
        self.unreadable += other.unreadable
        self.paired += other.paired
        self.unpaired += other.unpaired
        self.no_marker2 += other.no_marker2
        self.labelled += other.labelled
        self.invalid_labels.update(other.invalid_labels)


def _reason_kind(reason: str) -> str:
    """A reason without its particulars in brackets, so that counts group."""
    return reason.split(" (", maxsplit=1)[0]


def _markers_seen(raw: NDArray[np.float64]) -> str:
    """The markers a raw feature vector saw, as the ``markers_seen`` column holds them ("m1 m2 m3")."""
    return " ".join(m for m in ("m1", "m2", "m3") if raw[FEATURE_NAMES.index(f"{m}_seen")] == 1.0)


def _label_one(
    raw: NDArray[np.float64],
    seen: str,
    error: str,
    scan: Any,
    camera: CameraModel,
    robot: RobotConfig,
    run: LabelRun,
) -> LidarLabel:
    """The LiDAR label of one frame, or an invalid one saying why there is none (counting a missing marker 2)."""
    if error:
        return LidarLabel(reason=f"image unreadable: {error}")
    if "m2" not in seen.split():
        run.no_marker2 += 1
        return LidarLabel(reason="marker 2 not detected")
    if scan is None:
        return LidarLabel(reason="no scan within the pairing tolerance")
    corners = {
        m: raw[[FEATURE_NAMES.index(f"{m}_{c}_{a}") for c in ("tl", "tr", "br", "bl") for a in ("u", "v")]]
        for m in seen.split()
    }
    # The side markers' returns seed the face line too (they help when an occluder hides marker 2's).
    others = [c.reshape(4, 2) for m, c in corners.items() if m != "m2"]
    return label_frame(corners["m2"].reshape(4, 2), scan, camera, robot, other_corners=others)


def _append_values(
    cols: dict[str, list[Any]],
    raw: NDArray[np.float64],
    ref: NDArray[np.float64] | None,
    lab: LidarLabel,
    t: tuple[float, float, float] | None,
) -> None:
    """Append one row's features, refined corners (NaN when none), label and truth (NaN when none) to ``cols``."""
    for name, value in zip(FEATURE_NAMES, raw, strict=True):
        cols[name].append(float(value))
    ref = ref if ref is not None else np.full(len(REFINED_CORNER_NAMES), np.nan)
    for name, value in zip(REFINED_CORNER_NAMES, ref, strict=True):
        cols[name].append(float(value))
    for name, value in lab.row().items():
        cols[name].append(value)
    for name, value in zip(TRUTH_COLUMNS, t if t is not None else (math.nan,) * 3, strict=True):
        cols[name].append(value)


def label_frames(
    frames: list[tuple[int, float, NDArray[np.float64] | None, str]],
    scans: list[Any],
    pairing: NDArray[np.int64],
    truth: list[tuple[float, float, float] | None],
    camera: CameraModel,
    robot: RobotConfig,
    run: LabelRun,
    *,
    refined: list[NDArray[np.float64] | None] | None = None,
    on_row: Callable[[int], None] | None = None,
) -> dict[str, list[Any]]:
    """Dataset columns for detected frames.

    Args:
        frames: per image (index, stamp, raw feature vector or None when unreadable, error).
        scans: the recording's LaserScans.
        pairing: per image the index of its scan, -1 when none was within tolerance.
        truth: per image the true (x, y, yaw_deg), or None.
        camera, robot: the calibration the labels are made with.
        run: counts, updated in place.
        refined: per image its refined corners (REFINED_CORNER_NAMES order), or None.
        on_row: called with each row's index (progress).
    """
    cols: dict[str, list[Any]] = {n: [] for n in dataset_columns()}
    for k, (index, stamp, features, error) in enumerate(frames):
        pair = int(pairing[k])
        run.images += 1
        raw = features if features is not None else np.full(len(FEATURE_NAMES), np.nan)
        if features is None:
            run.unreadable += 1
            seen = ""
        else:
            seen = _markers_seen(raw)
        scan = scans[pair] if pair >= 0 else None
        if pair >= 0:
            run.paired += 1
        else:
            run.unpaired += 1
        lab = _label_one(raw, seen, error, scan, camera, robot, run)
        if lab.valid:
            run.labelled += 1
        else:
            run.invalid_labels[_reason_kind(lab.reason)] += 1
        cols["frame"].append(index)
        cols["image_stamp"].append(stamp)
        cols["scan_stamp"].append(float(scan.stamp) if scan is not None else math.nan)
        cols["paired"].append(pair >= 0)
        cols["markers_seen"].append(seen)
        ref = refined[k] if refined is not None else None
        _append_values(cols, raw, ref, lab, truth[k])
        if on_row is not None:
            on_row(k)
    return cols


# --- labelling a recording, in chunks of images (in worker processes when jobs > 1) ------------------------

# Images per task: ~0.1 s of work, ~2.5 MB to send at 640x480.
_LABEL_CHUNK = 8
# Workers only for a dozen chunks or more (~1 s of work): a short recording labels faster inline than the
# workers start.
_LABEL_INLINE_BELOW = 12
_FrameTask = tuple[Frame, Any, tuple[float, float, float] | None]  # the image, its paired scan, its truth


@dataclass(frozen=True)
class _LabelSetup:
    """What every chunk is labelled with (sent once to each worker)."""

    layout: DockLayout
    camera: CameraModel
    robot: RobotConfig
    refinement: str


_DETECTORS: dict[tuple[str, str], MarkerDetector] = {}  # per process: built once, reused for every chunk


def _detector(setup: _LabelSetup) -> MarkerDetector:
    key = (json.dumps(to_mapping(setup.layout), sort_keys=True), setup.refinement)
    if key not in _DETECTORS:
        _DETECTORS.clear()
        _DETECTORS[key] = MarkerDetector(setup.layout, refinement=setup.refinement)
    return _DETECTORS[key]


def _chunks(items: Iterator[_FrameTask], size: int) -> Iterator[list[_FrameTask]]:
    chunk: list[_FrameTask] = []
    for item in items:
        chunk.append(item)
        if len(chunk) == size:
            yield chunk
            chunk = []
    if chunk:
        yield chunk


def _label_chunk(setup: _LabelSetup, chunk: list[_FrameTask]) -> tuple[dict[str, list[Any]], LabelRun]:
    """Detect, refine and label a few images, each with its own paired scan: their columns and counts."""
    cam, layout = setup.camera, setup.layout
    frames: list[tuple[int, float, NDArray[np.float64] | None, str]] = []
    refined: list[NDArray[np.float64] | None] = []
    for f, _, _ in chunk:
        if f.image is None:
            frames.append((int(f.name), f.stamp, None, f.error or "cannot decode"))
            refined.append(None)
        elif (f.image.shape[1], f.image.shape[0]) != cam.size:
            size = f"{f.image.shape[1]}x{f.image.shape[0]}"
            frames.append(
                (int(f.name), f.stamp, None, f"image is {size}, camera calibration is {cam.width}x{cam.height}")
            )
            refined.append(None)
        else:
            gray = as_gray(f.image)
            det = _detector(setup).detect(gray)
            frames.append((int(f.name), f.stamp, feature_vector(det, cam), ""))
            refined.append(refined_vector(refine_detection(gray, det, cam, modules=layout.modules)))
    scans = [scan for _, scan, _ in chunk if scan is not None]
    pairing = np.full(len(chunk), -1, dtype=np.int64)
    pairing[[k for k, (_, scan, _) in enumerate(chunk) if scan is not None]] = np.arange(len(scans))
    run = LabelRun()
    cols = label_frames(frames, scans, pairing, [t for _, _, t in chunk], cam, setup.robot, run, refined=refined)
    return cols, run


def label_recording(
    path: str | os.PathLike[str],
    layout: DockLayout,
    *,
    camera: CameraModel | None = None,
    robot: RobotConfig | None = None,
    image_topic: str | None = None,
    camera_info_topic: str | None = None,
    scan_topic: str | None = None,
    tolerance_s: float = 0.05,
    refinement: str = "subpix",
    progress: bool = True,
    jobs: int = 1,
) -> tuple[Dataset, LabelRun, list[str]]:
    """Detect, pair and label every image of a recording (``monodock label``).

    The camera comes from the recording's CameraInfo and the mounts from its /tf_static, unless given; a
    recording without them needs them given. Returns the dataset, the counts and the reader's warnings.
    With ``jobs`` > 1 the images are detected and labelled in that many worker processes, a few chunks at a
    time (memory stays flat); every image is paired and labelled on its own, so the dataset does not depend
    on ``jobs``.
    """

    if not (tolerance_s > 0 and math.isfinite(tolerance_s)):
        raise InputError(f"pairing tolerance must be a positive number of seconds, got {tolerance_s}")
    with open_recording(
        path, image_topic=image_topic, camera_info_topic=camera_info_topic, scan_topic=scan_topic
    ) as rec:
        if rec.scan_topic is None:
            raise InputError(f"{path}: no sensor_msgs/LaserScan topic; labels need the LiDAR")
        cam = camera or rec.camera()
        if cam is None:
            raise InputError(f"{path}: no sensor_msgs/CameraInfo topic; give the calibration with --camera")
        if robot is None:
            if not rec.has_mounts():
                raise InputError(f"{path}: no /tf_static from base_link to the camera and the laser; give --robot")
            robot = rec.robot(RobotConfig.default())
        scans = rec.scans()
        scan_stamps = np.array([s.stamp for s in scans], dtype=np.float64)
        truth_poses = rec.ground_truth()
        truth_stamps = np.array([t for t, _ in truth_poses], dtype=np.float64)

        def paired(f: Frame) -> _FrameTask:
            """The image with its scan (nearest within the tolerance) and its truth (nearest within 1 ms)."""
            pair = int(pair_nearest([f.stamp], scan_stamps, tolerance_s)[0])
            match = int(pair_nearest([f.stamp], truth_stamps, 1e-3)[0]) if truth_poses else -1
            pose = truth_poses[match][1] if match >= 0 else None
            return f, scans[pair] if pair >= 0 else None, (pose.x, pose.y, pose.yaw_deg) if pose else None

        setup = _LabelSetup(layout, cam, robot, refinement)
        chunks = _chunks((paired(f) for f in rec.images()), _LABEL_CHUNK)
        run = LabelRun()
        cols: dict[str, list[Any]] = {n: [] for n in dataset_columns()}
        bar = tqdm(desc="detect", unit="frame", leave=False, disable=None if progress else True)
        stream = map_stream(_label_chunk, setup, chunks, jobs=jobs, inline_below=_LABEL_INLINE_BELOW)
        for part_cols, part_run in stream:
            for name, values in part_cols.items():
                cols[name] += values
            run.add(part_run)
            bar.update(part_run.images)
        bar.close()
        warnings = list(rec.warnings)
        source = {"path": str(path), "image_topic": rec.image_topic, "scan_topic": rec.scan_topic}
    metadata = {
        "monodock_version": __version__,
        "camera": cam.to_ros_dict(),
        "robot": to_mapping(robot),
        "layout": to_mapping(layout),
        "source": source,
        "pairing_tolerance_s": tolerance_s,
        "corner_refinement": refinement,
        "counts": to_record(run),
        "warnings": warnings,
        "has_truth": bool(truth_poses),
    }
    arrays = {n: np.asarray(v) for n, v in cols.items()}
    return Dataset(arrays, metadata), run, warnings


@dataclass(frozen=True)
class LabelError:
    """How far one label is from the simulator's truth: mean, MAE and p95 of the signed error."""

    label: str
    unit: str
    rows: int
    bias: float
    mae: float
    p95: float


def label_errors(dataset: Dataset) -> list[LabelError]:
    """Every label against truth (rows with a valid label and truth); empty without truth."""
    ok = np.asarray(dataset["label_valid"], dtype=bool) & np.isfinite(np.asarray(dataset["truth_x_m"], dtype=float))
    if not ok.any():
        return []
    out = []
    # The face line is the default label; the lines over marker 2 alone are what it replaced.
    pairs = (
        ("depth, nearest point (papers)", "cm", "label_x_m", "truth_x_m", 100.0),
        ("depth, marker-2 line at marker 2's centre", "cm", "label_x_line_marker_m", "truth_x_m", 100.0),
        ("depth, face line at marker 2's centre", "cm", "label_x_line_m", "truth_x_m", 100.0),
        ("lateral, marker-2 line at marker 2's centre", "cm", "label_y_marker_m", "truth_y_m", 100.0),
        ("lateral, face line at marker 2's centre", "cm", "label_y_m", "truth_y_m", 100.0),
        ("angle, endpoints (papers)", "deg", "label_yaw_endpoints_deg", "truth_yaw_deg", 1.0),
        ("angle, marker-2 line", "deg", "label_yaw_marker_deg", "truth_yaw_deg", 1.0),
        ("angle, face line", "deg", "label_yaw_deg", "truth_yaw_deg", 1.0),
    )
    for name, unit, col, ref, scale in pairs:
        e = (np.asarray(dataset[col], dtype=float) - np.asarray(dataset[ref], dtype=float))[ok] * scale
        if unit == "deg":
            e = (e + 180.0) % 360.0 - 180.0
        e = e[np.isfinite(e)]
        if e.size:
            a = np.abs(e)
            out.append(
                LabelError(name, unit, int(e.size), float(e.mean()), float(a.mean()), float(np.percentile(a, 95)))
            )
    return out


def label_error_table(errors: list[LabelError]) -> str:
    """Label errors as a markdown table."""
    head = "| label | rows | bias | MAE | p95 |\n|---|---:|---:|---:|---:|\n"
    return head + "".join(
        f"| {e.label} | {e.rows} | {e.bias:+.2f} {e.unit} | {e.mae:.2f} {e.unit} | {e.p95:.2f} {e.unit} |\n"
        for e in errors
    )
