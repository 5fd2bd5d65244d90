"""Writing outputs so that nothing the user has is lost: temp file or folder, then one rename.

Existing outputs are replaced only with ``force``; a crash half-way leaves the old output untouched.
"""

from __future__ import annotations

import os
import shutil
import tempfile
from collections.abc import Iterator
from contextlib import contextmanager
from pathlib import Path

from monodock.errors import InputError

__all__ = ["atomic_directory", "check_writable", "write_bytes_atomic", "write_text_atomic"]


def _umask() -> int:
    """The process's file-creation mask (reading it means setting it; it is put straight back)."""
    mask = os.umask(0)
    os.umask(mask)
    return mask


def check_writable(path: str | os.PathLike[str], *, force: bool) -> Path:
    """The path, checked before any work is done: InputError when it exists and ``force`` is not given,
    or when its folder cannot be made (a file stands where a folder should be)."""
    p = Path(path)
    if p.exists() and not force:
        raise InputError(f"{p} exists; pass --force to overwrite it")
    for parent in p.parents:
        if parent.exists():
            if not parent.is_dir():
                raise InputError(f"cannot write {p}: {parent} is a file, not a folder")
            if not os.access(parent, os.W_OK):
                raise InputError(f"cannot write {p}: no permission to write in {parent}")
            break
    return p


def write_bytes_atomic(path: str | os.PathLike[str], data: bytes, *, force: bool = False) -> None:
    """Write a file through a temporary file in the same folder and a rename."""
    p = check_writable(path, force=force)
    p.parent.mkdir(parents=True, exist_ok=True)
    fd, tmp = tempfile.mkstemp(prefix=f".{p.name}.", dir=p.parent)
    try:
        # mkstemp makes the file private (0600); the result should get the permissions of any new file.
        os.fchmod(fd, 0o666 & ~_umask())
        with os.fdopen(fd, "wb") as fh:
            fh.write(data)
        os.replace(tmp, p)
    except BaseException:
        Path(tmp).unlink(missing_ok=True)
        raise


def write_text_atomic(path: str | os.PathLike[str], text: str, *, force: bool = False) -> None:
    """Write a UTF-8 text file atomically."""
    write_bytes_atomic(path, text.encode("utf-8"), force=force)


@contextmanager
def atomic_directory(path: str | os.PathLike[str], *, force: bool = False) -> Iterator[Path]:
    """Yield a fresh temporary folder beside ``path``; on success it replaces ``path`` in one rename."""
    p = check_writable(path, force=force)
    p.parent.mkdir(parents=True, exist_ok=True)
    tmp = Path(tempfile.mkdtemp(prefix=f".{p.name}.", dir=p.parent))
    # mkdtemp makes the folder private (0700); the result should get the permissions of any new folder.
    tmp.chmod(0o777 & ~_umask())
    try:
        yield tmp
    except BaseException:
        shutil.rmtree(tmp, ignore_errors=True)
        raise
    old = None
    if p.exists():
        old = Path(tempfile.mkdtemp(prefix=f".{p.name}.old.", dir=p.parent))
        os.replace(p, old / "x")
    os.replace(tmp, p)
    if old is not None:
        shutil.rmtree(old, ignore_errors=True)
