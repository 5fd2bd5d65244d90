"""Hostile values and files around the valid ones, shared by the catalogue and the Hypothesis properties.

``plausible_*`` say whether a set-up is physically plausible by the ranges of issue 18 (focal length within
0.1-10x the image size, distortion OpenCV's model can invert over the image, mounts within 5 m, angles within
+-pi, marker sizes 5 mm-2 m): an implausible file must be refused, never give a ``valid=true`` estimate.
"""

from __future__ import annotations

import functools
import json
import math
import struct
import zlib
from collections.abc import Callable
from typing import Any

import numpy as np
import yaml
from numpy.typing import NDArray

from monodock.core.camera import CameraModel
from monodock.core.layout import DockLayout
from monodock.core.robot import RobotConfig
from monodock.core.settings import from_mapping

__all__ = [
    "HOSTILE_VALUES",
    "HUGE_INT",
    "alias_bomb_yaml",
    "deep_list_json",
    "deep_list_yaml",
    "dump_yaml",
    "plausible_camera",
    "plausible_layout",
    "plausible_robot",
    "png_with_ihdr",
]


class HugeInt:
    """A 5,000-digit integer, written verbatim into YAML and JSON text (Python refuses to print one by default)."""

    digits = "9" * 5000

    def __repr__(self) -> str:
        return "HUGE_INT"


HUGE_INT = HugeInt()

# Values that replace one number of a valid file: (label, value). Each is bad in a number field.
HOSTILE_VALUES: list[tuple[str, Any]] = [
    ("nan", math.nan),
    ("inf", math.inf),
    ("-inf", -math.inf),
    ("1e308", 1e308),
    ("-1e308", -1e308),
    ("1e-300", 1e-300),
    ("zero", 0),
    ("negative", -1.0),
    ("huge-int", HUGE_INT),
    ("string", "12abc"),
    ("list", [1.0, 2.0]),
    ("mapping", {"a": 1}),
    ("null", None),
    ("bool", True),
]


class _Dumper(yaml.SafeDumper):
    pass


def _huge(dumper: yaml.SafeDumper, _value: HugeInt) -> yaml.ScalarNode:
    return dumper.represent_scalar("tag:yaml.org,2002:int", HugeInt.digits)


_Dumper.add_representer(HugeInt, _huge)


def dump_yaml(data: Any) -> str:
    """YAML text of ``data``; a HugeInt becomes a 5,000-digit integer."""
    return yaml.dump(data, Dumper=_Dumper, sort_keys=False, default_flow_style=None)


def dump_json(data: Any) -> str:
    """JSON text of ``data`` (NaN and Infinity as Python writes them; HugeInt as 5,000 digits)."""
    text = json.dumps(_mark_huge(data), indent=1)
    return text.replace('"__HUGE_INT__"', HugeInt.digits)


def _mark_huge(data: Any) -> Any:
    if isinstance(data, HugeInt):
        return "__HUGE_INT__"
    if isinstance(data, dict):
        return {k: _mark_huge(v) for k, v in data.items()}
    if isinstance(data, list):
        return [_mark_huge(v) for v in data]
    return data


def alias_bomb_yaml(key: str, levels: int = 6, fan: int = 10) -> str:
    """YAML lines defining ``key`` as a billion-laughs style bomb: ``fan ** levels`` leaves through aliases."""
    lines = [f"{key}_0: &b0 [{', '.join(['lol'] * fan)}]"]
    for i in range(1, levels):
        lines.append(f"{key}_{i}: &b{i} [{', '.join([f'*b{i - 1}'] * fan)}]")
    lines.append(f"{key}: *b{levels - 1}")
    return "\n".join(lines) + "\n"


def deep_list_yaml(depth: int = 100_000) -> str:
    return "[" * depth + "]" * depth


def deep_list_json(depth: int = 100_000) -> str:
    return "[" * depth + "]" * depth


def _num(v: Any) -> float | None:
    if isinstance(v, bool) or not isinstance(v, int | float):
        return None
    try:
        f = float(v)
    except OverflowError:  # a 5,000-digit integer
        return None
    return f if math.isfinite(f) else None


@functools.lru_cache(maxsize=16)  # the fuzzers vary other fields far more often than the camera
def _corner_rays(cam: CameraModel) -> NDArray[np.float64] | None:
    """Every pixel corner's ray, (H + 1, W + 1, 2); None unless each projects back within the loader's 0.1 px.

    The loader checks its 0.1 px (a strong real lens: ~0.01 px) on the border and a grid; this checks every pixel
    corner, so a lens that fails between the loader's samples is a finding. Not the renderer's 1e-6 px, which only
    the simulator needs.
    """
    w, h = cam.width, cam.height
    u, v = np.meshgrid(np.arange(w + 1) - 0.5, np.arange(h + 1) - 0.5)
    corners = np.stack([u.ravel(), v.ravel()], axis=1)
    with np.errstate(all="ignore"):
        flat = cam.normalize(corners)
        back = cam.project(np.c_[flat, np.ones(len(flat))])
    if not np.all(np.abs(back - corners) < 0.1):
        return None
    return flat.reshape(h + 1, w + 1, 2)


def plausible_camera(data: dict[str, Any]) -> bool:
    """Whether a camera_info mapping (ROS spelling of ``CameraModel.to_ros_dict``) is physically plausible."""
    try:
        w, h = data["image_width"], data["image_height"]
        if isinstance(w, bool) or isinstance(h, bool) or not isinstance(w, int) or not isinstance(h, int):
            return False
        if not (1 <= w <= 20_000 and 1 <= h <= 20_000):
            return False
        k = [_num(v) for v in data["camera_matrix"]["data"]]
        d = [_num(v) for v in data["distortion_coefficients"]["data"]]
    except (KeyError, TypeError):
        return False
    if len(k) != 9 or len(d) not in (4, 5, 8) or any(v is None for v in k + d):
        return False
    fx, cx, fy, cy = k[0], k[2], k[4], k[5]
    size = max(w, h)
    if not all(0.1 * size <= f <= 10 * size for f in (fx, fy)):  # type: ignore[operator]
        return False
    if not (0 <= cx <= w and 0 <= cy <= h):  # type: ignore[operator]
        return False
    if [k[1], k[3], k[6], k[7], k[8]] != [0.0, 0.0, 0.0, 0.0, 1.0]:
        return False
    if data.get("distortion_model", "plumb_bob") not in ("plumb_bob", "rational_polynomial"):
        return False
    try:
        cam = CameraModel.from_ros_dict(data)
    except Exception:
        return False
    rays = _corner_rays(cam)
    if rays is None:
        return False
    # Invertible is not enough (k1 = 1e6 is monotonic, so invertible, and shrinks the field of view 100-fold): the
    # lens may bend the image's border at most 2x in or out of where the pinhole alone would put it.
    pinhole = np.array(
        [(-0.5 - cam.cx) / cam.fx, (w - 0.5 - cam.cx) / cam.fx, (-0.5 - cam.cy) / cam.fy, (h - 0.5 - cam.cy) / cam.fy]
    )
    lens = np.array([rays[:, 0, 0].min(), rays[:, -1, 0].max(), rays[0, :, 1].min(), rays[-1, :, 1].max()])
    with np.errstate(divide="ignore", invalid="ignore"):
        ratio = lens / pinhole
    big = np.abs(pinhole) > 0.05  # a side the principal point sits on says nothing
    return bool(np.all(np.isfinite(ratio[big])) and np.all((ratio[big] > 0.5) & (ratio[big] < 2)))


def plausible_layout(data: dict[str, Any]) -> bool:
    try:
        size = _num(data["marker_size"])
        markers = data["markers"]
        coords = [(_num(markers[r]["y"]), _num(markers[r]["z"])) for r in ("left", "center", "right")]
    except (KeyError, TypeError):
        return False
    if size is None or not 0.005 <= size <= 2.0:
        return False
    if any(v is None or abs(v) > 5.0 for c in coords for v in c):
        return False
    try:
        from_mapping(DockLayout, data, "layout")
    except Exception:
        return False
    return True


def plausible_robot(data: dict[str, Any]) -> bool:
    try:
        for mount in ("camera_mount", "laser_mount"):
            m = data[mount]
            for k in ("x", "y", "z"):
                v = _num(m[k])
                if v is None or abs(v) > 5.0:
                    return False
            for k in ("roll", "pitch", "yaw"):
                v = _num(m.get(k, 0.0))
                if v is None or abs(v) > math.pi:
                    return False
        fo = _num(data["front_offset"])
        if fo is None or not 0 <= fo <= 5.0:
            return False
        for k in ("max_linear_speed", "max_angular_speed"):
            if k in data:
                v = _num(data[k])
                if v is None or not 0 < v <= 100:
                    return False
        from_mapping(RobotConfig, data, "robot")
    except Exception:
        return False
    return True


# --- images ------------------------------------------------------------------------------------------


def png_chunks(png: bytes) -> list[tuple[bytes, bytes]]:
    """(type, data) of every chunk of a PNG."""
    out, pos = [], 8
    while pos + 8 <= len(png):
        (length,) = struct.unpack(">I", png[pos : pos + 4])
        kind = png[pos + 4 : pos + 8]
        out.append((kind, png[pos + 8 : pos + 8 + length]))
        pos += 12 + length
    return out


def png_from_chunks(chunks: list[tuple[bytes, bytes]]) -> bytes:
    body = b"".join(
        struct.pack(">I", len(d)) + k + d + struct.pack(">I", zlib.crc32(k + d) & 0xFFFFFFFF) for k, d in chunks
    )
    return b"\x89PNG\r\n\x1a\n" + body


def png_with_ihdr(png: bytes, **fields: int) -> bytes:
    """The PNG with IHDR fields (width, height, bit_depth, color_type) replaced and its CRC made right again."""
    chunks = png_chunks(png)
    k, d = chunks[0]
    w, h, bd, ct, comp, filt, inter = struct.unpack(">IIBBBBB", d)
    w = fields.get("width", w)
    h = fields.get("height", h)
    bd = fields.get("bit_depth", bd)
    ct = fields.get("color_type", ct)
    chunks[0] = (k, struct.pack(">IIBBBBB", w, h, bd, ct, comp, filt, inter))
    return png_from_chunks(chunks)


def jpeg_with_size(jpg: bytes, width: int, height: int) -> bytes:
    """The JPEG with its SOF0 frame size replaced."""
    i = jpg.find(b"\xff\xc0")
    if i < 0:
        return jpg
    b = bytearray(jpg)
    b[i + 5 : i + 9] = struct.pack(">HH", height, width)
    return bytes(b)


def flip_bytes(data: bytes, seed: int, count: int = 8, start: int = 0) -> bytes:
    """``count`` bytes of ``data`` past ``start`` replaced by seeded random ones."""
    rng = np.random.default_rng(seed)
    b = bytearray(data)
    for pos in rng.integers(start, len(b), count):
        b[int(pos)] = int(rng.integers(0, 256))
    return bytes(b)


def set_path(data: Any, path: tuple[Any, ...], value: Any) -> Any:
    """``data`` with the item at ``path`` (keys and indices) replaced; a missing sentinel deletes it. A path that an
    earlier edit of the same example removed (a deleted key, a shortened list, a container now a scalar) is left
    as it is."""
    if not path:
        return value
    if not isinstance(data, dict | list):  # an earlier edit replaced the container by a scalar
        return data
    head, rest = path[0], path[1:]
    if isinstance(data, dict):
        out = dict(data)
        if head not in data:
            if not rest and value is not DELETE:
                out[head] = value
            # a path under a key an earlier edit deleted: nothing to change
        elif rest or value is not DELETE:
            out[head] = set_path(data[head], rest, value)
        else:
            del out[head]
        return out
    out_list = list(data)
    if not -len(out_list) <= head < len(out_list):  # an earlier edit of the same example shortened the list
        return out_list
    if not rest and value is DELETE:
        del out_list[head]
    else:
        out_list[head] = set_path(data[head], rest, value)
    return out_list


class _Delete:
    def __repr__(self) -> str:
        return "DELETE"


DELETE: Any = _Delete()

Mutator = Callable[[Any], Any]
