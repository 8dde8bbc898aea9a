"""The per-part posing kernel against the obvious gather-and-einsum twin."""

import numpy as np
import pytest

from marionette.reconstruct.posing import per_part


@pytest.mark.parametrize("dim, transpose, dtype", [(3, False, np.float32), (4, True, np.float64),
                                                   (3, True, np.float32)])
def test_per_part_matches_the_gathered_einsum(dim, transpose, dtype):
    rng = np.random.default_rng(dim)
    rows = rng.normal(size=(200, dim)).astype(dtype)
    parts = rng.integers(0, 3, size=200)
    matrices = rng.normal(size=(3, dim, dim))
    shift = rng.normal(size=(3, dim))
    gathered = matrices[parts]  # (N, D, D)
    twin = np.einsum("nji,nj->ni" if transpose else "nij,nj->ni", gathered, rows.astype(np.float64)) + shift[parts]
    out = per_part(rows, parts, matrices, shift, transpose=transpose)
    assert out.dtype == np.float64 and out.shape == rows.shape
    np.testing.assert_allclose(out, twin, rtol=1e-12, atol=1e-12)
    np.testing.assert_allclose(per_part(rows, parts, matrices, transpose=transpose), twin - shift[parts],
                               rtol=1e-12, atol=1e-12)
