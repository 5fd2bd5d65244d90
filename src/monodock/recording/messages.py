"""Conversions between monodock's values and ROS messages (rosbags message objects, ROS 1 and ROS 2).

Messages read from a bag are the dataclasses of rosbags' typestore; their fields follow the bag's own
message definitions, so ROS 1 spellings (``K``, ``D``, ``secs``) and ROS 2 ones (``k``, ``d``, ``sec``) are
both accepted here. Writing uses the ROS 2 Humble types.
"""

from __future__ import annotations

import math
import struct
from typing import Any

import cv2
import numpy as np
from numpy.typing import NDArray
from rosbags.typesys import Stores, get_typestore
from rosbags.typesys.store import Typestore

from monodock.core import images, transforms
from monodock.core.camera import CameraModel
from monodock.core.pose import DockPose
from monodock.core.robot import RobotConfig
from monodock.core.scan import LaserScan
from monodock.errors import ConfigError

__all__ = [
    "BATTERY_STATE",
    "CAMERA_INFO",
    "COMPRESSED_IMAGE",
    "IMAGE",
    "IMAGE_ENCODINGS",
    "IMAGE_TYPES",
    "LASER_SCAN",
    "ODOMETRY",
    "POSE_STAMPED",
    "TF_MESSAGE",
    "DecodeError",
    "battery_msg",
    "camera_from_msg",
    "camera_info_msg",
    "charging_from_msg",
    "check_raw_image",
    "decode_image",
    "encode_image",
    "header_stamp",
    "humble_typestore",
    "matrix_from_quaternion",
    "normalize_msgtype",
    "odometry_from_msg",
    "odometry_msg",
    "pose_from_msg",
    "pose_msg",
    "raw_header_stamp",
    "scan_from_msg",
    "scan_msg",
    "split_stamp",
    "stamp_seconds",
    "tf_static_msg",
    "transform_of",
]

IMAGE = "sensor_msgs/msg/Image"
COMPRESSED_IMAGE = "sensor_msgs/msg/CompressedImage"
IMAGE_TYPES = (IMAGE, COMPRESSED_IMAGE)
CAMERA_INFO = "sensor_msgs/msg/CameraInfo"
LASER_SCAN = "sensor_msgs/msg/LaserScan"
TF_MESSAGE = "tf2_msgs/msg/TFMessage"
POSE_STAMPED = "geometry_msgs/msg/PoseStamped"
ODOMETRY = "nav_msgs/msg/Odometry"
BATTERY_STATE = "sensor_msgs/msg/BatteryState"
# sensor_msgs/BatteryState's power_supply_status of a battery that is being charged.
POWER_SUPPLY_STATUS_CHARGING = 1

# What write_recording can put in a bag: raw sensor_msgs/Image, or image_transport's compressed formats.
IMAGE_ENCODINGS = ("mono8", "bgr8", "png", "jpeg")

_HUMBLE: Typestore | None = None


def humble_typestore() -> Typestore:
    """The ROS 2 Humble typestore (built once)."""
    global _HUMBLE  # noqa: PLW0603 - building the typestore takes a while; one per process is enough
    if _HUMBLE is None:
        _HUMBLE = get_typestore(Stores.ROS2_HUMBLE)
    return _HUMBLE


class DecodeError(ValueError):
    """A message that cannot be turned into the value asked for; the text says why.

    ``kind`` names the sort of fault, so that a live node can report each sort once: "encoding" (an image encoding
    not supported), "size" (image dimensions, step and data that do not fit together), "compressed" (a compressed
    image that does not decode), "calibration" (a camera_info that is not a valid calibration), else "data".
    """

    def __init__(self, text: str, kind: str = "data") -> None:
        super().__init__(text)
        self.kind = kind


def normalize_msgtype(name: str) -> str:
    """ROS 2 spelling of a message type name: ``sensor_msgs/Image`` -> ``sensor_msgs/msg/Image``."""
    parts = [p for p in name.split("/") if p]
    if len(parts) == 2:
        return f"{parts[0]}/msg/{parts[1]}"
    return "/".join(parts)


# --- time -----------------------------------------------------------------------------------------


def stamp_seconds(stamp: Any) -> float:
    """Seconds of a builtin_interfaces/Time (``sec``/``nanosec``, or ROS 1 ``secs``/``nsecs``)."""
    sec = getattr(stamp, "sec", None)
    if sec is None:
        sec = stamp.secs
    nsec = getattr(stamp, "nanosec", None)
    if nsec is None:
        nsec = stamp.nsecs
    return float(sec) + float(nsec) * 1e-9


def header_stamp(msg: Any) -> float:
    """Seconds of a message's ``header.stamp``."""
    return stamp_seconds(msg.header.stamp)


def split_stamp(stamp: float) -> tuple[int, int]:
    """(sec, nanosec) of a stamp in seconds, the nanoseconds carried into the seconds when they round up."""
    ns = round(stamp * 1e9)
    return ns // 1_000_000_000, ns % 1_000_000_000


def _header(ts: Typestore, stamp: float, frame_id: str) -> Any:
    sec, nsec = split_stamp(stamp)
    Time = ts.types["builtin_interfaces/msg/Time"]
    return ts.types["std_msgs/msg/Header"](stamp=Time(sec=sec, nanosec=nsec), frame_id=frame_id)


def raw_header_stamp(raw: bytes | memoryview, *, ros1: bool) -> float | None:
    """The header stamp of a serialised message that starts with a std_msgs/Header, without decoding it all.

    ROS 2 CDR: 4 bytes of encapsulation, then int32 sec, uint32 nanosec. ROS 1: uint32 seq, then uint32
    secs, uint32 nsecs, little endian. None when the message is too short to hold a header.
    """
    if len(raw) < 12:
        return None
    if ros1:
        sec, nsec = struct.unpack_from("<II", raw, 4)
    else:
        order = "<" if raw[1] & 1 else ">"
        sec, nsec = struct.unpack_from(f"{order}iI", raw, 4)
    return float(sec) + float(nsec) * 1e-9


# --- geometry -------------------------------------------------------------------------------------


def matrix_from_quaternion(x: float, y: float, z: float, w: float) -> NDArray[np.float64]:
    """Rotation matrix, shape (3, 3), of a quaternion (normalised first); DecodeError if it is zero."""
    n = math.sqrt(x * x + y * y + z * z + w * w)
    if not (math.isfinite(n) and n > 1e-9):
        raise DecodeError(f"quaternion ({x}, {y}, {z}, {w}) is not a rotation")
    x, y, z, w = x / n, y / n, z / n, w / n
    return np.array(
        [
            [1 - 2 * (y * y + z * z), 2 * (x * y - z * w), 2 * (x * z + y * w)],
            [2 * (x * y + z * w), 1 - 2 * (x * x + z * z), 2 * (y * z - x * w)],
            [2 * (x * z - y * w), 2 * (y * z + x * w), 1 - 2 * (x * x + y * y)],
        ],
        dtype=np.float64,
    )


def transform_of(msg: Any) -> NDArray[np.float64]:
    """parent_T_child, 4x4, of a geometry_msgs/TransformStamped."""
    t, q = msg.transform.translation, msg.transform.rotation
    return transforms.transform(matrix_from_quaternion(q.x, q.y, q.z, q.w), (t.x, t.y, t.z))


def _transform_stamped(ts: Typestore, parent: str, child: str, T: NDArray[np.float64], stamp: float) -> Any:
    qx, qy, qz, qw = transforms.quaternion_from_matrix(T[:3, :3])
    Vector3 = ts.types["geometry_msgs/msg/Vector3"]
    Quaternion = ts.types["geometry_msgs/msg/Quaternion"]
    return ts.types["geometry_msgs/msg/TransformStamped"](
        header=_header(ts, stamp, parent),
        child_frame_id=child,
        transform=ts.types["geometry_msgs/msg/Transform"](
            translation=Vector3(x=float(T[0, 3]), y=float(T[1, 3]), z=float(T[2, 3])),
            rotation=Quaternion(x=qx, y=qy, z=qz, w=qw),
        ),
    )


def tf_static_msg(
    robot: RobotConfig,
    stamp: float,
    *,
    base_frame: str = "base_link",
    camera_frame: str = "camera_optical_frame",
    laser_frame: str = "laser",
) -> Any:
    """tf2_msgs/TFMessage of the sensor mounts: base -> camera optical frame (optical rotation included), laser."""
    ts = humble_typestore()
    return ts.types[TF_MESSAGE](
        transforms=[
            _transform_stamped(ts, base_frame, camera_frame, robot.base_T_optical(), stamp),
            _transform_stamped(ts, base_frame, laser_frame, robot.base_T_laser(), stamp),
        ]
    )


def pose_msg(pose: DockPose, stamp: float, frame_id: str = "base_link") -> Any:
    """geometry_msgs/PoseStamped of a DockPose: the dock frame in base_link, yaw about z."""
    ts = humble_typestore()
    half = 0.5 * pose.yaw
    return ts.types[POSE_STAMPED](
        header=_header(ts, stamp, frame_id),
        pose=ts.types["geometry_msgs/msg/Pose"](
            position=ts.types["geometry_msgs/msg/Point"](x=float(pose.x), y=float(pose.y), z=0.0),
            orientation=ts.types["geometry_msgs/msg/Quaternion"](x=0.0, y=0.0, z=math.sin(half), w=math.cos(half)),
        ),
    )


def pose_from_msg(msg: Any) -> DockPose:
    """DockPose of a geometry_msgs/PoseStamped (the floor-plane part of the pose)."""
    p, q = msg.pose.position, msg.pose.orientation
    R = matrix_from_quaternion(q.x, q.y, q.z, q.w)
    return DockPose.from_matrix(transforms.transform(R, (p.x, p.y, p.z)))


def odometry_msg(
    stamp: float,
    x: float,
    y: float,
    yaw: float,
    linear: float,
    angular: float,
    *,
    frame_id: str = "odom",
    child_frame_id: str = "base_link",
) -> Any:
    """nav_msgs/Odometry of a planar pose in the odometry frame and the body's forward and turn rates."""
    ts = humble_typestore()
    half = 0.5 * yaw
    Vector3 = ts.types["geometry_msgs/msg/Vector3"]
    cov = np.zeros(36)
    return ts.types[ODOMETRY](
        header=_header(ts, stamp, frame_id),
        child_frame_id=child_frame_id,
        pose=ts.types["geometry_msgs/msg/PoseWithCovariance"](
            pose=ts.types["geometry_msgs/msg/Pose"](
                position=ts.types["geometry_msgs/msg/Point"](x=float(x), y=float(y), z=0.0),
                orientation=ts.types["geometry_msgs/msg/Quaternion"](x=0.0, y=0.0, z=math.sin(half), w=math.cos(half)),
            ),
            covariance=cov,
        ),
        twist=ts.types["geometry_msgs/msg/TwistWithCovariance"](
            twist=ts.types["geometry_msgs/msg/Twist"](
                linear=Vector3(x=float(linear), y=0.0, z=0.0), angular=Vector3(x=0.0, y=0.0, z=float(angular))
            ),
            covariance=cov.copy(),
        ),
    )


def odometry_from_msg(msg: Any) -> tuple[float, float, float, float]:
    """(stamp, x, y, yaw) of a nav_msgs/Odometry: its header stamp and the pose's floor-plane part."""
    p, q = msg.pose.pose.position, msg.pose.pose.orientation
    R = matrix_from_quaternion(q.x, q.y, q.z, q.w)
    return header_stamp(msg), float(p.x), float(p.y), math.atan2(R[1, 0], R[0, 0])


def battery_msg(stamp: float, charging: bool, *, frame_id: str = "base_link") -> Any:
    """sensor_msgs/BatteryState saying whether the battery is being charged (the rest unknown, NaN)."""
    ts = humble_typestore()
    nan = math.nan
    return ts.types[BATTERY_STATE](
        header=_header(ts, stamp, frame_id),
        voltage=nan,
        temperature=nan,
        current=nan,
        charge=nan,
        capacity=nan,
        design_capacity=nan,
        percentage=nan,
        power_supply_status=POWER_SUPPLY_STATUS_CHARGING if charging else 3,  # 3: not charging
        power_supply_health=0,
        power_supply_technology=0,
        present=True,
        cell_voltage=np.zeros(0, dtype=np.float32),
        cell_temperature=np.zeros(0, dtype=np.float32),
        location="",
        serial_number="",
    )


def charging_from_msg(msg: Any) -> tuple[float, bool]:
    """(stamp, charging) of a sensor_msgs/BatteryState."""
    return header_stamp(msg), int(msg.power_supply_status) == POWER_SUPPLY_STATUS_CHARGING


# --- camera ---------------------------------------------------------------------------------------


def camera_info_msg(camera: CameraModel, stamp: float, frame_id: str) -> Any:
    """sensor_msgs/CameraInfo of a camera model (R identity, P = [K | 0], no binning, full ROI)."""
    ts = humble_typestore()
    P = np.zeros((3, 4))
    P[:, :3] = camera.matrix
    return ts.types[CAMERA_INFO](
        header=_header(ts, stamp, frame_id),
        height=camera.height,
        width=camera.width,
        distortion_model=camera.distortion_model,
        d=np.array(camera.D, dtype=np.float64),
        k=np.array(camera.K, dtype=np.float64),
        r=np.eye(3).ravel(),
        p=P.ravel(),
        binning_x=0,
        binning_y=0,
        roi=ts.types["sensor_msgs/msg/RegionOfInterest"](x_offset=0, y_offset=0, height=0, width=0, do_rectify=False),
    )


def _field(msg: Any, *names: str) -> Any:
    for name in names:
        if hasattr(msg, name):
            return getattr(msg, name)
    raise DecodeError(f"message has no field {names[0]}")


def camera_from_msg(msg: Any, name: str = "camera", *, rectified: bool = False) -> CameraModel | None:
    """CameraModel of a sensor_msgs/CameraInfo (ROS 1 K/D or ROS 2 k/d); None when K is all zero (uncalibrated).

    With ``rectified`` the images are image_proc's ``image_rect``: the camera is P's left 3x3 with no distortion,
    as image_geometry's PinholeCameraModel projects rectified points.

    Raises:
        DecodeError: the message holds a calibration that is not valid; the text says why.
    """
    K = [float(v) for v in np.asarray(_field(msg, "k", "K"), dtype=np.float64).ravel()]
    D = [float(v) for v in np.asarray(_field(msg, "d", "D"), dtype=np.float64).ravel()]
    if rectified and any(K):
        P = np.asarray(_field(msg, "p", "P"), dtype=np.float64).ravel()
        if P.size != 12 or not np.all(np.isfinite(P)) or P[0] <= 0 or P[5] <= 0:
            raise DecodeError("camera_info has no valid projection matrix P for rectified images", "calibration")
        K = [float(v) for v in P.reshape(3, 4)[:, :3].ravel()]
        D = []
    if not all(math.isfinite(v) for v in K + D):
        raise DecodeError("camera_info has NaN or infinite values in K or D", "calibration")
    if not any(K):
        return None
    model = str(msg.distortion_model) or "plumb_bob"
    if not D:  # simulated cameras often publish an empty D for "no distortion"
        D = [0.0] * (8 if model == "rational_polynomial" else 5)
    data = {"width": int(msg.width), "height": int(msg.height), "camera_name": name}
    data |= {"distortion_model": model, "k": K, "d": D}
    try:
        return CameraModel.from_ros_dict(data, "camera_info")
    except ConfigError as exc:
        raise DecodeError(str(exc), "calibration") from None


# --- images ---------------------------------------------------------------------------------------

# Raw encodings (sensor_msgs/image_encodings.hpp) -> (channels, bytes per channel, conversion to mono/BGR).
_RAW: dict[str, tuple[int, int, int | None]] = {
    "mono8": (1, 1, None),
    "8UC1": (1, 1, None),
    "bgr8": (3, 1, None),
    "8UC3": (3, 1, None),
    "rgb8": (3, 1, cv2.COLOR_RGB2BGR),
    "bgra8": (4, 1, cv2.COLOR_BGRA2BGR),
    "8UC4": (4, 1, cv2.COLOR_BGRA2BGR),
    "rgba8": (4, 1, cv2.COLOR_RGBA2BGR),
    "mono16": (1, 2, None),
    "16UC1": (1, 2, None),
}


def _raw_layout(msg: Any) -> tuple[int, int, int | None, int]:
    """(channels, bytes per channel, conversion, bytes per row) of a raw image; DecodeError if they cannot hold."""
    encoding = str(msg.encoding)
    spec = _RAW.get(encoding)
    if spec is None:
        known = ", ".join(k for k in _RAW if not k[0].isdigit())
        raise DecodeError(f"image encoding '{encoding}' is not supported ({known})", "encoding")
    channels, depth, conversion = spec
    width, height, step = int(msg.width), int(msg.height), int(msg.step)
    if width <= 0 or height <= 0:
        raise DecodeError(f"image size {width}x{height} is empty", "size")
    row = width * channels * depth
    if step < row:
        raise DecodeError(f"image step {step} is less than width x bytes per pixel = {row}", "size")
    return channels, depth, conversion, row


def check_raw_image(msg: Any) -> None:
    """Whether a sensor_msgs/Image can be decoded as it says: a supported encoding and exactly step x height bytes.

    Cheaper than decoding (no pixel is read), and stricter about the size than ``decode_image``, which accepts
    trailing bytes: a live camera that sends a size other than the one it declares is broken.

    Raises:
        DecodeError: kind "encoding" or "size", the text says what is wrong.
    """
    _raw_layout(msg)
    size, expected = len(msg.data), int(msg.step) * int(msg.height)
    if size != expected:
        raise DecodeError(f"image has {size} bytes of data, expected step x height = {expected}", "size")


def decode_image(msg: Any, msgtype: str) -> NDArray[np.uint8]:
    """Pixels (uint8, mono (H, W) or BGR (H, W, 3)) of a sensor_msgs/Image or CompressedImage.

    Raw images may have padded rows (``step`` > width x channels x bytes); mono16 is scaled to 8 bits.

    Raises:
        DecodeError: unknown encoding, too little data, or a compressed image that does not decode.
    """
    data = np.frombuffer(np.asarray(msg.data, dtype=np.uint8), dtype=np.uint8)
    if msgtype == COMPRESSED_IMAGE:
        try:
            return images.decode(data)
        except images.ImageError as exc:
            raise DecodeError(
                f"compressed image (format '{msg.format}') does not decode: {exc}", "compressed"
            ) from None
    channels, depth, conversion, row = _raw_layout(msg)
    width, height, step = int(msg.width), int(msg.height), int(msg.step)
    if data.size < step * (height - 1) + row:
        raise DecodeError(f"image has {data.size} bytes of data, expected step x height = {step * height}", "size")
    rows = np.lib.stride_tricks.as_strided(data, shape=(height, row), strides=(step, 1))
    if depth == 2:
        dtype = np.dtype(">u2" if msg.is_bigendian else "<u2")
        wide = np.ascontiguousarray(rows).view(dtype).reshape(height, width)
        return np.ascontiguousarray((wide >> 8).astype(np.uint8))
    img: NDArray[Any] = np.ascontiguousarray(rows).reshape(
        (height, width) if channels == 1 else (height, width, channels)
    )
    if conversion is not None:
        img = cv2.cvtColor(img, conversion)
    return np.asarray(img, dtype=np.uint8)


def _format(encoding: str, image: NDArray[np.uint8]) -> str:
    """image_transport's CompressedImage format string: "<encoding>; <codec> compressed <target>"."""
    source = "mono8" if image.ndim == 2 else "bgr8"
    return f"{source}; {encoding} compressed {source}"


def encode_image(image: NDArray[np.uint8], encoding: str, stamp: float, frame_id: str) -> tuple[str, Any]:
    """(message type, message) of a mono8 or BGR image as sensor_msgs/Image or CompressedImage.

    ``encoding``: "mono8" or "bgr8" (raw Image; mono is expanded to BGR for bgr8), "png" or "jpeg" (CompressedImage
    of the image as it is, like image_transport's compressed publisher).
    """
    ts = humble_typestore()
    header = _header(ts, stamp, frame_id)
    if encoding in ("png", "jpeg"):
        ext = ".png" if encoding == "png" else ".jpg"
        ok, buf = cv2.imencode(ext, image)
        if not ok:
            raise DecodeError(f"cannot encode image as {encoding}")
        msg = ts.types[COMPRESSED_IMAGE](
            header=header, format=_format(encoding, image), data=np.asarray(buf, dtype=np.uint8).ravel()
        )
        return COMPRESSED_IMAGE, msg
    if encoding == "mono8":
        img = image if image.ndim == 2 else cv2.cvtColor(image, cv2.COLOR_BGR2GRAY)
        channels = 1
    elif encoding == "bgr8":
        img = image if image.ndim == 3 else cv2.cvtColor(image, cv2.COLOR_GRAY2BGR)
        channels = 3
    else:
        raise DecodeError(f"image encoding '{encoding}' is not one of {', '.join(IMAGE_ENCODINGS)}")
    img = np.ascontiguousarray(img, dtype=np.uint8)
    height, width = img.shape[:2]
    msg = ts.types[IMAGE](
        header=header,
        height=height,
        width=width,
        encoding=encoding,
        is_bigendian=0,
        step=width * channels,
        data=img.reshape(-1),
    )
    return IMAGE, msg


# --- LiDAR ----------------------------------------------------------------------------------------


# The real-valued fields of a scan's geometry and timing, of the same names in LaserScan and sensor_msgs/LaserScan.
_SCAN_REALS = ("angle_min", "angle_max", "angle_increment", "time_increment", "scan_time", "range_min", "range_max")


def _scan_reals(scan: Any) -> dict[str, float]:
    """``_SCAN_REALS`` of a LaserScan or a sensor_msgs/LaserScan, as floats."""
    return {name: float(getattr(scan, name)) for name in _SCAN_REALS}


def scan_msg(scan: LaserScan) -> Any:
    """sensor_msgs/LaserScan of a scan; NaN and +-inf ranges kept as they are (REP 117)."""
    ts = humble_typestore()
    return ts.types[LASER_SCAN](
        header=_header(ts, scan.stamp, scan.frame_id),
        **_scan_reals(scan),
        ranges=np.asarray(scan.ranges, dtype=np.float32),
        intensities=np.zeros(0, dtype=np.float32),
    )


def scan_from_msg(msg: Any) -> LaserScan:
    """LaserScan of a sensor_msgs/LaserScan (header stamp; NaN and +-inf kept)."""
    return LaserScan(
        stamp=header_stamp(msg),
        frame_id=str(msg.header.frame_id),
        **_scan_reals(msg),
        ranges=np.array(msg.ranges, dtype=np.float32),
    )
