"""Write-then-rename, so a failed or interrupted write never leaves a partial file."""

from __future__ import annotations

import contextlib
import os
import tempfile
from collections.abc import Iterator
from pathlib import Path

from ..errors import InputError

__all__ = ["atomic_path", "check_output_path", "check_output_dir"]


def check_output_path(path: str | Path) -> Path:
    """Check that ``path``'s folder exists and is writable; return it as a Path."""
    path = Path(path)
    parent = path.parent if str(path.parent) else Path(".")
    if not parent.is_dir():
        raise InputError(f"output folder {parent} does not exist")
    if not os.access(parent, os.W_OK):
        raise InputError(f"output folder {parent} is not writable")
    if path.is_dir():
        raise InputError(f"output path {path} is a folder")
    return path


def check_output_dir(path: str | Path) -> Path:
    """Check that ``path`` is a writable folder or can be made as one; return it."""
    path = Path(path)
    if path.exists() and not path.is_dir():
        raise InputError(f"{path} exists and is not a folder")
    if path.is_dir():
        if not os.access(path, os.W_OK):
            raise InputError(f"output folder {path} is not writable")
        return path
    check_output_path(path)
    return path


def _umask() -> int:
    mask = os.umask(0)
    os.umask(mask)
    return mask


@contextlib.contextmanager
def atomic_path(path: str | Path) -> Iterator[Path]:
    """Yield a temporary path beside ``path``; rename it onto ``path`` on success.

    The temporary name keeps the suffix (writers pick formats by it). On any
    exception, KeyboardInterrupt included, the temporary file is removed and
    an existing ``path`` is left untouched.
    """
    path = check_output_path(path)
    fd, tmp = tempfile.mkstemp(prefix=f".{path.stem}.", suffix=f".tmp{path.suffix}", dir=path.parent or ".")
    os.close(fd)
    tmp = Path(tmp)
    try:
        yield tmp
        if tmp.is_file():  # mkstemp makes 0600 files; give the usual umask-based mode
            tmp.chmod(0o666 & ~_umask())
        os.replace(tmp, path)
    except BaseException:
        tmp.unlink(missing_ok=True)
        raise
