"""Scene files with the earthquake features: the Clough-Penzien filter, noise envelopes, the adjacent buildings and a
``[fragility]`` table; each the object the library's functions build, a run's fragility equal to ``jdpim.fragility``,
and one-line errors naming the key."""

import json

import numpy as np
import pytest

import jdpim
from jdpim import cli
from jdpim.cli._scenefile import SceneFileError, load

TAIL = """
[time]
t_end = 1.0
dt = 0.02
[method]
name = "monte_carlo"
n_samples = 16
"""
ONE_DOF = """
[model]
alpha = 0.2
gamma = "none"
barrier = "none"
r = 0.5
[noise]
D = 0.1
[time]
t_end = 2.0
dt = 0.02
[method]
name = "monte_carlo"
n_samples = 64
[output]
figures = false
densities = ["x"]
"""
FRAGILITY = '\n[fragility]\nquantity = "|x|"\nlevel = 0.4\nintensities = [0.5, 1.0, 2.0]\nconfidence = 0.9\n'


def _load(tmp_path, text: str):
    path = tmp_path / "s.toml"
    path.write_text(text)
    return load(path)


def test_adjacent_buildings_with_a_clough_penzien_filter_and_an_envelope_are_the_library_objects(tmp_path):
    sf = _load(
        tmp_path,
        '[model]\nkind = "adjacent_buildings"\nn_storeys = [2, 1]\nfrequency = [1.0, 1.5]\ngap = 0.2\n'
        '[[model.filters]]\nkind = "clough_penzien"\nomega_g = 10.0\nzeta_f = 0.7\n'
        '[noise]\nD = 0.01\nenvelope = { kind = "jennings", t1 = 0.5, t2 = 0.8 }\n' + TAIL,
    )
    built = jdpim.clough_penzien(
        jdpim.adjacent_buildings(n_storeys=(2, 1), frequency=(1.0, 1.5), gap=0.2), omega_g=10.0, zeta_f=0.7
    )
    assert sf.scene.model.coordinates == built.coordinates
    for name in ("mass", "damping", "stiffness", "gains"):
        np.testing.assert_array_equal(np.asarray(getattr(sf.scene.model, name)), np.asarray(getattr(built, name)))
    assert [float(c.position) for c in sf.scene.model.constraints] == [-0.2, -0.2][: len(built.constraints)]
    assert sf.scene.noise == jdpim.WhiteNoise(D=0.01, envelope=jdpim.Jennings(t1=0.5, t2=0.8))
    assert sf.table["model"] == {
        "kind": "adjacent_buildings",
        "n_storeys": [2, 1],
        "frequency": [1.0, 1.5],
        "damping_ratio": 0.05,
        "mass": 1.0,
        "gap": 0.2,
        "r": 0.6,
        "filters": [
            {
                "kind": "clough_penzien",
                "omega_g": 10.0,
                "zeta_g": 0.6,
                "omega_f": 1.5,
                "zeta_f": 0.7,
                "influence": "none",
            }
        ],
    }
    assert sf.table["noise"] == {"D": 0.01, "envelope": {"kind": "jennings", "t1": 0.5, "t2": 0.8, "c": 0.5}}
    free = _load(
        tmp_path, '[model]\nkind = "adjacent_buildings"\nn_storeys = 2\ngap = "none"\n[noise]\nD = 0.01\n' + TAIL
    )
    assert free.scene.model.constraints == () and free.scene.model.coordinates[:4] == ("xa1", "xa2", "xb1", "xb2")
    assert free.table["model"]["gap"] == "none" and free.table["model"]["n_storeys"] == 2


@pytest.mark.parametrize(
    ("model", "noise", "message"),
    [
        ('kind = "adjacent_buildings"\nfrequency = [1.0]', "", r"\[model\] frequency: must be one value for both"),
        ('kind = "adjacent_buildings"\nn_storeys = [1, 0]', "", r"\[model\] n_storeys\[1\]: must be an integer >= 1"),
        ('kind = "adjacent_buildings"\nsoil = 1.0', "", r"\[model\] soil: unknown key"),
        (
            'kind = "impact_damper"\n[[model.filters]]\nkind = "clough_penzien"\nomega_f = -1.0',
            "",
            r"\[model\] filters\[0\]\.omega_f: must lie in \(0, inf\), got -1",
        ),
        ("", 'envelope = { kind = "boxcar" }', r"\[noise\] envelope\.kind: must be one of \['shinozuka_sato', 'jenn"),
        ("", 'envelope = { kind = "jennings", b1 = 0.1 }', r"\[noise\] envelope\.b1: unknown key"),
        ("", 'envelope = { kind = "shinozuka_sato", b1 = 0.5, b2 = 0.1 }', r"\[noise\] envelope\.b2: must"),
    ],
)
def test_bad_earthquake_keys_fail_in_one_line_naming_the_key(tmp_path, model, noise, message):
    model = model or 'kind = "adjacent_buildings"'
    text = f"[model]\n{model}\n[noise]\nD = 0.01\n{noise}\n" + TAIL
    with pytest.raises(SceneFileError, match=r"^s\.toml: " + message) as err:
        _load(tmp_path, text)
    assert "\n" not in str(err.value)


def test_run_stores_the_fragility_curve_of_a_direct_call(tmp_path):
    path = tmp_path / "f.toml"
    path.write_text(ONE_DOF + FRAGILITY)
    assert cli.main(["run", str(path), "--out", str(tmp_path / "f"), "--quiet"]) == 0
    with np.load(tmp_path / "f" / "f.npz", allow_pickle=False) as npz:
        arrays = {k: npz[k] for k in npz.files}
    meta = json.loads((tmp_path / "f" / "f.json").read_text())
    assert meta["parameters"]["fragility"] == {
        "quantity": "|x|",
        "level": 0.4,
        "reference": 1.0,
        "confidence": 0.9,
        "intensities": [0.5, 1.0, 2.0],
    }
    assert "f_fragility.md" in meta["files"] and "fragility_wall_time_s" in meta

    model = jdpim.VibroImpactOscillator(alpha=0.2, gamma=None, barrier=None, r=0.5)
    scene = jdpim.Scene(model, noise=jdpim.WhiteNoise(D=0.1), t_end=2.0, dt=0.02)
    direct = jdpim.fragility(
        scene, lambda s: abs(s[0]), 0.4, [0.5, 1.0, 2.0], jdpim.MonteCarlo(n_samples=64, seed=0), confidence=0.9
    )
    for name in ("intensities", "probability", "probability_stderr", "lower", "upper", "median", "beta"):
        np.testing.assert_array_equal(arrays[f"fragility_{name}"], np.asarray(getattr(direct, name)), err_msg=name)
    assert 0.0 < arrays["fragility_probability"][1] < 1.0  # a level that tells something
    table = (tmp_path / "f" / "f_fragility.md").read_text()
    assert f"| 1 | {float(direct.probability[1]):.4g} |" in table and "lognormal fit: median" in table


@pytest.mark.parametrize(
    ("change", "message"),
    [
        (("level = 0.4", "level = 0.0"), r"\[fragility\] level: must lie in \(0, inf\), got 0"),
        (("[0.5, 1.0, 2.0]", "[1.0, 0.5]"), r"\[fragility\] intensities: must increase, got \[1\.0, 0\.5\]"),
        (("[0.5, 1.0, 2.0]", "[1.0]"), r"\[fragility\] intensities: must be an array of at least two"),
        (("confidence = 0.9", "confidence = 1.0"), r"\[fragility\] confidence: must lie in \(0, 1\), got 1"),
        (('quantity = "|x|"', 'quantity = "y"'), r"\[fragility\] quantity: must be a coordinate of the model"),
        (('quantity = "|x|"', 'quantity = "|x|"\nseed = 1'), r"\[fragility\] seed: unknown key"),
    ],
)
def test_bad_fragility_tables_fail_in_one_line_naming_the_key(tmp_path, change, message):
    with pytest.raises(SceneFileError, match=r"^s\.toml: " + message):
        _load(tmp_path, ONE_DOF + FRAGILITY.replace(*change))
    dpim_only = ONE_DOF.replace('name = "monte_carlo"\nn_samples = 64', 'name = "dpim"\nn_points = 8')
    with pytest.raises(SceneFileError, match=r'^s\.toml: \[fragility\]: needs the method "monte_carlo"'):
        _load(tmp_path, dpim_only + FRAGILITY)
