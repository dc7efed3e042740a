"""Does the time step or the cutoff bias MCS? E[x^2], E[v^2] and histograms (H100, float32).

Usage: `PYTHONPATH=$PWD python3 gpu_cut.py lin200 lin100 lin400 ref400`.
"""

import json
import os
import sys
import time

import numpy as np

import jdpim

OUT = os.environ.get("OUT", "/tmp/out")


def run(tag, model, D, dt, cutoff, n=1_000_000, seed=5):
    sc = jdpim.Scene(
        model,
        noise=jdpim.WhiteNoise(D=D),
        t_end=200.0,
        dt=dt,
        save_at=(200.0,),
        excitation=jdpim.SpectralRepresentation(cutoff=cutoff),
    )
    t0 = time.perf_counter()
    res = jdpim.monte_carlo(sc, n_samples=n, seed=seed, progress=False)
    s = np.asarray(res.states[:, 0, :], np.float64)
    s = s[np.all(np.isfinite(s), 1)]
    x2, v2 = s[:, 0] ** 2, s[:, 1] ** 2
    info = dict(
        tag=tag,
        D=D,
        dt=dt,
        cutoff=cutoff,
        n=len(s),
        seconds=time.perf_counter() - t0,
        Ex2=x2.mean(),
        Ex2_se=x2.std() / np.sqrt(len(s)),
        Ev2=v2.mean(),
        Ev2_se=v2.std() / np.sqrt(len(s)),
    )
    print(json.dumps(info), flush=True)
    np.savez_compressed(
        f"{OUT}/{tag}.npz",
        hx=np.histogram(s[:, 0], np.linspace(0, 4, 401))[0],
        hv=np.histogram(s[:, 1], np.linspace(-4, 4, 801))[0],
        n=len(s),
    )
    return info


if __name__ == "__main__":
    lin = jdpim.VibroImpactOscillator(alpha=0.05, gamma=None, r=1.0)
    ref = jdpim.VibroImpactOscillator(alpha=0.03, gamma=0.03, r=0.98)
    jobs = {
        "lin200": (lin, 0.01, 0.01, 200.0),
        "lin400": (lin, 0.01, 0.005, 400.0),
        "ref400": (ref, 0.01, 0.005, 400.0),
        "lin100": (lin, 0.01, 0.01, 100.0),
    }
    out = [run(k, *jobs[k]) for k in sys.argv[1:]]
    json.dump(out, open(f"{OUT}/cut.json", "w"), indent=1)
