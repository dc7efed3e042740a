"""Results on disk: ``result.save(path)`` / ``jdpim.load(path)`` round trips, their metadata, and ``to_xarray``.

Exact means: the same pytree structure (static fields: times, method, settings) and every leaf with the same
dtype, shape and bytes (NaN payloads included). Results computed here are the session's DPIM fixture, a small
sensitivity and the docs page's Monte Carlo example; the others are built from arrays of the shapes their
functions return (no compilation).
"""

import json
import math
import pathlib
import re
import sys
import zipfile

import jax
import jax.numpy as jnp
import numpy as np
import pytest
from conftest import DT_SMALL, FREE_MODEL, T_SMALL

import jdpim


def assert_same(a, b):
    """``a`` and ``b`` have the same pytree structure and bit-identical leaves of the same dtypes."""
    leaves_a, tree_a = jax.tree_util.tree_flatten(a)
    leaves_b, tree_b = jax.tree_util.tree_flatten(b)
    assert tree_a == tree_b
    for x, y in zip(leaves_a, leaves_b, strict=True):
        if not isinstance(x, (np.ndarray, jax.Array, np.generic)):
            assert type(x) is type(y)  # Python numbers stay Python numbers
        x, y = np.asarray(x), np.asarray(y)
        assert (x.dtype, x.shape) == (y.dtype, y.shape)
        assert x.tobytes() == y.tobytes()


def round_trip(obj, path, **context):
    obj.save(path, **context)
    return jdpim.load(path, metadata=True)


def first_passage():
    """A FirstPassage as ``first_passage(..., wrt=("alpha", "D"))`` by Monte Carlo returns it (float32)."""
    p = jnp.asarray([[0.5, 0.25, 0.0], [0.75, 0.5, 0.125]], jnp.float32)
    return jdpim.FirstPassage(
        (1.0, 5.0),
        jnp.asarray([0.1, 0.2, 0.3], jnp.float32),
        p,
        jnp.sqrt(p * (1 - p) / 32),
        jnp.zeros_like(p),
        "monte_carlo",
        derivative={"alpha": -p, "D": 2 * p},
        derivative_stderr={"alpha": p / 10, "D": p / 5},
    )


def impact_statistics():
    """An ImpactStatistics with a speed histogram (NaN before the first impact), float32."""
    nan = jnp.float32(jnp.nan)
    return jdpim.ImpactStatistics(
        (0.5, 1.0, 2.0),
        jnp.asarray([0.0, 0.25, 0.5], jnp.float32),
        jnp.asarray([0.0, 0.07, 0.09], jnp.float32),
        jnp.asarray([0.0, 0.5, 1.5], jnp.float32),
        jnp.asarray([0.0, 0.1, 0.2], jnp.float32),
        jnp.asarray([0.0, 0.1, 0.2], jnp.float32),
        jnp.asarray([[nan, nan], [5.0, 3.0], [6.0, 2.0]], jnp.float32),
        "dpim",
    )


def grid_result(stationary=False):
    """A GridResult shaped as ``PathIntegration(n_x=16, n_v=17, estimate_error=True)`` returns it."""
    rng = np.random.default_rng(0)

    def grid(n_x, n_v, coarse=None):
        s = 1 if stationary else 2
        nan = jnp.asarray(jnp.nan, jnp.float32)
        return jdpim.GridResult(
            (math.inf,) if stationary else (0.5, 1.0),
            jnp.asarray(rng.random((s, n_x, n_v)), jnp.float32),
            jnp.linspace(0.0, 2.0, n_x, dtype=jnp.float32),
            jnp.linspace(-1.0, 1.0, n_v, dtype=jnp.float32),
            jnp.full((n_x,), 2.0 / (n_x - 1), jnp.float32),
            jnp.full((n_v,), 2.0 / (n_v - 1), jnp.float32),
            jnp.asarray(rng.random(s) * 1e-3, jnp.float32),
            jnp.asarray(rng.random(s) * 1e-6, jnp.float32),
            jnp.asarray(1e-7, jnp.float32) if stationary else nan,
            jnp.asarray(0.999, jnp.float32) if stationary else nan,
            jnp.asarray(3 if stationary else 0, jnp.int32),
            jnp.asarray(1e-3, jnp.float32) if stationary else nan,
            coarse,
            order=4,
            folded=True,
            stationary=stationary,
            has_barrier=True,
        )

    return grid(16, 17, coarse=grid(8, 9))


@pytest.fixture(scope="module")
def small_sensitivity():
    """``dp(v)/dalpha`` by DPIM (pathwise) on a cheap scene; 16 points give a large standard error (warned)."""
    scene = jdpim.Scene(FREE_MODEL, noise=jdpim.WhiteNoise(D=0.05), t_end=T_SMALL, dt=DT_SMALL)
    method = jdpim.DPIM(16)
    with pytest.warns(jdpim.SensitivityWarning, match="standard error"):
        sens = jdpim.sensitivity(scene, ("alpha",), "v", np.linspace(-1.0, 1.0, 9), method=method)
    return scene, method, sens


def test_result_round_trip_is_exact(tmp_path, elastic_scene, elastic_dpim, x_grid):
    method = jdpim.DPIM(n_points=1000)
    back, meta = round_trip(elastic_dpim, tmp_path / "dpim.npz", scene=elastic_scene, method=method)
    assert_same(back, elastic_dpim)
    assert isinstance(back.states, np.ndarray) and back.states.dtype == elastic_dpim.states.dtype
    assert_same(meta.scene, elastic_scene)
    assert_same(meta.method, method)
    assert meta.result_type == "Result" and meta.format == jdpim._io.FORMAT
    assert meta.versions["jdpim"] == jdpim.__version__ and meta.versions["jax"] == jax.__version__
    assert meta.scene_text == repr(elastic_scene)
    # the loaded result computes the same densities, bit for bit
    t = elastic_scene.save_at[0]
    assert np.asarray(back.pdf("x", x_grid, t)).tobytes() == np.asarray(elastic_dpim.pdf("x", x_grid, t)).tobytes()
    assert jdpim.load(tmp_path / "dpim.npz").method == "dpim"  # metadata=False: the result alone


def test_result_of_several_degrees_of_freedom_with_its_scene(tmp_path):
    """A dict barrier, float64 states with NaN payloads, and an MDOF scene with every optional part set."""
    model = jdpim.impact_damper(clearance=0.2)
    scene = jdpim.Scene(
        model,
        noise=jdpim.WhiteNoise(D=0.02),
        t_end=2.0,
        dt=0.01,
        save_at=(1.0, 2.0),
        random={"stiffness[0,0]": jdpim.Normal(1.0, 0.1), "constraints[0].r": jdpim.Uniform(0.4, 0.6)},
        excitation=jdpim.GaussianNodes(),
        impacts=jdpim.ImpactRule(max_impacts=3, hold=(True, False)),
        substeps=jdpim.Substeps(max_substeps=4),
    )
    states = np.random.default_rng(1).standard_normal((5, 2, 4))
    states[0, 0, 0] = np.frombuffer(np.uint64(0x7FF8_0000_0000_BEEF).tobytes(), np.float64)[0]  # a NaN payload
    points = jdpim.randomised_points(
        jdpim.DPIM.input_distributions(scene.replace(excitation=None)), 5, 0, n_reference=256
    )  # a DPIM point set
    res = jdpim.Result((1.0, 2.0), states, points.weights, {"x1": np.float64(-0.2)}, "dpim", model.coordinates)
    method = jdpim.DPIM(points=points, chunk_size=4, progress=False)
    back, meta = round_trip(res, tmp_path / "mdof.npz", scene=scene, method=method)
    assert_same(back, res)
    assert type(back.barrier["x1"]) is np.float64
    assert jax.jit(lambda r: r.n_nonfinite())(back).tolist() == [1, 0]  # a loaded result passes through jax.jit
    assert_same(meta.scene, scene)
    assert_same(meta.method, method)
    assert meta.method.points.distributions == jdpim.DPIM.input_distributions(scene.replace(excitation=None))


def test_grid_result_round_trip_keeps_the_coarse_solve(tmp_path):
    for stationary in (False, True):
        res = grid_result(stationary)
        method = jdpim.PathIntegration(n_x=16, n_v=17, estimate_error=True, stationary=stationary, x_max=2.0)
        back, meta = round_trip(res, tmp_path / f"grid{stationary}.npz", method=method)
        assert_same(back, res)
        assert isinstance(back.coarse, jdpim.GridResult) and back.coarse.density.shape == (len(res.times), 8, 9)
        assert meta.method == method and meta.scene is None and meta.scene_text is None


def test_first_passage_and_impact_statistics_round_trip(tmp_path):
    fp = first_passage()
    back, meta = round_trip(fp, tmp_path / "fp.npz", method=jdpim.MonteCarlo(32, seed=1))
    assert_same(back, fp)
    assert list(back.derivative) == ["alpha", "D"] and meta.method == jdpim.MonteCarlo(32, seed=1)
    subset = jdpim.FirstPassage((5.0,), fp.levels, fp.probability[1:], None, fp.lost_mass[1:], "subset_simulation",
                                n_evaluations=370)  # fmt: skip
    method = jdpim.SubsetSimulation(n_per_level=100, p0=0.1)
    back, meta = round_trip(subset, tmp_path / "subset.npz", method=method)
    assert_same(back, subset)
    assert back.n_evaluations == 370 and meta.method == method
    st = impact_statistics()
    assert_same(round_trip(st, tmp_path / "impacts.npz")[0], st)


def test_response_statistics_and_fragility_round_trip(tmp_path):
    states = np.random.default_rng(0).normal(size=(200, 64, 2))
    mc = jdpim.Result(
        times=tuple(0.5 * np.arange(64)),
        states=states,
        weights=np.full(200, 1 / 200),
        method="monte_carlo",
        independent=True,
    )
    for stat in (
        jdpim.response_moments(mc, "x"),
        jdpim.response_psd(mc, "x", segment=16),
        jdpim.response_autocorrelation(mc, "x", max_lag=4),
    ):
        back, _ = round_trip(stat, tmp_path / f"{type(stat).__name__}.npz")
        assert type(back) is type(stat)
        assert_same(back, stat)
    noise = jdpim.WhiteNoise(0.03, envelope=jdpim.Jennings(t1=1.0, t2=3.0, c=0.5))
    scene = jdpim.Scene(jdpim.VibroImpactOscillator(), noise, t_end=5.0)
    back, meta = round_trip(mc, tmp_path / "scene.npz", scene=scene)
    assert meta.scene == scene


def test_sensitivity_round_trip(tmp_path, small_sensitivity):
    scene, method, dp = small_sensitivity
    back, meta = round_trip(dp, tmp_path / "dp.npz", scene=scene, method=method)
    assert_same(back, dp)
    assert back.estimators == dp.estimators and back.times == dp.times and dict(back).keys() == dp.keys()
    assert_same(meta.scene, scene)


def test_functions_in_a_scene_are_not_stored(tmp_path):
    """A scene with Python functions: the result is saved, the scene kept as text, one warning each way."""
    model = jdpim.Oscillator(params={"k3": 0.1}, g=lambda x, p: x + p["k3"] * x**3, r=0.9)
    scene = jdpim.Scene(model, t_end=1.0, dt=0.1)
    fp = first_passage()
    with pytest.warns(jdpim.PersistenceWarning) as saved:
        fp.save(tmp_path / "duffing.npz", scene=scene, method=jdpim.MonteCarlo(32))
    assert len(saved) == 1 and "\n" not in str(saved[0].message) and "scene/model/g" in str(saved[0].message)
    assert_same(jdpim.load(tmp_path / "duffing.npz"), fp)  # no warning without the metadata
    with pytest.warns(jdpim.PersistenceWarning, match="not restored") as loaded:
        _, meta = jdpim.load(tmp_path / "duffing.npz", metadata=True)
    assert len(loaded) == 1 and "\n" not in str(loaded[0].message)
    assert meta.scene is None and meta.scene_text == repr(scene) and meta.method == jdpim.MonteCarlo(32)


def rewrite(path, change):
    """The file at ``path`` with its JSON document changed by ``change(doc)``."""
    with np.load(path, allow_pickle=False) as npz:
        arrays = {k: npz[k] for k in npz.files}
    doc = json.loads(str(arrays["jdpim"]))
    change(doc)
    arrays["jdpim"] = np.array(json.dumps(doc))
    with open(path, "wb") as fh:
        np.savez(fh, **arrays)


def test_files_of_other_versions_warn_or_fail_in_one_line(tmp_path):
    path = tmp_path / "fp.npz"
    first_passage().save(path)
    rewrite(path, lambda doc: doc["versions"].update(jdpim="0.0.1"))
    with pytest.warns(jdpim.PersistenceWarning, match=r"written by jdpim 0\.0\.1; this is jdpim") as record:
        assert_same(jdpim.load(path), first_passage())
    assert len(record) == 1 and "\n" not in str(record[0].message)
    rewrite(path, lambda doc: doc.update(format=2))
    with pytest.raises(ValueError, match=r"file format 2 \(jdpim 0\.0\.1\); this jdpim .* reads format 1") as err:
        jdpim.load(path)
    assert "\n" not in str(err.value)
    rewrite(path, lambda doc: doc.update(format=1) or doc["result"]["fields"].update(extra=1))
    with pytest.warns(jdpim.PersistenceWarning), pytest.raises(ValueError, match="does not fit this jdpim"):
        jdpim.load(path)


def test_results_of_files_before_the_independent_field_take_their_methods(tmp_path):
    """A ``Result`` saved without ``independent`` loads with its method's: Monte Carlo's have standard errors."""
    states = np.random.default_rng(1).normal(size=(8, 1, 2))
    for method, independent in (("monte_carlo", True), ("dpim", False)):
        res = jdpim.Result(
            times=(1.0,), states=states, weights=np.full(8, 1 / 8), method=method, independent=independent
        )
        path = tmp_path / f"{method}.npz"
        res.save(path)
        rewrite(path, lambda doc: doc["result"]["fields"].pop("independent"))
        assert jdpim.load(path).independent is independent


def test_loading_runs_no_code_from_the_file(tmp_path):
    """Only jdpim's own classes are rebuilt, and pickled arrays are refused."""
    path = tmp_path / "fp.npz"
    first_passage().save(path)
    rewrite(path, lambda doc: doc["result"].update({"class": "Popen"}))
    with pytest.raises(ValueError, match="names a class 'Popen' that this jdpim does not know"):
        jdpim.load(path)
    rewrite(path, lambda doc: doc["result"].update({"class": "Result", "fields": {"times": {"nothing": 1}}}))
    with pytest.raises(ValueError, match="malformed jdpim document"):
        jdpim.load(path)
    with open(tmp_path / "pickled.npz", "wb") as fh:
        np.savez(fh, jdpim=np.array("{}"), evil=np.array([print], dtype=object))
    with pytest.raises(ValueError, match="allow_pickle"):
        jdpim.load(tmp_path / "pickled.npz")
    with open(tmp_path / "plain.npz", "wb") as fh:
        np.savez(fh, states=np.zeros(3))
    with pytest.raises(ValueError, match="not a jdpim result file"):
        jdpim.load(tmp_path / "plain.npz")
    with zipfile.ZipFile(path) as z:  # an open archive: one .npy per array and the JSON document
        assert sorted(z.namelist()) == sorted(
            f"{k}.npy" for k in ("jdpim", "result/levels", "result/probability", "result/probability_stderr",
                                 "result/lost_mass", "result/derivative/alpha", "result/derivative/D",
                                 "result/derivative_stderr/alpha", "result/derivative_stderr/D")
        )  # fmt: skip


def test_save_refuses_what_is_not_a_result_or_its_context(tmp_path):
    with pytest.raises(ValueError, match="method must be the method the result came from .'monte_carlo'. or None"):
        first_passage().save(tmp_path / "x.npz", method=jdpim.DPIM(16))
    with pytest.raises(TypeError, match="scene must be the jdpim.Scene the result came from, or None; got dict"):
        first_passage().save(tmp_path / "x.npz", scene={"D": 0.03})
    with pytest.raises(TypeError, match="save takes a jdpim result"):
        jdpim._io.save({"states": np.zeros(3)}, tmp_path / "x.npz")
    with pytest.raises(TypeError, match="save outside jax.jit"):
        jax.jit(lambda fp: fp.save(tmp_path / "x.npz"))(first_passage())


def test_to_xarray_labels_every_array(tmp_path, monkeypatch):
    import xarray as xr  # in the test extra (pip install -e .[test]): this test does not skip

    fp = first_passage()
    ds = fp.to_xarray()
    assert ds["probability"].dims == ("time", "level") and list(ds["time"].values) == [1.0, 5.0]
    np.testing.assert_array_equal(ds["level"].values, np.asarray(fp.levels))
    np.testing.assert_array_equal(ds["derivative_D"].values, np.asarray(fp.derivative["D"]))
    assert "grid_error" not in ds and ds.attrs["method"] == "monte_carlo"
    ds = grid_result().to_xarray()
    assert ds["density"].dims == ("time", "x", "v") and ds.attrs["folded"] == 1
    ds.to_netcdf(tmp_path / "grid.nc", engine="scipy")  # attributes and variables netCDF 3 can hold
    with xr.open_dataset(tmp_path / "grid.nc", engine="scipy") as nc:
        assert nc.load().identical(ds)
    np.testing.assert_array_equal(ds["density"].sel(time=1.0).values, np.asarray(grid_result().joint(1.0)))
    ds = impact_statistics().to_xarray()
    np.testing.assert_allclose(ds["speed"].values, [0.05, 0.15])
    assert ds["speed_density"].dims == ("time", "speed") and ds["speed_edges"].dims == ("edge",)
    res = jdpim.Result((1.0,), np.zeros((3, 1, 4)), np.full(3, 1 / 3), {"x1": -0.2}, "dpim", ("x1", "x2", "v1", "v2"))
    ds = res.to_xarray()
    assert ds["states"].dims == ("path", "time", "coordinate") and list(ds["coordinate"].values) == list(
        res.coordinates
    )
    assert ds.attrs["barrier_x1"] == -0.2
    assert isinstance(ds, xr.Dataset)
    values = np.arange(12.0).reshape(3, 2, 2)
    mean = values.mean(axis=0)
    tracked = jdpim.tracking.Tracked((1.0, 2.0), values, np.full(3, 1 / 3), mean, mean / 10, "monte_carlo")
    assert_same(round_trip(tracked, tmp_path / "tracked.npz")[0], tracked)
    ds = tracked.to_xarray()
    assert ds["values"].dims == ("path", "time", "component") and ds["mean_stderr"].dims == ("time", "component")
    monkeypatch.setitem(sys.modules, "xarray", None)  # as if xarray were not installed
    with pytest.raises(ImportError, match=r"pip install jdpim\[xarray\]"):
        res.to_xarray()


@pytest.mark.slow
def test_the_docs_examples_run(tmp_path, monkeypatch):
    """The code blocks of docs/persistence.md, in order, in a fresh folder (all but the cluster job's script, a run
    of 10^8 paths).

    slow: end-to-end repeats of what the default tier checks in test_result_round_trip_is_exact (save, load, the
    metadata), test_files_of_other_versions_warn_or_fail_in_one_line (the file's JSON record) and
    test_checkpoint.py::test_monte_carlo_resumes_bit_for_bit / test_first_passage_resumes_bit_for_bit (checkpoints
    of Monte Carlo and first passage)."""
    page = pathlib.Path(__file__).parent.parent / "docs" / "persistence.md"
    blocks = re.findall(r"```python\n(.*?)```", page.read_text(), flags=re.S)
    blocks = [code for code in blocks if not code.startswith("# reference.py")]
    assert len(blocks) == 3
    monkeypatch.chdir(tmp_path)
    for code in blocks:
        exec(compile(code, str(page), "exec"), {})
