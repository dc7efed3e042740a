"""Path integration's stationary sensitivities against the 5e5-path Monte Carlo estimates in data/ (CPU, float64).

Reference scene (alpha = gamma = D = 0.03, r = 0.98), reflected Gaussian kernel h = 0.1, x in [0, 2.5], v in
[-2.5, 2.5]. Path integration: `jax.jacfwd` through the stationary solve (implicit differentiation), the
grid density smoothed with the same kernel. Monte Carlo (t = 200 from rest, dt = 0.01, float32, H100):
CRN central differences with +-20 % steps (r: 0.97 / 0.99), compared with path integration's own central
difference at the same step (so the step's bias drops out; its size is printed), and the bounded
estimators (likelihood ratio for alpha and gamma, noise scaling for D), compared with the derivative.
Relative L2 distances are normalised by the reference's norm; "2se" is the fraction of grid points within
two standard errors.
"""

import json
import time
from pathlib import Path

import jax

jax.config.update("jax_enable_x64", True)

import jax.numpy as jnp  # noqa: E402
import numpy as np  # noqa: E402
from jdpim._path_integration import default_extents  # noqa: E402

import jdpim  # noqa: E402

DATA = Path(__file__).parent / "data"
NAMES = ("alpha", "gamma", "D", "r")
crn, lr = np.load(DATA / "crn.npz"), np.load(DATA / "lr.npz")
pairs = json.loads((DATA / "crn.json").read_text())
XG, VG, H = crn["xg"], crn["vg"], float(crn["h"])
NOMINAL = dict(alpha=0.03, gamma=0.03, D=0.03, r=0.98)


def scene(p):
    model = jdpim.VibroImpactOscillator(alpha=p["alpha"], gamma=p["gamma"], r=p["r"])
    return jdpim.Scene(model, noise=jdpim.WhiteNoise(D=p["D"]), t_end=200.0, dt=0.01, dtype="float64")


x_max, v_max = default_extents(scene(NOMINAL), jdpim.PathIntegration())
SETTINGS = jdpim.PathIntegration(x_max=1.3 * x_max, v_max=1.3 * v_max)  # room for the shifted parameters


def kernel(y, z):
    return jnp.exp(-0.5 * ((y[:, None] - z[None]) / H) ** 2) / (H * jnp.sqrt(2 * jnp.pi))


def smoothed(values):
    """Kernel-smoothed stationary marginals of x (reflected at 0) and v, concatenated."""
    res = jdpim.path_integration(scene(dict(zip(NAMES, values, strict=True))), SETTINGS, stationary=True)
    mx = res._weights(res.x) * res.nodal_marginal("x")
    mv = res._weights(res.v) * res.nodal_marginal("v")
    return jnp.concatenate([(kernel(XG, res.x) + kernel(XG, -res.x)) @ mx, kernel(VG, res.v) @ mv])


def rel(a, b):
    return np.linalg.norm(a - b) / np.linalg.norm(b)


nominal = jnp.array([NOMINAL[k] for k in NAMES])
start = time.perf_counter()
jac = np.asarray(jax.jacfwd(smoothed)(nominal))
print(f"path integration: jacfwd through the stationary solve, 4 parameters, {time.perf_counter() - start:.0f} s")
cut = len(XG)
for i, name in enumerate(NAMES):
    lo, hi = np.array(nominal), np.array(nominal)
    lo[i], hi[i] = pairs[name]["lo"], pairs[name]["hi"]
    pi_cd = (np.asarray(smoothed(jnp.asarray(hi))) - np.asarray(smoothed(jnp.asarray(lo)))) / (hi[i] - lo[i])
    for var, part in (("x", slice(0, cut)), ("v", slice(cut, None))):
        ad, cd = jac[part, i], pi_cd[part]
        mean, se = crn[f"{name}_{var}"], crn[f"{name}_{var}_se"]
        line = (
            f"{name:5s} {var}: step bias {rel(cd, ad):.3f}; CRN vs PI (same step) {rel(mean, cd):.3f}, "
            f"CRN se {np.linalg.norm(se) / np.linalg.norm(mean):.3f}, 2se {np.mean(np.abs(mean - cd) <= 2 * se):.2f}"
        )
        if f"{name}_{var}" in lr:
            mean, se = lr[f"{name}_{var}"], lr[f"{name}_{var}_se"]
            line += (
                f"; LR/NS vs PI {rel(mean, ad):.3f}, se {np.linalg.norm(se) / np.linalg.norm(mean):.3f}, "
                f"2se {np.mean(np.abs(mean - ad) <= 2 * se):.2f}"
            )
        print(line, flush=True)
