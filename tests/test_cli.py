"""The command line and scene files: help on every option, one-line errors with exit status 2, outputs."""

import argparse
import json
import pathlib

import jax
import jax.numpy as jnp
import numpy as np
import pytest

import jdpim
from jdpim import _report as report
from jdpim import cli
from jdpim.cli._scenefile import SceneFileError, load

EXAMPLE = pathlib.Path(__file__).parents[1] / "examples" / "reference.toml"


def _subparsers():
    parser = cli.parser()
    sub = next(a for a in parser._actions if isinstance(a, argparse._SubParsersAction))
    return {name: p for name, p in sub.choices.items() if name != "bench"}


@pytest.mark.parametrize("command", ["run", "paper"])
def test_every_option_has_help_and_shows_its_default(command):
    p = _subparsers()[command]
    assert issubclass(p.formatter_class, argparse.ArgumentDefaultsHelpFormatter)  # appends "(default: ...)"
    for action in p._actions:
        assert action.help, f"{command} {action.option_strings or action.dest} has no help text"
    text = " ".join(p.format_help().split())
    expected = {
        "run": ["--r R coefficient of restitution r (default: 0.98)", "--repeats REPEATS"],
        "paper": ["--quick"],
    }
    assert all(e in text for e in expected[command])
    assert "(default: jdpim_out)" in text


@pytest.mark.parametrize(
    ("argv", "message"),
    [
        (["run", "--r", "1.5"], "argument --r: must lie in [0, 1], got 1.5"),
        (["run", "--repeats", "0"], "argument --repeats: must be an integer >= 1, got 0"),
        (["run", "--points", "1"], "argument --points: must be an integer >= 2, got 1"),
        (["run", "--samples", "-5"], "argument --samples: must be an integer >= 2, got -5"),
        (["run", "--t-end", "0"], "argument --t-end: must lie in (0, inf), got 0"),
        (["run", "--dt", "-0.01"], "argument --dt: must lie in (0, inf), got -0.01"),
        (["run", "--D", "nan"], "argument --D: must be finite, got nan"),
        (["run", "--alpha", "x"], "argument --alpha: 'x' is not a number"),
        (["run", "--save-at", "300"], "--save-at times must lie in [0, --t-end=200], got 300"),
        (["run", "--t-end", "10", "--dt", "0.03", "--save-at", "10"], "t_end=10.0 must be a whole number of steps"),
        (["paper", "--samples", "0"], "argument --samples: must be an integer >= 2, got 0"),
        (["run", "--forcing", "fft"], "argument --forcing: invalid choice: 'fft'"),
        (["run", "missing.toml"], "missing.toml: no such file"),
    ],
)
def test_bad_values_fail_in_one_line_with_status_2(argv, message, capsys):
    assert cli.main(argv) == 2
    err = capsys.readouterr().err
    assert message in err
    assert err.count("\n") == 1 and "Traceback" not in err


def _scene_text(**replace):
    """The shipped example with small settings (and any key = value line replaced)."""
    text = EXAMPLE.read_text()
    small = {"t_end": "2.0", "dt": "0.02", "save_at": "[1.0, 2.0]", "n_points": "32", "n_samples": "64"}
    for key, value in {**small, **replace}.items():
        lines = [ln for ln in text.splitlines() if ln.split("=")[0].strip() == key]
        assert len(lines) == 1, key
        text = text.replace(lines[0], f"{key} = {value}" if value is not None else "")
    return text


def test_the_example_scene_file_parses_as_documented():
    sf = load(EXAMPLE)
    assert (sf.scene.model.alpha, sf.scene.model.gamma, sf.scene.model.r) == (0.03, 0.03, 0.98)
    assert float(sf.scene.noise.D) == 0.03 and sf.scene.save_at == (50.0, 200.0) and sf.scene.t_end == 200.0
    assert [(m.name, m.n_paths) for m in sf.methods] == [("dpim", 1000), ("monte_carlo", 10_000)]


def test_scene_files_choose_monte_carlos_forcing(tmp_path):
    """``[method] forcing``: ``"nodes"`` (the default) leaves the scene's excitation to each method; ``"spectral"``
    gives both methods the spectral representation."""
    path = tmp_path / "s.toml"
    path.write_text(_scene_text())
    assert load(path).scene.excitation is None and load(path).table["method"]["forcing"] == "nodes"
    path.write_text(_scene_text(n_samples='64\nforcing = "spectral"'))
    sf = load(path)
    assert sf.scene.excitation == jdpim.SpectralRepresentation() and sf.table["method"]["forcing"] == "spectral"
    assert jdpim.MonteCarlo().excitation(sf.scene) == jdpim.DPIM().excitation(sf.scene)


@pytest.mark.parametrize("spelling", ['"none"', None])
def test_an_absent_term_is_not_in_the_model(tmp_path, spelling):
    path = tmp_path / "s.toml"
    path.write_text(_scene_text(gamma=spelling))
    assert load(path).scene.model.gamma is None


@pytest.mark.parametrize(
    ("change", "message"),
    [
        ({"r": "1.5"}, "s.toml: [model] r: must lie in [0, 1], got 1.5"),
        ({"r": '"high"'}, "s.toml: [model] r: must be a number, got a string 'high'"),
        ({"alpha": "-1"}, "s.toml: [model] alpha: must lie in [0, inf), got -1"),
        (
            {"kind": '"duffing"'},
            "s.toml: [model] kind: must be one of ['vibro_impact', 'mdof', 'impact_damper', 'pounding_frame', "
            "'gear_pair', 'adjacent_buildings'], got 'duffing'",
        ),
        ({"D": "true"}, "s.toml: [noise] D: must be a number, got a boolean True"),
        ({"n_points": "1.5"}, "s.toml: [method] n_points: must be an integer, got a float 1.5"),
        ({"n_samples": "1"}, "s.toml: [method] n_samples: must be an integer >= 2, got 1"),
        ({"name": '"fem"'}, "s.toml: [method] name: must be one of ['dpim', 'monte_carlo'], got 'fem'"),
        (
            {"n_samples": '64\nforcing = "fft"'},
            "s.toml: [method] forcing: must be one of ['nodes', 'spectral'], got 'fft'",
        ),
        (
            {"name": '"dpim"', "n_samples": None, "n_points": '32\nforcing = "spectral"'},
            "s.toml: [method] forcing: does not apply to method 'dpim'",
        ),
        ({"save_at": "[1.0, 3.0]"}, "s.toml: [time] save_at: must lie in [0, 2], got 3"),
        ({"save_at": "[1.01, 2.0]"}, "s.toml: [time] save_at: save_at times [1.01] are not multiples of dt=0.02"),
        ({"dt": "0.03"}, "s.toml: [time] t_end: t_end=2.0 must be a whole number of steps dt=0.03"),
        ({"densities": '["x", "energy"]'}, "s.toml: [output] densities: must be one of ['x', 'v', 'joint']"),
        ({"states": '"yes"'}, "s.toml: [output] states: must be true or false, got a string 'yes'"),
        ({"D": None}, "s.toml: [noise] D: is required"),
        ({"gamma": "0.03\nstiffness = 2"}, "s.toml: [model] stiffness: unknown key; allowed keys are"),
        ({"t_end": "2.0 2"}, "s.toml: not valid TOML"),
    ],
)
def test_bad_scene_files_fail_in_one_line_naming_file_and_key(tmp_path, capsys, change, message):
    path = tmp_path / "s.toml"
    path.write_text(_scene_text(**change))
    with pytest.raises(SceneFileError, match=None) as info:
        load(path)
    assert message in str(info.value) and "\n" not in str(info.value)
    assert cli.main(["run", str(path), "--out", str(tmp_path / "out")]) == 2
    err = capsys.readouterr().err
    assert message in err and err.count("\n") == 1


@pytest.mark.parametrize("extra", [["--D", "0.5"], ["--r=0.5", "--points", "10"]])
def test_main_job_options_beside_a_scene_file_are_refused(extra, capsys):
    example = pathlib.Path(__file__).parents[1] / "examples" / "reference.toml"
    assert cli.main(["run", str(example), *extra]) == 2
    err = capsys.readouterr().err.strip()
    assert len(err.splitlines()) == 1 and "carries its own settings" in err and extra[0].split("=")[0] in err


def test_unknown_table(tmp_path):
    path = tmp_path / "s.toml"
    path.write_text(_scene_text() + "\n[solver]\nrtol = 1e-3\n")
    with pytest.raises(SceneFileError, match=r"s.toml: \[solver\]: unknown table"):
        load(path)


def test_run_scene_file_writes_only_what_it_asks(tmp_path, capsys):
    path = tmp_path / "small.toml"
    text = _scene_text(gamma='"none"', densities='["x"]', states="true").replace(
        'name = ["dpim", "monte_carlo"]', 'name = "monte_carlo"'
    )
    path.write_text(text.replace("n_points = 32", ""))
    assert cli.main(["run", str(path), "--out", str(tmp_path), "--quiet"]) == 0
    assert capsys.readouterr().err == ""  # --quiet: no progress lines
    with np.load(tmp_path / "small.npz", allow_pickle=False) as npz:
        arrays = {k: npz[k] for k in npz.files}
    assert set(arrays) == {
        "times", "x_grid", "monte_carlo_pdf_x", "monte_carlo_stderr_x", "monte_carlo_atoms_x", "monte_carlo_nonfinite",
    }  # fmt: skip
    assert arrays["monte_carlo_atoms_x"].shape == (2, 2)  # held at the barrier (sticking) and above it (no bound)
    assert np.all(arrays["monte_carlo_atoms_x"][:, 1] == 0)
    assert arrays["monte_carlo_pdf_x"].shape == (2, 201)
    res, saved = jdpim.load(tmp_path / "small_monte_carlo.npz", metadata=True)  # states = true: the whole result
    assert res.states.shape == (64, 2, 2) and saved.scene.model.gamma is None and saved.method.n_samples == 64
    integral = np.trapezoid(arrays["monte_carlo_pdf_x"][-1], arrays["x_grid"])
    assert 0.97 < integral <= 1.0 + 1e-4  # the grid holds 99.9 % of the samples
    meta = json.loads((tmp_path / "small.json").read_text())
    assert meta["parameters"]["model"]["gamma"] == "none"
    assert meta["versions"]["jdpim"] == jdpim.__version__ and "jax" in meta["versions"]
    files = ["small.npz", "small_timing.csv", "small_monte_carlo.npz", "small_marginal_x.png", "small.json"]
    assert sorted(meta["files"]) == sorted(files)
    assert all((tmp_path / f).is_file() for f in meta["files"])


def test_mcs_standard_error_matches_independent_batches():
    """``kde_stderr`` from one batch's per-path contributions against the spread of 200 independent batches."""
    rng = np.random.default_rng(0)
    batches = rng.normal(size=(200, 400)).astype(np.float32)
    grid = np.linspace(-3.0, 3.0, 13)
    w = np.full(400, 1 / 400, np.float32)
    pdfs = np.asarray(jax.vmap(lambda b: jdpim.kde(b, w, grid, 0.3))(batches))
    se = np.asarray(jax.vmap(lambda b: jdpim.kde_stderr(b, w, grid, 0.3))(batches))
    np.testing.assert_allclose(se.mean(0), pdfs.std(0, ddof=1), rtol=0.15)


def test_one_point_and_scalar_grids():
    y, w = np.linspace(0.0, 2.0, 50), np.full(50, 0.02)
    full = np.asarray(jdpim.kde(y, w, np.array([0.3, 0.5]), 0.2, 0.0))
    assert np.asarray(jdpim.kde(y, w, np.array([0.5]), 0.2, 0.0)).shape == (1,)
    assert float(jdpim.kde(y, w, 0.5, 0.2, 0.0)) == pytest.approx(full[1], rel=1e-6)
    res = jdpim.Result(
        times=np.array([1.0]),
        states=np.stack([y, y], -1)[:, None],
        weights=w,
        barrier=0.0,
        method="monte_carlo",
        independent=True,
    )
    assert res.joint_pdf(("x", "v"), (0.5, np.array([0.1, 0.5])), 1.0).shape == (2,)
    with pytest.raises(ValueError, match="pdf_error of a sampling result needs independent samples"):
        dpim = jdpim.Result(times=res.times, states=res.states, weights=w, barrier=0.0, method="dpim")
        dpim.pdf_error("x", 0.5, 1.0)


def test_no_stray_public_names():
    assert not hasattr(jdpim, "PackageNotFoundError")
    with pytest.raises(ValueError, match=r"got \[20\.0\]$"):
        jdpim.Scene(jdpim.VibroImpactOscillator(), t_end=10.0, save_at=np.array([20.0]))


def test_one_point_pdf_is_differentiable():
    """``jax.grad`` of a one-point density through ``Result.pdf`` (states scaled by a parameter) against FD."""
    base = np.linspace(0.05, 2.0, 40)

    def p_at(s):
        states = jnp.stack([s * base, -s * base], -1)[:, None]
        res = jdpim.Result(
            times=np.array([1.0]), states=states, weights=jnp.full(40, 1 / 40), barrier=0.0, method="dpim"
        )
        return res.pdf("x", jnp.array([0.5]), 1.0)[0]

    fd = (p_at(1.001) - p_at(0.999)) / 0.002
    assert float(jax.grad(p_at)(1.0)) == pytest.approx(float(fd), rel=1e-2)


@pytest.mark.slow
def test_grad_of_one_point_dpim_density_in_D():
    """The issue's example: ``jax.grad`` of a DPIM density at one point with respect to D, against FD."""
    scene = jdpim.Scene(
        jdpim.VibroImpactOscillator(), t_end=2.0, dt=0.02, x0=0.3, impacts=jdpim.ImpactRule(stick_velocity=0.0)
    )  # no sticking (a switch) and a fixed bandwidth, as in docs/gradients.md
    pts = jdpim.dpim_points(scene, 64)

    def p_at(D):
        res = jdpim.dpim(scene.replace(noise=jdpim.WhiteNoise(D=D)), points=pts)
        return res.pdf("x", jnp.array([0.3]), 2.0, bandwidth=0.05)[0]

    fd = (p_at(0.0301) - p_at(0.0299)) / 0.0002  # converged: h = 3e-4 is not (impacts near grazing)
    # AD is exact on these 64 points; as an estimate of the density's derivative it is not, and it says so
    with pytest.warns(jdpim.SensitivityWarning, match="not reliable"):
        g = float(jax.grad(p_at)(0.03))
    assert g == pytest.approx(float(fd), rel=1e-2)


def test_paper_command_passes_its_settings(monkeypatch, tmp_path):
    """``jdpim paper --quick --samples N --pdf --quiet`` reaches ``jdpim.paper.reproduce`` with those settings."""
    from jdpim import paper

    seen = {}
    monkeypatch.setattr(paper, "reproduce", lambda settings, out, **kw: seen.update(settings=settings, out=out, **kw))
    assert cli.main(["paper", "--quick", "--samples", "2000", "--pdf", "--quiet", "--out", str(tmp_path)]) == 0
    s = seen["settings"]
    assert (s.name, s.n_samples, s.n_points, s.noise_levels) == ("quick", 2000, 1000, (0.01, 0.03, 0.08))
    assert seen["pdf"] is True and seen["progress"] is False and seen["out"] == tmp_path
    assert s.label().startswith("QUICK settings: DPIM 1000 points, MCS 2000 samples")
    assert s.excitation is None and "spectral" not in s.label()  # Monte Carlo's own forcing
    assert cli.main(["paper", "--quick", "--forcing", "spectral", "--quiet", "--out", str(tmp_path)]) == 0
    s = seen["settings"]
    assert s.excitation == jdpim.SpectralRepresentation() and s.label().endswith(", MCS on the spectral forcing")
    assert paper.scene(0.03, s).excitation == s.excitation
    assert paper.FULL.n_samples == 100_000 and paper.FULL.n_points == 1000  # the paper's sizes


def test_main_job_reference_says_why_it_is_missing():
    """Saved times before path integration's start leave the main job without a reference, and the log says why."""
    scene = jdpim.Scene(jdpim.VibroImpactOscillator(), t_end=2.0, dt=0.01, save_at=(0.5, 2.0))
    lines = []
    assert report.reference(scene, jdpim.PathIntegration(), lines.append) is None
    assert "no path-integration reference: saved time 0.5 must be t0=1.0" in lines[-1]


def test_terminal_tables_show_the_bars_the_markdown_escapes():
    table = report.probability_table([1.0], [0.5], np.array([[0.25]]), quantity="|x1|")
    assert "| t (s) | P(\\|x1\\| > 0.5) |" in table
    assert "| t (s) | P(|x1| > 0.5) |" in report.terminal(table) and "\\" not in report.terminal(table)


def test_figure_titles_count_degrees_of_freedom_not_filter_coordinates():
    def title(model):
        return report.scene_title(jdpim.Scene(model, noise=jdpim.WhiteNoise(D=0.01), t_end=1.0))

    assert title(jdpim.impact_damper()).startswith("2 degrees of freedom, 2 constraints")
    assert title(jdpim.kanai_tajimi(jdpim.impact_damper())).startswith(
        "2 degrees of freedom and 1 filter coordinate (xf), 2 constraints"
    )
    assert title(jdpim.first_order_filter(jdpim.pounding_frame(n_storeys=1), a=2.0)).startswith(
        "1 degree of freedom and 1 filter coordinate (xf), 1 constraint ("
    )
