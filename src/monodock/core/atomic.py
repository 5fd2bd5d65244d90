"""Writing outputs so that nothing the user has is lost: temp file or folder, then one rename.

Existing outputs are replaced only with ``force``; a crash half-way leaves the old output untouched.
"""

from __future__ import annotations

import errno
import os
import shutil
import stat
import tempfile
from collections.abc import Iterable, Iterator
from contextlib import contextmanager
from pathlib import Path

from monodock.errors import InputError

__all__ = ["atomic_directory", "check_writable", "resolved", "write_bytes_atomic", "write_text_atomic"]


def _umask() -> int:
    """The process's file-creation mask (reading it means setting it; it is put straight back)."""
    mask = os.umask(0)
    os.umask(mask)
    return mask


def _kind(mode: int) -> str | None:
    """What a file that is neither a regular file nor a folder is, or None."""
    for test, name in (
        (stat.S_ISCHR, "a character device"),
        (stat.S_ISBLK, "a block device"),
        (stat.S_ISFIFO, "a FIFO (named pipe)"),
        (stat.S_ISSOCK, "a socket"),
    ):
        if test(mode):
            return name
    return None if stat.S_ISREG(mode) or stat.S_ISDIR(mode) else "not a regular file or folder"


def resolved(path: str | os.PathLike[str]) -> Path:
    """The absolute path with every symbolic link followed, as far as they go: a loop of links (``a -> a``) is
    left where it loops instead of raising (``Path.resolve`` raises RuntimeError on one before Python 3.13)."""
    return Path(os.path.realpath(path))


def _input_conflict(p: Path, inputs: Iterable[str | os.PathLike[str] | None]) -> str | None:
    """Why writing ``p`` would destroy one of ``inputs`` (the same file, or a folder holding it), or None."""
    out = resolved(p)
    for item in inputs:
        if item is None or str(item) in ("", "-"):
            continue
        q = Path(item)
        try:
            if p.exists() and q.exists() and os.path.samefile(p, q):
                return f"it is the input {q}"
        except OSError:
            pass
        inp = resolved(q)
        if inp == out:
            return f"it is the input {q}"
        if out in inp.parents:
            return f"it holds the input {q}"
    return None


def check_writable(
    path: str | os.PathLike[str],
    *,
    force: bool,
    inputs: Iterable[str | os.PathLike[str] | None] = (),
    stream: bool = False,
) -> Path:
    """The path, checked before any work is done; InputError (one line, even with ``force``) when

    - it exists and ``force`` is not given;
    - it is one of ``inputs`` (the same file, also through a symlink or a hard link) or a folder holding one:
      replacing it would destroy what the command reads;
    - it is a device, FIFO or socket (``/dev/null``): never replaced by a regular file; a ``stream`` output
      (written into, not replaced) may be a character device or a FIFO, and needs no ``force`` for them;
    - its folder cannot be made (a file stands where a folder should be) or written.
    """
    p = Path(path)
    conflict = _input_conflict(p, inputs)
    if conflict is not None:
        raise InputError(f"refusing to write {p}: {conflict} (even with --force)")
    try:
        mode: int | None = os.stat(p).st_mode
    except OSError:
        mode = None
    kind = None if mode is None else _kind(mode)
    if kind is not None and mode is not None:
        if stream and (stat.S_ISCHR(mode) or stat.S_ISFIFO(mode)):
            return p
        raise InputError(f"refusing to write {p}: it is {kind}, not a regular file or folder (even with --force)")
    if (p.exists() or p.is_symlink()) and not force:
        raise InputError(f"{p} exists; pass --force to overwrite it")
    for parent in p.parents:
        if parent.exists():
            if not parent.is_dir():
                raise InputError(f"cannot write {p}: {parent} is a file, not a folder")
            if not os.access(parent, os.W_OK):
                raise InputError(f"cannot write {p}: no permission to write in {parent}")
            break
    return p


# Errors of writing that may come without a file name (from a write() call): they are the output's.
_WRITE_ERRNOS = (errno.ENOSPC, errno.EDQUOT, errno.EFBIG, errno.EROFS, errno.EIO)


def _named(exc: OSError, tmp: str | os.PathLike[str], final: Path, *, unnamed_is_ours: bool) -> OSError:
    """An error of writing the temp file or folder (a full disk), naming the user's path instead of the temp."""
    where = None if exc.filename is None else os.fsdecode(exc.filename)
    if where is not None and where.startswith(str(tmp)):
        name = str(final) + where[len(str(tmp)) :]
    elif where is None and (unnamed_is_ours or exc.errno in _WRITE_ERRNOS):
        name = str(final)
    else:
        return exc
    return OSError(exc.errno, exc.strerror or str(exc), name)


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
    except OSError as exc:
        Path(tmp).unlink(missing_ok=True)
        named = _named(exc, tmp, p, unnamed_is_ours=True)
        if named is exc:
            raise
        raise named from exc
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
    except OSError as exc:  # a full disk, say: nothing is left behind, and the message names the user's path
        shutil.rmtree(tmp, ignore_errors=True)
        named = _named(exc, tmp, p, unnamed_is_ours=False)
        if named is exc:
            raise
        raise named from exc
    except BaseException:  # an error, Ctrl-C or SIGTERM (core.interrupt)
        shutil.rmtree(tmp, ignore_errors=True)
        raise
    old = None
    if p.exists():
        old = Path(tempfile.mkdtemp(prefix=f".{p.name}.old.", dir=p.parent))
        os.replace(p, old / "x")
    os.replace(tmp, p)
    if old is not None:
        shutil.rmtree(old, ignore_errors=True)
