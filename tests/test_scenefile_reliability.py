"""Scene files with a ``[reliability]`` table: first-passage probabilities stored beside the densities, equal to
``jdpim.first_passage`` on the same scene and method; one-line errors naming the file and the key; a file
without the table writes what it wrote before."""

import json
import pathlib

import numpy as np
import pytest

import jdpim
from jdpim import cli
from jdpim.cli._scenefile import Magnitude, SceneFileError, load

EXAMPLES = pathlib.Path(__file__).parents[1] / "examples"
SCENE = """
[model]
alpha = 0.03
gamma = 0.03
r = 0.98

[noise]
D = 0.03

[time]
t_end = 2.0
dt = 0.02
save_at = [1.0, 2.0]

[method]
name = "monte_carlo"
n_samples = 64

[output]
figures = false
"""
RELIABILITY = '\n[reliability]\nquantity = "x"\nlevels = [0.05, 0.1]\n'


def _run(tmp_path, text: str, name: str) -> tuple[dict, dict]:
    """``jdpim run`` of ``text`` as ``<name>.toml``: the ``.npz`` arrays and the JSON metadata."""
    path = tmp_path / f"{name}.toml"
    path.write_text(text)
    out = tmp_path / name
    assert cli.main(["run", str(path), "--out", str(out), "--quiet"]) == 0
    with np.load(out / f"{name}.npz", allow_pickle=False) as npz:
        arrays = {k: npz[k] for k in npz.files}
    return arrays, json.loads((out / f"{name}.json").read_text())


def test_run_stores_first_passage_equal_to_a_direct_call_and_leaves_the_rest_as_without_the_table(tmp_path):
    plain, plain_meta = _run(tmp_path, SCENE, "plain")
    arrays, meta = _run(tmp_path, SCENE + RELIABILITY, "s")
    assert not any(k.startswith("first_passage") for k in plain) and "first_passage_wall_time_s" not in plain_meta
    assert "reliability" not in plain_meta["parameters"] and load(tmp_path / "plain.toml").reliability is None

    # the same outputs as without the table, and the first passage beside them
    fp_keys = {f"first_passage_monte_carlo_{a}" for a in ("probability", "lost_mass")}
    assert set(arrays) == set(plain) | fp_keys | {"first_passage_levels", "first_passage_monte_carlo_stderr"}
    for k, v in plain.items():
        np.testing.assert_array_equal(arrays[k], v, err_msg=k)
    plain_files = {f.replace("plain", "s") for f in plain_meta["files"]}
    assert set(meta["files"]) == plain_files | {"s_first_passage.md"}
    assert meta["parameters"]["reliability"] == {"quantity": "x", "levels": [0.05, 0.1]}
    assert set(meta["first_passage_wall_time_s"]) == {"monte_carlo"}

    # equal to jdpim.first_passage on the scene built by hand, with the same method (DPIM's: the mdof test below)
    model = jdpim.VibroImpactOscillator(alpha=0.03, gamma=0.03, r=0.98)
    scene = jdpim.Scene(model, noise=jdpim.WhiteNoise(D=0.03), t_end=2.0, dt=0.02, save_at=(1.0, 2.0))
    np.testing.assert_array_equal(arrays["first_passage_levels"], [0.05, 0.1])
    fp = jdpim.first_passage(scene, "x", [0.05, 0.1], jdpim.MonteCarlo(n_samples=64, seed=0))
    np.testing.assert_array_equal(arrays["first_passage_monte_carlo_probability"], fp.probability)
    np.testing.assert_array_equal(arrays["first_passage_monte_carlo_lost_mass"], fp.lost_mass)
    np.testing.assert_array_equal(arrays["first_passage_monte_carlo_stderr"], fp.probability_stderr)
    assert 0.0 < arrays["first_passage_monte_carlo_probability"][-1, -1] < 1.0  # a level that tells something

    # the report: a table per method, a row per saved time, p ± se for Monte Carlo (p alone for DPIM: below)
    table = (tmp_path / "s" / "s_first_passage.md").read_text()
    p, se = arrays["first_passage_monte_carlo_probability"], arrays["first_passage_monte_carlo_stderr"]
    assert "| t (s) | P(x > 0.05) | P(x > 0.1) |" in table
    assert f"| 2 | {p[1, 0]:.3g} ± {se[1, 0]:.2g} | {p[1, 1]:.3g} ± {se[1, 1]:.2g} |" in table


def test_mdof_magnitude_of_a_coordinate(tmp_path):
    text = (EXAMPLES / "impact_damper.toml").read_text()
    for old, new in (
        ("t_end = 50.0", "t_end = 2.0"),
        ("dt = 0.01", "dt = 0.02"),
        ("save_at = [10.0, 50.0]", "save_at = [1.0, 2.0]"),
        ('name = ["dpim", "monte_carlo"]', 'name = "dpim"'),
        ("n_points = 2000", "n_points = 32"),
        ("n_samples = 4000", ""),
        ('densities = ["x1", "x2", "v1", "v2"]', 'densities = ["x1"]\nfigures = false'),
        ('joint = [["x1", "x2"]]', ""),
    ):
        assert old in text, old
        text = text.replace(old, new, 1)
    text += '\n[reliability]\nquantity = "|x1|"\nlevels = 0.05\n'
    arrays, meta = _run(tmp_path, text, "damper")
    sf = load(tmp_path / "damper.toml")
    assert sf.reliability.quantity == Magnitude("x1", 0) and hash(sf.reliability.quantity) == hash(Magnitude("x1", 0))
    assert meta["parameters"]["reliability"] == {"quantity": "|x1|", "levels": [0.05]}
    table = (tmp_path / "damper" / "damper_first_passage.md").read_text()
    assert "| t (s) | P(\\|x1\\| > 0.05) |" in table
    assert f"| 1 | {arrays['first_passage_dpim_probability'][0, 0]:.3g} |" in table  # DPIM: no standard error
    assert float(sf.reliability.quantity(np.array([-0.3, 0.2, 0.1, -0.4]))) == 0.3  # |x1|: both sides count
    fp = jdpim.first_passage(sf.scene, Magnitude("x1", 0), 0.05, jdpim.DPIM(n_points=32))  # the run's program
    np.testing.assert_array_equal(arrays["first_passage_dpim_probability"], fp.probability)
    assert arrays["first_passage_dpim_probability"].shape == (2, 1) and "first_passage_dpim_stderr" not in arrays
    assert 0.0 < arrays["first_passage_dpim_probability"][0, 0] < 1.0  # a level that tells something


@pytest.mark.parametrize(
    ("table", "message"),
    [
        ('quantity = "x"\nlevels = 0.1\nlevel = 0.2', "[reliability] level: unknown key; allowed keys are ['levels', "),
        ("levels = 0.1", "[reliability] quantity: is required"),
        ('quantity = "x"', "[reliability] levels: is required"),
        (
            'quantity = "y"\nlevels = 0.1',
            "[reliability] quantity: must be a coordinate of the model, one of ['x', 'v'], or its magnitude (\"|x|\"), "
            "got a string 'y'",
        ),
        ('quantity = "|y|"\nlevels = 0.1', "[reliability] quantity: must be a coordinate of the model"),
        ("quantity = 1\nlevels = 0.1", "[reliability] quantity: must be a coordinate of the model, one of ['x', 'v']"),
        ('quantity = "x"\nlevels = []', "[reliability] levels: must be a number or a non-empty array of numbers, got"),
        ('quantity = "x"\nlevels = "high"', "[reliability] levels: must be a number or a non-empty array of numbers"),
        ('quantity = "x"\nlevels = [0.1, "a"]', "[reliability] levels[1]: must be a number, got a string 'a'"),
        ('quantity = "x"\nlevels = [0.1, inf]', "[reliability] levels[1]: must be finite, got inf"),
        ('quantity = "x"\nlevels = nan', "[reliability] levels: must be finite, got nan"),
        (
            'quantity = "x"\nlevels = [0.0, 0.1]',
            "[reliability] levels: level [0.0] is at or below the lower bound of 'x' (0, a barrier)",
        ),
        ('quantity = "|v|"\nlevels = -0.1', "[reliability] levels: must lie in (0, inf), got -0.1"),
    ],
)
def test_bad_reliability_tables_fail_in_one_line_naming_file_and_key(tmp_path, capsys, table, message):
    path = tmp_path / "s.toml"
    path.write_text(f"{SCENE}\n[reliability]\n{table}\n")
    with pytest.raises(SceneFileError) as info:
        load(path)
    assert str(info.value).startswith(f"s.toml: {message}") and "\n" not in str(info.value)
    assert cli.main(["run", str(path), "--out", str(tmp_path / "out")]) == 2
    err = capsys.readouterr().err
    assert message in err and err.count("\n") == 1


def test_a_reliability_key_that_is_not_a_table(tmp_path):
    path = tmp_path / "s.toml"
    path.write_text(f"reliability = 0.1\n{SCENE}")
    with pytest.raises(SceneFileError, match=r"^s\.toml: \[reliability\]: must be a table, got a float$"):
        load(path)


def test_mdof_quantity_names_the_model_coordinates(tmp_path):
    path = tmp_path / "damper.toml"
    path.write_text((EXAMPLES / "impact_damper.toml").read_text() + '\n[reliability]\nquantity = "x"\nlevels = 0.1\n')
    with pytest.raises(
        SceneFileError,
        match=r"^damper\.toml: \[reliability\] quantity: must be a coordinate of the model, one of "
        r"\['x1', 'x2', 'v1', 'v2'\], or its magnitude \(\"\|x1\|\"\), got a string 'x'$",
    ):
        load(path)
