"""Compiled per-frame kernels: numba's ``njit``, typed for mypy and cached on disk.

Why: after an ArUco detection has swept the image through the caches, each small numpy call of a
vectorised refiner costs several microseconds, and a few hundred of them cost as much as a third of the
detection (``bench/speed.py``). A kernel that loops over the profiles in compiled code makes one call.

``cache=True`` writes the machine code beside the module (or in the user's cache directory when that is
read-only), so only the first process on a machine pays the compilation (a few seconds).
``error_model="numpy"``: a division by zero gives inf or NaN, as in numpy, for the checks after it to catch,
instead of raising.
"""

from __future__ import annotations

from collections.abc import Callable
from typing import Any, TypeVar, cast

import numba

__all__ = ["inlined", "kernel"]

F = TypeVar("F", bound=Callable[..., Any])


def kernel(fn: F) -> F:
    """``fn`` compiled with numba (nopython, cached, numpy's error model, the GIL released)."""
    return cast(F, numba.njit(cache=True, error_model="numpy", nogil=True)(fn))


def inlined(fn: F) -> F:
    """A small helper of kernels, inlined into each kernel that calls it.

    Why: a call between compiled functions passes each array with a reference-count increment and decrement
    (atomic operations), which costs more than the helper's own work when it runs once per pixel.
    """
    return cast(F, numba.njit(cache=True, error_model="numpy", nogil=True, inline="always")(fn))
