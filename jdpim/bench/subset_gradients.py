"""``python -m jdpim.bench.subset_gradients {subset,monte-carlo,reference} ...``: derivatives of small first-passage
probabilities of Au & Beck's oscillator by subset simulation, against Monte Carlo and an exact-in-law reference.

The oscillator: ``x'' + 2 zeta omega x' + omega^2 x = xi``, ``omega = 7.85 rad/s``, ``zeta = 0.02``, ``S = 1``
(``D = pi S``), ``T = 30 s``, ``dt = 0.02 s``, from rest; ``q = |x|``, levels in units of the stationary standard
deviation ``sigma``. ``dP/dzeta = 2 omega dP/dalpha``.

- ``subset``: ``R`` runs of ``SubsetSimulation(n_per_level=N, seed=k)`` with ``wrt=("alpha", "D")``: the mean, the
  spread of the runs against their stated standard errors.
- ``monte-carlo``: ``first_passage(..., MonteCarlo(...), wrt=("alpha", "D"))`` in chunks of independent seeds
  (likelihood ratio for alpha, central differences for D), pooled.
- ``reference``: the discretised problem solved by importance sampling at the design points (Au & Beck 2001): the
  oscillator is linear and starts at rest, so ``x`` after step ``k`` is ``a_k . z`` in the node normals ``z`` (RK4
  is linear in the forcing), and failure is ``max_k |a_k . z| > b``, the event Monte Carlo and subset simulation
  sample. ``P = P_sum E_q[1 / N(z)]`` with ``q`` the mixture of the normal law conditioned on each elementary event
  ``s a_k . z > b`` and ``N(z)`` the number of them ``z`` lies in; its derivatives are central differences with
  common random numbers (relative step ``--step``).
"""

from __future__ import annotations

import argparse
import json

import numpy as np

W, ZETA, S, T_END, DT = 7.85, 0.02, 1.0, 30.0, 0.02
D = np.pi * S
SIGMA = float(np.sqrt(D / (2 * ZETA * W**3)))


def scene(zeta: float = ZETA, dtype: str | None = None, save_at=None):
    import jdpim

    model = jdpim.VibroImpactOscillator(alpha=2 * zeta * W, gamma=None, barrier=None, omega=W)
    return jdpim.Scene(model, noise=jdpim.WhiteNoise(D=D), t_end=T_END, dt=DT, dtype=dtype, save_at=save_at)


def absolute(state):
    return abs(state[0])


def _row(fp, j: int) -> dict:
    out = {"P": (float(fp.probability[0, j]), float(fp.probability_stderr[0, j]))}
    out["dzeta"] = tuple(2 * W * float(a[0, j]) for a in (fp.derivative["alpha"], fp.derivative_stderr["alpha"]))
    out["dD"] = tuple(float(a[0, j]) for a in (fp.derivative["D"], fp.derivative_stderr["D"]))
    return out


def subset(levels, n: int, runs: int, estimator: str) -> dict:
    """Per level and quantity: the mean of ``runs`` runs, its standard error from their spread, the spread (one
    run's actual error) and the root mean square of the stated standard errors."""
    import jdpim

    est = jdpim.CentralDifference() if estimator == "cd" else None
    rows, evaluations = [], 0
    for k in range(runs):
        fp = jdpim.first_passage(
            scene(), absolute, SIGMA * np.asarray(levels), jdpim.SubsetSimulation(n_per_level=n, seed=k),
            wrt=("alpha", "D"), estimator=est,
        )  # fmt: skip
        rows.append([_row(fp, j) for j in range(len(levels))])
        evaluations = fp.n_evaluations
    out = {"n_per_level": n, "runs": runs, "evaluations_per_run": evaluations}
    for j, level in enumerate(levels):
        for key in ("P", "dzeta", "dD"):
            v = np.array([r[j][key][0] for r in rows])
            s = np.array([r[j][key][1] for r in rows])
            spread = float(v.std(ddof=1))
            out[f"{level} {key}"] = {
                "mean": float(v.mean()), "stderr": spread / np.sqrt(runs), "spread": spread,
                "stated": float(np.sqrt(np.mean(s**2))),
            }  # fmt: skip
    return out


def monte_carlo(levels, n: int, chunks: int) -> dict:
    """Monte Carlo in ``chunks`` independent runs of ``n`` paths (seeds 100, 101, ...), pooled."""
    import jdpim

    rows = []
    for k in range(chunks):
        method = jdpim.MonteCarlo(n_samples=n, seed=100 + k)
        fp = jdpim.first_passage(scene(), absolute, SIGMA * np.asarray(levels), method, wrt=("alpha", "D"))
        rows.append([_row(fp, j) for j in range(len(levels))])
    out = {"paths": n * chunks}
    for j, level in enumerate(levels):
        for key in ("P", "dzeta", "dD"):
            v, s = (np.array([r[j][key][i] for r in rows]) for i in (0, 1))
            out[f"{level} {key}"] = {"mean": float(v.mean()), "stderr": float(np.sqrt(np.sum(s**2)) / chunks)}
    return out


def impulse_matrix(zeta: float) -> np.ndarray:
    """``(K, n)``: ``x`` after steps ``1 .. K`` per unit node normal (float64)."""
    import jax
    import jax.numpy as jnp

    import jdpim
    from jdpim.methods._paths import integrate_forcing

    jax.config.update("jax_enable_x64", True)
    n_steps = int(round(T_END / DT))
    sc = scene(zeta, "float64", tuple(DT * k for k in range(1, n_steps + 1)))
    n = 2 * n_steps + 1
    rows = []
    for start in range(0, n, 512):
        idx = np.arange(start, min(n, start + 512))
        z = jnp.zeros((idx.size, n, 1)).at[np.arange(idx.size), idx, 0].set(1.0)
        states = integrate_forcing(sc, jdpim.GaussianNodes().from_normals(sc, z), jnp.zeros((idx.size, 0)))
        rows.append(np.asarray(states[:, :, 0]))
    return np.concatenate(rows).T


def _isd(gram, proj, b, u_k, u_s, u_t):
    """Per-sample estimates ``P_sum / N(z)`` for one batch (``proj = z0 @ a.T``, ``gram = a @ a.T``)."""
    from scipy.special import ndtr, ndtri

    sig = np.sqrt(np.diag(gram))
    pk = ndtr(-b / sig)
    k = np.minimum(np.searchsorted(np.cumsum(pk) / pk.sum(), u_k), len(pk) - 1)
    s = np.where(u_s < 0.5, 1.0, -1.0)
    t = -ndtri(u_t * pk[k])  # the normal conditioned on exceeding b / sig_k along s a_k / sig_k
    along = s * proj[np.arange(len(k)), k] / sig[k]
    x = proj + ((t - along) * s / sig[k])[:, None] * gram[k]
    return 2.0 * pk.sum() / np.sum(np.abs(x) > b, axis=1)


def reference(levels, samples: int, step: float) -> dict:
    """P, dP/dzeta and dP/dD by importance sampling at the design points, in batches of 2000 samples."""
    base = impulse_matrix(ZETA)
    mats = {"base": (base, 1.0), "zeta+": (impulse_matrix(ZETA * (1 + step)), 1.0)}
    mats |= {"zeta-": (impulse_matrix(ZETA * (1 - step)), 1.0), "D+": (base, 1 + step), "D-": (base, 1 - step)}
    grams = {k: c * a @ a.T for k, (a, c) in mats.items()}
    est = {(k, lv): [] for k in mats for lv in levels}
    for batch in range(samples // 2000):
        rng = np.random.default_rng(1000 + batch)
        u = rng.random((3, 2000))
        z0 = rng.standard_normal((2000, base.shape[1]))
        proj = {k: z0 @ a.T for k, (a, _) in mats.items() if k in ("base", "zeta+", "zeta-")}
        proj |= {"D+": np.sqrt(1 + step) * proj["base"], "D-": np.sqrt(1 - step) * proj["base"]}
        for k in mats:
            for lv in levels:
                est[k, lv].append(_isd(grams[k], proj[k], lv * SIGMA, *u))
    out = {"samples": samples // 2000 * 2000, "step": step}
    for lv in levels:
        e = {k: np.concatenate(est[k, lv]) for k in mats}
        out[f"{lv} P"] = {
            "mean": float(e["base"].mean()),
            "stderr": float(e["base"].std(ddof=1) / np.sqrt(e["base"].size)),
        }
        for name, width in (("zeta", 2 * step * ZETA), ("D", 2 * step * D)):
            diff = (e[name + "+"] - e[name + "-"]) / width  # paired: common random numbers
            out[f"{lv} d{name}"] = {"mean": float(diff.mean()), "stderr": float(diff.std(ddof=1) / np.sqrt(diff.size))}
    return out


def main(argv=None) -> int:
    parser = argparse.ArgumentParser(prog="python -m jdpim.bench.subset_gradients", description=__doc__)
    parser.add_argument("part", choices=["subset", "monte-carlo", "reference"])
    parser.add_argument("--levels", type=float, nargs="+", default=[4.5, 5.5], help="levels in units of sigma")
    parser.add_argument("--n", type=int, default=1000, help="subset: samples per level; monte-carlo: paths per chunk")
    parser.add_argument("--runs", type=int, default=20, help="subset: independent runs; monte-carlo: chunks")
    parser.add_argument("--estimator", choices=["default", "cd"], default="default", help="subset: the estimator")
    parser.add_argument("--samples", type=int, default=4000, help="reference: importance samples")
    parser.add_argument("--step", type=float, default=0.02, help="reference: relative half step of the differences")
    args = parser.parse_args(argv)
    if args.part == "subset":
        out = subset(args.levels, args.n, args.runs, args.estimator)
    elif args.part == "monte-carlo":
        out = monte_carlo(args.levels, args.n, args.runs)
    else:
        out = reference(args.levels, args.samples, args.step)
    print(json.dumps(out, indent=1))
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
