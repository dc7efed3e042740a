"""The batched normals are JAX's own, bit for bit, with the keys on the last axis."""

import jax
import jax.numpy as jnp
import numpy as np
import pytest

from jdpim._normals import normals, threefry2x32


def test_threefry_gives_the_known_answers_of_random123():
    """Known-answer vectors of Threefry-2x32 (20 rounds), as published with Random123."""
    cases = (
        ((0x0, 0x0), (0x0, 0x0), (0x6B200159, 0x99BA4EFE)),
        ((0xFFFFFFFF, 0xFFFFFFFF), (0xFFFFFFFF, 0xFFFFFFFF), (0x1CB996FC, 0xBB002BE7)),
        ((0x13198A2E, 0x03707344), (0x243F6A88, 0x85A308D3), (0xC4923A9C, 0x483DF7A0)),
    )
    for key, count, expected in cases:
        words = [jnp.asarray(np.uint32(w)) for w in key + count]
        assert tuple(int(w) for w in threefry2x32(*words)) == expected


def _reference(keys, shape, fold):
    def one(k):
        key = jax.random.wrap_key_data(k)
        return jax.random.normal(key if fold is None else jax.random.fold_in(key, fold), shape, jnp.float32)

    return np.moveaxis(np.asarray(jax.vmap(one)(keys)), 0, -1)


@pytest.mark.parametrize("shape", [(1,), (3,), (32, 2, 1), (2, 2, 7)])
@pytest.mark.parametrize("fold", [None, 0, 5, 2**31 + 3])
def test_normals_equal_jax_random_normal(shape, fold):
    keys = jax.random.key_data(jax.random.split(jax.random.key(11), 257))
    got = np.asarray(jax.jit(lambda k: normals(k, shape, fold))(keys))
    assert got.shape == (*shape, 257) and got.dtype == np.float32
    np.testing.assert_array_equal(got, _reference(keys, shape, fold))


def test_normals_with_a_traced_fold_and_jax_s_other_schemes():
    keys = jax.random.key_data(jax.random.split(jax.random.key(2), 64))
    traced = jax.jit(lambda k, c: normals(k, (4, 2), fold=c))
    for c in (1, 17):
        np.testing.assert_array_equal(np.asarray(traced(keys, c)), _reference(keys, (4, 2), c))
    with jax.threefry_partitionable(False):  # JAX's former scheme: its own values, through the fallback
        np.testing.assert_array_equal(np.asarray(normals(keys, (4, 2), fold=3)), _reference(keys, (4, 2), 3))
