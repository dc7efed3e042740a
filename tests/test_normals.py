"""The keyed normals: Threefry-2x32 itself, two standard normals per hash, and the nodes drawn from them."""

import functools

import jax
import jax.numpy as jnp
import numpy as np

from jdpim._excitation import NodeSource
from jdpim._normals import normal_pair, threefry2x32


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


def _keys(n, seed=11):
    return jax.random.key_data(jax.random.split(jax.random.key(seed), n))


def test_pairs_are_independent_standard_normals():
    """2^17 pairs (512 keys x 256 counters): mean, variance, tail mass and the correlations of the two parts, of
    neighbouring counters and of neighbouring keys, each within 4 standard errors of a standard normal's."""
    keys = _keys(512)
    counter = jnp.arange(256, dtype=jnp.uint32)[None, :]
    z = np.asarray(jax.jit(normal_pair)(keys[:, :1], keys[:, 1:], counter, jnp.uint32(3)))
    assert z.shape == (512, 256) and z.dtype == np.complex64
    for x in (z.real, z.imag):
        n = x.size
        assert abs(x.mean()) < 4 / np.sqrt(n)
        assert abs(x.var() - 1.0) < 4 * np.sqrt(2.0 / n)
        tail = np.mean(np.abs(x) > 2.0)  # 0.0455 for a standard normal
        assert abs(tail - 0.0455) < 4 * np.sqrt(0.0455 * 0.9545 / n)
    for a, b in ((z.real, z.imag), (z.real[:, 1:], z.real[:, :-1]), (z.imag[1:], z.imag[:-1])):
        assert abs(np.mean(a * b)) < 4 / np.sqrt(a.size)


def test_a_pair_depends_on_its_key_and_counter_alone():
    """The same (key, counter) gives the same pair in any batch, order or program; another counter another pair."""
    keys = _keys(64)
    grid = jax.jit(normal_pair)(keys[:, :1], keys[:, 1:], jnp.arange(8, dtype=jnp.uint32)[None, :], jnp.uint32(0))
    pick = np.array([5, 63, 0, 5])
    one = jax.jit(normal_pair)(keys[pick, 0], keys[pick, 1], jnp.asarray([7, 2, 0, 7], jnp.uint32), jnp.uint32(0))
    np.testing.assert_array_equal(np.asarray(one), np.asarray(grid)[pick, [7, 2, 0, 7]])
    assert len(np.unique(np.asarray(grid))) == grid.size


def test_nodes_are_the_documented_words_and_the_same_in_any_chunk():
    """Node 0 of source i is the first word of counter (0, i); step k's middle and end nodes the two words of
    (k + 1, i), times the scale; a chunk of the paths draws their values."""
    keys, scale = _keys(10), jnp.asarray([[2.0, 0.0], [0.5, 1.0]], jnp.float32)
    nodes = NodeSource(keys, scale, jnp.float32)

    @functools.partial(jax.jit, static_argnums=1)
    def nodes_of_step(nodes, k):
        carry = nodes.start()
        for j in range(k + 1):
            e, carry = nodes.step(jnp.asarray(j), carry)
        return jnp.stack(e)

    def expected(counter, part):
        z = jax.jit(normal_pair)(
            keys[:, :1], keys[:, 1:], jnp.uint32(counter), jnp.arange(2, dtype=jnp.uint32)[None, :]
        )
        return np.asarray(getattr(z, part)) @ np.asarray(scale).T

    e = np.asarray(nodes_of_step(nodes, 3))
    np.testing.assert_allclose(e[0], expected(3, "imag"), rtol=1e-6)  # the end of step 2 is the start of step 3
    np.testing.assert_allclose(e[1], expected(4, "real"), rtol=1e-6)
    np.testing.assert_allclose(e[2], expected(4, "imag"), rtol=1e-6)
    np.testing.assert_allclose(np.asarray(nodes.start()[0]), expected(0, "real"), rtol=1e-6)
    chunk = np.asarray(nodes_of_step(NodeSource(keys[4:7], scale, jnp.float32), 3))
    np.testing.assert_array_equal(chunk, e[:, 4:7])
