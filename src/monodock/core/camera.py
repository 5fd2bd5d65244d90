"""The camera model: pinhole intrinsics, plumb_bob lens distortion and image size.

Reads and writes the ROS camera_info YAML of camera_calibration_parsers, and reads OpenCV FileStorage
calibration files. Pixel coordinates follow OpenCV: the centre of the top-left pixel is (0, 0).
"""

from __future__ import annotations

import dataclasses
import functools
import math
import os
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import cv2
import numpy as np
from numpy.typing import ArrayLike, NDArray

from monodock.core.config import MAX_FILE_BYTES, Fields, load_yaml, write_text_atomic, yaml_text
from monodock.errors import ConfigError

__all__ = ["CameraModel"]

_DISTORTION_COUNTS = {"plumb_bob": (5,), "rational_polynomial": (8,)}
_UNDISTORT_CRITERIA = (cv2.TERM_CRITERIA_COUNT | cv2.TERM_CRITERIA_EPS, 100, 1e-14)

# What a camera file may hold (docs/input-files.md): anything outside is a typo or a unit slip, and a lens the
# model cannot invert over the image turns markers into poses tens of metres away.
MAX_IMAGE_SIDE = 16384
FOCAL_RANGE = (0.1, 10.0)  # times the image's longer side: from a 157° fisheye to a 6° telephoto
MAX_SKEW = 1e-3  # times fx: OpenCV's PnP and projectPoints ignore skew, so a file with skew cannot be honoured
FIELD_SCALE_RANGE = (0.5, 2.0)  # how much the distortion may widen or narrow the field against the pinhole


@dataclass(frozen=True)
class CameraModel:
    """Intrinsics of one camera: ``K`` row-major (9 values), distortion ``D`` and the image size."""

    width: int
    height: int
    K: tuple[float, ...]
    D: tuple[float, ...] = (0.0, 0.0, 0.0, 0.0, 0.0)
    distortion_model: str = "plumb_bob"
    name: str = "camera"

    def __post_init__(self) -> None:
        if self.width <= 0 or self.height <= 0:
            raise ConfigError(f"image size must be positive, got {self.width}x{self.height}")
        if len(self.K) != 9:
            raise ConfigError(f"camera_matrix needs 9 values, got {len(self.K)}")
        if not (self.fx > 0 and self.fy > 0):
            raise ConfigError(f"camera_matrix: focal lengths must be positive, got fx={self.fx}, fy={self.fy}")
        counts = _DISTORTION_COUNTS.get(self.distortion_model)
        if counts is None:
            raise ConfigError(
                f"distortion_model '{self.distortion_model}' is not supported (plumb_bob, rational_polynomial)"
            )
        if len(self.D) not in counts:
            raise ConfigError(f"{self.distortion_model} needs {counts[0]} distortion coefficients, got {len(self.D)}")

    # --- construction ---------------------------------------------------------------------------

    @classmethod
    def from_intrinsics(
        cls,
        width: int,
        height: int,
        fx: float,
        fy: float,
        cx: float,
        cy: float,
        dist: ArrayLike = (0.0, 0.0, 0.0, 0.0, 0.0),
        name: str = "camera",
    ) -> CameraModel:
        """A plumb_bob camera from its numbers."""
        d = tuple(float(v) for v in np.asarray(dist, dtype=np.float64).ravel())
        model = "rational_polynomial" if len(d) == 8 else "plumb_bob"
        K = (float(fx), 0.0, float(cx), 0.0, float(fy), float(cy), 0.0, 0.0, 1.0)
        return cls(int(width), int(height), K, d, model, name)

    @classmethod
    def default(cls) -> CameraModel:
        """The simulator's camera: a 640x480 webcam (~55 degrees across) with mild barrel distortion.

        The principal point is off centre on purpose, so that code which assumes the image centre fails.
        """
        return cls.from_intrinsics(
            640, 480, 615.0, 613.0, 322.4, 237.1, (-0.12, 0.08, 0.0006, -0.0004, -0.02), name="sim_camera"
        )

    # --- numbers --------------------------------------------------------------------------------

    @property
    def fx(self) -> float:
        return self.K[0]

    @property
    def fy(self) -> float:
        return self.K[4]

    @property
    def cx(self) -> float:
        return self.K[2]

    @property
    def cy(self) -> float:
        return self.K[5]

    @property
    def matrix(self) -> NDArray[np.float64]:
        """The 3x3 camera matrix."""
        return np.array(self.K, dtype=np.float64).reshape(3, 3)

    @property
    def dist(self) -> NDArray[np.float64]:
        """The distortion coefficients in OpenCV's order."""
        return np.array(self.D, dtype=np.float64)

    @property
    def size(self) -> tuple[int, int]:
        """(width, height) in pixels."""
        return self.width, self.height

    def focal_scaled(self, factor: float) -> CameraModel:
        """This camera with fx and fy times ``factor`` (a focal length that is off, as the miscalibration studies
        and the scale check try); the principal point, distortion and size stay."""
        K = list(self.K)
        K[0] *= factor
        K[4] *= factor
        return dataclasses.replace(self, K=tuple(K))

    def check_plausible(self, source: str = "camera") -> None:
        """ConfigError, one line naming ``source`` and the key, unless this is a camera that can exist.

        The ranges: image sides 1..MAX_IMAGE_SIDE; fx and fy within FOCAL_RANGE times the longer side; the
        principal point on the image; no skew (MAX_SKEW); K's last row 0 0 1; and a lens that OpenCV's model
        inverts over the whole image, one to one, changing the field of view by FIELD_SCALE_RANGE at most
        (checked on the border and a grid, a few ms).
        """
        side = max(self.width, self.height)
        if not (self.width <= MAX_IMAGE_SIDE and self.height <= MAX_IMAGE_SIDE):
            raise ConfigError(f"{source}: image size {self.width}x{self.height} is over {MAX_IMAGE_SIDE} px a side")
        lo, hi = FOCAL_RANGE[0] * side, FOCAL_RANGE[1] * side
        for key, value in (("fx", self.fx), ("fy", self.fy)):
            if not lo <= value <= hi:
                raise ConfigError(
                    f"{source}: camera_matrix: {key} must be within {FOCAL_RANGE[0]:g}-{FOCAL_RANGE[1]:g} times the "
                    f"image's longer side ({lo:g} to {hi:g} px), got {value:g}"
                )
        for key, value, size in (("cx", self.cx, self.width), ("cy", self.cy, self.height)):
            if not 0.0 <= value <= size:
                raise ConfigError(
                    f"{source}: camera_matrix: {key} must be on the image (0 to {size} px), got {value:g}"
                )
        if not abs(self.K[1]) <= MAX_SKEW * self.fx:
            raise ConfigError(
                f"{source}: camera_matrix: skew must be 0 (OpenCV's PnP ignores it; at most {MAX_SKEW:g} fx), "
                f"got {self.K[1]:g}"
            )
        if (self.K[3], self.K[6], self.K[7], self.K[8]) != (0.0, 0.0, 0.0, 1.0):
            raise ConfigError(f"{source}: camera_matrix: expected [fx s cx; 0 fy cy; 0 0 1], got {list(self.K)}")
        problem = _lens_problem(self)
        if problem:
            raise ConfigError(f"{source}: distortion_coefficients: {problem}")

    # --- geometry -------------------------------------------------------------------------------

    def project(self, points_optical: ArrayLike) -> NDArray[np.float64]:
        """Pixels, shape (N, 2), of points in the camera's optical frame, shape (N, 3), through the lens."""
        p = np.asarray(points_optical, dtype=np.float64).reshape(-1, 3)
        px, _ = cv2.projectPoints(p, np.zeros(3), np.zeros(3), self.matrix, self.dist)
        return np.asarray(px, dtype=np.float64).reshape(-1, 2)

    def normalize(self, pixels: ArrayLike) -> NDArray[np.float64]:
        """Undistorted normalised image coordinates (x/z, y/z), shape (N, 2), of distorted pixels.

        Iterates to 1e-14, so that re-projecting the result lands on the pixel to ~1e-12 px.
        """
        px = np.asarray(pixels, dtype=np.float64).reshape(-1, 1, 2)
        out = cv2.undistortPoints(px, self.matrix, self.dist, criteria=_UNDISTORT_CRITERIA)
        return np.asarray(out, dtype=np.float64).reshape(-1, 2)

    def in_view_field(self, points_optical: ArrayLike, margin: float = 0.05) -> NDArray[np.bool_]:
        """Which points (N, 3) are in front of the camera and inside the field the lens maps onto the image.

        A polynomial lens model folds directions far outside the field of view back into the picture (barrel
        distortion turns over past the image's corners), so ``project`` alone can put a point that the camera
        cannot see on a pixel. ``margin`` widens the field by that fraction of its extent.
        """
        p = np.asarray(points_optical, dtype=np.float64).reshape(-1, 3)
        lo, hi = _field_bounds(self)
        pad = (hi - lo) * margin
        with np.errstate(divide="ignore", invalid="ignore"):
            n = p[:, :2] / p[:, 2:3]
        return np.asarray((p[:, 2] > 1e-9) & np.all((n >= lo - pad) & (n <= hi + pad), axis=1))

    def vertex_rays(self) -> NDArray[np.float64]:
        """Normalised coordinates of every pixel corner, shape (height+1, width+1, 2); cached per camera."""
        return _vertex_rays(self)

    # --- files ----------------------------------------------------------------------------------

    def to_ros_dict(self) -> dict[str, Any]:
        """The mapping of a ROS camera_info YAML file (camera_calibration_parsers)."""
        P = np.zeros((3, 4))
        P[:, :3] = self.matrix

        def mat(rows: int, cols: int, data: ArrayLike) -> dict[str, Any]:
            return {"rows": rows, "cols": cols, "data": [float(v) for v in np.asarray(data).ravel()]}

        return {
            "image_width": self.width,
            "image_height": self.height,
            "camera_name": self.name,
            "camera_matrix": mat(3, 3, self.matrix),
            "distortion_model": self.distortion_model,
            "distortion_coefficients": mat(1, len(self.D), self.dist),
            "rectification_matrix": mat(3, 3, np.eye(3)),
            "projection_matrix": mat(3, 4, P),
        }

    def save(self, path: str | os.PathLike[str], *, force: bool = False) -> None:
        """Write the camera as ROS camera_info YAML, atomically."""
        text = yaml_text(self.to_ros_dict(), flow=None)
        write_text_atomic(Path(path), text, force=force)

    @classmethod
    def from_ros_dict(cls, data: dict[str, Any], source: str = "camera") -> CameraModel:
        """Build from a camera_info YAML mapping; also accepts ROS 1 / ROS 2 message spellings (K, D, k, d).

        Read with ``Fields``, not ``core.settings``: ROS's format, with its matrices, its aliases and coefficients
        whose count follows ``distortion_model`` (docs/architecture.md, "Where a change goes").
        """
        f = Fields(data, source)
        width = f.integer("image_width" if f.has("image_width") else "width", minimum=1, maximum=MAX_IMAGE_SIDE)
        height = f.integer("image_height" if f.has("image_height") else "height", minimum=1, maximum=MAX_IMAGE_SIDE)

        def matrix_field(names: tuple[str, ...], counts: tuple[int, ...]) -> list[float]:
            for name in names:
                if f.has(name):
                    value = f.raw(name)
                    if isinstance(value, dict):
                        return f.child(name).numbers("data", counts)
                    return f.numbers(name, counts)
            raise ConfigError(f"{source}: missing field '{names[0]}'")

        K = matrix_field(("camera_matrix", "K", "k"), (9,))
        model = f.string("distortion_model", "plumb_bob")
        counts = _DISTORTION_COUNTS.get(model)
        if counts is None:
            raise f.error("distortion_model", f"'{model}' is not supported (plumb_bob, rational_polynomial)")
        D = matrix_field(("distortion_coefficients", "D", "d"), (4, *counts) if model == "plumb_bob" else counts)
        if len(D) == 4:  # k1 k2 p1 p2 without k3, as some calibrators write it
            D.append(0.0)
        name = f.string("camera_name", "camera")
        f.warn_unknown(_ROS_KEYS)
        try:
            camera = cls(width, height, tuple(K), tuple(D), model, name)
        except ConfigError as exc:
            raise ConfigError(f"{source}: {exc}") from None
        camera.check_plausible(source)
        return camera

    @classmethod
    def load(cls, path: str | os.PathLike[str]) -> CameraModel:
        """Read a ROS camera_info YAML or an OpenCV FileStorage calibration file (YAML, XML or JSON)."""
        p = Path(path)
        if not p.is_file():
            raise ConfigError(f"camera file not found: {p}")
        data = p.read_bytes()
        # OpenCV writes "%YAML:1.0" (3.x/4.x) or "%YAML 1.2" (5.x) and tags matrices !!opencv-matrix.
        if (
            data.lstrip().startswith((b"%YAML", b"<?xml"))
            or b"opencv-matrix" in data
            or p.suffix.lower() in (".xml", ".json")
        ):
            return _load_opencv_storage(p)
        return cls.from_ros_dict(load_yaml(p, "camera"), str(p))


@functools.lru_cache(maxsize=8)
def _field_bounds(camera: CameraModel) -> tuple[NDArray[np.float64], NDArray[np.float64]]:
    """The box in normalised coordinates that the image's border pixels see (through the lens).

    Only the border's pixel corners are undistorted, to the very numbers ``vertex_rays`` gives them (OpenCV
    undistorts point by point): a camera that is only bounded, e.g. the what-if study's twice-the-pixels one,
    does not pay for its whole image's rays (2.5 s of a core at 1280x960).
    """
    w, h = camera.width, camera.height
    u = np.arange(w + 1, dtype=np.float64) - 0.5
    v = np.arange(h + 1, dtype=np.float64) - 0.5
    across, down = np.ones(w + 1), np.ones(h + 1)
    edge = _rays(
        camera,
        np.concatenate(
            [np.c_[u, -0.5 * across], np.c_[u, (h - 0.5) * across], np.c_[-0.5 * down, v], np.c_[(w - 0.5) * down, v]]
        ),
    )
    return edge.min(axis=0), edge.max(axis=0)


@functools.lru_cache(maxsize=8)
def _vertex_rays(camera: CameraModel) -> NDArray[np.float64]:
    u, v = np.meshgrid(
        np.arange(camera.width + 1, dtype=np.float64) - 0.5,
        np.arange(camera.height + 1, dtype=np.float64) - 0.5,
    )
    out = _rays(camera, np.stack([u.ravel(), v.ravel()], axis=1)).reshape(camera.height + 1, camera.width + 1, 2)
    out.setflags(write=False)
    return out


def _rays(camera: CameraModel, pts: NDArray[np.float64]) -> NDArray[np.float64]:
    """Normalised coordinates (N, 2) of pixels (N, 2); ConfigError when the lens does not map them back."""
    rays = camera.normalize(pts)
    check = camera.project(np.c_[rays, np.ones(len(rays))])
    worst = float(np.max(np.abs(check - pts)))
    if not worst < 1e-6:
        raise ConfigError(
            f"camera '{camera.name}': lens distortion cannot be inverted over the image "
            f"(re-projection off by {worst:.2g} px); check distortion_coefficients"
        )
    return rays


_ROS_KEYS = (
    "image_width",
    "image_height",
    "width",
    "height",
    "camera_name",
    "camera_matrix",
    "K",
    "k",
    "distortion_model",
    "distortion_coefficients",
    "D",
    "d",
    "rectification_matrix",
    "projection_matrix",
    "R",
    "P",
    "r",
    "p",
    "header",
    "binning_x",
    "binning_y",
    "roi",
)


@functools.lru_cache(maxsize=16)  # a camera_info topic repeats the same camera with every image: check it once
def _lens_problem(camera: CameraModel) -> str | None:
    """Why the lens cannot be used over this image, or None.

    Two things must hold for every pixel: undistortion finds a ray that projects back onto it, and the lens maps
    rays outward from the principal point one to one (a polynomial that turns over folds far rays back into the
    picture, so a marker there would be read at the wrong place). Checked on the border pixels, a grid inside,
    and 48 points along the ray to each border pixel.
    """
    w, h = camera.width, camera.height
    step = max(1.0, max(w, h) / 128.0)
    us = np.append(np.arange(-0.5, w - 0.5, step), w - 0.5)
    vs = np.append(np.arange(-0.5, h - 0.5, step), h - 0.5)
    border = np.concatenate(
        [
            np.c_[us, np.full_like(us, -0.5)],
            np.c_[us, np.full_like(us, h - 0.5)],
            np.c_[np.full_like(vs, -0.5), vs],
            np.c_[np.full_like(vs, w - 0.5), vs],
        ]
    )
    gu, gv = np.meshgrid(np.linspace(0, w - 1, 16), np.linspace(0, h - 1, 12))
    pixels = np.concatenate([border, np.c_[gu.ravel(), gv.ravel()]])
    with np.errstate(all="ignore"):
        rays = camera.normalize(pixels)
        back = camera.project(np.c_[rays, np.ones(len(rays))])
        worst = float(np.max(np.abs(back - pixels)))
        if not worst < 0.1:  # a strong real lens comes back within ~0.01 px; one that cannot be inverted, by pixels
            return f"the lens cannot be inverted over the image (a pixel comes back {worst:.2g} px off)"
        # How much the lens widens or narrows the image's field against the pinhole of the same K: a real lens by
        # well under 2x; a k1 of 50 or 1e6 keeps fx plausible and shrinks the field 3 to 100 times (markers read
        # 0.4 m or 46 m too far).
        spread = np.ptp(rays[: len(border)], axis=0)
        scale = spread * np.array([camera.fx / w, camera.fy / h])
        # Each side on its own too: a decentred lens (a tangential term of 0.15) can keep the whole field's width
        # and still push one side 2.3 times out, where markers would be read at the wrong bearing.
        edge = rays[: len(border)]
        lens_sides = np.array([edge[:, 0].min(), edge[:, 0].max(), edge[:, 1].min(), edge[:, 1].max()])
        left, right = (-0.5 - camera.cx) / camera.fx, (w - 0.5 - camera.cx) / camera.fx
        top, bottom = (-0.5 - camera.cy) / camera.fy, (h - 0.5 - camera.cy) / camera.fy
        pinhole = np.array([left, right, top, bottom])
        informative = np.abs(pinhole) > 0.05  # a side the principal point sits on says nothing
        sides = (lens_sides / np.where(informative, pinhole, 1.0))[informative]
        scale = np.concatenate([scale, sides])
        if not np.all((scale >= FIELD_SCALE_RANGE[0]) & (scale <= FIELD_SCALE_RANGE[1])):
            worst_scale = float(scale[np.argmax(np.abs(np.log(np.maximum(scale, 1e-300))))])
            return (
                f"the distortion changes the image's field of view {worst_scale:.3g} times against the pinhole; "
                f"a real lens changes it {FIELD_SCALE_RANGE[0]:g} to {FIELD_SCALE_RANGE[1]:g} times"
            )
        t = np.linspace(0.02, 1.0, 48)
        outward = (rays[: len(border), None, :] * t[None, :, None]).reshape(-1, 2)
        px = camera.project(np.c_[outward, np.ones(len(outward))]).reshape(len(border), len(t), 2)
        centre = camera.project(np.array([[0.0, 0.0, 1.0]]))[0]
        radius = np.linalg.norm(px - centre, axis=2)
        if not np.all(np.diff(radius, axis=1) > 0):
            return "the lens folds back inside the image (distortion turns over before the border)"
    return None


def _load_opencv_storage(path: Path) -> CameraModel:
    if path.stat().st_size > MAX_FILE_BYTES:
        raise ConfigError(f"{path}: too large for a camera file (at most {MAX_FILE_BYTES} bytes)")
    try:
        return _read_opencv_storage(path)
    except (cv2.error, SystemError, TypeError, ValueError, OverflowError) as exc:
        # OpenCV's parser reports a malformed file as cv2.error (or, from some nodes, SystemError); a node of the
        # wrong kind comes back as None or an empty matrix.
        detail = str(exc).strip().splitlines()[-1] if str(exc).strip() else type(exc).__name__
        raise ConfigError(f"{path}: cannot be read as an OpenCV FileStorage camera file ({detail[:120]})") from None


def _numbers(matrix: Any, key: str, path: Path) -> NDArray[np.float64]:
    """A FileStorage matrix as float64; refused when it is not one, or stored in a type too small for a camera
    (``dt: u`` keeps focal lengths modulo 256)."""
    if not isinstance(matrix, np.ndarray):
        raise ConfigError(f"{path}: {key}: expected a matrix")
    if matrix.dtype not in (np.float32, np.float64, np.int32):
        raise ConfigError(f"{path}: {key}: stored as {matrix.dtype} (dt), which cannot hold it; use d or f")
    return np.asarray(matrix, dtype=np.float64)


def _refuse_repeated_keys(fs: cv2.FileStorage, path: Path) -> None:
    """Refuse a file whose top-level map names a key twice."""
    # OpenCV keeps the first of a key named twice without a word; monodock's YAML loader refuses it (config.py)
    keys = list(fs.root().keys()) if fs.root().isMap() else []
    twice = next((k for i, k in enumerate(keys) if k in keys[:i]), None)
    if twice is not None:
        raise ConfigError(f"{path}: key '{twice[:80]}' appears twice; each key may appear once")


def _first_node(fs: cv2.FileStorage, *names: str) -> Any:
    """The first non-empty node among ``names`` (alternative spellings of one field), or None."""
    for n in names:
        nd = fs.getNode(n)
        if not nd.empty():
            return nd
    return None


def _storage_image_size(fs: cv2.FileStorage, path: Path) -> tuple[float, float]:
    """(width, height) from image_width/image_height, else from a two-element image_size; not yet checked."""
    wn, hn = _first_node(fs, "image_width", "width"), _first_node(fs, "image_height", "height")
    if wn is not None and hn is not None:
        return float(wn.real()), float(hn.real())
    sn = _first_node(fs, "image_size", "imageSize")
    if sn is None:
        raise ConfigError(f"{path}: missing field 'image_width'")
    if sn.isSeq() and sn.size() == 2:
        size = np.array([sn.at(0).real(), sn.at(1).real()])
    else:
        m = sn.mat() if not sn.isSeq() and not sn.isMap() else None
        size = np.asarray(m).ravel() if m is not None else np.zeros(0)
    if size.size != 2:
        raise ConfigError(f"{path}: image_size: expected [width, height]")
    return float(size[0]), float(size[1])


def _check_storage_size(width_f: float, height_f: float, path: Path) -> None:
    """Refuse an image size that is not whole, finite, positive and at most ``MAX_IMAGE_SIDE`` px a side."""
    if not (math.isfinite(width_f) and math.isfinite(height_f)) or not (
        0 < width_f <= MAX_IMAGE_SIDE
        and 0 < height_f <= MAX_IMAGE_SIDE
        and width_f == int(width_f)
        and height_f == int(height_f)
    ):
        raise ConfigError(
            f"{path}: image size must be whole numbers 1 to {MAX_IMAGE_SIDE} px, got {width_f:g}x{height_f:g}"
        )


def _read_opencv_storage(path: Path) -> CameraModel:
    fs = cv2.FileStorage(str(path), cv2.FILE_STORAGE_READ)
    if not fs.isOpened():
        raise ConfigError(f"{path}: cannot be read as an OpenCV FileStorage file")
    try:
        _refuse_repeated_keys(fs, path)
        km = _first_node(fs, "camera_matrix", "cameraMatrix", "K", "intrinsic_matrix")
        if km is None:
            raise ConfigError(f"{path}: missing field 'camera_matrix'")
        K = _numbers(km.mat(), "camera_matrix", path)
        if K.size != 9:
            raise ConfigError(f"{path}: camera_matrix: expected a 3x3 matrix")
        dn = _first_node(fs, "distortion_coefficients", "dist_coeffs", "distCoeffs", "D")
        if dn is None:
            raise ConfigError(f"{path}: missing field 'distortion_coefficients'")
        D = _numbers(dn.mat(), "distortion_coefficients", path).ravel()
        width_f, height_f = _storage_image_size(fs, path)
        if D.size == 4:
            D = np.r_[D, 0.0]
        model = "rational_polynomial" if D.size == 8 else "plumb_bob"
        if not (np.all(np.isfinite(K)) and np.all(np.isfinite(D))):
            raise ConfigError(f"{path}: camera_matrix or distortion_coefficients hold NaN or infinite values")
        _check_storage_size(width_f, height_f, path)
        try:
            camera = CameraModel(
                int(width_f), int(height_f), tuple(K.ravel().tolist()), tuple(D.tolist()), model, path.stem
            )
        except ConfigError as exc:
            raise ConfigError(f"{path}: {exc}") from None
        camera.check_plausible(str(path))
        return camera
    finally:
        fs.release()
