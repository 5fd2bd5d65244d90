"""Image files' bytes to the 8-bit mono or BGR pixels the detector takes: sizes checked before decoding, the C
libraries' messages kept quiet, 16-bit, float, alpha and one-channel images converted, anything else a reason.

Every image monodock reads from a file or a CompressedImage message comes through ``decode``; ``printable`` is how
a file name that is not UTF-8 appears in messages and output rows.
"""

from __future__ import annotations

import re
import struct
from typing import Any

import cv2
import numpy as np
from numpy.typing import NDArray

from monodock.core.quiet import library_output

__all__ = [
    "MAX_IMAGE_PIXELS",
    "MAX_IMAGE_SIDE",
    "ImageError",
    "decode",
    "encode_png",
    "header_size",
    "printable",
    "to_uint8",
]

# The largest image decoded: a side of 16384 px and 100 megapixels (an 8K frame is 33). A header that claims more
# is refused before any pixel is allocated.
MAX_IMAGE_SIDE = 16384
MAX_IMAGE_PIXELS = 100_000_000


class ImageError(ValueError):
    """Bytes that do not give a usable image; the text says why (without the file's name)."""


# What libjpeg says about an image it decoded anyway, filling what it could not read (libpng's warnings are about
# ancillary chunks, and it fails outright on damaged pixel data).
_DAMAGED = re.compile(r"Corrupt JPEG data|Premature end of JPEG|Invalid SOS|Huffman")


def printable(name: str) -> str:
    """A file name as text that prints and writes as UTF-8: bytes that are not UTF-8 shown as ``\\xNN``."""
    return name.encode("utf-8", "surrogateescape").decode("utf-8", "backslashreplace")


def _jpeg_size(b: bytes) -> tuple[int, int] | None:
    i = 2
    while i + 9 < len(b):
        if b[i] != 0xFF:
            return None
        marker = b[i + 1]
        if marker == 0xFF:  # fill byte
            i += 1
            continue
        if marker in (0xD8, 0x01) or 0xD0 <= marker <= 0xD7:
            i += 2
            continue
        (length,) = struct.unpack(">H", b[i + 2 : i + 4])
        if 0xC0 <= marker <= 0xCF and marker not in (0xC4, 0xC8, 0xCC):
            h, w = struct.unpack(">HH", b[i + 5 : i + 9])
            return int(w), int(h)
        i += 2 + length
    return None


def _tiff_size(b: bytes) -> tuple[int, int] | None:
    end = "<" if b[:2] == b"II" else ">"
    (offset,) = struct.unpack(end + "I", b[4:8])
    if offset + 2 > len(b):
        return None
    (count,) = struct.unpack(end + "H", b[offset : offset + 2])
    size: dict[int, int] = {}
    for k in range(min(count, 4096)):
        at = offset + 2 + 12 * k
        if at + 12 > len(b):
            break
        tag, kind = struct.unpack(end + "HH", b[at : at + 4])
        if tag in (256, 257):
            size[tag] = struct.unpack(end + ("H" if kind == 3 else "I"), b[at + 8 : at + (10 if kind == 3 else 12)])[0]
    return (size[256], size[257]) if len(size) == 2 else None


def header_size(data: bytes) -> tuple[int, int] | None:
    """(width, height) an image file's header claims (PNG, JPEG, BMP, TIFF, WebP, PNM), None when unknown."""
    b = bytes(data[:65536])
    try:
        if b[:8] == b"\x89PNG\r\n\x1a\n" and b[12:16] == b"IHDR":
            w, h = struct.unpack(">II", b[16:24])
            return int(w), int(h)
        if b[:2] == b"\xff\xd8":
            return _jpeg_size(b)
        if b[:2] == b"BM":
            w, h = struct.unpack("<ii", b[18:26])
            return abs(int(w)), abs(int(h))
        if b[:4] in (b"II*\x00", b"MM\x00*"):
            return _tiff_size(b)
        if b[:4] == b"RIFF" and b[8:12] == b"WEBP":
            if b[12:16] == b"VP8X":
                return 1 + int.from_bytes(b[24:27], "little"), 1 + int.from_bytes(b[27:30], "little")
            if b[12:16] == b"VP8 ":
                w, h = struct.unpack("<HH", b[26:30])
                return w & 0x3FFF, h & 0x3FFF
            if b[12:16] == b"VP8L":
                bits = int.from_bytes(b[21:25], "little")
                return (bits & 0x3FFF) + 1, ((bits >> 14) & 0x3FFF) + 1
        if b[:1] == b"P" and b[1:2] in b"123456":
            words = b[2:200].split(b"#")[0].split()
            return int(words[0]), int(words[1])
    except (struct.error, ValueError, IndexError):
        return None
    return None


def to_uint8(image: NDArray[Any]) -> NDArray[np.uint8]:
    """8-bit mono (H, W) or BGR (H, W, 3) of what ``cv2.imdecode`` returns.

    16-bit is scaled by 1/256 (as cv_bridge does), float is taken as 0-1 when its maximum is at most 1 and as
    0-255 otherwise (clipped); an alpha channel is dropped, a single channel is mono.

    Raises:
        ImageError: another pixel type (signed, 32-bit integers), non-finite float pixels, 2 or 5+ channels.
    """
    img = np.asarray(image)
    if img.ndim == 3 and img.shape[2] == 1:
        img = img[:, :, 0]
    if img.ndim not in (2, 3) or (img.ndim == 3 and img.shape[2] not in (3, 4)):
        channels = img.shape[2] if img.ndim == 3 else img.ndim
        raise ImageError(f"{channels} channels (monodock reads mono, BGR and BGRA)")
    if img.dtype == np.uint16:
        img = (img >> 8).astype(np.uint8)
    elif img.dtype.kind == "f":
        if not np.all(np.isfinite(img)):
            raise ImageError("pixels that are NaN or infinite")
        scale = 255.0 if img.size and float(img.max()) <= 1.0 else 1.0
        img = np.clip(np.rint(img * scale), 0, 255).astype(np.uint8)
    elif img.dtype != np.uint8:
        raise ImageError(f"pixel type {img.dtype} (monodock reads 8- and 16-bit unsigned and float images)")
    if img.ndim == 3 and img.shape[2] == 4:
        img = cv2.cvtColor(img, cv2.COLOR_BGRA2BGR)
    return np.ascontiguousarray(img, dtype=np.uint8)


def decode(data: NDArray[np.uint8] | bytes) -> NDArray[np.uint8]:
    """The 8-bit mono or BGR pixels of an image file's bytes (``to_uint8``).

    Raises:
        ImageError: empty, a header claiming more than ``MAX_IMAGE_SIDE`` / ``MAX_IMAGE_PIXELS``, bytes that do
            not decode (truncated, corrupt, not an image), or pixels ``to_uint8`` refuses.
    """
    buf = np.frombuffer(data, dtype=np.uint8) if isinstance(data, bytes) else np.asarray(data, dtype=np.uint8).ravel()
    if buf.size == 0:
        raise ImageError("the file is empty")
    size = header_size(buf[:65536].tobytes())
    if size is not None:
        w, h = size
        if w > MAX_IMAGE_SIDE or h > MAX_IMAGE_SIDE or w * h > MAX_IMAGE_PIXELS:
            raise ImageError(
                f"its header claims {w}x{h} pixels (at most {MAX_IMAGE_SIDE} a side and "
                f"{MAX_IMAGE_PIXELS // 1_000_000} megapixels)"
            )
        if w == 0 or h == 0:
            raise ImageError(f"its header claims {w}x{h} pixels")
    try:
        with library_output() as said:
            img = cv2.imdecode(buf, cv2.IMREAD_UNCHANGED)
    except cv2.error:  # OpenCV's own size limits, a decoder's assertion
        img = None
    if img is None or img.size == 0:
        raise ImageError("not an image, or truncated or corrupt")
    if _DAMAGED.search(said.text):
        # libjpeg fills what it cannot decode and only warns: the picture is wrong where the markers may be
        # (flipped bytes gave board poses 0.75 m off). Seen only in a command session, where fd 2 is captured.
        raise ImageError("damaged JPEG data: the decoder filled in what it could not read")
    return to_uint8(img)


def encode_png(image: NDArray[Any]) -> bytes:
    """PNG bytes of an image, made in memory: the caller writes them with Python, so that a full disk is an
    ``OSError`` (ENOSPC) naming nothing of libpng ("libpng error: Write Error" on stderr, then only False from
    ``cv2.imwrite``)."""
    ok, buf = cv2.imencode(".png", image)
    if not ok:
        raise ImageError(f"cannot encode a {image.dtype} image of shape {image.shape} as PNG")
    return bytes(buf.tobytes())
