"""Exceptions a user can act on: the CLI prints them as one line and exits non-zero."""

from __future__ import annotations

__all__ = ["ConfigError", "InputError", "MonodockError"]


class MonodockError(Exception):
    """Base of every error that is the input's fault, not the code's."""


class ConfigError(MonodockError):
    """A layout, camera or robot file is missing a field or holds a wrong value."""


class InputError(MonodockError):
    """An image, recording or other input cannot be read or used."""
