"""Adjacent buildings pounding: the frames, the closing of the gap, the probability of pounding as a first
passage on the scene without contact, symmetric buildings, refusals."""

import pathlib

import jax
import numpy as np
import pytest

import jdpim

ENVELOPE = jdpim.ShinozukaSato(b1=0.2, b2=1.0)
GAP = 0.05


def ground(model):
    """The ground motion of these tests: Kanai-Tajimi filtered white noise."""
    return jdpim.kanai_tajimi(model, omega_g=15.6, zeta_g=0.6)


def scene_of(model):
    return jdpim.Scene(model, noise=jdpim.WhiteNoise(0.01, envelope=ENVELOPE), t_end=6.0, dt=0.01)


def test_the_frames():
    model = jdpim.adjacent_buildings(
        n_storeys=(3, 2), frequency=(1.0, 2.0), damping_ratio=(0.05, 0.02), mass=(2.0, 1.0)
    )
    assert model.coordinates[:5] == ("xa1", "xa2", "xa3", "xb1", "xb2")
    M, C, K = (np.asarray(m) for m in (model.mass, model.damping, model.stiffness))
    assert not M[:3, 3:].any() and not K[:3, 3:].any() and not C[:3, 3:].any()  # coupled only by impacts
    for block, w, zeta in ((slice(0, 3), 1.0, 0.05), (slice(3, 5), 2.0, 0.02)):
        modes = np.linalg.eigvals(np.linalg.solve(M[block, block], K[block, block]))
        w1 = np.sqrt(modes.real.min())
        assert w1 == pytest.approx(w, rel=1e-12)
        assert C[block, block] == pytest.approx(2.0 * zeta / w * K[block, block])  # zeta in the first mode
    np.testing.assert_array_equal(np.asarray(model.gains)[:, 0], -np.diag(M))  # the ground acceleration
    assert [c.normal for c in model.constraints] == [(-1.0, 0.0, 0.0, 1.0, 0.0), (0.0, -1.0, 0.0, 0.0, 1.0)]
    assert all(c.position == -0.1 for c in model.constraints)
    # building a of unit storey mass is the frame of pounding_frame
    frame, alone = jdpim.adjacent_buildings(n_storeys=2, frequency=1.0, damping_ratio=0.02), jdpim.pounding_frame(2)
    np.testing.assert_array_equal(np.asarray(frame.stiffness)[:2, :2], np.asarray(alone.stiffness))
    np.testing.assert_array_equal(np.asarray(frame.damping)[:2, :2], np.asarray(alone.damping))
    assert jdpim.adjacent_buildings(gap=None).constraints == ()


def test_first_impact_is_the_first_passage_without_contact():
    """Until the first impact a path does not feel the gap: the probability of an impact by the end of the record
    (with contact) equals that of the closing's first passage on the scene without contact, path for path
    (the same seed), and the impact speeds have a density: its bins cover every impact speed (eight of 0.05 up to
    0.4 and one up to 2, far beyond the fastest impact of 20 runs of 200 paths, 0.6), so it integrates to one."""
    contact = ground(jdpim.adjacent_buildings(frequency=(2 * np.pi, 1.4 * np.pi), gap=GAP))
    free = scene_of(contact.replace(constraints=()))
    mc = jdpim.MonteCarlo(n_samples=200, seed=0)
    fp = jdpim.first_passage(free, jdpim.systems.closing(contact), [GAP, 2 * GAP], mc)
    edges = np.append(np.linspace(0.0, 0.4, 9), 2.0)
    st = jdpim.impact_statistics(scene_of(contact), mc, speed_edges=edges)
    assert 0.1 < float(fp.probability[-1, 0]) < 0.9 and float(fp.probability[-1, 1]) < float(fp.probability[-1, 0])
    assert float(st.probability[-1]) == pytest.approx(float(fp.probability[-1, 0]), abs=1.5 / 200)
    density = np.asarray(st.speed_density[-1])
    assert float(np.sum(density * np.diff(edges))) == pytest.approx(1.0, abs=1e-5)  # float32 sums


def test_symmetric_buildings_never_pound():
    """Identical buildings under a common ground motion from rest move as one: the closing stays zero (to
    rounding) on every path, so they never pound (the first passage of the test above, compiled once)."""
    contact = ground(jdpim.adjacent_buildings(frequency=2 * np.pi, gap=GAP))
    free = scene_of(contact.replace(constraints=()))
    fp = jdpim.first_passage(free, jdpim.systems.closing(contact), [1e-5, 1e-3], jdpim.MonteCarlo(200, seed=0))
    np.testing.assert_array_equal(np.asarray(fp.probability), 0.0)
    moving = jdpim.first_passage(free, lambda s: abs(s[0]), [1e-5, 1e-3], jdpim.MonteCarlo(200, seed=0))
    assert float(moving.probability[-1, 1]) == 1.0  # while each building moves by centimetres


def test_refusals():
    with pytest.raises(ValueError, match=r"^n_storeys must be one integer or two"):
        jdpim.adjacent_buildings(n_storeys=(1, 2, 3))
    with pytest.raises(ValueError, match=r"^n_storeys must be an integer >= 1, got 0"):
        jdpim.adjacent_buildings(n_storeys=(0, 2))
    with pytest.raises(ValueError, match=r"^frequency must lie in \(0, inf\), got -1.0"):
        jdpim.adjacent_buildings(frequency=(1.0, -1.0))
    with pytest.raises(ValueError, match=r"^mass must be one number or two"):
        jdpim.adjacent_buildings(mass=(1.0,))
    with pytest.raises(ValueError, match=r"^gap must lie in \(0, inf\), got 0.0"):
        jdpim.adjacent_buildings(gap=0.0)
    with pytest.raises(ValueError, match=r"^r must lie in \[0, 1\], got 1.5"):
        jdpim.adjacent_buildings(r=1.5)
    with pytest.raises(ValueError, match=r"^model has no constraints"):
        jdpim.systems.closing(jdpim.adjacent_buildings(gap=None))
    with pytest.raises(TypeError, match=r"^model must be a jdpim.MDOFOscillator"):
        jdpim.systems.closing(jdpim.VibroImpactOscillator())


def test_the_example_scene_file_is_the_free_pair():
    """examples/adjacent_buildings.toml is adjacent_buildings(gap=None) under modulated Clough-Penzien ground motion,
    and its reliability and fragility quantity is the closing."""
    from jdpim.cli._scenefile import load

    sf = load(pathlib.Path(__file__).parents[1] / "examples" / "adjacent_buildings.toml")
    built = jdpim.clough_penzien(jdpim.adjacent_buildings(frequency=(2 * np.pi, 2.5 * np.pi), gap=None))
    for name in ("mass", "damping", "stiffness", "gains"):
        np.testing.assert_array_equal(np.asarray(getattr(sf.scene.model, name)), np.asarray(getattr(built, name)))
    assert sf.scene.noise.envelope == jdpim.ShinozukaSato(0.2, 0.6)
    contact = jdpim.clough_penzien(jdpim.adjacent_buildings(frequency=(2 * np.pi, 2.5 * np.pi), gap=0.1))
    state = jax.numpy.arange(1.0, 9.0)
    assert float(sf.fragility.quantity(state)) == float(jdpim.systems.closing(contact)(state))
    assert float(sf.reliability.quantity(state)) == float(jdpim.systems.closing(contact)(state))
