"""3DGS .ply reading and writing (marionette.io.ply)."""

from __future__ import annotations

import os
import stat

import numpy as np
import pytest
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st
from plyfile import PlyData, PlyElement

from marionette.errors import InputError
from marionette.gaussians import Gaussians
from marionette.io import read_ply, write_ply

FIELDS = ("means", "quats", "log_scales", "opacity_logits", "sh")


def random_gaussians(n: int, c: int, seed: int = 0) -> Gaussians:
    """N Gaussians with C SH coefficients per channel, all attributes random."""
    rng = np.random.default_rng(seed)
    return Gaussians(rng.normal(size=(n, 3)), rng.normal(size=(n, 4)), rng.normal(size=(n, 3)),
                     rng.normal(size=n), rng.normal(size=(n, c, 3)))


def reference_properties(g: Gaussians) -> list[tuple[str, np.ndarray]]:
    """(name, (N,) values) in the order of the reference ``GaussianModel.save_ply``, built one by one.

    The reference stores ``features_rest`` (N, C-1, 3) as ``transpose(1, 2).flatten(1)``:
    property ``f_rest_{ch * (C-1) + (k-1)}`` holds coefficient k of channel ch.
    """
    n, c = g.sh.shape[:2]
    props = [("x", g.means[:, 0]), ("y", g.means[:, 1]), ("z", g.means[:, 2])]
    props += [(name, np.zeros(n, np.float32)) for name in ("nx", "ny", "nz")]
    props += [(f"f_dc_{ch}", g.sh[:, 0, ch]) for ch in range(3)]
    for ch in range(3):
        for k in range(1, c):
            props.append((f"f_rest_{ch * (c - 1) + k - 1}", g.sh[:, k, ch]))
    props.append(("opacity", g.opacity_logits))
    props += [(f"scale_{i}", g.log_scales[:, i]) for i in range(3)]
    props += [(f"rot_{i}", g.quats[:, i]) for i in range(4)]
    return props


def write_raw(path, props, *, types=None, text=False, extra_elements=()) -> None:
    """Write a vertex element with the given (name, values) list through plyfile directly."""
    types = types or {}
    n = len(props[0][1])
    vertex = np.empty(n, dtype=[(name, types.get(name, "<f4")) for name, _ in props])
    for name, values in props:
        vertex[name] = values
    PlyData([PlyElement.describe(vertex, "vertex"), *extra_elements], text=text).write(str(path))


def assert_same(a: Gaussians, b: Gaussians) -> None:
    for name in FIELDS:
        x, y = getattr(a, name), getattr(b, name)
        assert x.dtype == y.dtype == np.float32 and x.shape == y.shape, name
        assert x.tobytes() == y.tobytes(), name  # bitwise


@pytest.mark.parametrize("c", [1, 4, 9, 16])
@pytest.mark.parametrize("n", [0, 37])
def test_round_trip_is_bitwise_exact(tmp_path, n, c):
    g = random_gaussians(n, c, seed=c)
    write_ply(tmp_path / "g.ply", g)
    h = read_ply(tmp_path / "g.ply")
    assert_same(g, h)
    assert h.sh_degree == int(np.sqrt(c)) - 1


@pytest.mark.parametrize("c", [4, 16])
def test_layout_matches_reference(tmp_path, c):
    g = random_gaussians(5, c, seed=1)
    write_raw(tmp_path / "ref.ply", reference_properties(g))
    assert_same(read_ply(tmp_path / "ref.ply"), g)
    # our writer produces the same bytes as the hand-built reference file
    write_ply(tmp_path / "ours.ply", g)
    assert (tmp_path / "ours.ply").read_bytes() == (tmp_path / "ref.ply").read_bytes()


def test_f_rest_is_channel_major(tmp_path):
    # degree 1: f_rest_0..2 are red's coefficients 1..3, f_rest_3..5 green's, f_rest_6..8 blue's
    props = reference_properties(random_gaussians(1, 1))
    props[9:9] = [(f"f_rest_{i}", np.array([float(i)], np.float32)) for i in range(9)]
    write_raw(tmp_path / "g.ply", props)
    sh = read_ply(tmp_path / "g.ply").sh[0]  # (4, 3)
    np.testing.assert_array_equal(sh[1:, 0], [0, 1, 2])
    np.testing.assert_array_equal(sh[1:, 1], [3, 4, 5])
    np.testing.assert_array_equal(sh[1:, 2], [6, 7, 8])


def test_extra_and_double_properties_and_missing_normals_load(tmp_path):
    g = random_gaussians(6, 4, seed=2)
    props = [p for p in reference_properties(g) if p[0] not in ("nx", "ny", "nz")]
    props.insert(3, ("red", np.arange(6)))
    props.append(("confidence", np.linspace(0, 1, 6)))
    types = {"red": "u1", "x": "<f8", "opacity": "<f8", "f_rest_4": ">f8", "confidence": "<f8"}
    faces = PlyElement.describe(np.array([([0, 1, 2],)], dtype=[("vertex_indices", "O")]), "face")
    write_raw(tmp_path / "g.ply", props, types=types, extra_elements=[faces])
    assert_same(read_ply(tmp_path / "g.ply"), g)  # float32 → double → float32 is exact


def test_ascii_loads(tmp_path):
    g = random_gaussians(4, 9, seed=3)
    write_raw(tmp_path / "g.ply", reference_properties(g), text=True)
    assert (tmp_path / "g.ply").read_bytes().startswith(b"ply\nformat ascii")
    assert_same(read_ply(tmp_path / "g.ply"), g)  # plyfile prints float32 with round-trip precision


def test_missing_property_is_named(tmp_path):
    props = [p for p in reference_properties(random_gaussians(3, 1)) if p[0] != "rot_2"]
    write_raw(tmp_path / "g.ply", props)
    with pytest.raises(InputError, match="missing the vertex property 'rot_2'"):
        read_ply(tmp_path / "g.ply")


def test_missing_f_rest_is_named(tmp_path):
    props = reference_properties(random_gaussians(3, 4))
    props = [p if p[0] != "f_rest_5" else ("f_rest_9", p[1]) for p in props]
    write_raw(tmp_path / "g.ply", props)
    with pytest.raises(InputError, match="'f_rest_5'"):
        read_ply(tmp_path / "g.ply")


def test_wrong_f_rest_count(tmp_path):
    props = [p for p in reference_properties(random_gaussians(3, 4)) if p[0] != "f_rest_8"]
    write_raw(tmp_path / "g.ply", props)
    with pytest.raises(InputError, match="8 f_rest properties; expected 0, 9, 24 or 45"):
        read_ply(tmp_path / "g.ply")


@pytest.mark.parametrize("value", [np.nan, np.inf, 1e300])  # 1e300 overflows float32
def test_non_finite_value_is_named(tmp_path, value):
    props = reference_properties(random_gaussians(4, 1))
    props = [(name, np.where(np.arange(4) == 2, value, v.astype(np.float64)) if name == "opacity" else v)
             for name, v in props]
    write_raw(tmp_path / "g.ply", props, types={"opacity": "<f8"})
    with pytest.raises(InputError, match="'opacity' has NaN or infinite values \\(first at vertex 2\\)"):
        read_ply(tmp_path / "g.ply")


def test_list_property_is_rejected(tmp_path):
    header = b"ply\nformat ascii 1.0\nelement vertex 1\nproperty list uchar float x\nend_header\n1 0.5\n"
    (tmp_path / "g.ply").write_bytes(header)
    with pytest.raises(InputError):
        read_ply(tmp_path / "g.ply")


def test_no_vertex_element(tmp_path):
    (tmp_path / "g.ply").write_bytes(b"ply\nformat ascii 1.0\nelement point 1\nproperty float x\nend_header\n1\n")
    with pytest.raises(InputError, match="no 'vertex' element"):
        read_ply(tmp_path / "g.ply")


@pytest.mark.parametrize("keep", [0.5, 0.99])
def test_truncated_file(tmp_path, keep):
    write_ply(tmp_path / "g.ply", random_gaussians(20, 4))
    data = (tmp_path / "g.ply").read_bytes()
    (tmp_path / "t.ply").write_bytes(data[: int(len(data) * keep)])
    with pytest.raises(InputError, match="truncated"):
        read_ply(tmp_path / "t.ply")


def test_truncated_header(tmp_path):
    write_ply(tmp_path / "g.ply", random_gaussians(2, 1))
    (tmp_path / "t.ply").write_bytes((tmp_path / "g.ply").read_bytes()[:60])
    with pytest.raises(InputError, match="no end_header"):
        read_ply(tmp_path / "t.ply")


@pytest.mark.parametrize("fmt", ["ascii", "binary_little_endian"])
def test_absurd_vertex_count_is_caught_before_reading(tmp_path, fmt):
    # plyfile would try to allocate 10^15 rows for an ASCII file
    header = f"ply\nformat {fmt} 1.0\nelement vertex 1000000000000000\nproperty float x\nend_header\n"
    (tmp_path / "g.ply").write_bytes(header.encode() + b"1 2 3\n")
    with pytest.raises(InputError, match="declares 1000000000000000 'vertex' elements"):
        read_ply(tmp_path / "g.ply")


@pytest.mark.parametrize("content", [b"", b"hello world\n", b"\x00\xff" * 100])
def test_garbage_is_rejected(tmp_path, content):
    (tmp_path / "g.ply").write_bytes(content)
    with pytest.raises(InputError, match="PLY"):
        read_ply(tmp_path / "g.ply")


def test_missing_file(tmp_path):
    with pytest.raises(InputError, match="does not exist"):
        read_ply(tmp_path / "nope.ply")


def test_write_is_atomic_and_checked(tmp_path):
    target = tmp_path / "g.ply"
    target.write_bytes(b"old")
    g = random_gaussians(3, 1)
    bad = Gaussians(g.means, g.quats, g.log_scales, np.array([0, np.nan, 0]), g.sh)
    with pytest.raises(InputError, match="opacity_logits"):
        write_ply(target, bad)
    assert target.read_bytes() == b"old"
    assert [p.name for p in tmp_path.iterdir()] == ["g.ply"]
    with pytest.raises(InputError, match="does not exist"):
        write_ply(tmp_path / "missing" / "g.ply", g)


def test_written_files_get_the_umask_mode(tmp_path):
    old = os.umask(0o022)
    try:
        write_ply(tmp_path / "g.ply", random_gaussians(3, 1))
    finally:
        os.umask(old)
    assert stat.S_IMODE((tmp_path / "g.ply").stat().st_mode) == 0o644


@pytest.fixture(scope="module")
def valid_files(tmp_path_factory) -> dict[str, bytes]:
    """Contents of a small valid binary and ASCII file, to mutate."""
    folder = tmp_path_factory.mktemp("fuzz")
    g = random_gaussians(3, 4, seed=4)
    write_ply(folder / "b.ply", g)
    write_raw(folder / "a.ply", reference_properties(g), text=True)
    return {"binary": (folder / "b.ply").read_bytes(), "ascii": (folder / "a.ply").read_bytes()}


@settings(max_examples=150, deadline=None, derandomize=True, database=None,
          suppress_health_check=[HealthCheck.function_scoped_fixture])
@given(
    kind=st.sampled_from(["binary", "ascii"]),
    edits=st.lists(st.tuples(st.floats(0, 1, exclude_max=True), st.integers(0, 255)), max_size=4),
    cut=st.one_of(st.none(), st.floats(0, 1)),
)
def test_fuzzed_files_load_or_raise_input_error(tmp_path, valid_files, kind, edits, cut):
    data = bytearray(valid_files[kind])
    for where, value in edits:
        data[int(where * len(data))] = value
    if cut is not None:
        data = data[: int(cut * len(data))]
    path = tmp_path / "f.ply"
    path.write_bytes(bytes(data))
    try:
        g = read_ply(path)
    except InputError as exc:
        assert "\n" not in str(exc)
    else:
        assert isinstance(g, Gaussians)
