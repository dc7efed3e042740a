"""Scene files of several degrees of freedom (``kind = "mdof"``): the example, a run equal to ``jdpim.solve`` on
the same scene built by hand, and one-line errors naming the file and the key."""

import json
import pathlib

import numpy as np
import pytest

import jdpim
from jdpim import cli
from jdpim.cli._scenefile import SceneFileError, load

EXAMPLE = pathlib.Path(__file__).parents[1] / "examples" / "impact_damper.toml"
COORDINATES = ("x1", "x2", "v1", "v2")
# small settings; the damper starts moving so that it hits the clearance's ends before the first saved time
SMALL = (
    ("t_end = 50.0", "t_end = 2.0"),
    ("dt = 0.01", "dt = 0.02"),
    ("save_at = [10.0, 50.0]", "save_at = [1.0, 2.0]"),
    ("n_points = 2000", "n_points = 32"),
    ("n_samples = 4000", "n_samples = 64"),
    ("[output]", "[initial]\nv0 = [0.5, 0.0]\n\n[output]"),
)
GAP = ("[output]", "[output]\nderived = { gap = { x2 = 1.0, x1 = -1.0 } }")  # the relative displacement


def _write(tmp_path, *changes, name="damper.toml") -> pathlib.Path:
    """The example with small settings and each ``(old, new)`` of ``changes`` replaced once."""
    text = EXAMPLE.read_text()
    for old, new in SMALL + changes:
        assert old in text, old
        text = text.replace(old, new, 1)
    path = tmp_path / name
    path.write_text(text)
    return path


def test_the_example_parses_as_documented():
    sf = load(EXAMPLE)
    model = sf.scene.model
    assert isinstance(model, jdpim.MDOFOscillator) and model.coordinates == COORDINATES
    assert model.mass == ((1.0, 0.0), (0.0, 0.05))
    np.testing.assert_array_equal(model.damping, [[0.02, 0.0], [0.0, 0.0]])
    np.testing.assert_array_equal(model.stiffness, [[1.0, 0.0], [0.0, 0.0]])
    assert [(c.normal, float(c.position), float(c.r)) for c in model.constraints] == [
        ((-1.0, 1.0), -0.1, 0.5),
        ((1.0, -1.0), -0.1, 0.5),
    ]
    assert float(sf.scene.noise.D) == 0.01 and sf.scene.save_at == (10.0, 50.0) and sf.scene.dt == 0.01
    assert [(m.name, m.n_paths) for m in sf.methods] == [("dpim", 2000), ("monte_carlo", 4000)]
    assert sf.outputs.marginals == COORDINATES and sf.outputs.joint == (("x1", "x2"),)
    assert sf.table["initial"] == {"x0": [0.0, 0.0], "v0": [0.0, 0.0]}  # at rest by default


def test_run_stores_every_coordinate_and_equals_solve_on_the_scene_built_by_hand(tmp_path):
    path = _write(tmp_path, GAP)
    assert cli.main(["run", str(path), "--out", str(tmp_path / "out"), "--quiet"]) == 0
    out = tmp_path / "out"
    with np.load(out / "damper.npz", allow_pickle=False) as npz:
        arrays = {k: npz[k] for k in npz.files}
    meta = json.loads((out / "damper.json").read_text())
    pngs = [f"damper_marginal_{c}.png" for c in (*COORDINATES, "gap")] + ["damper_joint_x1_x2.png"]
    assert sorted(meta["files"]) == sorted(["damper.npz", "damper_timing.csv", "damper.json", *pngs])
    assert all((out / f).is_file() for f in meta["files"])
    assert meta["parameters"]["model"]["names"] == ["x1", "x2"]
    assert meta["parameters"]["output"]["derived"] == {"gap": {"x2": 1.0, "x1": -1.0}}
    assert (out / "damper_timing.csv").read_text().splitlines()[1] == "method,paths,steps,wall_s,cpu_s"

    model = jdpim.MDOFOscillator(
        mass=np.diag([1.0, 0.05]),
        gains=[[1.0], [0.0]],
        damping=np.diag([0.02, 0.0]),
        stiffness=np.diag([1.0, 0.0]),
        constraints=(jdpim.Barrier((-1.0, 1.0), -0.1, 0.5), jdpim.Barrier((1.0, -1.0), -0.1, 0.5)),
    )
    scene = jdpim.Scene(
        model, noise=jdpim.WhiteNoise(D=0.01), v0=np.array([0.5, 0.0]), t_end=2.0, dt=0.02, save_at=(1.0, 2.0)
    )
    joint = (arrays["x1_grid_joint"], arrays["x2_grid_joint"])
    for name, method in (("dpim", jdpim.DPIM(n_points=32)), ("monte_carlo", jdpim.MonteCarlo(n_samples=64, seed=0))):
        res = jdpim.solve(scene, method)
        assert res.bounds(lambda s: s[1] - s[0]) == pytest.approx((-0.1, 0.1))  # the gap, from the constraints
        for i, t in enumerate(scene.save_at):
            for c in COORDINATES:
                grid = arrays[f"{c}_grid"]
                assert grid.shape == (201,) and np.all(np.diff(grid) > 0)
                close = {"rtol": 1e-5, "atol": 1e-6 * arrays[f"{name}_pdf_{c}"].max()}
                np.testing.assert_allclose(arrays[f"{name}_pdf_{c}"][i], res.pdf(c, grid, t), **close)
                if name == "monte_carlo":
                    np.testing.assert_allclose(arrays[f"{name}_stderr_{c}"][i], res.pdf_error(c, grid, t), **close)
            np.testing.assert_allclose(
                arrays[f"{name}_joint_x1_x2"][i], res.joint_pdf(("x1", "x2"), joint, t), rtol=1e-5, atol=1e-6
            )
            gap, grid = (lambda s: s[1] - s[0]), arrays["gap_grid"]  # the derived quantity: x2 - x1
            assert grid[0] < 0 < grid[-1] and np.all(np.diff(grid) > 0)
            close = {"rtol": 1e-5, "atol": 1e-6 * arrays[f"{name}_pdf_gap"].max()}
            np.testing.assert_allclose(arrays[f"{name}_pdf_gap"][i], res.pdf(gap, grid, t), **close)
            if name == "monte_carlo":
                np.testing.assert_allclose(arrays[f"{name}_stderr_gap"][i], res.pdf_error(gap, grid, t), **close)
    assert "dpim_stderr_x1" not in arrays  # DPIM points are not independent samples


@pytest.mark.parametrize(
    ("changes", "message"),
    [
        (
            [("position = -0.1\nr = 0.5\n\n[noise]", "position = -0.1\nr = 1.5\n\n[noise]")],
            "damper.toml: [model] constraints[1].r: must lie in [0, 1], got 1.5",
        ),
        (
            [("mass = [[1.0, 0.0], [0.0, 0.05]]", "mass = [[1.0, 0.0], [0.0, -0.05]]")],
            "damper.toml: [model] mass: must be symmetric positive definite, got [[1.0, 0.0], [0.0, -0.05]]",
        ),
        (
            [("mass = [[1.0, 0.0], [0.0, 0.05]]", "mass = [[1.0, 0.0]]")],
            "damper.toml: [model] mass: must be a square (n, n) matrix, got shape (1, 2)",
        ),
        (
            [("mass = [[1.0, 0.0], [0.0, 0.05]]", 'mass = [[1.0, "a"], [0.0, 0.05]]')],
            "damper.toml: [model] mass[0,1]: must be a number, got a string 'a'",
        ),
        (
            [("damping = [[0.02, 0.0], [0.0, 0.0]]", "damping = [[0.02, 0.0, 0.0], [0.0, 0.0, 0.0]]")],
            "damper.toml: [model] damping: must be a matrix of shape (2, 2), got shape [2, 3]",
        ),
        (
            [("gains = [[1.0], [0.0]]", "gains = [[1.0], [0.0, 1.0]]")],
            "damper.toml: [model] gains: must be a matrix: its rows have [1, 2] entries",
        ),
        (
            [("normal = [-1.0, 1.0]", "normal = [-1.0, 1.0, 0.0]")],
            "damper.toml: [model] constraints[0].normal: must be an array of 2 numbers, one per coordinate, got "
            "[-1.0, 1.0, 0.0]",
        ),
        (
            [("normal = [-1.0, 1.0]", "normal = [0.0, 0.0]")],
            "damper.toml: [model] constraints[0].normal: must not be zero",
        ),
        (
            [("normal = [-1.0, 1.0]", "normal = [-1.0, 1.0]\nrr = 0.5")],
            "damper.toml: [model] constraints[0].rr: unknown key; allowed keys are ['normal', 'position', 'r']",
        ),
        (
            [('kind = "mdof"', 'kind = "mdof"\nalpha = 0.1')],
            "damper.toml: [model] alpha: unknown key; allowed keys are ['constraints', 'damping', 'filters', 'gains', "
            "'kind', 'mass', 'names', 'stiffness']",
        ),
        (
            [('kind = "mdof"', 'kind = "mdof"\nnames = ["x", "v"]')],
            "damper.toml: [model] names: give the coordinates ['x', 'v', 'v', 'v_v'], with repeats",
        ),
        (
            [("D = 0.01", "D = [[0.01, 0.0], [0.0, 0.01]]")],
            "damper.toml: [noise] D: must be a (1, 1) matrix, a row and a column per noise source (column of [model] "
            "gains), got shape (2, 2)",
        ),
        (
            [
                ("gains = [[1.0], [0.0]]", "gains = [[1.0, 0.0], [0.0, 1.0]]"),
                ("D = 0.01", "D = [[0.01, 0.02], [0.02, 0.01]]"),
            ],
            "damper.toml: [noise] D: must be positive definite",
        ),
        (
            [("gains = [[1.0], [0.0]]", "gains = [[1.0, 0.0], [0.0, 1.0]]")],
            "damper.toml: [noise] D: must be a (2, 2) matrix, a row and a column per noise source (column of [model] "
            "gains), got a float 0.01",
        ),
        (
            [("v0 = [0.5, 0.0]", "v0 = [0.5]")],
            "damper.toml: [initial] v0: must be an array of 2 numbers, one per coordinate, got [0.5]",
        ),
        (
            [("v0 = [0.5, 0.0]", "v0 = [0.5, 0.0]\nx0 = [0.0, 0.5]")],
            "damper.toml: [initial] x0: x0=[0.0, 0.5] violates constraints[1]",
        ),
        (
            [('densities = ["x1", "x2", "v1", "v2"]', 'densities = ["x1", "x3"]')],
            "damper.toml: [output] densities: must be one of ['x1', 'x2', 'v1', 'v2'], got 'x3'",
        ),
        (
            [GAP, ("gap = { x2 = 1.0, x1 = -1.0 }", "gap = { x2 = 1.0, x3 = -1.0 }")],
            "damper.toml: [output] derived.gap.x3: must be a coordinate of the model, one of ['x1', 'x2', 'v1', 'v2']",
        ),
        (
            [GAP, ("gap = { x2 = 1.0, x1 = -1.0 }", "x1 = { x2 = 1.0 }")],
            "damper.toml: [output] derived.x1: must be a name (a letter, then letters, digits or _) other than the "
            "coordinates",
        ),
        (
            [GAP, ("gap = { x2 = 1.0, x1 = -1.0 }", "gap = { x2 = 1.0, x1 = true }")],
            "damper.toml: [output] derived.gap.x1: must be a number, got a boolean True",
        ),
        (
            [GAP, ("gap = { x2 = 1.0, x1 = -1.0 }", "gap = 1.0")],
            "damper.toml: [output] derived.gap: must be a table of names, each a table of coefficients by coordinate",
        ),
        (
            [('joint = [["x1", "x2"]]', 'joint = [["x1", "x1"]]')],
            "damper.toml: [output] joint[0]: must be a pair of distinct coordinates from ['x1', 'x2', 'v1', 'v2']",
        ),
    ],
)
def test_bad_mdof_scene_files_fail_in_one_line_naming_file_and_key(tmp_path, capsys, changes, message):
    path = _write(tmp_path, *changes)
    with pytest.raises(SceneFileError) as info:
        load(path)
    assert message in str(info.value) and "\n" not in str(info.value)
    assert cli.main(["run", str(path), "--out", str(tmp_path / "out")]) == 2
    err = capsys.readouterr().err
    assert message in err and err.count("\n") == 1


def test_a_joint_key_of_one_degree_of_freedom_points_to_densities(tmp_path):
    path = tmp_path / "s.toml"
    text = (EXAMPLE.parent / "reference.toml").read_text()
    path.write_text(text.replace('densities = ["x", "v", "joint"]', 'joint = [["x", "v"]]'))
    with pytest.raises(SceneFileError, match=r'\[output\] joint: applies to kind = "mdof"; for one degree of freedom'):
        load(path)
