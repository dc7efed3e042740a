"""The band limit's bias on a 2-core CPU: exact r = 1 case (alpha = 0.1, D = 0.01, E[x^2] = 0.1), cutoff 50 rad/s.

Same cutoff at two time steps, then without sticking and with more located impacts per step (float64,
1e5 paths, t = 100 from x0 = 0.3). Output: cutoff_cpu.txt.
"""

import time

import jax

jax.config.update("jax_enable_x64", True)

import numpy as np  # noqa: E402

import jdpim  # noqa: E402

n = 100_000
m = jdpim.VibroImpactOscillator(alpha=0.1, gamma=None, r=1.0)
cases = [
    (0.04, jdpim.ImpactRule()),
    (0.02, jdpim.ImpactRule()),
    (0.04, jdpim.ImpactRule(stick_velocity=0.0)),
    (0.04, jdpim.ImpactRule(max_impacts=4)),
]
for dt, rule in cases:
    sc = jdpim.Scene(
        m,
        noise=jdpim.WhiteNoise(D=0.01),
        x0=0.3,
        t_end=100.0,
        dt=dt,
        save_at=(100.0,),
        dtype="float64",
        excitation=jdpim.SpectralRepresentation(cutoff=50.0),
        impacts=rule,
    )
    t0 = time.perf_counter()
    s = np.asarray(jdpim.monte_carlo(sc, n, seed=3, progress=False).states[:, 0, :])
    x2 = s[:, 0] ** 2
    v2 = s[:, 1] ** 2
    print(
        f"dt {dt} {rule}: E x^2 {x2.mean():.5f} +- {x2.std() / np.sqrt(n):.5f} (exact 0.1), E v^2 {v2.mean():.5f}; "
        f"{time.perf_counter() - t0:.0f}s",
        flush=True,
    )
