"""An open resource that is its own context manager: the end of a ``with`` block closes it."""

from __future__ import annotations

from types import TracebackType
from typing import Self

__all__ = ["Closing"]


class Closing:
    """A base for what holds something open (a device, a file, a recording) until ``close``: ``with`` gives the
    object itself, and the block's end closes it whatever happened in the block."""

    def close(self) -> None:
        raise NotImplementedError

    def __enter__(self) -> Self:
        return self

    def __exit__(
        self, exc_type: type[BaseException] | None, exc: BaseException | None, tb: TracebackType | None
    ) -> None:
        self.close()
