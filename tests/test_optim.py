"""Adam against the textbook update (Kingma & Ba 2015, Algorithm 1), written out here."""

import numpy as np

from marionette.optim import Adam


def test_adam_matches_the_textbook_update_to_the_bit_and_reindexes_its_state():
    rng = np.random.default_rng(0)
    # "c" is a transposed view: updated in place like the others, though not contiguous
    params = {"a": rng.normal(size=(50, 3)).astype(np.float32), "b": rng.normal(size=(50,)),
              "c": rng.normal(size=(4, 50)).astype(np.float32).T}
    twin = {k: v.copy() for k, v in params.items()}
    adam = Adam(params)
    m = {k: np.zeros(v.shape) for k, v in twin.items()}
    v = {k: np.zeros(v.shape) for k, v in twin.items()}
    lrs = {"a": 0.01, "b": 0.2, "c": 0.05}
    c_array = params["c"]
    for step in range(1, 8):
        grads = {k: rng.normal(size=p.shape) for k, p in params.items()}
        adam.update(params, grads, lrs)
        c1, c2 = 1 - 0.9 ** step, 1 - 0.999 ** step
        for k in twin:
            m[k] = 0.9 * m[k] + (1 - 0.9) * grads[k]
            v[k] = 0.999 * v[k] + (1 - 0.999) * grads[k] * grads[k]
            twin[k] -= (lrs[k] * (m[k] / c1) / (np.sqrt(v[k] / c2) + 1e-15)).astype(twin[k].dtype)
        for k in params:
            np.testing.assert_array_equal(params[k], twin[k])
        assert params["c"] is c_array
    keep = np.array([4, 0, 7])
    adam.reindex(keep, 2)
    np.testing.assert_array_equal(adam.m["a"][:3], m["a"][keep])
    np.testing.assert_array_equal(adam.v["b"][:3], v["b"][keep])
    assert not adam.m["a"][3:].any() and adam.v["b"].shape == (5,)
