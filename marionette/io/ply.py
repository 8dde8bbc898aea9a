"""3D Gaussian Splatting ``.ply`` files, in the reference layout.

The reference implementation (Kerbl et al. 2023, ``GaussianModel.save_ply``)
writes one ``vertex`` element of float32 properties::

    x y z nx ny nz f_dc_0 f_dc_1 f_dc_2 f_rest_0 … f_rest_{3(C-1)-1}
    opacity scale_0 scale_1 scale_2 rot_0 rot_1 rot_2 rot_3

``f_rest`` is channel-major: the (N, C-1, 3) higher-order coefficients are
transposed to (N, 3, C-1) before flattening, so ``f_rest_0 … f_rest_{C-2}``
are red's coefficients 1 … C-1, then green's, then blue's. Normals are
written as zeros and ignored on reading.
"""

from __future__ import annotations

import re
from pathlib import Path

import numpy as np
from plyfile import PlyData, PlyElement, PlyListProperty

from ..errors import InputError
from ..gaussians import Gaussians
from .atomic import atomic_path

__all__ = ["read_ply", "write_ply", "read_ply_property", "PLY_FRAME_NAME"]

#: Names of the per-frame files of :func:`marionette.pipeline.write_ply_frames` (a folder of only these may be
#: replaced).
PLY_FRAME_NAME = r"\d{5,}\.ply"

_REQUIRED = ("x", "y", "z", "f_dc_0", "f_dc_1", "f_dc_2", "opacity",
             "scale_0", "scale_1", "scale_2", "rot_0", "rot_1", "rot_2", "rot_3")
#: Number of f_rest properties → SH degree.
_REST_TO_DEGREE = {0: 0, 9: 1, 24: 2, 45: 3}
#: Bytes per value of each PLY scalar type, for the header size check.
_TYPE_SIZES = {
    "char": 1, "int8": 1, "uchar": 1, "uint8": 1, "short": 2, "int16": 2,
    "ushort": 2, "uint16": 2, "int": 4, "int32": 4, "uint": 4, "uint32": 4,
    "float": 4, "float32": 4, "double": 8, "float64": 8,
}
#: Headers longer than this are treated as corrupt (real ones are < 4 KiB).
_MAX_HEADER_BYTES = 1 << 20


def _property_names(sh_coeffs: int) -> list[str]:
    """Property names of the reference layout for C = ``sh_coeffs`` SH coefficients."""
    rest = [f"f_rest_{i}" for i in range(3 * (sh_coeffs - 1))]
    return (["x", "y", "z", "nx", "ny", "nz", "f_dc_0", "f_dc_1", "f_dc_2"] + rest
            + ["opacity", "scale_0", "scale_1", "scale_2", "rot_0", "rot_1", "rot_2", "rot_3"])


def write_ply(path: str | Path, gaussians: Gaussians, *, extra: dict[str, np.ndarray] | None = None) -> None:
    """Write ``gaussians`` as a binary little-endian 3DGS ``.ply`` (atomically).

    All values are stored as float32, so :func:`read_ply` gives them back bitwise.
    ``extra`` adds vertex properties after the reference ones, by name: (N,)
    integer arrays are written as ``int``, others as ``float`` (e.g. ``part``,
    a Gaussian's rigid part, as ``reconstruct`` writes it); 3DGS readers
    ignore them, :func:`read_ply_property` reads them back.
    """
    gaussians.check_finite()  # we would refuse to read such a file back
    g = gaussians
    extra = dict(extra or {})
    for name, values in extra.items():
        values = np.asarray(values)
        if not re.fullmatch(r"[A-Za-z_][A-Za-z0-9_]*", name) or name in _property_names(g.sh.shape[1]):
            raise InputError(f"extra .ply property name {name!r} is not a free identifier")
        if values.shape != (len(g),) or values.dtype.kind not in "iuf" or not np.all(np.isfinite(values)):
            raise InputError(f"extra .ply property {name!r} must be {len(g)} finite numbers, got shape {values.shape}")
    n, c = len(g), g.sh.shape[1]
    rest = g.sh[:, 1:, :].transpose(0, 2, 1).reshape(n, 3 * (c - 1))  # (N, 3(C-1)) channel-major
    columns = np.concatenate(
        [g.means, np.zeros((n, 3), np.float32), g.sh[:, 0, :], rest,
         g.opacity_logits[:, None], g.log_scales, g.quats], axis=1,
    )  # (N, P) float32, one column per property
    dtype = np.dtype([(name, "<f4") for name in _property_names(c)])
    vertices = np.ascontiguousarray(columns, dtype="<f4").view(dtype).reshape(n)
    if extra:
        kinds = {name: "<i4" if np.asarray(v).dtype.kind in "iu" else "<f4" for name, v in extra.items()}
        full = np.empty(n, dtype=np.dtype(dtype.descr + list(kinds.items())))
        for name in dtype.names:
            full[name] = vertices[name]
        for name, values in extra.items():
            full[name] = np.asarray(values).astype(kinds[name])
        vertices = full
    ply = PlyData([PlyElement.describe(vertices, "vertex")], text=False, byte_order="<")
    with atomic_path(path) as tmp:
        ply.write(str(tmp))


def read_ply(path: str | Path) -> Gaussians:
    """Read a 3DGS ``.ply`` written by us or by common 3DGS tools.

    Accepts ASCII or binary files, any numeric property types (cast to
    float32), extra properties and elements (ignored) and missing normals.
    The SH degree (0 to 3) follows from the number of ``f_rest_*`` properties.
    Raises :class:`InputError` with a one-line reason for anything else.
    """
    path = Path(path)
    if not path.is_file():
        raise InputError(f"{path} does not exist" if not path.exists() else f"{path} is not a file")
    _check_header(path)
    try:
        ply = PlyData.read(str(path))
    except Exception as exc:  # plyfile raises many types on corrupt data; all mean the same to the user
        raise InputError(f"{path} is not a valid PLY file: {_one_line(exc)}") from exc

    elements = {element.name: element for element in ply.elements}
    if "vertex" not in elements:
        raise InputError(f"{path} has no 'vertex' element, so it holds no Gaussians")
    vertex = elements["vertex"]
    properties = {prop.name: prop for prop in vertex.properties}

    rest_names = [name for name in properties if re.fullmatch(r"f_rest_\d+", name)]
    if len(rest_names) not in _REST_TO_DEGREE:
        raise InputError(f"{path} has {len(rest_names)} f_rest properties; expected 0, 9, 24 or 45 "
                         "(SH degree 0 to 3)")
    c = len(rest_names) // 3 + 1
    needed = list(_REQUIRED) + [f"f_rest_{i}" for i in range(3 * (c - 1))]
    for name in needed:
        if name not in properties:
            raise InputError(f"{path} is missing the vertex property '{name}'")
        if isinstance(properties[name], PlyListProperty):
            raise InputError(f"{path}: vertex property '{name}' is a list, expected a number")

    def column(name: str) -> np.ndarray:
        """(N,) float32 values of one property, checked finite."""
        with np.errstate(over="ignore", invalid="ignore"):  # out-of-range doubles become inf, caught below
            values = np.asarray(vertex.data[name], dtype=np.float32)
        bad = np.flatnonzero(~np.isfinite(values))
        if bad.size:
            raise InputError(f"{path}: vertex property '{name}' has NaN or infinite values "
                             f"(first at vertex {bad[0]})")
        return values

    n = vertex.count

    def stack(names: list[str]) -> np.ndarray:
        """(N, len(names)) float32."""
        return np.stack([column(name) for name in names], axis=1) if names else np.zeros((n, 0), np.float32)

    dc = stack(["f_dc_0", "f_dc_1", "f_dc_2"])  # (N, 3)
    rest = stack([f"f_rest_{i}" for i in range(3 * (c - 1))]).reshape(n, 3, c - 1)  # (N, 3, C-1)
    sh = np.concatenate([dc[:, None, :], rest.transpose(0, 2, 1)], axis=1)  # (N, C, 3)
    quats = stack(["rot_0", "rot_1", "rot_2", "rot_3"])  # (N, 4)
    with np.errstate(over="ignore", under="ignore"):  # float32 norms, as the quaternions are normalised later
        norms = np.linalg.norm(quats, axis=1)
    bad = np.flatnonzero(~(np.isfinite(norms) & (norms > 0)))
    if bad.size:
        raise InputError(f"{path}: the rotation rot_0..rot_3 of vertex {bad[0]} is zero or out of range "
                         "(its length is not a positive float32)")
    return Gaussians(
        means=stack(["x", "y", "z"]),
        quats=quats,
        log_scales=stack(["scale_0", "scale_1", "scale_2"]),
        opacity_logits=column("opacity"),
        sh=sh,
    )


def read_ply_property(path: str | Path, name: str) -> np.ndarray | None:
    """(N,) values of the extra vertex property ``name`` of a 3DGS ``.ply`` (int64 for integer types), or None.

    The file is checked as :func:`read_ply` checks it; e.g. ``part``, the
    rigid part of each Gaussian written by ``reconstruct``.
    """
    path = Path(path)
    read_ply(path)
    ply = PlyData.read(str(path))
    vertex = ply["vertex"]
    props = {prop.name: prop for prop in vertex.properties}
    if name not in props:
        return None
    if isinstance(props[name], PlyListProperty):
        raise InputError(f"{path}: vertex property '{name}' is a list, expected a number")
    values = np.asarray(vertex.data[name])
    if values.dtype.kind in "iu":
        return values.astype(np.int64)
    values = values.astype(np.float64)
    if not np.all(np.isfinite(values)):
        raise InputError(f"{path}: vertex property '{name}' has NaN or infinite values")
    return values


def _check_header(path: Path) -> None:
    """Reject non-PLY files and headers that promise more data than the file holds.

    plyfile allocates the declared element count up front (for ASCII files and
    list properties), so an absurd count must be caught before it reads.
    """
    try:
        with open(path, "rb") as f:
            head = f.read(_MAX_HEADER_BYTES)
    except OSError as exc:
        raise InputError(f"cannot read {path}: {exc.strerror}") from None
    if not head.startswith(b"ply"):
        raise InputError(f"{path} is not a PLY file (it does not start with 'ply')")
    end = head.find(b"end_header")
    if end < 0:
        raise InputError(f"{path} is not a valid PLY file: no end_header (truncated or corrupt header)")
    try:
        lines = head[:end].decode("ascii").splitlines()
    except UnicodeDecodeError:
        raise InputError(f"{path} is not a valid PLY file: its header is not ASCII text") from None

    text = False
    counts: list[tuple[str, int]] = []
    row_bytes: list[int] = []  # lower bound on the bytes per row of each element
    for line in lines:
        words = line.split()
        if len(words) >= 2 and words[0] == "format":
            text = words[1] == "ascii"
        elif len(words) == 3 and words[0] == "element" and words[2].isdigit():
            counts.append((words[1], int(words[2])))
            row_bytes.append(0)
        elif len(words) >= 3 and words[0] == "property" and counts:
            # a value takes at least 2 bytes in ASCII (digit + separator); a list at least its length field
            type_name = words[2] if words[1] == "list" else words[1]
            row_bytes[-1] += 2 if text else _TYPE_SIZES.get(type_name, 1)
    needed = sum(count * size for (_, count), size in zip(counts, row_bytes)) - (1 if text else 0)
    available = path.stat().st_size - (end + len(b"end_header\n"))
    if needed > available:
        declared = ", ".join(f"{count} '{name}'" for name, count in counts)
        raise InputError(f"{path} is truncated or corrupt: its header declares {declared} elements "
                         f"(at least {needed} bytes) but only {max(available, 0)} bytes follow")


def _one_line(exc: BaseException) -> str:
    """The first line of an exception's message, or its type name."""
    lines = str(exc).strip().splitlines()
    return lines[0] if lines else type(exc).__name__
