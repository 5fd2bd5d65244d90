"""Hostile images, videos, recordings and .npz files through the CLI (issue 18): one line of monodock's own and exit
2, never a traceback or a line of libpng, libjpeg, libtiff, FFmpeg or OpenCV; a valid but unusual image (16-bit,
float, alpha, one channel, a name that is not UTF-8) gives the estimate of the plain 8-bit image."""

from __future__ import annotations

import csv
import os
import shutil
import sqlite3
import struct
import zlib
from pathlib import Path

import cv2
import numpy as np
import pytest

from monodock.cli.main import main
from monodock.core.images import MAX_IMAGE_SIDE, ImageError, decode, header_size, printable, to_uint8
from monodock.core.quiet import command_session, library_output
from monodock.sim import Nuisances, Simulator
from shared import pose_at

NOISE = ("Traceback", "libpng", "[ WARN", "[ERROR", "OpenCV(", "ffmpeg", "Corrupt JPEG", " @ 0x", "moov atom")


def _chunk(kind: bytes, data: bytes, crc: int | None = None) -> bytes:
    c = zlib.crc32(kind + data) if crc is None else crc
    return struct.pack(">I", len(data)) + kind + data + struct.pack(">I", c & 0xFFFFFFFF)


def png_claiming(width: int, height: int) -> bytes:
    """A PNG whose header claims width x height, with almost no pixel data."""
    ihdr = _chunk(b"IHDR", struct.pack(">IIBBBBB", width, height, 8, 0, 0, 0, 0))
    return b"\x89PNG\r\n\x1a\n" + ihdr + _chunk(b"IDAT", zlib.compress(b"\0" * 64)) + _chunk(b"IEND", b"")


def jpeg_claiming(width: int, height: int) -> bytes:
    return b"\xff\xd8\xff\xc0" + struct.pack(">HBHHB", 11, 8, height, width, 1) + b"\x01\x11\x00\xff\xd9"


def with_bad_text_crc(png: bytes) -> bytes:
    """A valid PNG with an ancillary chunk whose CRC is wrong: libpng warns ("tEXt: CRC error") and decodes."""
    return png[:33] + _chunk(b"tEXt", b"k\0v", crc=1) + png[33:]


def run(argv: list[str], capfd: pytest.CaptureFixture[str]) -> tuple[int, str, str]:
    try:
        code = main(argv)
    except SystemExit as exc:
        code = int(exc.code or 0)
    out, err = capfd.readouterr()
    return code, out, err


def assert_one_line(code: int, err: str, needle: str = "") -> None:
    lines = err.strip().splitlines()
    assert code == 2, err
    assert len(lines) == 1, err
    assert lines[0].startswith("monodock "), err
    assert ": error: " in lines[0], err
    assert "error::" not in lines[0], err
    assert needle in lines[0], err
    assert not any(n in err for n in NOISE), err


def assert_quiet(err: str) -> None:
    assert not any(n in err for n in NOISE), err


@pytest.fixture(scope="module")
def scene(tmp_path_factory: pytest.TempPathFactory) -> Path:
    """One clean frame of the charger at a known pose (plain.png, 8-bit mono), and the calibration files."""
    root = tmp_path_factory.mktemp("hostile")
    sim = Simulator(nuisances=Nuisances.clean().updated(supersample=1), seed=4)
    image = sim.frame(pose_at(0.9, 0.1, 12.0), 0.0, np.random.default_rng(0)).image
    assert image.dtype == np.uint8
    assert image.ndim == 2
    cv2.imwrite(str(root / "plain.png"), image)
    sim.camera.save(root / "camera.yaml")
    sim.layout.save(root / "layout.yaml")
    sim.robot.save(root / "robot.yaml")
    return root


def cal(scene: Path) -> list[str]:
    return [f"--{k}={scene / f'{k}.yaml'}" for k in ("camera", "layout", "robot")]


def estimate_rows(path: Path) -> list[dict[str, str]]:
    with open(path, newline="", encoding="utf-8") as f:
        return list(csv.DictReader(f))


def pose(row: dict[str, str]) -> tuple[float, float, float]:
    return float(row["x_m"]), float(row["y_m"]), float(row["yaw_deg"])


# --- bad images -----------------------------------------------------------------------------------------------


def _bad_images(scene: Path) -> dict[str, bytes]:
    good = (scene / "plain.png").read_bytes()
    jpg = cv2.imencode(".jpg", cv2.imread(str(scene / "plain.png")))[1].tobytes()
    return {
        "huge.png": png_claiming(60000, 60000),
        "huge.jpg": jpeg_claiming(60000, 60000),
        "wide.png": png_claiming(1_000_000, 2),
        "truncated.png": good[: len(good) // 2],
        "truncated.jpg": jpg[: len(jpg) // 2],
        "garbage.png": bytes(np.random.default_rng(1).integers(0, 256, 5000, dtype=np.uint8)),
        "garbage.tif": b"II*\x00" + bytes(np.random.default_rng(2).integers(0, 256, 3000, dtype=np.uint8)),
        "empty.png": b"",
    }


@pytest.mark.parametrize("name", ["huge.png", "huge.jpg", "wide.png", "truncated.png", "truncated.jpg",
                                  "garbage.png", "garbage.tif", "empty.png"])  # fmt: skip
@pytest.mark.parametrize("command", ["show", "estimate"])
def test_bad_image_is_one_line(
    command: str, name: str, scene: Path, tmp_path: Path, capfd: pytest.CaptureFixture[str]
) -> None:
    bad = tmp_path / name
    bad.write_bytes(_bad_images(scene)[name])
    out = tmp_path / ("o.png" if command == "show" else "o.csv")
    code, _, err = run([command, str(bad), "--out", str(out), *cal(scene)], capfd)
    assert_one_line(code, err, name)
    assert not out.exists()


def test_header_size_is_checked_before_decoding() -> None:
    assert header_size(png_claiming(60000, 50)) == (60000, 50)
    assert header_size(jpeg_claiming(640, 480)) == (640, 480)
    with pytest.raises(ImageError, match=r"60000x60000"):
        decode(png_claiming(60000, 60000))
    with pytest.raises(ImageError, match="claims"):
        decode(png_claiming(MAX_IMAGE_SIDE + 1, 1))
    real = cv2.imencode(".tif", np.zeros((7, 9), np.uint8))[1].tobytes()
    assert header_size(real) == (9, 7)
    assert header_size(cv2.imencode(".bmp", np.zeros((7, 9, 3), np.uint8))[1].tobytes()) == (9, 7)
    assert header_size(cv2.imencode(".webp", np.zeros((7, 9, 3), np.uint8))[1].tobytes()) == (9, 7)


def test_mixed_folder_with_skip_bad_gives_invalid_rows(
    scene: Path, tmp_path: Path, capfd: pytest.CaptureFixture[str]
) -> None:
    folder = tmp_path / "mixed"
    folder.mkdir()
    for name, data in _bad_images(scene).items():
        (folder / name).write_bytes(data)
    shutil.copy(scene / "plain.png", folder / "plain.png")
    (folder / "notes.txt").write_text("not an image")
    (folder / "sub.png").mkdir()  # a folder named like an image
    code, _, err = run(["estimate", str(folder), "--out", str(tmp_path / "a.csv"), *cal(scene)], capfd)
    assert_one_line(code, err)
    code, _, err = run(["estimate", str(folder), "--skip-bad", "--out", str(tmp_path / "b.csv"), *cal(scene)], capfd)
    assert code == 0, err
    assert_quiet(err)
    rows = {r["frame"]: r for r in estimate_rows(tmp_path / "b.csv")}
    assert rows["plain.png"]["valid"] == "true"
    assert all(rows[n]["valid"] == "false" and rows[n]["reason"] for n in _bad_images(scene))
    assert "60000x60000" in rows["huge.png"]["reason"]


# --- valid but unusual images ---------------------------------------------------------------------------------


def _unusual(image: np.ndarray) -> dict[str, np.ndarray]:
    return {
        "deep.png": image.astype(np.uint16) * 257,
        "alpha.png": cv2.cvtColor(image, cv2.COLOR_GRAY2BGRA),
        "color.png": cv2.cvtColor(image, cv2.COLOR_GRAY2BGR),
        "gray.tif": image,
        "float.tif": image.astype(np.float32) / 255.0,
        "bgra.tif": cv2.cvtColor(image, cv2.COLOR_GRAY2BGRA),
        "deep.tif": cv2.cvtColor(image, cv2.COLOR_GRAY2BGR).astype(np.uint16) * 257,
    }


@pytest.mark.parametrize("name", ["deep.png", "alpha.png", "color.png", "gray.tif", "float.tif", "bgra.tif",
                                  "deep.tif", "crc.png"])  # fmt: skip
def test_unusual_image_gives_the_plain_images_estimate(
    name: str, scene: Path, tmp_path: Path, capfd: pytest.CaptureFixture[str]
) -> None:
    plain = cv2.imread(str(scene / "plain.png"), cv2.IMREAD_UNCHANGED)
    path = tmp_path / name
    if name == "crc.png":
        path.write_bytes(with_bad_text_crc((scene / "plain.png").read_bytes()))
    else:
        assert cv2.imwrite(str(path), _unusual(plain)[name])
    code, _, err = run(["estimate", str(scene / "plain.png"), "--out", str(tmp_path / "ref.csv"), *cal(scene)], capfd)
    assert code == 0, err
    code, _, err = run(["estimate", str(path), "--out", str(tmp_path / "e.csv"), *cal(scene)], capfd)
    assert code == 0, err
    assert_quiet(err)
    (ref,), (got,) = estimate_rows(tmp_path / "ref.csv"), estimate_rows(tmp_path / "e.csv")
    assert got["valid"] == ref["valid"] == "true", got["reason"]
    assert np.allclose(pose(got), pose(ref), atol=1e-3)
    # The truth: the dock 0.9 m from the camera, 0.1 m to the side, yawed 12 degrees.
    assert np.allclose(pose(got), (0.9 + 0.17, 0.1, 12.0), atol=(0.03, 0.03, 2.0))
    code, _out, err = run(["show", str(path), "--out", str(tmp_path / "o.png"), *cal(scene)], capfd)
    assert code == 0, err
    assert_quiet(err)
    overlay = cv2.imread(str(tmp_path / "o.png"))
    assert overlay is not None
    assert overlay.dtype == np.uint8


def test_to_uint8_conversions_and_refusals() -> None:
    img = np.arange(256, dtype=np.uint8).reshape(16, 16)
    assert np.array_equal(to_uint8(img.astype(np.uint16) * 257), img)
    assert np.array_equal(to_uint8(img.astype(np.float64) / 255.0), img)
    assert np.array_equal(to_uint8(img.astype(np.float32)), img)  # 0-255 floats stay
    assert to_uint8(np.dstack([img] * 4)).shape == (16, 16, 3)
    assert to_uint8(img[:, :, None]).shape == (16, 16)
    with pytest.raises(ImageError, match="NaN"):
        to_uint8(np.full((4, 4), np.nan, np.float32))
    with pytest.raises(ImageError, match="int16"):
        to_uint8(np.zeros((4, 4), np.int16))
    with pytest.raises(ImageError, match="2 channels"):
        to_uint8(np.zeros((4, 4, 2), np.uint8))


def test_file_name_that_is_not_utf8(scene: Path, tmp_path: Path, capfd: pytest.CaptureFixture[str]) -> None:
    folder = tmp_path / "names"
    folder.mkdir()
    odd = os.fsdecode(os.fsencode(folder) + b"/caf\xe9.png")
    shutil.copy(scene / "plain.png", odd)
    est = tmp_path / "e.csv"
    code, out, err = run(["estimate", str(folder), "--out", str(est), *cal(scene)], capfd)
    assert code == 0, err
    (row,) = estimate_rows(est)
    assert row["frame"] == "caf\\xe9.png" == printable(os.path.basename(odd))
    assert row["valid"] == "true"
    odd_out = os.fsdecode(os.fsencode(tmp_path) + b"/\xff.png")
    code, out, err = run(["show", odd, "--out", odd_out, *cal(scene)], capfd)
    assert code == 0, err
    assert "\\xff.png" in out
    assert Path(odd_out).is_file()
    # A bad image of such a name: the one line names it with \xNN.
    bad = os.fsdecode(os.fsencode(tmp_path) + b"/\xfe.png")
    Path(bad).write_bytes(b"junk")
    code, _, err = run(["show", bad, "--out", str(tmp_path / "x.png"), *cal(scene)], capfd)
    assert_one_line(code, err, "\\xfe.png")


def test_folder_and_missing_image_in_show(scene: Path, tmp_path: Path, capfd: pytest.CaptureFixture[str]) -> None:
    code, _, err = run(["show", str(tmp_path), "--out", str(tmp_path / "o.png"), *cal(scene)], capfd)
    assert_one_line(code, err, "is a folder, not an image")
    code, _, err = run(["show", str(tmp_path / "no.png"), "--out", str(tmp_path / "o.png"), *cal(scene)], capfd)
    assert_one_line(code, err, "image not found")


# --- the libraries' own lines -----------------------------------------------------------------------------------


def test_libpng_warning_is_dropped_in_a_command_and_kept_under_debug(
    scene: Path, tmp_path: Path, capfd: pytest.CaptureFixture[str]
) -> None:
    data = with_bad_text_crc((scene / "plain.png").read_bytes())
    # Outside a command, as a library: libpng says what it says (this is what the CLI must hide).
    decode(data)
    assert "libpng warning" in capfd.readouterr().err
    with command_session(debug=False):
        decode(data)
    assert capfd.readouterr().err == ""
    with command_session(debug=True):
        decode(data)
    assert "libpng warning" in capfd.readouterr().err
    # The whole command line, with --debug: the library's warning is kept.
    path = tmp_path / "crc.png"
    path.write_bytes(data)
    code, _, err = run(["--debug", "show", str(path), "--out", str(tmp_path / "o.png"), *cal(scene)], capfd)
    assert code == 0
    assert "libpng warning" in err


def test_stderr_is_back_after_the_libraries_spoke(capfd: pytest.CaptureFixture[str]) -> None:
    env, level = os.environ.get("OPENCV_FFMPEG_LOGLEVEL"), cv2.utils.logging.getLogLevel()
    with command_session(debug=False):
        assert os.environ["OPENCV_FFMPEG_LOGLEVEL"] == "-8"
        assert cv2.utils.logging.getLogLevel() == cv2.utils.logging.LOG_LEVEL_SILENT
        with library_output():
            os.write(2, b"dropped\n")
        os.write(2, b"kept\n")
    assert capfd.readouterr().err == "kept\n"
    assert os.environ.get("OPENCV_FFMPEG_LOGLEVEL") == env
    assert cv2.utils.logging.getLogLevel() == level


# --- videos, recordings, scans.npz ------------------------------------------------------------------------------


@pytest.mark.parametrize("kind", ["garbage", "empty", "header"])
@pytest.mark.parametrize("command", ["estimate", "run"])
def test_bad_video_is_one_line(
    kind: str, command: str, scene: Path, tmp_path: Path, capfd: pytest.CaptureFixture[str]
) -> None:
    video = tmp_path / f"{kind}.mp4"
    junk = bytes(np.random.default_rng(3).integers(0, 256, 20000, dtype=np.uint8))
    video.write_bytes({"garbage": junk, "empty": b"", "header": b"\x00\x00\x00\x18ftypmp42" + junk[:4000]}[kind])
    out = str(tmp_path / "o.csv")
    argv = ["estimate", str(video), "--out", out] if command == "estimate" else ["run", "--source", str(video)]
    code, _, err = run([*argv, *cal(scene)], capfd)
    assert_one_line(code, err, f"{kind}.mp4")


def _recording(tmp_path: Path, kind: str) -> Path:
    rng = np.random.default_rng(5)
    if kind == "garbage_metadata":
        (tmp_path / kind).mkdir()
        (tmp_path / kind / "metadata.yaml").write_text("rosbag2_bagfile_information: [unclosed\n")
        return tmp_path / kind
    if kind == "truncated.mcap":  # the magic, then a record length of random bytes (up to 2^64)
        (tmp_path / kind).write_bytes(b"\x89MCAP0\r\n\x01" + b"\xff" * 8 + bytes(rng.integers(0, 256, 500, np.uint8)))
        return tmp_path / kind
    if kind == "truncated.bag":
        (tmp_path / kind).write_bytes(
            b"#ROSBAG V2.0\n" + b"\xff\xff\xff\xf0" + bytes(rng.integers(0, 256, 300, np.uint8))
        )
        return tmp_path / kind
    if kind == "garbage.db3":
        (tmp_path / kind).write_bytes(b"SQLite format 3\x00" + bytes(rng.integers(0, 256, 2000, np.uint8)))
        return tmp_path / kind
    assert kind == "no_images.db3"
    db = sqlite3.connect(tmp_path / kind)
    db.executescript(
        "CREATE TABLE topics(id INTEGER PRIMARY KEY, name TEXT, type TEXT, serialization_format TEXT, "
        "offered_qos_profiles TEXT); CREATE TABLE messages(id INTEGER PRIMARY KEY, topic_id INTEGER, "
        "timestamp INTEGER, data BLOB);"
    )
    db.close()
    return tmp_path / kind


@pytest.mark.parametrize("kind", ["garbage_metadata", "truncated.mcap", "truncated.bag", "garbage.db3",
                                  "no_images.db3"])  # fmt: skip
@pytest.mark.parametrize("command", ["estimate", "run", "label"])
def test_bad_recording_is_one_line(
    kind: str, command: str, scene: Path, tmp_path: Path, capfd: pytest.CaptureFixture[str]
) -> None:
    rec = str(_recording(tmp_path, kind))
    out = str(tmp_path / "o.csv")
    argv = {
        "estimate": ["estimate", rec, "--out", out, *cal(scene)],
        "run": ["run", "--source", rec, "--out", out, *cal(scene)],
        "label": ["label", rec, "--layout", str(scene / "layout.yaml"), "--out", str(tmp_path / "d.parquet")],
    }[command]
    code, _, err = run(argv, capfd)
    assert_one_line(code, err, kind)


@pytest.mark.parametrize("kind", ["random", "empty", "zip_of_junk", "pickle", "scalar_geometry"])
def test_bad_scans_npz_is_one_line(kind: str, scene: Path, tmp_path: Path, capfd: pytest.CaptureFixture[str]) -> None:
    views = tmp_path / "views"
    views.mkdir()
    shutil.copy(scene / "plain.png", views / "0000.png")
    npz = views / "scans.npz"
    rng = np.random.default_rng(6)
    if kind == "random":
        npz.write_bytes(bytes(rng.integers(0, 256, 3000, np.uint8)))
    elif kind == "empty":
        npz.write_bytes(b"")
    elif kind == "zip_of_junk":
        npz.write_bytes(b"PK\x03\x04" + bytes(rng.integers(0, 256, 500, np.uint8)))
    elif kind == "pickle":  # an object array would need unpickling: refused, never loaded
        np.savez(npz, ranges=np.array([{"a": 1}], dtype=object), angle_min=0.0, angle_increment=0.01,
                 range_min=0.1, range_max=10.0)  # fmt: skip
    else:
        np.savez(npz, ranges=np.ones((1, 10)), angle_min=np.zeros(3), angle_increment=np.nan, range_min=0.1,
                 range_max=10.0)  # fmt: skip
    argv = [
        "calibrate",
        "extrinsics",
        "--target-views",
        str(views),
        *cal(scene)[::2],
        "--out",
        str(tmp_path / "x.yaml"),
    ]
    code, _, err = run(argv, capfd)
    assert_one_line(code, err, "scans.npz")


@pytest.mark.parametrize("damage", ["cut", "middle"])
def test_damaged_video_gives_its_readable_frames_quietly(
    damage: str, scene: Path, tmp_path: Path, capfd: pytest.CaptureFixture[str]
) -> None:
    """FFmpeg's decoder complains ("[mjpeg @ 0x...] overread 8", "bad vlc") on every damaged frame: not here."""
    frame = cv2.cvtColor(cv2.imread(str(scene / "plain.png"), cv2.IMREAD_GRAYSCALE), cv2.COLOR_GRAY2BGR)
    video = tmp_path / "v.avi"
    writer = cv2.VideoWriter(str(video), cv2.VideoWriter_fourcc(*"MJPG"), 10.0, frame.shape[1::-1])
    for _ in range(10):
        writer.write(frame)
    writer.release()
    data = bytearray(video.read_bytes())
    if damage == "cut":
        data = data[: len(data) * 6 // 10]
    else:
        data[len(data) // 3 : len(data) // 3 + 3000] = np.random.default_rng(0).bytes(3000)
    video.write_bytes(bytes(data))
    est = tmp_path / "e.csv"
    code, _, err = run(["estimate", str(video), "--out", str(est), *cal(scene)], capfd)
    assert code == 0, err
    assert_quiet(err)
    assert sum(r["valid"] == "true" for r in estimate_rows(est)) >= 4


def test_a_jpeg_that_libjpeg_decodes_only_by_filling_in_is_refused(
    scene: Path, tmp_path: Path, capfd: pytest.CaptureFixture[str]
) -> None:
    """Bytes flipped in a JPEG's entropy-coded data: libjpeg warns ("Corrupt JPEG data") and fills in what it
    could not read, and the board pose of that picture was 0.75 m off the truth. Its warning marks the image
    damaged: one line naming it, or with --skip-bad an invalid row; never a pose."""
    ok, jpg = cv2.imencode(".jpg", cv2.imread(str(scene / "plain.png"), cv2.IMREAD_UNCHANGED))
    assert ok
    data = bytearray(jpg.tobytes())
    rng = np.random.default_rng(9)
    for pos in rng.integers(len(data) // 2, len(data) - 2, 20):
        data[int(pos)] = int(rng.integers(0, 255))
    bad = tmp_path / "damaged.jpg"
    bad.write_bytes(bytes(data))
    assert cv2.imread(str(bad)) is not None, "OpenCV still decodes it: the case this test is about"
    capfd.readouterr()  # libjpeg's own line, from the imread just above (outside a command)

    out = tmp_path / "e.csv"
    code, _, err = run(["estimate", str(bad), "--method", "board", *cal(scene), "--out", str(out)], capfd)
    assert_one_line(code, err, "damaged JPEG data: the decoder filled in what it could not read")
    assert not out.exists()
    code, _, err = run(["estimate", str(bad), "--method", "board", *cal(scene), "--out", str(out), "--skip-bad"], capfd)
    assert code == 0, err
    assert [row["valid"] for row in estimate_rows(out)] == ["false"]
