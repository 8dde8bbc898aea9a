"""Property-based and fuzz tests of the loaders of untrusted files (issue 7).

Valid files come from the project's own writers. Random byte edits,
insertions, deletions and truncations of them, and random values in place of
their fields, must give either a valid object or an :class:`InputError` with
a one-line message, never another exception. Round trips of random valid
objects must give them back exactly.
"""

from __future__ import annotations

import io
import json
import os
import struct
import zipfile
import zlib

import numpy as np
import pytest
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st
from hypothesis.extra import numpy as hnp

from marionette.camera import Camera
from marionette.errors import InputError
from marionette.gaussians import Gaussians
from marionette.geometry import axis_angle_to_matrix, make_transform
from marionette.io import (
    read_image,
    read_ply,
    read_prior,
    write_image,
    write_ply,
    write_prior,
)
from marionette.prior import SpatPrior
from marionette.render.camera_path import load_camera_path

FUZZ = settings(max_examples=120, deadline=None, derandomize=True, database=None,
                suppress_health_check=[HealthCheck.function_scoped_fixture, HealthCheck.too_slow])
ROUND_TRIP = settings(max_examples=40, deadline=None, derandomize=True, database=None,
                      suppress_health_check=[HealthCheck.function_scoped_fixture])


def load_or_refuse(load, path):
    """``load(path)``, or None when it raises an InputError with a one-line message."""
    try:
        return load(path)
    except InputError as exc:
        assert str(exc) and "\n" not in str(exc), repr(exc)
        return None


# Mutations of a byte string: (position in [0, 1), kind, byte value).
edits = st.lists(st.tuples(st.floats(0, 1, exclude_max=True), st.sampled_from(["set", "insert", "delete"]),
                           st.integers(0, 255)), max_size=6)
cuts = st.one_of(st.none(), st.floats(0, 1))


def mutate(data: bytes, changes, cut) -> bytes:
    out = bytearray(data)
    for where, kind, value in changes:
        i = int(where * len(out)) if out else 0
        if kind == "set" and out:
            out[i] = value
        elif kind == "insert":
            out.insert(i, value)
        elif out:
            del out[i]
    return bytes(out[: int(cut * len(out))] if cut is not None else out)


def random_prior(seed: int, parts: int = 2, frames: int = 5) -> SpatPrior:
    rng = np.random.default_rng(seed)
    poses = np.array([[make_transform(axis_angle_to_matrix(rng.normal(scale=0.3, size=3)), rng.normal(size=3))
                       for _ in range(frames)] for _ in range(parts)])
    centroids = rng.normal(size=(parts, frames, 3)) + [0, 0, 4]
    labels = rng.integers(-1, parts, size=(6, 8)).astype(np.int16)
    labels[0, 0] = 0
    return SpatPrior.from_poses(poses, centroids, rng.uniform(0.1, 2, parts), fps=float(rng.uniform(1, 60)),
                                image_size=(8, 6), intrinsics=Camera.from_fov(8, 6).K,
                                extras={"labels": labels}, metadata={"seed": seed})


# ---------------------------------------------------------------- PLY


@pytest.fixture(scope="module")
def ply_files(tmp_path_factory) -> dict[str, bytes]:
    """A small binary file written by write_ply, and the same Gaussians as ASCII."""
    folder = tmp_path_factory.mktemp("ply")
    rng = np.random.default_rng(3)
    g = Gaussians(rng.normal(size=(4, 3)), rng.normal(size=(4, 4)), rng.normal(size=(4, 3)), rng.normal(size=4),
                  rng.normal(size=(4, 4, 3)))
    write_ply(folder / "b.ply", g)
    from plyfile import PlyData

    ply = PlyData.read(str(folder / "b.ply"))
    ply.text = True
    ply.write(str(folder / "a.ply"))
    return {"binary": (folder / "b.ply").read_bytes(), "ascii": (folder / "a.ply").read_bytes()}


def header_edit(data: bytes, word: int, value: str) -> bytes:
    """``data`` with the ``word``-th whitespace-separated header word replaced by ``value``."""
    end = data.index(b"end_header")
    words = data[:end].split(b" ")
    words[word % len(words)] = value.encode()
    return b" ".join(words) + data[end:]


@FUZZ
@given(kind=st.sampled_from(["binary", "ascii"]), changes=edits, cut=cuts,
       header=st.one_of(st.none(), st.tuples(st.integers(0, 200), st.sampled_from(
           ["1000000000000", "-1", "0", "99999999999999999999", "double", "list", "uchar", "nan", "float",
            "binary_big_endian", "ascii", "vertex", "x", "f_rest_0", "face", "1"]))))
def test_mutated_ply_loads_or_is_refused(tmp_path, ply_files, kind, changes, cut, header):
    data = ply_files[kind]
    if header is not None:
        data = header_edit(data, *header)
    path = tmp_path / "f.ply"
    path.write_bytes(mutate(data, changes, cut))
    g = load_or_refuse(read_ply, path)
    if g is not None:  # what loads is usable
        assert isinstance(g, Gaussians)
        for name in ("means", "quats", "log_scales", "opacity_logits", "sh"):
            assert np.all(np.isfinite(getattr(g, name))), name


@pytest.mark.parametrize("fmt", ["ascii", "binary_little_endian", "binary_big_endian"])
@pytest.mark.parametrize("element", ["vertex", "face"])
def test_absurd_element_count_fails_fast(tmp_path, fmt, element):
    """A header claiming 10^12 rows (of the Gaussians or of another element) is refused before reading."""
    rows = "element vertex 1\nproperty float x\n"
    absurd = f"element {element} 1000000000000\nproperty float x\nproperty list uchar int idx\n"
    body = rows + absurd if element == "face" else absurd
    path = tmp_path / "big.ply"
    path.write_bytes(f"ply\nformat {fmt} 1.0\n{body}end_header\n".encode() + b"\0" * 64)
    with pytest.raises(InputError, match="truncated or corrupt"):
        read_ply(path)


@ROUND_TRIP
@given(n=st.integers(0, 20), c=st.sampled_from([1, 4, 9, 16]), seed=st.integers(0, 2**32 - 1),
       scale=st.sampled_from([1e-30, 1.0, 1e30]))
def test_ply_round_trip(tmp_path, n, c, seed, scale):
    rng = np.random.default_rng(seed)
    g = Gaussians(rng.normal(size=(n, 3)) * scale, rng.normal(size=(n, 4)), rng.normal(size=(n, 3)),
                  rng.normal(size=n) * scale, rng.normal(size=(n, c, 3)))
    write_ply(tmp_path / "g.ply", g)
    back = read_ply(tmp_path / "g.ply")
    for name in ("means", "quats", "log_scales", "opacity_logits", "sh"):
        assert getattr(back, name).tobytes() == getattr(g, name).tobytes(), name


# ---------------------------------------------------------------- prior .npz


@pytest.fixture(scope="module")
def prior_files(tmp_path_factory) -> dict[str, bytes]:
    """A prior written by write_prior (deflated), and the same arrays stored uncompressed.

    Edits of the compressed file mostly break the zip checksums; the stored one
    lets them reach the .npy headers and the array values.
    """
    folder = tmp_path_factory.mktemp("prior")
    write_prior(folder / "p.npz", random_prior(5))
    with np.load(folder / "p.npz") as d:
        np.savez(folder / "s.npz", **dict(d))
    return {"deflated": (folder / "p.npz").read_bytes(), "stored": (folder / "s.npz").read_bytes()}


@FUZZ
@given(kind=st.sampled_from(["deflated", "stored"]), changes=edits, cut=cuts)
def test_mutated_prior_loads_or_is_refused(tmp_path, prior_files, kind, changes, cut):
    path = tmp_path / "p.npz"
    path.write_bytes(mutate(prior_files[kind], changes, cut))
    prior = load_or_refuse(read_prior, path)
    if prior is not None:
        assert isinstance(prior, SpatPrior) and np.all(np.isfinite(prior.poses))


PRIOR_KEYS = ["format", "version", "fps", "image_size", "intrinsics", "poses", "rotations", "translations",
              "centroids", "radii", "metadata", "labels"]
any_array = hnp.arrays(
    dtype=st.one_of(hnp.scalar_dtypes(), hnp.unicode_string_dtypes(max_len=4)),
    shape=hnp.array_shapes(min_dims=0, max_dims=4, min_side=0, max_side=5),
)


@FUZZ
@given(key=st.sampled_from(PRIOR_KEYS), value=st.one_of(st.none(), any_array))
def test_prior_with_a_random_value_loads_or_is_refused(tmp_path, prior_files, key, value):
    """Any key removed or replaced by an array of any dtype (NaN, inf, strings, complex, …) and shape."""
    with np.load(io.BytesIO(prior_files["stored"])) as d:
        arrays = dict(d)
    if value is None:
        del arrays[key]
    else:
        arrays[key] = value
    path = tmp_path / "p.npz"
    np.savez(path, **arrays)
    prior = load_or_refuse(read_prior, path)
    if prior is not None:
        assert np.all(np.isfinite(prior.poses)) and prior.fps > 0 and np.all(prior.radii > 0)


@pytest.mark.parametrize("key, value, words", [
    ("poses", np.zeros((2, 5, 4, 4)), "'poses' holds matrices that are not rotations"),
    ("intrinsics", np.zeros((3, 3)), "'intrinsics'"),
    ("radii", np.array([1.0, np.inf]), "'radii' contains NaN or infinite"),
    ("image_size", np.array([8.0, 6.0]), "'image_size' has dtype float64"),
    ("image_size", np.array([10**6, 6]), "'image_size' must be at most"),
    ("version", np.array(1.5), "'version' has dtype float64, expected integers"),
    ("fps", np.array("30"), "'fps' has dtype <U2, expected numbers"),
    ("centroids", np.zeros((2, 5, 3), complex), "'centroids' has dtype complex128"),
    ("labels", np.full((6, 8), 7, np.int16), "'labels'"),
    ("metadata", np.array("{" * 100000), "'metadata' is not valid JSON"),
])
def test_bad_prior_value_is_named(tmp_path, prior_files, key, value, words):
    with np.load(io.BytesIO(prior_files["stored"])) as d:
        arrays = dict(d)
    arrays[key] = value
    np.savez(tmp_path / "p.npz", **arrays)
    with pytest.raises(InputError, match=words):
        read_prior(tmp_path / "p.npz")


def test_npy_header_claiming_terabytes_is_refused_before_allocating(tmp_path):
    header = io.BytesIO()
    np.lib.format.write_array_header_1_0(header, {"descr": "<f8", "fortran_order": False, "shape": (10**12,)})
    with zipfile.ZipFile(tmp_path / "p.npz", "w") as z:
        z.writestr("poses.npy", header.getvalue() + b"\0" * 64)
    with pytest.raises(InputError, match="header declares"):
        read_prior(tmp_path / "p.npz")


@ROUND_TRIP
@given(seed=st.integers(0, 2**32 - 1), parts=st.integers(1, 3), frames=st.integers(2, 6))
def test_prior_round_trip(tmp_path, seed, parts, frames):
    prior = random_prior(seed, parts, frames)
    write_prior(tmp_path / "p.npz", prior)
    back = read_prior(tmp_path / "p.npz")
    for key in ("image_size", "intrinsics", "poses", "rotations", "translations", "centroids", "radii"):
        assert getattr(back, key).tobytes() == getattr(prior, key).tobytes(), key
    assert back.fps == prior.fps and back.metadata == prior.metadata
    assert back.extras["labels"].tobytes() == prior.extras["labels"].tobytes()


# ---------------------------------------------------------------- camera JSON


def random_camera(seed: int) -> Camera:
    rng = np.random.default_rng(seed)
    pose = make_transform(axis_angle_to_matrix(rng.normal(size=3)), rng.normal(size=3))
    return Camera.from_fov(int(rng.integers(1, 4000)), int(rng.integers(1, 4000)), float(rng.uniform(1, 170)), pose)


json_scalars = st.none() | st.booleans() | st.integers() | st.floats() | st.text(max_size=5)
json_values = (json_scalars | st.lists(json_scalars, max_size=5)
               | st.lists(st.lists(json_scalars, max_size=5), max_size=5)
               | st.dictionaries(st.text(max_size=5), json_scalars, max_size=4))
CAMERA_KEYS = ["width", "height", "fx", "fy", "cx", "cy", "world_to_camera"]


@FUZZ
@given(changes=edits, cut=cuts, as_list=st.booleans())
def test_mutated_camera_json_loads_or_is_refused(tmp_path, changes, cut, as_list):
    d = random_camera(1).to_dict()
    text = json.dumps([d, d] if as_list else d).encode()
    path = tmp_path / "c.json"
    path.write_bytes(mutate(text, changes, cut))
    cameras = load_or_refuse(lambda p: load_camera_path(p, 2) if as_list else [Camera.load(p)], path)
    for cam in cameras or []:
        assert np.array_equal(cam.world_to_camera[3], [0, 0, 0, 1]) and cam.fx > 0 and cam.fy > 0


@FUZZ
@given(key=st.sampled_from(CAMERA_KEYS), value=json_values, row=st.integers(0, 3), col=st.integers(0, 3),
       in_matrix=st.booleans())
def test_camera_with_a_random_value_loads_or_is_refused(tmp_path, key, value, row, col, in_matrix):
    """A key (or one entry of world_to_camera) replaced by any JSON value, huge integers included."""
    d = random_camera(2).to_dict()
    if in_matrix:
        d["world_to_camera"][row][col] = value
    else:
        d[key] = value
    path = tmp_path / "c.json"
    path.write_text(json.dumps(d))
    cam = load_or_refuse(Camera.load, path)
    if cam is not None:
        assert np.all(np.isfinite(cam.K)) and 1 <= cam.width <= 8192


@pytest.mark.parametrize("change, words", [
    ({"fx": 10**400}, "'fx' must be a finite number"),
    ({"world_to_camera": [[10**400, 0, 0, 0], [0, 1, 0, 0], [0, 0, 1, 0], [0, 0, 0, 1]]}, "finite numbers"),
    ({"world_to_camera": [[1, 0, 0, 0], [0, 1, 0, 0], [0, 0, 1, 0], [1, 0, 0, 1]]}, r"\[0, 0, 0, 1\]"),
    ({"world_to_camera": [[1, 0, 0, 0], [0, 1, 0, 0], [0, 0, 0, 0], [0, 0, 0, 1]]}, "not a proper rotation"),
    ({"world_to_camera": [[1e300, 0, 0, 0], [0, 1, 0, 0], [0, 0, 1, 0], [0, 0, 0, 1]]}, "not a proper rotation"),
    ({"width": 100000}, "width must be an integer in 1..8192"),
    ({"height": 2.5}, "height must be an integer"),
])
def test_bad_camera_value_is_named(tmp_path, change, words):
    d = {**random_camera(3).to_dict(), **change}
    (tmp_path / "c.json").write_text(json.dumps(d))
    with pytest.raises(InputError, match=words):
        Camera.load(tmp_path / "c.json")


@pytest.mark.parametrize("content, words", [
    (b"[" * 100000 + b"]" * 100000, "nested too deeply"),
    (b"\xff\xfe{}", "not UTF-8"),
    (b"", "not valid JSON"),
])
def test_unparsable_camera_file(tmp_path, content, words):
    (tmp_path / "c.json").write_bytes(content)
    with pytest.raises(InputError, match=words):
        Camera.load(tmp_path / "c.json")
    with pytest.raises(InputError, match=words):
        load_camera_path(tmp_path / "c.json", 3)


def test_camera_path_names_the_bad_camera(tmp_path):
    good = random_camera(4).to_dict()
    (tmp_path / "p.json").write_text(json.dumps([good, {**good, "fy": -1}, good]))
    with pytest.raises(InputError, match="camera 1: focal lengths must be positive"):
        load_camera_path(tmp_path / "p.json", 3)


@ROUND_TRIP
@given(seed=st.integers(0, 2**32 - 1))
def test_camera_round_trip(tmp_path, seed):
    cam = random_camera(seed)
    (tmp_path / "c.json").write_text(json.dumps(cam.to_dict()))
    back = Camera.load(tmp_path / "c.json")
    assert back.K.tobytes() == cam.K.tobytes() and back.world_to_camera.tobytes() == cam.world_to_camera.tobytes()
    assert (back.width, back.height) == (cam.width, cam.height)


# ---------------------------------------------------------------- images


@pytest.fixture(scope="module")
def image_files(tmp_path_factory) -> dict[str, bytes]:
    folder = tmp_path_factory.mktemp("img")
    image = np.random.default_rng(6).integers(0, 256, size=(12, 16, 4), dtype=np.uint8)
    write_image(folder / "i.png", image)
    write_image(folder / "i.jpg", image[..., :3])
    return {".png": (folder / "i.png").read_bytes(), ".jpg": (folder / "i.jpg").read_bytes()}


@settings(FUZZ, max_examples=60)
@given(suffix=st.sampled_from([".png", ".jpg"]), changes=edits, cut=cuts)
def test_mutated_image_loads_or_is_refused(tmp_path, image_files, suffix, changes, cut):
    path = tmp_path / f"i{suffix}"
    path.write_bytes(mutate(image_files[suffix], changes, cut))
    image = load_or_refuse(read_image, path)
    if image is not None:
        assert image.dtype == np.uint8 and image.ndim == 3 and image.shape[2] in (3, 4)


def png_header(width: int, height: int) -> bytes:
    """A PNG that declares ``width`` x ``height`` RGB pixels but holds one row of data."""
    def chunk(kind: bytes, data: bytes) -> bytes:
        return struct.pack(">I", len(data)) + kind + data + struct.pack(">I", zlib.crc32(kind + data))

    ihdr = struct.pack(">IIBBBBB", width, height, 8, 2, 0, 0, 0)
    return (b"\x89PNG\r\n\x1a\n" + chunk(b"IHDR", ihdr) + chunk(b"IDAT", zlib.compress(bytes(3 * width + 1)))
            + chunk(b"IEND", b""))


@pytest.mark.parametrize("width, height, words", [
    (12000, 12000, "more than the limit"),  # below Pillow's own limit, above ours
    (100000, 100000, "too large"),
])
def test_decompression_bomb_is_refused_before_decoding(tmp_path, width, height, words):
    (tmp_path / "bomb.png").write_bytes(png_header(width, height))
    with pytest.raises(InputError, match=words):
        read_image(tmp_path / "bomb.png")


@pytest.mark.parametrize("bad", [[0, 0, 0, 0], [0, 1e-30, 0, 0], [1e30, 0, 0, 1e30]])
def test_quaternion_without_a_usable_length_is_refused(tmp_path, bad):
    """Zero, or so small or large that its float32 length is 0 or inf: normalising it would give NaN."""
    quats = np.array([[1.0, 0, 0, 0], bad, [0, 1.0, 0, 0]])
    g = Gaussians(np.zeros((3, 3)), quats, np.zeros((3, 3)), np.zeros(3), np.zeros((3, 1, 3)))
    write_ply(tmp_path / "g.ply", g)
    with pytest.raises(InputError, match="vertex 1 is zero or out of range"):
        read_ply(tmp_path / "g.ply")


@pytest.mark.skipif(not os.path.exists("/proc/self/mem"), reason="needs Linux /proc")
@pytest.mark.parametrize("suffix, load", [
    (".ply", read_ply), (".npz", read_prior), (".png", read_image), (".json", Camera.load),
    (".json", lambda p: load_camera_path(p, 3)),
])
def test_unreadable_file_is_an_input_error(tmp_path, suffix, load):
    """A file whose reads fail (even for root: /proc/self/mem gives EIO at offset 0)."""
    path = tmp_path / f"f{suffix}"
    path.symlink_to("/proc/self/mem")
    with pytest.raises(InputError):
        load(path)
