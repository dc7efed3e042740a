"""Path integration against the 1e6-sample Monte Carlo histograms in data/ (run on any CPU, float64).

Prints, per case: chi^2 per degree of freedom of the bin probabilities (bins of 0.05 holding more than 20
expected samples), the largest |z|, the L1 distance of the bin probabilities and the L1 expected from
Monte Carlo noise alone, and E[x^2], E[v^2] with their standard errors.
"""

import json
from pathlib import Path

import jax

jax.config.update("jax_enable_x64", True)

import numpy as np  # noqa: E402
from scipy.stats import norm  # noqa: E402

import jdpim  # noqa: E402

DATA = Path(__file__).parent / "data"


def stats(counts, p, n):
    keep = p * n > 20
    se = np.sqrt(p * (1 - p) / n)
    z = (counts / n - p)[keep] / se[keep]
    return (
        f"chi2/dof {np.sum(z**2) / keep.sum():.2f} (dof {keep.sum()}), max|z| {np.abs(z).max():.1f}, "
        f"L1 {np.abs(counts / n - p).sum():.4f} (noise {(np.sqrt(2 / np.pi) * se).sum():.4f})"
    )


def bin_mass(res, var, edges, t=None):
    sub = 20
    y = (edges[:-1, None] + (np.arange(sub) + 0.5)[None] / sub * np.diff(edges)[:, None]).ravel()
    return np.asarray(res.pdf(var, y, t=t)).reshape(-1, sub).mean(1) * np.diff(edges)


def histograms(tag):
    m = np.load(DATA / f"{tag}.npz")
    return m["hx"].reshape(-1, 5).sum(1), m["hv"].reshape(-1, 5).sum(1), int(m["n"])


EX, EV = np.linspace(0, 4, 81), np.linspace(-4, 4, 161)

print("## Reference scene (alpha = gamma = 0.03, r = 0.98), t = 200 from rest; MCS 1e6 float32, dt = 0.01")
mcs = json.loads((DATA / "mcs.json").read_text())
for D in (0.01, 0.03, 0.08):
    scene = jdpim.Scene(
        jdpim.VibroImpactOscillator(alpha=0.03, gamma=0.03, r=0.98),
        noise=jdpim.WhiteNoise(D=D),
        t_end=200.0,
        dt=0.01,
        save_at=(200.0,),
        dtype="float64",
    )
    st = jdpim.path_integration(scene, stationary=True)
    tr = jdpim.path_integration(scene)
    hx, hv, n = histograms(f"mcs_D{D}")
    m = mcs[str(D)]
    print(
        f"D = {D}: E[x^2] PI stationary {float(st.moment('x', 2)):.5f}, "
        f"PI t = 200 {float(tr.moment('x', 2, t=200.0)):.5f}, MCS {m['Ex2']:.5f} +- {m['Ex2_se']:.5f}; "
        f"E[v^2] PI {float(st.moment('v', 2)):.5f}, MCS {m['Ev2']:.5f} +- {m['Ev2_se']:.5f}"
    )
    print(f"   x: {stats(hx, bin_mass(tr, 'x', EX, 200.0), n)}")
    print(f"   v: {stats(hv, bin_mass(tr, 'v', EV, 200.0), n)}")

print("\n## The Monte Carlo time step: exact r = 1 case (alpha = 0.05, gamma = 0, D = 0.01, E[x^2] = 0.2), t = 200")
cut = {c["tag"]: c for c in json.loads((DATA / "cut.json").read_text())}
s = np.sqrt(0.2)
px = 2 * np.diff(norm.cdf(EX, scale=s))
pv = np.diff(norm.cdf(EV, scale=s))
for tag in ("lin100", "lin200", "lin400"):
    c = cut[tag]
    hx, hv, n = histograms(tag)
    print(
        f"dt = {c['dt']}, cutoff = {c['cutoff']:g}: E[x^2] {c['Ex2']:.5f} +- {c['Ex2_se']:.5f}, "
        f"E[v^2] {c['Ev2']:.5f} +- {c['Ev2_se']:.5f}\n   x: {stats(hx, px, n)}\n   v: {stats(hv, pv, n)}"
    )
scene = jdpim.Scene(
    jdpim.VibroImpactOscillator(alpha=0.03, gamma=0.03, r=0.98),
    noise=jdpim.WhiteNoise(D=0.01),
    t_end=200.0,
    dt=0.01,
    save_at=(200.0,),
    dtype="float64",
)
st = jdpim.path_integration(scene, stationary=True)
c = cut["ref400"]
hx, hv, n = histograms("ref400")
print(
    f"reference scene D = 0.01 with MCS dt = 0.005, cutoff 400: E[x^2] {c['Ex2']:.5f} +- {c['Ex2_se']:.5f} "
    f"(PI {float(st.moment('x', 2)):.5f}), E[v^2] {c['Ev2']:.5f} +- {c['Ev2_se']:.5f} "
    f"(PI {float(st.moment('v', 2)):.5f})"
)
print(f"   x: {stats(hx, bin_mass(st, 'x', EX), n)}")
print(f"   v: {stats(hv, bin_mass(st, 'v', EV), n)}")
