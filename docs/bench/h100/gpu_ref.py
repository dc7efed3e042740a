"""Large Monte Carlo references on a GPU (H100, float32): `PYTHONPATH=$PWD python3 gpu_ref.py mcs crn lr`.

part "mcs": MCS 1e6 samples, reference scene, D in (0.01, 0.03, 0.08), t = 200 from the default start:
            fine histograms of x and v, a joint histogram, moments, and (D = 0.03) the raw states.
part "crn": CRN central differences (5e5 paths, same seed) at D = 0.03 for alpha, gamma, D, r, from the
            states at theta -+ d: per-path reflected-kernel differences, mean and standard error.
part "lr":  jdpim.sensitivity(method="monte_carlo", n_samples=5e5) auto estimators for alpha, gamma, D.
"""

import json
import os
import sys
import time

import jax
import jax.numpy as jnp
import numpy as np

import jdpim

OUT = os.environ.get("OUT", "/tmp/out")
XG = np.linspace(0.0, 2.5, 51)
VG = np.linspace(-2.5, 2.5, 101)
H = 0.1  # fixed kernel standard deviation for x and v


def scene(D=0.03, **kw):
    p = dict(alpha=0.03, gamma=0.03, r=0.98)
    p.update(kw)
    model = jdpim.VibroImpactOscillator(**p)
    return jdpim.Scene(model, noise=jdpim.WhiteNoise(D=D), t_end=200.0, dt=0.01, save_at=(200.0,))


def states(sc, n, seed):
    t0 = time.perf_counter()
    res = jdpim.monte_carlo(sc, n_samples=n, seed=seed, progress=False)
    s = np.asarray(res.states[:, 0, :])
    return s, time.perf_counter() - t0, int(np.asarray(res.n_nonfinite())[0])


def mcs():
    info = {}
    for D in (0.01, 0.03, 0.08):
        s, dt, bad = states(scene(D), 1_000_000, 1)
        x, v = s[:, 0], s[:, 1]
        ok = np.isfinite(x) & np.isfinite(v)
        x, v = x[ok], v[ok]
        out = dict(
            hx=np.histogram(x, np.linspace(0, 4, 401))[0],
            hv=np.histogram(v, np.linspace(-4, 4, 801))[0],
            hxv=np.histogram2d(x, v, [np.linspace(0, 4, 81), np.linspace(-4, 4, 161)])[0],
            n=len(x),
        )
        if D == 0.03:
            out["x"], out["v"] = x.astype(np.float32), v.astype(np.float32)
        np.savez_compressed(f"{OUT}/mcs_D{D}.npz", **out)
        x2, v2 = x.astype(np.float64) ** 2, v.astype(np.float64) ** 2
        info[D] = dict(
            seconds=dt,
            nonfinite=bad,
            Ex2=x2.mean(),
            Ex2_se=x2.std() / np.sqrt(len(x)),
            Ev2=v2.mean(),
            Ev2_se=v2.std() / np.sqrt(len(x)),
            below=int(np.sum(x < 0)),
        )
        print(D, info[D], flush=True)
    json.dump(info, open(f"{OUT}/mcs.json", "w"), indent=1)


def kern(y, z, reflect):
    k = jnp.exp(-0.5 * ((y[None] - z[:, None]) / H) ** 2)
    if reflect:
        k = k + jnp.exp(-0.5 * ((y[None] + z[:, None]) / H) ** 2)
    return k / (H * jnp.sqrt(2 * jnp.pi))


@jax.jit
def diff_stats(a, b, scale):
    """Mean and standard error of per-path kernel differences (b - a) * scale, for x and v grids."""
    out = []
    for col, g, refl in ((0, XG, True), (1, VG, False)):

        def body(carry, ab, col=col, g=g, refl=refl):
            d = (kern(jnp.asarray(g), ab[1][:, col], refl) - kern(jnp.asarray(g), ab[0][:, col], refl)) * scale
            ok = jnp.all(jnp.isfinite(ab[0]), 1) & jnp.all(jnp.isfinite(ab[1]), 1)
            d = jnp.where(ok[:, None], d, 0.0)
            return (carry[0] + d.sum(0), carry[1] + (d**2).sum(0), carry[2] + ok.sum()), None

        n = a.shape[0] // 10_000
        ab = (a.reshape(n, 10_000, 2), b.reshape(n, 10_000, 2))
        (s1, s2, m), _ = jax.lax.scan(body, (jnp.zeros(len(g)), jnp.zeros(len(g)), 0), ab)
        mean = s1 / m
        out += [mean, jnp.sqrt((s2 / m - mean**2) / m)]
    return out


def crn():
    n, seed, rel = 500_000, 2, 0.2
    nominal = dict(alpha=0.03, gamma=0.03, D=0.03, r=0.98)
    res, info = {}, {}
    for name in ("alpha", "gamma", "D", "r"):
        d = 0.01 if name == "r" else rel * nominal[name]
        lo, hi = nominal[name] - d, nominal[name] + d
        if name == "r":
            lo, hi = 0.97, 0.99
        sa, ta, _ = states(scene(**{**nominal, name: lo}), n, seed)
        sb, tb, _ = states(scene(**{**nominal, name: hi}), n, seed)
        mx, sx, mv, sv = diff_stats(jnp.asarray(sa), jnp.asarray(sb), 1.0 / (hi - lo))
        res.update({f"{name}_x": mx, f"{name}_x_se": sx, f"{name}_v": mv, f"{name}_v_se": sv})
        info[name] = dict(lo=lo, hi=hi, seconds=ta + tb)
        rel_se = float(jnp.linalg.norm(sx) / jnp.linalg.norm(mx))
        print(name, info[name], "rel se x", rel_se, flush=True)
    np.savez(f"{OUT}/crn.npz", xg=XG, vg=VG, h=H, n=n, **{k: np.asarray(v) for k, v in res.items()})
    json.dump(info, open(f"{OUT}/crn.json", "w"), indent=1)


def lr():
    out = {}
    for var, g in (("x", XG), ("v", VG)):
        t0 = time.perf_counter()
        s = jdpim.sensitivity(
            scene(), ("alpha", "gamma", "D"), var, g, method="monte_carlo", n_samples=500_000, seed=3, bandwidth=H
        )
        names = {k: type(e).__name__ for k, e in s.estimators.items()}
        print(var, "seconds", time.perf_counter() - t0, names, flush=True)
        for k in s:
            out[f"{k}_{var}"] = np.asarray(s.value[k])
            out[f"{k}_{var}_se"] = np.asarray(s.value_stderr[k])
    np.savez(f"{OUT}/lr.npz", xg=XG, vg=VG, h=H, **out)


if __name__ == "__main__":
    print(jax.devices(), jax.__version__, flush=True)
    for part in sys.argv[1:]:
        {"mcs": mcs, "crn": crn, "lr": lr}[part]()
