"""Frozen dataclasses registered as JAX pytrees, and input validation helpers.

Fields marked ``static_field()`` are pytree structure (they decide shapes or Python control flow and
are hashed into the jit cache); every other field is a traced leaf that can be vmapped and
differentiated. Validation runs in ``__post_init__`` on concrete values only, so that JAX can rebuild
the classes with tracers or placeholders during transformations.
"""

from __future__ import annotations

import dataclasses
import numbers
from typing import Any

import jax
import jax.numpy as jnp
import numpy as np


def static_field(**kwargs: Any) -> Any:
    """A dataclass field that is pytree structure (hashable, static under jit)."""
    return dataclasses.field(metadata={"static": True}, **kwargs)


def pytree_dataclass(cls: type) -> type:
    """Make ``cls`` a frozen dataclass and register it as a pytree (static fields via metadata)."""
    cls = dataclasses.dataclass(frozen=True)(cls)
    fields = dataclasses.fields(cls)
    meta = [f.name for f in fields if f.metadata.get("static", False)]
    data = [f.name for f in fields if not f.metadata.get("static", False)]
    return jax.tree_util.register_dataclass(cls, data_fields=data, meta_fields=meta)


def concrete(value: Any) -> np.ndarray | None:
    """``value`` as a NumPy array if it is a concrete number or array, else ``None`` (tracers, placeholders)."""
    if value is None or isinstance(value, jax.core.Tracer):
        return None
    if isinstance(value, (numbers.Number, np.ndarray, np.generic, jax.Array, list, tuple)):
        try:
            arr = np.asarray(value)
        except Exception:  # noqa: BLE001 - anything unconvertible is simply not validated here
            return None
        return arr if arr.dtype != object else None
    return None


def array_leaf(name: str, value: Any) -> Any:
    """A nested list or tuple of numbers as one array (one pytree leaf, not a leaf per entry); else ``value``.

    Raises a ``TypeError`` naming ``name`` for text, a ``ValueError`` for ragged rows.
    """
    if not isinstance(value, (list, tuple)):
        return value
    leaves = jax.tree_util.tree_leaves(value)
    if any(isinstance(x, (str, bytes)) for x in leaves):
        raise TypeError(f"{name} must be numbers, got {value!r}")
    try:
        if any(isinstance(x, jax.core.Tracer) for x in leaves):
            return jnp.asarray(value)
        return np.asarray(value, dtype=float)
    except (TypeError, ValueError):
        raise ValueError(f"{name} must be a rectangular array of numbers, got {value!r}") from None


def plain(value: Any) -> Any:
    """``value`` for an error message: NumPy and JAX arrays as plain numbers or lists (no ``array(...)``)."""
    arr = concrete(value)
    if arr is None or isinstance(value, (numbers.Number, list, tuple)) and not isinstance(value, np.generic):
        return value
    return arr.tolist()


def check_real(
    name: str,
    value: Any,
    *,
    low: float | None = None,
    high: float | None = None,
    low_open: bool = False,
    high_open: bool = False,
    scalar: bool = False,
) -> None:
    """Raise ``ValueError`` unless every element of ``value`` is finite and inside the stated range.

    Text raises ``TypeError``; ``scalar=True`` also rejects arrays of more than one number. Tracers and
    placeholders pass unchecked (they are validated when the caller builds the object with concrete values).
    """
    if isinstance(value, (str, bytes)):
        raise TypeError(f"{name} must be a real number, got {value!r}")
    arr = concrete(value)
    if arr is None:
        return
    if scalar and arr.ndim != 0:
        raise ValueError(f"{name} must be a scalar (one number), got shape {list(arr.shape)}: {plain(value)!r}")
    if not np.issubdtype(arr.dtype, np.number) or np.iscomplexobj(arr):
        raise TypeError(f"{name} must be real-valued, got {plain(value)!r}")
    if not np.all(np.isfinite(arr)):
        raise ValueError(f"{name} must be finite, got {plain(value)!r}")
    lo_txt = "-inf" if low is None else f"{low:g}"
    hi_txt = "inf" if high is None else f"{high:g}"
    rng = f"{'(' if low_open or low is None else '['}{lo_txt}, {hi_txt}{')' if high_open or high is None else ']'}"
    bad_low = low is not None and (np.any(arr <= low) if low_open else np.any(arr < low))
    bad_high = high is not None and (np.any(arr >= high) if high_open else np.any(arr > high))
    if bad_low or bad_high:
        raise ValueError(f"{name} must lie in {rng}, got {plain(value)!r}")


def check_number(name: str, value: Any, **bounds) -> float:
    """``value`` as a float, after :func:`check_real` with ``bounds`` (one number, in range): for a setting that
    is not traced (it sets a matrix or a grid)."""
    if not isinstance(value, (int, float, np.integer, np.floating)) or isinstance(value, bool):
        raise TypeError(f"{name} must be a number, got {value!r}")
    check_real(name, value, scalar=True, **bounds)
    return float(value)


def check_int(name: str, value: Any, *, low: int) -> int:
    """Return ``value`` as ``int`` after checking it is an integer ``>= low``."""
    if isinstance(value, bool) or not isinstance(value, (numbers.Integral, np.integer)):
        raise TypeError(f"{name} must be an integer, got {value!r}")
    if value < low:
        raise ValueError(f"{name} must be an integer >= {low}, got {value!r}")
    return int(value)


def real_array(name: str, value: Any, expected: str) -> np.ndarray:
    """``value`` as a concrete float array; text (also inside a sequence), booleans, other non-numbers and traced
    values are a ``TypeError``: ``{name} must be {expected}, got {value!r}``."""
    arr = None if isinstance(value, (str, bytes)) else concrete(value)
    if arr is None or arr.dtype == bool or not np.issubdtype(arr.dtype, np.number):
        raise TypeError(f"{name} must be {expected}, got {value!r}")
    return arr.astype(float)


def _numeric(name: str, value: Any) -> np.ndarray | None:
    """``value`` as a concrete array (``None`` if traced); text and other non-numbers are a ``TypeError``."""
    if isinstance(value, (str, bytes)):
        raise TypeError(f"{name} must be numbers (a scalar or a 1-D array), got {value!r}")
    arr = concrete(value)
    if arr is not None and not (np.issubdtype(arr.dtype, np.number) or arr.dtype == bool):
        raise TypeError(f"{name} must be numbers (a scalar or a 1-D array), got {plain(value)!r}")
    return arr


def check_grid(name: str, grid: Any) -> np.ndarray | None:
    """Check a 1-D evaluation grid: non-empty, finite and strictly increasing. Returns it if concrete."""
    arr = _numeric(name, grid)
    if arr is None:
        return None
    if arr.ndim != 1 or arr.size < 2:
        raise ValueError(f"{name} must be a 1-D array with at least 2 points, got shape {arr.shape}")
    if not np.all(np.isfinite(arr)):
        raise ValueError(f"{name} must be finite")
    if not np.all(np.diff(arr) > 0):
        raise ValueError(f"{name} must be strictly increasing")
    return arr


def check_points(name: str, points: Any) -> np.ndarray | None:
    """Check evaluation points: a scalar or a non-empty 1-D array, finite and strictly increasing.

    Returns them as an array if concrete. Unlike :func:`check_grid`, one point (or a scalar) is allowed,
    so that a density can be evaluated, and differentiated, at a single value.
    """
    arr = _numeric(name, points)
    if arr is None:
        return None
    if arr.ndim > 1 or arr.size < 1:
        raise ValueError(f"{name} must be a scalar or a non-empty 1-D array, got shape {list(arr.shape)}")
    if not np.all(np.isfinite(arr)):
        raise ValueError(f"{name} must be finite")
    if arr.ndim == 1 and not np.all(np.diff(arr) > 0):
        raise ValueError(f"{name} must be strictly increasing")
    return arr
