"""Bad input: every public constructor and function rejects it before tracing, naming parameter, value and range."""

import math

import numpy as np
import pytest

import jdpim

INF, NAN = math.inf, math.nan


def model(**kw):
    return jdpim.VibroImpactOscillator(**kw)


def scene(**kw):
    kw.setdefault("t_end", 10.0)
    kw.setdefault("dt", 0.01)
    return jdpim.Scene(kw.pop("model", model()), **kw)


@pytest.fixture(scope="module")
def result():
    """A small result built directly (no simulation): 4 paths, saved at t = 1 and 2."""
    states = np.stack([np.linspace(0.1, 1.0, 8).reshape(4, 2), np.linspace(-1.0, 1.0, 8).reshape(4, 2)], axis=-1)
    return jdpim.Result(
        times=np.array([1.0, 2.0]),
        states=states,
        weights=np.full(4, 0.25),
        barrier=0.0,
        method="monte_carlo",
        independent=True,
    )


CONSTRUCTORS = {
    # restitution outside [0, 1]
    "r-above": (lambda: model(r=1.5), r"r must lie in \[0, 1\], got 1\.5"),
    "r-below": (lambda: model(r=-0.1), r"r must lie in \[0, 1\], got -0\.1"),
    "r-general-model": (lambda: jdpim.Oscillator(r=2.0), r"r must lie in \[0, 1\], got 2\.0"),
    "r-nan": (lambda: model(r=NAN), r"r must be finite, got nan"),
    # other model parameters
    "alpha-negative": (lambda: model(alpha=-0.01), r"alpha must lie in \[0, inf\), got -0\.01"),
    "gamma-inf": (lambda: model(gamma=INF), r"gamma must be finite, got inf"),
    "omega-zero": (lambda: model(omega=0.0), r"omega must lie in \(0, inf\), got 0\.0"),
    "barrier-nan": (lambda: model(barrier=NAN), r"barrier must be finite, got nan"),
    "n_sources": (lambda: jdpim.Oscillator(n_sources=0), r"n_sources must be an integer >= 1, got 0"),
    # noise intensity
    "D-negative": (lambda: jdpim.WhiteNoise(D=-0.1), r"D must lie in \[0, inf\), got -0\.1"),
    "D-nan": (lambda: jdpim.WhiteNoise(D=NAN), r"D must be finite"),
    "D-not-positive-definite": (lambda: jdpim.WhiteNoise(D=[[1.0, 2.0], [2.0, 1.0]]), r"D must be positive definite"),
    "D-not-symmetric": (lambda: jdpim.WhiteNoise(D=[[1.0, 0.5], [0.2, 1.0]]), r"D must be symmetric"),
    "D-ragged": (lambda: jdpim.WhiteNoise(D=[[1.0, 0.0], [0.0]]), r"D must be a scalar or a square \(m, m\) matrix"),
    "D-shape": (lambda: jdpim.WhiteNoise(D=[1.0, 2.0]), r"D must be a scalar or a square \(m, m\) matrix"),
    # time grid
    "dt-zero": (lambda: scene(dt=0.0), r"dt must lie in \(0, inf\), got 0\.0"),
    "dt-negative": (lambda: scene(dt=-0.01), r"dt must lie in \(0, inf\), got -0\.01"),
    "dt-equals-t_end": (lambda: scene(dt=10.0), r"dt must lie in \(0, t_end=10\.0\), got 10\.0"),
    "dt-beyond-t_end": (lambda: scene(dt=20.0), r"dt must lie in \(0, t_end=10\.0\), got 20\.0"),
    "dt-nan": (lambda: scene(dt=NAN), r"dt must be finite, got nan"),
    "t_end-inf": (lambda: scene(t_end=INF), r"t_end must be finite, got inf"),
    "t_end-not-multiple": (lambda: scene(dt=0.03), r"t_end=10\.0 must be a whole number of steps dt=0\.03"),
    # saved times
    "save-after-t_end": (lambda: scene(save_at=(5.0, 11.0)), r"save_at must lie in \[0, 10\], got"),
    "save-negative": (lambda: scene(save_at=(-1.0,)), r"save_at must lie in \[0, 10\], got"),
    "save-decreasing": (lambda: scene(save_at=(5.0, 2.0)), r"save_at must be strictly increasing"),
    "save-repeated": (lambda: scene(save_at=(2.0, 2.0)), r"save_at must be strictly increasing"),
    "save-empty": (lambda: scene(save_at=()), r"save_at must be a non-empty 1-D sequence"),
    "save-off-grid": (lambda: scene(save_at=(0.005,)), r"save_at times \[0\.005\] are not multiples of dt=0\.01"),
    "save-nan": (lambda: scene(save_at=(NAN,)), r"save_at must be finite"),
    # initial state
    "x0-inf": (lambda: scene(x0=INF), r"x0 must be finite, got inf"),
    "v0-nan": (lambda: scene(v0=NAN), r"v0 must be finite, got nan"),
    "x0-beyond-barrier": (lambda: scene(x0=-0.1), r"x0=-0\.1 lies beyond the barrier at 0\.0"),
    # names and shapes
    "random-unknown-name": (lambda: scene(random={"beta": jdpim.Normal(0.0, 1.0)}), r"random parameter 'beta'"),
    "noise-sources-mismatch": (
        lambda: scene(noise=jdpim.WhiteNoise(D=np.eye(2))),
        r"the model's gains expect 1 noise source\(s\) but noise\.D has 2",
    ),
    "dtype": (lambda: scene(dtype="float16"), r"dtype must be None, 'float32' or 'float64', got 'float16'"),
    "cutoff-above-nyquist": (
        lambda: scene(dt=0.5, excitation=jdpim.SpectralRepresentation(cutoff=20.0)),
        r"cutoff=20 rad/s is at or above the Nyquist frequency",
    ),
    # numerical settings
    "impact-method": (lambda: jdpim.ImpactRule(method="flip"), r"method must be 'locate' or 'mirror', got 'flip'"),
    "max_impacts": (lambda: jdpim.ImpactRule(max_impacts=0), r"max_impacts must be an integer >= 1, got 0"),
    "stick_velocity": (lambda: jdpim.ImpactRule(stick_velocity=-1.0), r"stick_velocity must lie in \[0, inf\)"),
    "mirror_below": (lambda: jdpim.ImpactRule(mirror_below=-1.0), r"mirror_below must lie in \[0, inf\)"),
    "max_substeps": (lambda: jdpim.Substeps(max_substeps=0), r"max_substeps must be an integer >= 1, got 0"),
    "substep-limit": (lambda: jdpim.Substeps(limit=3.0), r"limit must lie in \(0, 2\.785\), got 3\.0"),
    "cutoff": (lambda: jdpim.SpectralRepresentation(cutoff=0.0), r"cutoff must lie in \(0, inf\), got 0\.0"),
    "normal-std": (lambda: jdpim.Normal(0.0, 0.0), r"std must lie in \(0, inf\), got 0\.0"),
    "uniform-order": (lambda: jdpim.Uniform(1.0, 0.0), r"Uniform needs high > low, got low=1\.0, high=0\.0"),
}


@pytest.mark.parametrize("case", CONSTRUCTORS, ids=list(CONSTRUCTORS))
def test_constructor_rejects(case):
    build, message = CONSTRUCTORS[case]
    with pytest.raises(ValueError, match=message):
        build()


@pytest.mark.parametrize(
    "build",
    [
        lambda: jdpim.Scene("not a model"),
        lambda: scene(noise=0.03),
        lambda: scene(impacts="locate"),
        lambda: jdpim.WhiteNoise(D=[["a"]]),
    ],
    ids=["model", "noise", "impacts", "D-text-in-matrix"],
)
def test_wrong_types_are_rejected(build):
    with pytest.raises(TypeError, match=r"must be"):
        build()


RUNS = {
    "n_points": (lambda s: jdpim.dpim(s, n_points=1), r"n_points must be an integer >= 2, got 1"),
    "n_samples": (lambda s: jdpim.monte_carlo(s, n_samples=1), r"n_samples must be an integer >= 2, got 1"),
    "seed": (lambda s: jdpim.monte_carlo(s, n_samples=8, seed=-1), r"seed must be an integer >= 0, got -1"),
    "chunk_size": (lambda s: jdpim.monte_carlo(s, n_samples=8, chunk_size=0), r"chunk_size must be an integer >= 1"),
    "chunk_size-int32": (  # 60000 paths x 40500 excitation samples > 2**31 (came back NaN on a GPU)
        lambda s: jdpim.monte_carlo(
            s.replace(t_end=200.0, excitation=jdpim.SpectralRepresentation()), n_samples=60_000, chunk_size=60_000
        ),
        r"chunk_size=60000 exceeds 53024 for this scene",
    ),
    "points-mismatch": (
        lambda s: jdpim.dpim(s, points=jdpim.select_points((jdpim.Uniform(),), 8)),
        r"points\.distributions do not match",
    ),
}


@pytest.mark.parametrize("case", RUNS, ids=list(RUNS))
def test_pipelines_reject_before_tracing(case):
    run, message = RUNS[case]
    with pytest.raises(ValueError, match=message):
        run(scene())


RESULT_CALLS = {
    "grid-empty": (lambda r: r.pdf("x", [], 1.0), r"grid must be a scalar or a non-empty 1-D array, got shape \[0\]"),
    "grid-decreasing": (lambda r: r.pdf("v", [0.0, 1.0, 0.5], 1.0), r"grid must be strictly increasing"),
    "grid-2d": (lambda r: r.pdf("v", np.zeros((2, 2)), 1.0), r"grid must be a scalar or a non-empty 1-D array"),
    "grid-nan": (lambda r: r.pdf("v", [0.0, NAN], 1.0), r"grid must be finite"),
    "x_grid": (
        lambda r: r.joint_pdf(("x", "v"), ([1.0, 0.0], [0.0, 1.0]), 1.0),
        r"grids\[0\] must be strictly increasing",
    ),
    "v_grid": (
        lambda r: r.joint_pdf(("x", "v"), ([0.0, 1.0], []), 1.0),
        r"grids\[1\] must be a scalar or a non-empty 1-D array",
    ),
    "edges": (lambda r: r.histogram("x", [0.0, 0.0, 1.0], 1.0), r"edges must be strictly increasing"),
    "variable": (
        lambda r: r.pdf("y", [0.0, 1.0], 1.0),
        r"var must be one of the coordinates \('x', 'v'\) or a function",
    ),
    "samples-variable": (lambda r: r.samples("displacement", 1.0), r"var must be one of"),
    "time-not-saved": (lambda r: r.pdf("x", [0.0, 1.0], 1.5), r"t=1\.5 was not saved; saved times are \[1\.0, 2\.0\]"),
    "bandwidth": (lambda r: r.pdf("x", [0.0, 1.0], 1.0, bandwidth=-0.1), r"bandwidth must lie in \(0, inf\)"),
    "bandwidth-pair": (
        lambda r: r.joint_pdf(("x", "v"), ([0.0, 1.0], [0.0, 1.0]), 1.0, bandwidth=0.1),
        r"bandwidth must be None or",
    ),
    "rule": (lambda r: r.pdf("x", [0.0, 1.0], 1.0, rule="magic"), r"rule must be one of"),
}


@pytest.mark.parametrize("case", RESULT_CALLS, ids=list(RESULT_CALLS))
def test_result_methods_reject(result, case):
    call, message = RESULT_CALLS[case]
    with pytest.raises(ValueError, match=message):
        call(result)


def test_valid_inputs_pass(result):
    """The boundaries of the allowed ranges are accepted (r = 0 and 1, D = 0, save at 0 and t_end)."""
    for r in (0.0, 1.0):
        scene(model=model(r=r), noise=jdpim.WhiteNoise(D=0.0), save_at=(0.0, 10.0))
    assert np.asarray(result.pdf("x", [0.0, 0.5, 1.0], 2.0)).shape == (3,)


def test_saved_times_match_at_their_own_precision():
    """A float32 result stores 0.2 as 0.2000000030: asking for t = 0.2 finds it, t = 0.2001 does not."""
    from jdpim._scene import saved_index

    times = np.asarray([0.1, 0.2], np.float32)
    assert saved_index(times, 0.2) == 1
    with pytest.raises(ValueError, match=r"t=0\.2001 was not saved"):
        saved_index(times, 0.2001)
    with pytest.raises(ValueError, match=r"t=0\.2000001 was not saved"):
        saved_index((0.1, 0.2), 0.2000001)  # float64 times keep the tight tolerance


def _tiny():
    return jdpim.Scene(model(), t_end=1.0, dt=0.01)


TYPED = {
    # text, sequences and floats where a number or an integer is wanted fail before any tracing
    "r-text": (lambda: model(r="high"), TypeError, r"^r must be a real number, got 'high'$"),
    "alpha-text": (lambda: model(alpha="0.03"), TypeError, r"^alpha must be a real number"),
    "barrier-text": (lambda: model(barrier="abc"), TypeError, r"^barrier must be a real number"),
    "alpha-list": (lambda: model(alpha=[0.03, 0.05]), ValueError, r"^alpha must be a scalar"),
    "barrier-pair": (lambda: model(barrier=(-1.0, 1.0)), ValueError, r"^barrier must be a scalar"),
    "omega-text": (lambda: model(omega="1"), TypeError, r"^omega must be a real number"),
    "general-r-text": (lambda: jdpim.Oscillator(r="x"), TypeError, r"^r must be a real number"),
    "D-text": (lambda: jdpim.WhiteNoise(D="x"), TypeError, r"^D must be a real number"),
    "t_end-text": (lambda: scene(t_end="10"), TypeError, r"^t_end must be a real number"),
    "save_at-text": (lambda: scene(save_at=["a"]), TypeError, r"^save_at must be a sequence of times"),
    "save_at-numeric-text": (lambda: scene(save_at="1.0"), TypeError, r"^save_at must be a sequence of times"),
    "x0-list": (lambda: scene(x0=[0.1, 0.2]), ValueError, r"^x0 must be a scalar"),
    "uniform-text": (lambda: jdpim.Uniform("a", 1.0), TypeError, r"^low must be a real number"),
    "normal-text": (lambda: jdpim.Normal(0.0, "b"), TypeError, r"^std must be a real number"),
    "pi-n_x-float": (lambda: jdpim.PathIntegration(n_x=61.0), TypeError, r"^n_x must be an integer"),
    "pi-tau-text": (lambda: jdpim.PathIntegration(tau="0.1"), TypeError, r"^tau must be a real number"),
    "pi-estimate": (lambda: jdpim.PathIntegration(estimate_error="yes"), TypeError, r"^estimate_error must be"),
    "impacts-text": (lambda: jdpim.ImpactRule(max_impacts="2"), TypeError, r"^max_impacts must be an integer"),
    "substeps-text": (lambda: jdpim.Substeps(limit="0.5"), TypeError, r"^limit must be a real number"),
    "spectral-text": (lambda: jdpim.SpectralRepresentation(cutoff="x"), TypeError, r"^cutoff must be a real number"),
    "n_samples-float": (lambda: jdpim.monte_carlo(_tiny(), n_samples=2.5), TypeError, r"^n_samples must be an integer"),
    "seed-text": (lambda: jdpim.monte_carlo(_tiny(), n_samples=20, seed="a"), TypeError, r"^seed must be an integer"),
    "n_points-text": (lambda: jdpim.dpim(_tiny(), n_points="10"), TypeError, r"^n_points must be an integer"),
    "n_points-1e9": (lambda: jdpim.dpim(_tiny(), n_points=1e9), TypeError, r"^n_points must be an integer"),
    # runs that cannot fit fail at once, naming the public parameter and the memory
    "n_samples-huge": (
        lambda: jdpim.monte_carlo(_tiny(), n_samples=10**10),
        ValueError,
        r"^n_samples=10000000000 needs about .* GiB .* more than half of this host's",
    ),
    "n_points-huge": (lambda: jdpim.dpim(_tiny(), n_points=10**10), ValueError, r"^n_points=10000000000 needs about"),
    "points-huge": (lambda: jdpim.dpim_points(_tiny(), 10**10), ValueError, r"^n_points=10000000000 needs about"),
}


@pytest.mark.parametrize("case", sorted(TYPED))
def test_typed_inputs_fail_in_one_line_naming_the_parameter(case):
    make, kind, message = TYPED[case]
    with pytest.raises(kind, match=message) as info:
        make()
    assert type(info.value) is kind and "\n" not in str(info.value)
