"""Write-then-rename, so a failed or interrupted write never leaves a partial file."""

from __future__ import annotations

import contextlib
import glob
import os
import re
import shutil
import tempfile
from collections.abc import Iterator
from pathlib import Path

from ..errors import InputError

__all__ = ["atomic_path", "atomic_folder", "write_text", "leftover_temporaries", "check_output_path",
           "check_output_dir", "check_output_folder"]


def _check_parent(path: Path) -> None:
    parent = path.parent if str(path.parent) else Path(".")
    if not parent.is_dir():
        raise InputError(f"output folder {parent} does not exist")
    if not os.access(parent, os.W_OK):
        raise InputError(f"output folder {parent} is not writable")


def check_output_path(path: str | Path) -> Path:
    """Check that ``path``'s folder exists and is writable; return it as a Path."""
    path = Path(path)
    _check_parent(path)
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


def write_text(path: str | Path, text: str) -> None:
    """Write a UTF-8 text file atomically."""
    with atomic_path(path) as tmp:
        tmp.write_text(text, encoding="utf-8")


_TMP_PREFIX, _TMP_SUFFIX = ".{}.", ".tmp{}"


def leftover_temporaries(path: str | Path) -> list[Path]:
    """Temporary files :func:`atomic_path` made for ``path`` and could not remove (its process was killed)."""
    path = Path(path)
    # mkstemp's random part is 8 characters; "*" would also match the temporaries of "a.b.mp4" for "a.mp4"
    pattern = _TMP_PREFIX.format(glob.escape(path.stem)) + "?" * 8 + _TMP_SUFFIX.format(glob.escape(path.suffix))
    return sorted(path.parent.glob(pattern))


@contextlib.contextmanager
def atomic_path(path: str | Path) -> Iterator[Path]:
    """Yield a temporary path beside ``path``; rename it onto ``path`` on success.

    The temporary name keeps the suffix (writers pick formats by it). On any
    exception, KeyboardInterrupt included, the temporary file is removed and
    an existing ``path`` is left untouched.
    """
    path = check_output_path(path)
    fd, tmp = tempfile.mkstemp(prefix=_TMP_PREFIX.format(path.stem), suffix=_TMP_SUFFIX.format(path.suffix),
                               dir=path.parent or ".")
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


def check_output_folder(path: str | Path, replaceable: str) -> Path:
    """Check that ``path`` can become an output folder (see :func:`atomic_folder`); return it."""
    path = Path(path)
    _check_parent(path)
    if path.exists() and not path.is_dir():
        raise InputError(f"{path} is a file, not a folder")
    if path.is_dir():
        others = sorted(f.name for f in path.iterdir() if not re.fullmatch(replaceable, f.name))
        if others:
            raise InputError(f"output folder {path} is not empty (it holds {others[0]}); give a new or empty folder")
    return path


@contextlib.contextmanager
def atomic_folder(path: str | Path, replaceable: str) -> Iterator[Path]:
    """Yield a temporary folder beside ``path``; it becomes ``path`` on success.

    An existing folder at ``path`` is replaced (only once the new one is
    complete) if it is empty or holds nothing but files whose names fully
    match the regular expression ``replaceable`` (an earlier output of the
    same kind); anything else in it is the user's, and is an error. On any
    exception, KeyboardInterrupt included, the temporary folder is removed
    and ``path`` is left as it was.
    """
    path = check_output_folder(path, replaceable)
    tmp = Path(tempfile.mkdtemp(prefix=f".{path.name}.", suffix=".tmp", dir=path.parent))
    try:
        yield tmp
        tmp.chmod(0o777 & ~_umask())
        if path.is_dir():
            old = tmp.with_name(tmp.name + ".old")
            os.replace(path, old)
            try:
                os.replace(tmp, path)
            except BaseException:
                os.replace(old, path)
                raise
            shutil.rmtree(old)
        else:
            os.replace(tmp, path)
    except BaseException:
        shutil.rmtree(tmp, ignore_errors=True)
        raise
