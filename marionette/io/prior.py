"""SpaT prior files (``.npz``, the contract in DESIGN.md), loaded without pickle."""

from __future__ import annotations

import json
import zipfile
from pathlib import Path

import numpy as np

from ..errors import InputError
from ..prior import PRIOR_FORMAT, PRIOR_VERSION, SpatPrior
from .atomic import atomic_path

__all__ = ["read_prior", "write_prior"]

_REQUIRED = ("format", "version", "fps", "image_size", "intrinsics", "poses", "rotations",
             "translations", "centroids", "radii")


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


def _scalar(data, key: str, kind: type):
    value = data[key]
    if value.shape != ():
        raise InputError(f"prior key '{key}' must be a scalar, got shape {value.shape}")
    try:
        return kind(value.item())
    except (TypeError, ValueError):
        raise InputError(f"prior key '{key}' has the wrong type ({value.dtype})") from None


def read_prior(path: str | Path) -> SpatPrior:
    """Read and validate a prior file; errors name the offending key."""
    path = Path(path)
    if not path.is_file():
        raise InputError(f"prior file {path} does not exist")
    if not zipfile.is_zipfile(path):
        raise InputError(f"prior file {path} is not a readable .npz file (not a zip archive)")
    try:
        with np.load(path, allow_pickle=False) as data:
            missing = [k for k in _REQUIRED if k not in data.files]
            if missing:
                raise InputError(f"prior file {path} lacks key '{missing[0]}'")
            fmt = _scalar(data, "format", str)
            if fmt != PRIOR_FORMAT:
                raise InputError(f"prior key 'format' is '{fmt}', expected '{PRIOR_FORMAT}'")
            version = _scalar(data, "version", int)
            if version != PRIOR_VERSION:
                raise InputError(f"prior key 'version' is {version}; this tool reads version {PRIOR_VERSION}")
            metadata = {}
            if "metadata" in data.files:
                try:
                    metadata = json.loads(_scalar(data, "metadata", str))
                except json.JSONDecodeError:
                    raise InputError("prior key 'metadata' is not valid JSON") from None
            fields = {k: data[k] for k in _REQUIRED[3:]}
            extras = {k: data[k] for k in data.files if k not in _REQUIRED and k != "metadata"}
            fps = _scalar(data, "fps", float)
    except InputError:
        raise
    except ValueError as e:
        # np.load refuses object arrays (pickle) with a ValueError.
        raise InputError(f"prior file {path} holds pickled objects or bad data: {e}") from None
    except (OSError, zipfile.BadZipFile, EOFError, KeyError) as e:
        raise InputError(f"prior file {path} is not a readable .npz file ({type(e).__name__})") from None
    return SpatPrior(fps=fps, extras=extras, metadata=metadata if isinstance(metadata, dict) else {}, **fields)
