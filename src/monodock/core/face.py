"""A subpackage's face, loaded lazily (PEP 562): its ``__init__`` names what the other subpackages use, and each
name loads its module on first use, so that importing one module of a subpackage does not load the rest of it
(the robot side loads only what it runs; ``import monodock`` does the same for the public API).

A face declares each name once, as a typing import (``if TYPE_CHECKING: from monodock.io.frames import
open_frames``) and in ``__all__``; the typing imports are where ``lazy_face`` finds each name's module.
"""

from __future__ import annotations

import ast
import importlib
import sys
from collections.abc import Callable, Sequence
from pathlib import Path
from typing import Any

__all__ = ["lazy_face"]


def _typing_imports(path: Path) -> dict[str, str]:
    """Each name a module imports under ``if TYPE_CHECKING:``, with the module it comes from."""
    where: dict[str, str] = {}
    for node in ast.parse(path.read_text(encoding="utf-8")).body:
        if isinstance(node, ast.If) and isinstance(node.test, ast.Name) and node.test.id == "TYPE_CHECKING":
            for imp in node.body:
                if isinstance(imp, ast.ImportFrom) and imp.module:
                    where.update({a.asname or a.name: imp.module for a in imp.names})
    return where


def lazy_face(package: str, names: Sequence[str]) -> tuple[Callable[[str], Any], Callable[[], list[str]]]:
    """The module-level ``__getattr__`` and ``__dir__`` of ``package``, whose face is ``names`` (its ``__all__``),
    each from the module its ``__init__`` imports it from under ``TYPE_CHECKING``."""
    where: dict[str, str] = {}

    def face_getattr(name: str) -> Any:
        if name not in names:
            raise AttributeError(f"module {package!r} has no attribute {name!r}")
        if not where:
            where.update(_typing_imports(Path(str(sys.modules[package].__file__))))
        value = getattr(importlib.import_module(where[name]), name)
        setattr(sys.modules[package], name, value)  # the next access is a plain attribute
        return value

    def face_dir() -> list[str]:
        return sorted(names)

    return face_getattr, face_dir
