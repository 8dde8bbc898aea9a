"""Write-then-rename, so a failed or interrupted write never leaves a partial file.

:class:`StagedOutputs` extends this to every output of a command: each is
written under a temporary name beside its place and all are renamed onto
their places together when the command succeeds, or all removed when it
fails or is interrupted.
"""

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

__all__ = ["atomic_path", "atomic_folder", "StagedOutputs", "staged_outputs", "write_text", "leftover_temporaries",
           "check_output_path", "check_output_dir", "check_output_folder"]


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
    with staged_outputs() as outputs:
        yield outputs.file(path)


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
    with staged_outputs() as outputs:
        yield outputs.folder(path, replaceable)


class StagedOutputs:
    """The outputs of one command, written under temporary names and put in place together.

    :meth:`file` and :meth:`folder` check an output's place and return a
    temporary name beside it, which the command writes to (and reads back
    from: the output is not in place before :meth:`commit`). :meth:`commit`
    renames every temporary onto its place, :meth:`discard` removes them all;
    :func:`staged_outputs` calls one or the other as the command ends. Until
    the commit, files already at the outputs' places are untouched.
    """

    def __init__(self) -> None:
        self._staged: list[tuple[Path, Path, str | None]] = []  # (temporary, place, replaceable or None)

    def file(self, path: str | Path) -> Path:
        """A temporary file beside ``path`` (same suffix) that becomes ``path`` on commit."""
        path = check_output_path(path)
        fd, tmp = tempfile.mkstemp(prefix=_TMP_PREFIX.format(path.stem), suffix=_TMP_SUFFIX.format(path.suffix),
                                   dir=path.parent)
        os.close(fd)
        self._staged.append((Path(tmp), path, None))
        return Path(tmp)

    def folder(self, path: str | Path, replaceable: str | None = None) -> Path:
        """An empty temporary folder beside ``path`` whose files go to ``path`` on commit.

        With ``replaceable`` (a regular expression), ``path`` must be missing,
        empty or hold only files whose names fully match it (an earlier output
        of the same kind), and it is replaced whole on commit. Without, an
        existing folder keeps its other files and the new files replace their
        namesakes.
        """
        path = check_output_dir(path) if replaceable is None else check_output_folder(path, replaceable)
        tmp = Path(tempfile.mkdtemp(prefix=f".{path.name}.", suffix=".tmp", dir=path.parent))
        self._staged.append((tmp, path, replaceable))
        return tmp

    def commit(self) -> None:
        """Put every output in its place, in the order staged."""
        for i, (tmp, path, replaceable) in enumerate(self._staged):
            try:
                if tmp.is_dir():
                    _publish_folder(tmp, path, replaceable)
                else:
                    _publish_file(tmp, path)
            except BaseException:
                self._staged = self._staged[i:]
                self.discard()
                raise
        self._staged = []

    def discard(self) -> None:
        """Remove every temporary; nothing is put in place."""
        for tmp, _, _ in self._staged:
            if tmp.is_dir():
                shutil.rmtree(tmp, ignore_errors=True)
            else:
                tmp.unlink(missing_ok=True)
        self._staged = []


@contextlib.contextmanager
def staged_outputs() -> Iterator[StagedOutputs]:
    """Yield a :class:`StagedOutputs`; commit it if the block succeeds, else discard it (Ctrl-C included)."""
    outputs = StagedOutputs()
    try:
        yield outputs
    except BaseException:
        outputs.discard()
        raise
    outputs.commit()


def _publish_file(tmp: Path, path: Path) -> None:
    if tmp.is_file():  # mkstemp makes 0600 files; give the usual umask-based mode
        tmp.chmod(0o666 & ~_umask())
    os.replace(tmp, path)


def _publish_folder(tmp: Path, path: Path, replaceable: str | None) -> None:
    """Move folder ``tmp`` to ``path``: replace an earlier output whole, or add to the user's folder."""
    tmp.chmod(0o777 & ~_umask())
    if not path.is_dir():
        os.replace(tmp, path)
    elif replaceable is not None:  # checked to hold only an earlier output
        old = tmp.with_name(tmp.name + ".old")
        os.replace(path, old)
        try:
            os.replace(tmp, path)
        except BaseException:
            os.replace(old, path)
            raise
        shutil.rmtree(old)
    else:
        for item in tmp.iterdir():
            os.replace(item, path / item.name)
        tmp.rmdir()
