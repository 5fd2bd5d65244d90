"""A camera frame as every frame source hands it over: its name, stamp and pixels, or why there are none."""

from __future__ import annotations

import math
from dataclasses import dataclass, field

import numpy as np
from numpy.typing import NDArray

__all__ = ["Frame"]


@dataclass(frozen=True)
class Frame:
    """One image to process.

    Attributes:
        name: the image file's name; for a video, camera, stream or recording, the frame's index in it.
        stamp: seconds. The one rule of every source: a recording's header stamp, a video's position in the
            file, the capture time (``time.time()``) of a camera or stream, NaN for an image file.
        image: mono or BGR uint8 pixels; None when the frame could not be read.
        error: why there are no pixels ("" when there are).
        arrival: ``time.perf_counter()`` when the source handed the frame over (NaN before), for latency.
    """

    name: str
    stamp: float
    image: NDArray[np.uint8] | None
    error: str = ""
    arrival: float = field(default=math.nan, compare=False)
