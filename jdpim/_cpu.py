"""Every CPU core as a JAX device, so that the path axis is split over the cores.

XLA's thread pool spreads only part of one compiled program's work over the cores of a CPU, so a single CPU device
leaves the other cores mostly idle or spinning (docs/speed.md measures it). Presented as several devices, the
CPU runs one shard of paths per core at once (``dpim`` and ``monte_carlo`` shard over every local device).
"""

from __future__ import annotations

import os
import re

import jax

from ._pytree import check_int

DEVICE_COUNT_FLAG = re.compile(r"--xla_force_host_platform_device_count=(\d+)")


def on_cpu() -> bool:
    """Whether JAX computes on a CPU (its default backend): no accelerator, so a branch's predicate is read from
    the same memory and chunks are sized for the CPU's caches."""
    return jax.default_backend() == "cpu"


def usable_cores() -> int:
    """The number of CPU cores this process may run on (its affinity mask where the OS reports one)."""
    if hasattr(os, "sched_getaffinity"):
        return len(os.sched_getaffinity(0))
    return os.cpu_count() or 1


def use_cpu_cores(n: int | None = None) -> int:
    """Present the CPU as ``n`` JAX devices (default: one per usable core); returns the device count.

    Call it right after ``import jdpim``, before any JAX computation: JAX fixes its devices when its first
    computation runs. A device count already chosen through ``XLA_FLAGS``
    (``--xla_force_host_platform_device_count``) or ``JAX_NUM_CPU_DEVICES`` is kept when ``n`` is
    ``None``. States do not depend on the number of devices beyond rounding (``docs/speed.md``).

    Args:
        n: number of CPU devices (>= 1), or ``None`` for :func:`usable_cores`.

    Raises:
        RuntimeError: JAX has already run a computation with another number of CPU devices.

    Examples:
        >>> import jdpim
        >>> n = jdpim.use_cpu_cores()  # doctest: +SKIP
    """
    if n is not None:
        n = check_int("n", n, low=1)
    elif (flag := DEVICE_COUNT_FLAG.search(os.environ.get("XLA_FLAGS", ""))) is not None:
        return int(flag.group(1))
    elif os.environ.get("JAX_NUM_CPU_DEVICES"):
        n = check_int("JAX_NUM_CPU_DEVICES", int(os.environ["JAX_NUM_CPU_DEVICES"]), low=1)
    else:
        n = usable_cores()
    try:
        jax.config.update("jax_num_cpu_devices", n)
    except RuntimeError:  # the backend is up: nothing to change if it already has n CPU devices
        current = len(jax.devices("cpu"))
        if current != n:
            raise RuntimeError(
                f"use_cpu_cores(n={n}): JAX already runs on {current} CPU device(s); call it right after "
                "`import jdpim`, before any JAX computation (or restart the kernel)"
            ) from None
    return n


def start_devices(n: int | None = None) -> str:
    """The command line's device setup: :func:`use_cpu_cores` where JAX has not started; says what is used.

    With ``n=None`` a JAX already started (the command line called from Python) is left as it is.

    Raises:
        ValueError: ``n`` is given and JAX already runs on another number of CPU devices.
    """
    try:
        use_cpu_cores(n)
    except RuntimeError as err:
        if n is not None:
            raise ValueError(str(err)) from None
    devices = jax.local_devices()
    return f"{len(devices)} {devices[0].platform.upper()} device(s)"


def host_memory() -> int:
    """Bytes of physical memory of this host (``8 GiB`` where the OS does not say)."""
    try:
        return os.sysconf("SC_PAGE_SIZE") * os.sysconf("SC_PHYS_PAGES")
    except (AttributeError, ValueError, OSError):
        return 8 * 2**30
