"""Standard normals of many keys at once: the values of ``jax.random.normal`` for each key, with the keys last.

Monte Carlo draws its normals from one key per path. ``jax.vmap(jax.random.normal)`` over those keys gives
every path's values, but on a CPU JAX lowers its threefry hash as a loop that XLA does not fuse, with the paths
on the leading axis. :func:`normals` computes the same hash unrolled in ``jnp`` operations with the keys on the
last axis, so that XLA fuses the hash, the uniform and the inverse error function into one pass over
contiguous paths; the values are equal bit for bit (``tests/test_normals.py``). It applies to JAX's default
keys (``threefry2x32`` with ``jax_threefry_partitionable``, the default since JAX 0.5); under other settings,
and off a CPU (where JAX's threefry is a kernel of its own), it calls ``jax.random.normal`` itself.
"""

import math

import jax
import jax.numpy as jnp
import numpy as np

from ._cpu import on_cpu

_ROTATIONS = ((13, 15, 26, 6), (17, 29, 16, 24))
_KEY_PARITY = np.uint32(0x1BD11BDA)
_LOW = np.nextafter(np.float32(-1.0), np.float32(0.0))  # jax.random.normal's uniform lies in (-1, 1)


def threefry2x32(k1, k2, x1, x2):
    """The Threefry-2x32 hash (20 rounds) of the counter words ``(x1, x2)`` under the key ``(k1, k2)``.

    All four are ``uint32`` arrays that broadcast together; returns the two hashed words, as JAX's
    ``threefry2x32`` primitive does.
    """
    ks = (k1, k2, k1 ^ k2 ^ _KEY_PARITY)
    x1, x2 = x1 + ks[0], x2 + ks[1]
    for i in range(5):
        for r in _ROTATIONS[i % 2]:
            x1 = x1 + x2
            x2 = x1 ^ ((x2 << np.uint32(r)) | (x2 >> np.uint32(32 - r)))
        x1 = x1 + ks[(i + 1) % 3]
        x2 = x2 + ks[(i + 2) % 3] + np.uint32(i + 1)
    return x1, x2


def _unrolled() -> bool:
    """Whether :func:`normals` reproduces JAX's own values here (see the module's docstring)."""
    return on_cpu() and jax.config.jax_threefry_partitionable and jax.config.jax_default_prng_impl == "threefry2x32"


def normals(keys, shape: tuple[int, ...], fold: int | jax.Array | None = None) -> jax.Array:
    """Float32 standard normals ``(*shape, n)``: column ``p`` is ``jax.random.normal(key_p, shape)``.

    Args:
        keys: key data of ``n`` threefry keys, ``uint32`` of shape ``(n, 2)``.
        shape: the shape drawn from each key.
        fold: if given, each key is first folded with it (``jax.random.fold_in(key_p, fold)``); a Python or
            traced integer.
    """
    if not _unrolled():

        def one(k):
            key = jax.random.wrap_key_data(k)
            return jax.random.normal(key if fold is None else jax.random.fold_in(key, fold), shape, jnp.float32)

        return jnp.moveaxis(jax.vmap(one)(keys), 0, -1)
    k1, k2 = keys[:, 0], keys[:, 1]
    if fold is not None:
        k1, k2 = threefry2x32(k1, k2, jnp.zeros_like(k1), jnp.full_like(k1, jnp.asarray(fold, jnp.uint32)))
    index = jax.lax.iota(np.uint32, math.prod(shape)).reshape(*shape, 1)
    lead = (1,) * len(shape)
    b1, b2 = threefry2x32(k1.reshape(*lead, -1), k2.reshape(*lead, -1), jnp.zeros_like(index), index)
    mantissa = ((b1 ^ b2) >> np.uint32(9)) | np.uint32(0x3F800000)  # 23 random bits in [1, 2)
    u = jax.lax.bitcast_convert_type(mantissa, jnp.float32) - np.float32(1.0)
    u = jnp.maximum(_LOW, u * (np.float32(1.0) - _LOW) + _LOW)
    return np.float32(math.sqrt(2.0)) * jax.lax.erf_inv(u)
