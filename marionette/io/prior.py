"""SpaT prior files (``.npz``, the contract in docs/DESIGN.md), loaded without pickle."""

from __future__ import annotations

import json
import math
import zipfile
import zlib
from pathlib import Path
from typing import BinaryIO

import numpy as np

from ..errors import InputError
from ..prior import PRIOR_FORMAT, PRIOR_VERSION, SpatPrior
from .atomic import atomic_path

__all__ = ["read_prior", "write_prior"]

_REQUIRED = ("format", "version", "fps", "image_size", "intrinsics", "poses", "rotations",
             "translations", "centroids", "radii")
#: Largest total of (uncompressed) array data read from a prior file.
MAX_PRIOR_BYTES = 1 << 30
#: numpy dtype kinds each key accepts (others: "iuf").
_KINDS = {"format": "U", "version": "iu", "image_size": "iu", "metadata": "U"}
_KIND_NAMES = {"U": "a string", "iu": "integers", "iuf": "numbers"}
_HEADER_READERS = {(1, 0): np.lib.format.read_array_header_1_0, (2, 0): np.lib.format.read_array_header_2_0}


def write_prior(path: str | Path, prior: SpatPrior) -> None:
    """Write ``prior`` to ``path`` (.npz), atomically.

    Contract keys plus every array in ``prior.extras`` and ``metadata`` as a
    JSON string.
    """
    arrays = {
        "format": np.array(PRIOR_FORMAT), "version": np.array(PRIOR_VERSION),
        "fps": np.array(prior.fps), "image_size": prior.image_size.astype(np.int64),
        "intrinsics": prior.intrinsics, "poses": prior.poses, "rotations": prior.rotations,
        "translations": prior.translations, "centroids": prior.centroids, "radii": prior.radii,
        "metadata": np.array(prior.metadata_json()),
    }
    for key, value in prior.extras.items():
        if key in arrays:
            raise ValueError(f"prior extra '{key}' would overwrite a contract key")
        arrays[key] = np.asarray(value)
    with atomic_path(path) as tmp:
        with open(tmp, "wb") as f:
            np.savez_compressed(f, **arrays)


def read_prior(path: str | Path) -> SpatPrior:
    """Read and validate a prior file; errors name the offending key.

    Arrays are read without pickle, and each one's declared size is checked
    against the archive before anything is allocated.
    """
    path = Path(path)
    if not path.is_file():
        raise InputError(f"prior file {path} does not exist" if not path.exists()
                         else f"prior file {path} is not a file")
    arrays = _read_arrays(path)
    missing = [k for k in _REQUIRED if k not in arrays]
    if missing:
        raise InputError(f"prior file {path} lacks key '{missing[0]}'")
    for key in (*_REQUIRED, "metadata"):
        kinds = _KINDS.get(key, "iuf")
        if key in arrays and arrays[key].dtype.kind not in kinds:
            raise InputError(f"prior key '{key}' has dtype {arrays[key].dtype}, expected {_KIND_NAMES[kinds]}")
    fmt = _scalar(arrays, "format")
    if fmt != PRIOR_FORMAT:
        raise InputError(f"prior key 'format' is {fmt[:40]!r}, expected '{PRIOR_FORMAT}'")
    version = _scalar(arrays, "version")
    if version != PRIOR_VERSION:
        raise InputError(f"prior key 'version' is {version}; this tool reads version {PRIOR_VERSION}")
    metadata = {}
    if "metadata" in arrays:
        try:
            metadata = json.loads(_scalar(arrays, "metadata"))
        except (json.JSONDecodeError, RecursionError):
            raise InputError("prior key 'metadata' is not valid JSON") from None
    fields = {k: arrays[k] for k in _REQUIRED[3:]}
    extras = {k: v for k, v in arrays.items() if k not in _REQUIRED and k != "metadata"}
    return SpatPrior(fps=float(_scalar(arrays, "fps")), extras=extras,
                     metadata=metadata if isinstance(metadata, dict) else {}, **fields)


def _scalar(arrays: dict[str, np.ndarray], key: str):
    """The value of a 0-d array."""
    value = arrays[key]
    if value.shape != ():
        raise InputError(f"prior key '{key}' must be a scalar, got shape {value.shape}")
    return value.item()


def _read_arrays(path: Path) -> dict[str, np.ndarray]:
    """Every array of an ``.npz``, without pickle; an :class:`InputError` for anything corrupt.

    ``np.load`` allocates the shape an array's header declares before reading
    it, so a few corrupt bytes could ask for terabytes: headers are checked
    against the member's size first, and the total against
    :data:`MAX_PRIOR_BYTES`.
    """
    arrays = {}
    try:
        with open(path, "rb") as file, zipfile.ZipFile(file) as archive:
            members = [info for info in archive.infolist() if info.filename.endswith(".npy")]
            total = sum(info.file_size for info in members)
            if total > MAX_PRIOR_BYTES:
                raise InputError(f"prior file {path} holds {total >> 20} MiB of arrays; "
                                 f"the limit is {MAX_PRIOR_BYTES >> 20} MiB")
            for info in members:
                key = info.filename[:-4]
                with archive.open(info) as f:
                    arrays[key] = _read_npy(f, info.file_size, f"prior file {path}, key '{key}'")
    except InputError:  # a ValueError too, but already worded for the user
        raise
    except (OSError, EOFError, ValueError, zipfile.BadZipFile, zlib.error, NotImplementedError) as exc:
        raise InputError(f"prior file {path} is not a readable .npz file ({_one_line(exc)})") from None
    return arrays


def _read_npy(f: BinaryIO, size: int, what: str) -> np.ndarray:
    """One ``.npy`` array from the stream ``f`` of ``size`` bytes, its header checked before allocating."""
    version = np.lib.format.read_magic(f)
    if version not in _HEADER_READERS:
        raise InputError(f"{what}: unsupported .npy version {version}")
    shape, fortran, dtype = _HEADER_READERS[version](f)
    if dtype.hasobject:
        raise InputError(f"{what} holds pickled objects, which are not loaded")
    count = math.prod(shape)
    nbytes = count * dtype.itemsize
    if nbytes > size:
        raise InputError(f"{what}: its header declares {shape} {dtype} ({nbytes} bytes) "
                         f"but the archive holds {size} bytes")
    data = bytearray(nbytes)
    if f.readinto(data) != nbytes:
        raise InputError(f"{what} is truncated")
    array = np.frombuffer(data, dtype=dtype, count=count)
    return array.reshape(shape[::-1]).T if fortran else array.reshape(shape)


def _one_line(exc: BaseException) -> str:
    """The first line of an exception's message, or its type name."""
    lines = str(exc).strip().splitlines()
    return lines[0] if lines else type(exc).__name__
