"""Standard normals keyed by a path's key and a counter: two normals per Threefry-2x32 hash.

Monte Carlo draws the forcing of every path and step inside the integration. :func:`normal_pair` hashes the
counter words ``(x1, x2)`` under the path's key with Threefry-2x32 (20 rounds, written in ``jnp`` operations
so that XLA fuses the hash and the conversion into one pass over contiguous paths, on every platform) and
turns each of the two 32-bit words into one float32 normal through the inverse error function. The normals
depend on the key and the counter alone, never on the chunks, devices or processes that compute them.

The pair comes back as one ``complex64``: XLA computes an elementwise fusion element by element, so two
``float32`` outputs would each repeat the hash, while the real and imaginary parts of one element share it.
"""

import math

import jax
import jax.numpy as jnp
import numpy as np

_ROTATIONS = ((13, 15, 26, 6), (17, 29, 16, 24))
_KEY_PARITY = np.uint32(0x1BD11BDA)
_LOW = np.nextafter(np.float32(-1.0), np.float32(0.0))  # the uniform lies in (-1, 1)


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


def _normal(bits):
    """A float32 standard normal from the 23 high bits of ``bits`` (``uint32``): ``sqrt2 erf_inv(u)`` for ``u`` on
    a grid of step ``2^-22`` in ``(-1, 1)``, as ``jax.random.normal`` maps its bits (values in ``[-5.42, 5.22]``)."""
    mantissa = (bits >> np.uint32(9)) | np.uint32(0x3F800000)  # 23 random bits in [1, 2)
    u = jax.lax.bitcast_convert_type(mantissa, jnp.float32) - np.float32(1.0)
    u = jnp.maximum(_LOW, u * (np.float32(1.0) - _LOW) + _LOW)
    return np.float32(math.sqrt(2.0)) * jax.lax.erf_inv(u)


def normal_pair(k1, k2, x1, x2) -> jax.Array:
    """Two independent float32 standard normals per element, as the real and imaginary parts of a ``complex64``.

    Args:
        k1, k2: the key words, ``uint32`` arrays.
        x1, x2: the counter words, ``uint32`` arrays; all four broadcast together.

    Returns:
        ``complex64`` of the broadcast shape: the normals of the two words of ``threefry2x32(k1, k2, x1, x2)``.
    """
    b1, b2 = threefry2x32(k1, k2, x1, x2)
    return jax.lax.complex(_normal(b1), _normal(b2))
