"""Scene files with the example systems (``kind = "impact_damper"``, ...), filters (``[[model.filters]]``) and derived
quantities in ``[reliability]``: each the model the library's functions build, and one-line errors."""

import pathlib

import numpy as np
import pytest

import jdpim
from jdpim.cli._scenefile import Linear, Magnitude, SceneFileError, load

TAIL = """
[noise]
D = 0.01
[time]
t_end = 1.0
dt = 0.02
[method]
name = "monte_carlo"
n_samples = 16
"""


def _load(tmp_path, model: str, tail: str = TAIL):
    path = tmp_path / "s.toml"
    path.write_text(f"[model]\n{model}\n{tail}")
    return load(path)


def _same_model(a, b):
    assert a.coordinates == b.coordinates and a.start == b.start
    for name in ("mass", "damping", "stiffness", "gains"):
        x, y = getattr(a, name), getattr(b, name)
        assert (x is None) == (y is None), name
        if x is not None:
            np.testing.assert_array_equal(np.asarray(x), np.asarray(y), err_msg=name)
    assert [(c.normal, float(c.position), float(c.r)) for c in a.constraints] == [
        (c.normal, float(c.position), float(c.r)) for c in b.constraints
    ]


@pytest.mark.parametrize(
    ("model", "expected", "table"),
    [
        (
            'kind = "impact_damper"\nclearance = 0.2\nr = 0.3',
            jdpim.impact_damper(clearance=0.2, r=0.3),
            {"mass_ratio": 0.05, "frequency": 1.0, "damping_ratio": 0.01, "clearance": 0.2, "r": 0.3},
        ),
        (
            'kind = "pounding_frame"\nn_storeys = 3\ngap = 0.4',
            jdpim.pounding_frame(n_storeys=3, gap=0.4),
            {"n_storeys": 3, "frequency": 1.0, "damping_ratio": 0.02, "gap": 0.4, "r": 0.6, "storey": 3},
        ),
        (
            'kind = "pounding_frame"\nn_storeys = 3\nstorey = 1',
            jdpim.pounding_frame(n_storeys=3, storey=1),
            {"n_storeys": 3, "frequency": 1.0, "damping_ratio": 0.02, "gap": 0.5, "r": 0.6, "storey": 1},
        ),
        (
            'kind = "gear_pair"\nbacklash = 0.05',
            jdpim.gear_pair(backlash=0.05),
            {"mass_ratio": 1.0, "drag": 0.05, "bearing_damping": 0.0, "backlash": 0.05, "r": 0.7},
        ),
    ],
)
def test_an_example_system_is_the_model_its_function_builds(tmp_path, model, expected, table):
    sf = _load(tmp_path, model)
    _same_model(sf.scene.model, expected)
    kind = model.split('"')[1]
    assert sf.table["model"] == {"kind": kind, **table, "filters": []}  # every argument recorded, defaults too
    assert sf.table["initial"]["x0"] == [0.0] * expected.dimension


def test_filters_apply_in_order_and_a_harmonic_filter_starts_at_one(tmp_path):
    model = """kind = "impact_damper"
[[model.filters]]
kind = "kanai_tajimi"
omega_g = 3.0
influence = [1.0, 0.0]
[[model.filters]]
kind = "harmonic"
amplitude = 0.2
frequency = 0.9
"""
    sf = _load(tmp_path, model)
    expected = jdpim.harmonic(
        jdpim.kanai_tajimi(jdpim.impact_damper(), omega_g=3.0, influence=[1.0, 0.0]), amplitude=0.2, frequency=0.9
    )
    _same_model(sf.scene.model, expected)
    assert sf.scene.model.coordinates[:4] == ("x1", "x2", "xf", "xh")
    assert sf.table["model"]["filters"] == [
        {"kind": "kanai_tajimi", "omega_g": 3.0, "zeta_g": 0.6, "influence": [1.0, 0.0]},
        {"kind": "harmonic", "amplitude": 0.2, "frequency": 0.9, "direction": "none"},
    ]
    assert sf.table["initial"]["x0"] == [0.0, 0.0, 0.0, 1.0]  # the model's start: cos(0) = 1
    np.testing.assert_array_equal(np.asarray(sf.scene.initial_state()[0]), [0.0, 0.0, 0.0, 1.0])
    first_order = _load(tmp_path, 'kind = "gear_pair"\n[[model.filters]]\nkind = "first_order"\na = 2.0').scene.model
    _same_model(first_order, jdpim.first_order_filter(jdpim.gear_pair(), a=2.0))


def test_a_derived_quantity_or_its_magnitude_is_a_reliability_quantity(tmp_path):
    tail = TAIL + "[output]\nderived = { gap = { x2 = 1.0, x1 = -1.0 }, mix = { x1 = 0.5, v2 = 2.0 } }\n"
    state = np.array([0.3, 0.1, -0.2, 0.7])
    for quantity, value in (("gap", -0.2), ("|gap|", 0.2), ("mix", 0.5 * 0.3 + 2.0 * 0.7)):
        sf = _load(tmp_path, 'kind = "impact_damper"', f'{tail}[reliability]\nquantity = "{quantity}"\nlevels = 0.05\n')
        q = sf.reliability.quantity
        assert isinstance(q, Magnitude if quantity.startswith("|") else Linear) and str(q) == quantity
        assert hash(q) == hash(load(tmp_path / "s.toml").reliability.quantity)  # a static argument of first_passage
        np.testing.assert_allclose(q(state), value, rtol=1e-12)
    assert [str(d) for d in sf.outputs.derived] == ["gap", "mix"]
    with pytest.raises(
        SceneFileError, match=r"a quantity of \[output\] derived \(\['gap', 'mix'\]\), or the magnitude"
    ):
        _load(tmp_path, 'kind = "impact_damper"', f'{tail}[reliability]\nquantity = "|gep|"\nlevels = 0.05\n')


@pytest.mark.parametrize(
    ("model", "message"),
    [
        ('kind = "impact_damper"\nclearance = -1.0', "s.toml: [model] clearance: must lie in (0, inf), got -1"),
        ('kind = "impact_damper"\nclearance = "wide"', "s.toml: [model] clearance: must be a number, got a string"),
        ('kind = "pounding_frame"\nn_storeys = 2.5', "s.toml: [model] n_storeys: must be an integer, got a float"),
        ('kind = "pounding_frame"\nn_storeys = 2\nstorey = 3', "s.toml: [model] storey: must lie in [1, 2]"),
        (
            'kind = "gear_pair"\nclearance = 0.1',
            "s.toml: [model] clearance: unknown key; allowed keys are ['backlash', 'bearing_damping', 'drag',",
        ),
        (
            'kind = "damper"',
            "s.toml: [model] kind: must be one of ['vibro_impact', 'mdof', 'impact_damper', 'pounding_frame', "
            "'gear_pair', 'adjacent_buildings'], got 'damper'",
        ),
        (
            'kind = "vibro_impact"\nr = 0.9\n[[model.filters]]\nkind = "first_order"',
            "s.toml: [model] filters: unknown key; allowed keys are ['alpha', 'barrier',",
        ),
        (
            'kind = "impact_damper"\n[[model.filters]]\nkind = "white"',
            "s.toml: [model] filters[0].kind: must be one of ['kanai_tajimi', 'clough_penzien', 'first_order', "
            "'harmonic'], got 'white'",
        ),
        (
            'kind = "impact_damper"\n[[model.filters]]\nkind = "first_order"\na = 0.0',
            "s.toml: [model] filters[0].a: must lie in (0, inf), got 0",
        ),
        (
            'kind = "impact_damper"\n[[model.filters]]\nkind = "first_order"\nomega_g = 1.0',
            "s.toml: [model] filters[0].omega_g: unknown key; allowed keys are ['a', 'kind']",
        ),
        (
            'kind = "impact_damper"\n[[model.filters]]\nkind = "harmonic"\nfrequency = 1.0',
            "s.toml: [model] filters[0].amplitude: is required",
        ),
        (
            'kind = "impact_damper"\n[[model.filters]]\nkind = "kanai_tajimi"\ninfluence = [1.0]',
            "s.toml: [model] filters[0].influence: must be an array of 2 numbers, one per coordinate, got [1.0]",
        ),
        (
            'kind = "impact_damper"\nfilters = 3',
            "s.toml: [model] filters: must be an array of tables [[model.filters]]",
        ),
    ],
)
def test_bad_systems_and_filters_fail_in_one_line_naming_the_key(tmp_path, model, message):
    with pytest.raises(SceneFileError) as info:
        _load(tmp_path, model)
    assert message in str(info.value) and "\n" not in str(info.value)


def test_the_pounding_frame_example_parses_as_documented():
    sf = load(pathlib.Path(__file__).parents[1] / "examples" / "pounding_frame.toml")
    expected = jdpim.kanai_tajimi(jdpim.pounding_frame(n_storeys=2, gap=0.3, r=0.6), omega_g=3.0, zeta_g=0.6)
    _same_model(sf.scene.model, expected)
    assert sf.outputs.derived == (Linear("drift", ((1, 1.0), (0, -1.0))),)
    assert sf.reliability.quantity == Magnitude("drift", Linear("drift", ((1, 1.0), (0, -1.0))))
    assert sf.reliability.levels == (0.2, 0.3) and sf.scene.save_at == (10.0, 40.0)
