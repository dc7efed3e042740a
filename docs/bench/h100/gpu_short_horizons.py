# ruff: noqa: E501, B023  (the script as it ran on the H100; only its usage lines were edited)
"""Issue 8, item c/d: path-integration sensitivities of the reference scene against Monte Carlo with common
random numbers (CRN central differences) and the bounded estimators (likelihood ratio / noise scaling).

Usage: [DT=0.02] PYTHONPATH=$PWD python3 gpu_short_horizons.py N T [T ...]
Ran as: DT=0.005 python3 gpu_short_horizons.py 2000000 5 20 (H100: 142 s in all; log in data/short_horizons.log)
Monte Carlo's time step matters at short horizons from rest on the barrier: at t = 5 its density differs from
path integration's (the dt -> 0 limit) by 0.85 % / 0.47 % / 0.23 % (relative L2) at dt = 0.02 / 0.01 / 0.005,
and dp/dalpha by 3.1 % / 2.4 % / 1.3 %: use dt <= 0.005 for t = 5 and 20. Arrays go to $OUT (or /tmp).
Prints one table row per (t, parameter). Columns (relative L2 over x in [0, 2.5], normalised by ||PI||):
  pi_ad_vs_pi_cd : path-integration AD against PI's own central difference with the same step (step bias)
  cd_se          : standard error of the MC central difference (CRN, same seed at both ends)
  pi_cd_vs_mc_cd : PI central difference against MC central difference (same step: no step bias)
  z2_cd          : fraction of grid points where |PI_cd - MC_cd| < 2 se
  pi_vs_mc_cd    : PI AD against MC central difference (the acceptance number)
  auto_se, pi_vs_auto, z2_auto : the same against the bounded estimator (LR for alpha/gamma, noise scaling for D)
"""

import os
import sys
import time
import warnings

import numpy as np

import jdpim
from jdpim.sensitivities._path_integration import grid_density

N = int(sys.argv[1])
TIMES = [float(a) for a in sys.argv[2:]] or [5.0, 20.0]
DT, H = float(os.environ.get("DT", "0.02")), 0.1
OUT = os.environ.get("OUT", "/tmp")
XS = np.linspace(0.0, 2.5, 51)
STEPS = {"alpha": 0.009, "gamma": 0.009, "D": 0.009, "r": 0.01}
NAMES = tuple(STEPS)
print("load", os.getloadavg(), "N", N, "dt", DT, "h", H, flush=True)
print(
    "| t | parameter | pi_ad_vs_pi_cd | cd_se | pi_cd_vs_mc_cd | z2_cd | pi_vs_mc_cd | auto | auto_se | pi_vs_auto | z2_auto |"
)
print("|---|---|---|---|---|---|---|---|---|---|---|")
for t in TIMES:
    scene = jdpim.Scene(
        jdpim.VibroImpactOscillator(alpha=0.03, gamma=0.03, r=0.98), noise=jdpim.WhiteNoise(D=0.03), t_end=t, dt=DT
    )
    t0 = time.perf_counter()
    pi = jdpim.sensitivity(scene, NAMES, "x", XS, bandwidth=H)
    settings = pi.estimators["alpha"]
    pi_cd = {}
    for name, step in STEPS.items():
        lo, hi = jdpim.CentralDifference(step).pair(
            name, float(getattr(scene.model, name, 0.03) if name != "D" else 0.03)
        )
        ends = []
        for val in (lo, hi):
            s = jdpim.with_parameters(scene, {name: val}).replace(save_at=(t,))
            ends.append(np.asarray(grid_density(jdpim.path_integration(s, settings), "x", XS, t, H, s.model.barrier)))
        pi_cd[name] = (ends[1] - ends[0]) / (hi - lo)
    t_pi = time.perf_counter() - t0
    t0 = time.perf_counter()
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        est = {n: jdpim.CentralDifference(s) for n, s in STEPS.items()}
        cd = jdpim.sensitivity(
            scene, NAMES, "x", XS, method="monte_carlo", n_samples=N, seed=1, bandwidth=H, estimator=est
        )
        auto = jdpim.sensitivity(scene, NAMES[:3], "x", XS, method="monte_carlo", n_samples=N, seed=2, bandwidth=H)
        p_mc = np.asarray(jdpim.monte_carlo(scene, N, seed=1).pdf("x", XS, t, bandwidth=H))
    t_mc = time.perf_counter() - t0
    p_pi = np.asarray(grid_density(jdpim.path_integration(scene.replace(save_at=(t,)), settings), "x", XS, t, H, 0.0))
    print(f"t = {t:g}: density p(x) MC vs PI relative L2 {np.linalg.norm(p_mc - p_pi) / np.linalg.norm(p_pi):.4f}")
    arrays = {"p_mc": p_mc, "p_pi": p_pi}
    for n in NAMES:
        arrays |= {f"pi_{n}": np.asarray(pi[n]), f"picd_{n}": pi_cd[n], f"cd_{n}": np.asarray(cd[n])}
        arrays |= {f"cdse_{n}": np.asarray(cd.value_stderr[n])}
        if n in auto:
            arrays |= {f"auto_{n}": np.asarray(auto[n]), f"autose_{n}": np.asarray(auto.value_stderr[n])}
    np.savez(os.path.join(OUT, f"gpu8_t{t:g}_n{N}_dt{DT:g}.npz"), xs=XS, **arrays)
    for n in NAMES:
        p = np.asarray(pi[n])
        nr = np.linalg.norm(p)
        c, cs = np.asarray(cd[n]), np.asarray(cd.value_stderr[n])
        rel = lambda a, b: np.linalg.norm(a - b) / nr  # noqa: E731
        row = [
            f"{t:g}",
            n,
            f"{rel(p, pi_cd[n]):.4f}",
            f"{np.linalg.norm(cs) / nr:.3f}",
            f"{rel(pi_cd[n], c):.3f}",
            f"{np.mean(np.abs(pi_cd[n] - c) < 2 * cs):.2f}",
            f"{rel(p, c):.3f}",
        ]
        if n in auto:
            a, s_ = np.asarray(auto[n]), np.asarray(auto.value_stderr[n])
            row += [
                type(auto.estimators[n]).__name__,
                f"{np.linalg.norm(s_) / nr:.3f}",
                f"{rel(p, a):.3f}",
                f"{np.mean(np.abs(p - a) < 2 * s_):.2f}",
            ]
        else:
            row += ["-", "-", "-", "-"]
        print("| " + " | ".join(row) + " |", flush=True)
    print(
        f"t = {t:g}: path integration {t_pi:.1f} s (AD + CD), Monte Carlo {t_mc:.1f} s, load {os.getloadavg()}",
        flush=True,
    )
