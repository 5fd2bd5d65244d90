"""Hostile images, videos, recordings, .npz files and command-line numbers against the CLI (issue 18, items 3-4).

Every case runs ``python -m monodock.cli.main ...`` in a subprocess with ``PYTHONPATH=SRC`` and is judged by the
promise: bad input gives exit 2 and exactly one stderr line (no traceback, no libpng/OpenCV/FFmpeg line); an input
that is valid but unusual (a 16-bit PNG, a float TIFF, a file name that is not UTF-8) gives exit 0, no library
line, and the same estimate as the plain 8-bit image. Prints the cases per family and how many misbehaved.

    PYTHONPATH=src python bench/hostile_inputs.py [--src SRC] [--verbose]

Run it with ``--src`` pointing at another checkout's ``src`` to compare before and after.
"""

from __future__ import annotations

import argparse
import csv
import os
import shutil
import sqlite3
import struct
import subprocess
import sys
import tempfile
import zlib
from collections import Counter
from collections.abc import Callable
from dataclasses import dataclass, field
from pathlib import Path

import cv2
import numpy as np

NOISE = ("Traceback", "libpng", "[ WARN", "[ERROR", "OpenCV(", "ffmpeg", "Corrupt JPEG", "@ 0x", "moov atom")
TIMEOUT_S = 60


@dataclass
class Case:
    family: str
    name: str
    argv: list[str]
    ok: bool = False  # a valid input: exit 0 expected
    check: Callable[[Path], str] | None = field(default=None, repr=False)  # "" when the output is right


def _chunk(kind: bytes, data: bytes, crc: int | None = None) -> bytes:
    c = zlib.crc32(kind + data) if crc is None else crc
    return struct.pack(">I", len(data)) + kind + data + struct.pack(">I", c & 0xFFFFFFFF)


def _png_header(w: int, h: int) -> bytes:
    ihdr = _chunk(b"IHDR", struct.pack(">IIBBBBB", w, h, 8, 0, 0, 0, 0))
    return b"\x89PNG\r\n\x1a\n" + ihdr + _chunk(b"IDAT", zlib.compress(b"\0" * 64)) + _chunk(b"IEND", b"")


def _jpeg_header(w: int, h: int) -> bytes:
    sof = b"\xff\xc0" + struct.pack(">HBHHB", 11, 8, h, w, 1) + b"\x01\x11\x00"
    return b"\xff\xd8" + sof + b"\xff\xd9"


def _estimates(path: Path) -> list[tuple[str, float, float, float]]:
    with open(path, newline="", encoding="utf-8") as f:
        rows = list(csv.DictReader(f))
    return [(r["valid"], *(float(r[k] or "nan") for k in ("x_m", "y_m", "yaw_deg"))) for r in rows]  # type: ignore[misc]


def build(root: Path, run: Callable[..., subprocess.CompletedProcess[str]]) -> list[Case]:
    """Make the inputs in ``root``; the cases that use them."""
    sim = root / "sim"
    r = run(["simulate", "--out", str(sim), "--frames", "1", "--clean", "--supersample", "1"], timeout=None)
    assert r.returncode == 0, r.stderr
    code = "from monodock.sim import Simulator; s = Simulator(); s.camera.save('camera.yaml'); "
    code += "s.layout.save('layout.yaml'); s.robot.save('robot.yaml')"
    subprocess.run([sys.executable, "-c", code], cwd=root, check=True, env=os.environ)
    cal = [f"--camera={root / 'camera.yaml'}", f"--layout={root / 'layout.yaml'}", f"--robot={root / 'robot.yaml'}"]
    good = cv2.imread(str(sim / "images" / "frame_000000.png"), cv2.IMREAD_UNCHANGED)
    img = root / "img"
    img.mkdir()
    # Bad images.
    (img / "huge.png").write_bytes(_png_header(60000, 60000))
    (img / "huge.jpg").write_bytes(_jpeg_header(60000, 60000))
    (img / "wide.png").write_bytes(_png_header(1_000_000, 2))
    png = cv2.imencode(".png", good)[1].tobytes()
    jpg = cv2.imencode(".jpg", good)[1].tobytes()
    (img / "trunc.png").write_bytes(png[: len(png) // 2])
    (img / "trunc.jpg").write_bytes(jpg[: len(jpg) // 2])
    (img / "garbage.png").write_bytes(os.urandom(5000))
    (img / "garbage.tif").write_bytes(b"II*\x00" + os.urandom(3000))
    (img / "empty.png").write_bytes(b"")
    # Valid but unusual images: the same picture, as the 8-bit PNG must give.
    cv2.imwrite(str(img / "plain.png"), good)
    cv2.imwrite(str(img / "deep.png"), good.astype(np.uint16) * 257)
    cv2.imwrite(str(img / "alpha.png"), cv2.cvtColor(good, cv2.COLOR_GRAY2BGRA))
    cv2.imwrite(str(img / "gray.tif"), good)
    cv2.imwrite(str(img / "float.tif"), good.astype(np.float32) / 255.0)
    cv2.imwrite(str(img / "bgra.tif"), cv2.cvtColor(good, cv2.COLOR_GRAY2BGRA))
    (img / "crc.png").write_bytes(png[:33] + _chunk(b"tEXt", b"k\0v", crc=1) + png[33:])
    (img / "iccp.png").write_bytes(png[:33] + _chunk(b"iCCP", b"x\0\0garbage") + png[33:])
    bad_name = os.fsdecode(bytes(img) + b"/caf\xe9.png")
    shutil.copy(img / "plain.png", bad_name)
    mixed = root / "mixed"
    mixed.mkdir()
    for name in ("plain.png", "garbage.png", "empty.png", "trunc.jpg", "deep.png", "huge.png"):
        shutil.copy(img / name, mixed / name)
    (mixed / "notes.txt").write_text("hello")
    (mixed / "sub.png").mkdir()
    # Videos.
    vid = root / "vid"
    vid.mkdir()
    (vid / "garbage.mp4").write_bytes(os.urandom(20000))
    (vid / "empty.mp4").write_bytes(b"")
    (vid / "header.mp4").write_bytes(b"\x00\x00\x00\x18ftypmp42" + os.urandom(4000))
    frame = cv2.cvtColor(good, cv2.COLOR_GRAY2BGR)
    for name, fourcc in (("v.avi", "MJPG"), ("v.mp4", "mp4v")):
        writer = cv2.VideoWriter(str(vid / name), cv2.VideoWriter_fourcc(*fourcc), 10.0, frame.shape[1::-1])
        for i in range(20):
            writer.write(np.roll(frame, 3 * i, axis=1))
        writer.release()
        data = bytearray((vid / name).read_bytes())
        (vid / f"cut_{name}").write_bytes(data[: len(data) * 6 // 10])
        data[len(data) // 3 : len(data) // 3 + 3000] = np.random.default_rng(0).bytes(3000)
        (vid / f"mid_{name}").write_bytes(bytes(data))
    # Recordings.
    rec = root / "rec"
    rec.mkdir()
    (rec / "garbage_meta").mkdir()
    (rec / "garbage_meta" / "metadata.yaml").write_text("rosbag2_bagfile_information: [unclosed\n")
    (rec / "list_meta").mkdir()
    (rec / "list_meta" / "metadata.yaml").write_text("- 1\n- 2\n")
    (rec / "trunc.mcap").write_bytes(b"\x89MCAP0\r\n" + os.urandom(500))
    (rec / "empty.mcap").write_bytes(b"")
    (rec / "garbage.db3").write_bytes(b"SQLite format 3\x00" + os.urandom(2000))
    db = sqlite3.connect(rec / "noimages.db3")
    db.executescript(
        "CREATE TABLE topics(id INTEGER PRIMARY KEY, name TEXT, type TEXT, serialization_format TEXT, "
        "offered_qos_profiles TEXT); CREATE TABLE messages(id INTEGER PRIMARY KEY, topic_id INTEGER, "
        "timestamp INTEGER, data BLOB);"
    )
    db.close()
    # .npz files of the target views.
    npz = root / "npz"
    for kind, data in (("garbage", os.urandom(3000)), ("empty", b""), ("zip_of_junk", b"PK\x03\x04" + os.urandom(500))):
        (npz / kind).mkdir(parents=True)
        shutil.copy(img / "plain.png", npz / kind / "0000.png")
        (npz / kind / "scans.npz").write_bytes(data)
    (npz / "pickle").mkdir()
    shutil.copy(img / "plain.png", npz / "pickle" / "0000.png")
    np.savez(npz / "pickle" / "scans.npz", ranges=np.array([{"a": 1}], dtype=object))

    out = root / "out"
    out.mkdir()
    n = iter(range(10_000))

    def o(suffix: str = ".csv") -> str:
        return str(out / f"o{next(n)}{suffix}")

    def same_as_plain(path: Path) -> str:
        ref = root / "ref.csv"
        if not ref.exists():
            run(["estimate", str(img / "plain.png"), *cal, "--out", str(ref)])
        a, b = _estimates(ref), _estimates(path)
        same = [
            x[0] == y[0] and np.allclose(x[1:], y[1:], atol=1e-3, equal_nan=True) for x, y in zip(a, b, strict=False)
        ]
        if len(a) != len(b) or not all(same):
            return f"estimate {b} differs from the 8-bit PNG's {a}"
        return ""

    cases: list[Case] = []
    bad = ["huge.png", "huge.jpg", "wide.png", "trunc.png", "trunc.jpg", "garbage.png", "garbage.tif", "empty.png"]
    for name in bad:
        cases.append(Case("images", f"show {name}", ["show", str(img / name), "--out", o(".png"), *cal]))
        cases.append(Case("images", f"estimate {name}", ["estimate", str(img / name), "--out", o(), *cal]))
    cases.append(Case("images", "estimate mixed folder", ["estimate", str(mixed), "--out", o(), *cal]))
    cases.append(
        Case(
            "images",
            "estimate mixed folder --skip-bad",
            ["estimate", str(mixed), "--out", o(), "--skip-bad", *cal],
            ok=True,
        )
    )
    cases.append(
        Case("images", "calibrate intrinsics mixed", ["calibrate", "intrinsics", str(mixed), "--out", o(".yaml")])
    )
    for name in ("deep.png", "alpha.png", "gray.tif", "float.tif", "bgra.tif", "crc.png", "iccp.png"):
        cases.append(Case("images", f"show {name}", ["show", str(img / name), "--out", o(".png"), *cal], ok=True))
        cases.append(
            Case(
                "images",
                f"estimate {name}",
                ["estimate", str(img / name), "--out", o(), *cal],
                ok=True,
                check=same_as_plain,
            )
        )
    cases.append(Case("images", "show non-UTF-8 name", ["show", bad_name, "--out", o(".png"), *cal], ok=True))
    cases.append(
        Case(
            "images",
            "estimate non-UTF-8 name",
            ["estimate", bad_name, "--out", o(), *cal],
            ok=True,
            check=same_as_plain,
        )
    )
    cases.append(
        Case(
            "images",
            "estimate folder with non-UTF-8 name",
            ["estimate", str(img), "--out", o(), "--skip-bad", *cal],
            ok=True,
        )
    )
    cases.append(
        Case(
            "images",
            "show --out non-UTF-8",
            ["show", str(img / "plain.png"), "--out", os.fsdecode(bytes(out) + b"/\xff.png"), *cal],
            ok=True,
        )
    )
    cases.append(Case("images", "show missing image", ["show", str(img / "nope.png"), "--out", o(".png"), *cal]))
    cases.append(Case("images", "show a folder", ["show", str(img), "--out", o(".png"), *cal]))
    for name in ("garbage.mp4", "empty.mp4", "header.mp4"):
        cases.append(Case("videos", f"estimate {name}", ["estimate", str(vid / name), "--out", o(), *cal]))
        cases.append(Case("videos", f"run {name}", ["run", "--source", str(vid / name), "--out", o(), *cal]))
    for name in ("cut_v.avi", "mid_v.avi", "mid_v.mp4"):  # frames to the cut or around the damage: exit 0, quietly
        cases.append(Case("videos", f"estimate {name}", ["estimate", str(vid / name), "--out", o(), *cal], ok=True))
        cases.append(Case("videos", f"run {name}", ["run", "--source", str(vid / name), "--out", o(), *cal], ok=True))
    cases.append(Case("videos", "estimate cut_v.mp4", ["estimate", str(vid / "cut_v.mp4"), "--out", o(), *cal]))
    for name in ("garbage_meta", "list_meta", "trunc.mcap", "empty.mcap", "garbage.db3", "noimages.db3"):
        p = str(rec / name)
        cases.append(Case("recordings", f"estimate {name}", ["estimate", p, "--out", o(), *cal]))
        cases.append(Case("recordings", f"run {name}", ["run", "--source", p, "--out", o(), *cal]))
        cases.append(Case("recordings", f"label {name}", ["label", p, "--layout", cal[1][9:], "--out", o(".parquet")]))
    for kind in ("garbage", "empty", "zip_of_junk", "pickle"):
        cases.append(
            Case(
                "npz",
                f"calibrate extrinsics {kind} scans.npz",
                ["calibrate", "extrinsics", "--target-views", str(npz / kind), cal[0], cal[2], "--out", o(".yaml")],
            )
        )
    numbers = [
        ["--seed", "-1"],
        ["--seed", "99999999999999999999999"],
        ["--depth", "1", "inf"],
        ["--depth", "nan", "1"],
        ["--depth", "2", "1"],
        ["--depth", "-1", "1"],
        ["--depth", "0", "1"],
        ["--lateral", "-inf", "0"],
        ["--lateral", "1", "-1"],
        ["--yaw", "1000", "2000"],
        ["--yaw", "-200", "0"],
        ["--yaw", "nan", "0"],
        ["--gamma", "0"],
        ["--gamma", "nan"],
        ["--gamma", "1e308"],
        ["--exposure", "0"],
        ["--exposure", "inf"],
        ["--read-noise", "1e300"],
        ["--defocus", "1e9"],
        ["--motion-blur", "1e9"],
        ["--vignetting", "5"],
        ["--occluder-probability", "2"],
        ["--exposure-jitter", "1e6"],
        ["--shot-noise", "1e300"],
        ["--side-walls", "0"],
        ["--side-walls", "nan"],
        ["--side-walls", "-1"],
        ["--format", "rosbag2", "--camera-rate", "1e-9"],
        ["--format", "rosbag2", "--camera-rate", "nan"],
        ["--format", "rosbag2", "--lidar-rate", "0"],
        ["--format", "rosbag2", "--lidar-rate", "1e12"],
        ["--format", "rosbag2", "--density", "1,nan"],
        ["--format", "rosbag2", "--density", "-1," + ",".join(["1"] * 44)],
        ["--frames", "0"],
        ["--frames", "10000000000"],
        ["--preview", "-3"],
        ["--jobs", "-2"],
    ]
    for extra in numbers:
        frames = [] if "--frames" in extra else ["--frames", "1"]
        cases.append(Case("numbers", "simulate " + " ".join(extra), ["simulate", "--out", o(""), *frames, *extra]))
    others = [
        ["train", str(root / "none.parquet"), "--out", o(""), "--trials", "0"],
        ["train", str(root / "none.parquet"), "--out", o(""), "--trials", "100000000"],
        ["train", str(root / "none.parquet"), "--out", o(""), "--fusion-holdout", "nan"],
        ["train", str(root / "none.parquet"), "--out", o(""), "--seed", "-1"],
        ["train", str(root / "none.parquet"), "--out", o(""), "--jobs", "-1"],
        ["label", str(rec / "noimages.db3"), "--layout", cal[1][9:], "--out", o(".parquet"), "--tolerance", "nan"],
        ["label", str(rec / "noimages.db3"), "--layout", cal[1][9:], "--out", o(".parquet"), "--tolerance", "1e300"],
        ["run", "--source", str(img / "plain.png"), "--max-frames", "0", *cal],
        ["calibrate", "intrinsics", str(img), "--out", o(".yaml"), "--square", "nan"],
        ["calibrate", "intrinsics", str(img), "--out", o(".yaml"), "--max-views", "100000000"],
        ["calibrate", "intrinsics", str(img), "--out", o(".yaml"), "--min-views", "0"],
        ["calibrate", "intrinsics", str(img), "--out", o(".yaml"), "--max-blur", "inf"],
        [
            "calibrate",
            "extrinsics",
            "--target-views",
            str(npz / "garbage"),
            cal[0],
            cal[2],
            "--out",
            o(".yaml"),
            "--tolerance",
            "inf",
        ],
        ["evaluate", "--robustness", "--model", str(root), "--out", o(""), "--frames", "100000000"],
        ["evaluate", "--robustness", "--model", str(root), "--out", o(""), "--seed", "-1"],
        ["evaluate", "--robustness", "--model", str(root), "--out", o(""), "--jobs", "0"],
        ["dock-sim", "--trials", "100000000"],
        ["dock-sim", "--seed", "-1"],
        ["dock-sim", "--distance", "1", "nan"],
        ["dock-sim", "--distance", "1", "1e300"],
        ["dock-sim", "--max-heading", "nan"],
        ["dock-sim", "--camera-rate", "nan"],
        ["dock-sim", "--camera-rate", "1e-9"],
        ["dock-sim", "--exposure", "nan"],
        ["dock-sim", "--standoff", "inf"],
        ["dock-sim", "--standoff", "nan"],
        ["dock-sim", "--max-retries", "100000000"],
        ["dock-sim", "--train-stops", "10000000000"],
        ["dock-sim", "--jobs", "-1"],
        ["demo", "--out", o(""), "--seed", "-1"],
        ["demo", "--out", o(""), "--jobs", "-1"],
    ]
    quick = ["--method", "board", "--cases", "1", "--trials", "1"]
    for words in others:
        argv = [*words, *quick[: 4 if "--trials" in words else 6]] if words[0] == "dock-sim" else words
        cases.append(Case("numbers", " ".join(a if not a.startswith(str(root)) else Path(a).name for a in argv), argv))
    return cases


def judge(case: Case, r: subprocess.CompletedProcess[str] | None) -> str:
    """ "" if the case kept the promise, else what went wrong."""
    if r is None:
        return f"no answer in {TIMEOUT_S} s"
    lines = r.stderr.splitlines()
    noise = [line for line in lines if any(n in line for n in NOISE)]
    if noise:
        return f"library or traceback line: {noise[0][:120]!r}"
    if case.ok:
        if r.returncode != 0:
            return f"exit {r.returncode}: {r.stderr.strip()[:160]!r}"
        if case.check is not None:
            return case.check(Path(case.argv[case.argv.index("--out") + 1]))
        return ""
    if r.returncode != 2:
        return f"exit {r.returncode}: {r.stderr.strip()[:160]!r}"
    if len(lines) != 1:
        return f"{len(lines)} stderr lines: {r.stderr.strip()[:200]!r}"
    if "error::" in lines[0]:
        return f"bad message: {lines[0]!r}"
    return ""


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--src", default=str(Path(__file__).resolve().parents[1] / "src"), help="monodock's src folder")
    ap.add_argument("--verbose", action="store_true", help="print every case and its stderr")
    ap.add_argument("--family", help="only this family")
    args = ap.parse_args()
    env = {**os.environ, "PYTHONPATH": args.src, "PYTHONIOENCODING": "utf-8", "MONODOCK_CACHE": ""}

    def run(argv: list[str], timeout: float | None = TIMEOUT_S) -> subprocess.CompletedProcess[str]:
        return subprocess.run(
            [sys.executable, "-m", "monodock.cli.main", *argv],
            check=False,
            capture_output=True,
            text=True,
            errors="backslashreplace",
            env=env,
            timeout=timeout,
            stdin=subprocess.DEVNULL,
        )

    with tempfile.TemporaryDirectory() as tmp:
        root = Path(tmp)
        cases = build(root, run)
        tried: Counter[str] = Counter()
        failed: Counter[str] = Counter()
        for case in cases:
            if args.family and case.family != args.family:
                continue
            try:
                r: subprocess.CompletedProcess[str] | None = run(case.argv)
            except subprocess.TimeoutExpired:
                r = None
            verdict = judge(case, r)
            tried[case.family] += 1
            failed[case.family] += bool(verdict)
            if verdict or args.verbose:
                print(f"{'FAIL' if verdict else 'ok  '} [{case.family}] {case.name}: {verdict}", flush=True)
                if args.verbose and r is not None:
                    print("      " + r.stderr.strip().replace("\n", "\n      ")[:600], flush=True)
        for family in tried:
            print(f"{family:12s} {tried[family]:3d} cases, {failed[family]:3d} misbehaved")
        print(f"{'total':12s} {sum(tried.values()):3d} cases, {sum(failed.values()):3d} misbehaved")
    return 0


if __name__ == "__main__":
    sys.exit(main())
