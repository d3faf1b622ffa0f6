"""Model and builder numerics: immutability, states, rest lengths, bulk adds; fixed particles never move."""

from __future__ import annotations

import numpy as np
import pytest

from helpers import random_scene
from springsim import ModelBuilder, simulate
from springsim.integrators import INTEGRATORS, make_integrator

ARRAYS = ("particle_q", "particle_qd", "particle_mass", "particle_radius", "particle_drag", "particle_fixed",
          "spring_indices", "spring_stiffness", "spring_damping", "spring_rest_length",
          "gravitational_indices", "gravitational_G")


@pytest.mark.parametrize("name", ARRAYS)
def test_model_arrays_are_read_only(name):
    """Every model array is read-only."""
    model = random_scene(np.random.default_rng(1101))
    a = getattr(model, name)
    assert isinstance(a, np.ndarray) and not a.flags.writeable
    with pytest.raises(ValueError):
        a[...] = 0


def _assert_immutable(model, original):
    """Every array of ``model`` refuses writes and ``setflags(write=True)``, and equals ``original``'s."""
    for name in ARRAYS + ("gravitational_softening",):
        a = getattr(model, name)
        assert not a.flags.writeable, name
        with pytest.raises(ValueError):
            a.setflags(write=True)
        with pytest.raises(ValueError):
            a[...] = 0
        np.testing.assert_array_equal(a, getattr(original, name))


def test_model_stays_immutable_through_pickle_and_copies():
    """Pickling, copy.copy and copy.deepcopy give models whose arrays stay unwritable (no setflags(write=True))."""
    import copy
    import pickle

    model = random_scene(np.random.default_rng(1103))
    _assert_immutable(model, model)
    for clone in (pickle.loads(pickle.dumps(model)), copy.deepcopy(model), copy.copy(model)):
        assert type(clone) is type(model) and clone.fingerprint() == model.fingerprint()
        assert clone.metadata == model.metadata and clone.cloth_grids == model.cloth_grids
        _assert_immutable(clone, model)


def test_model_does_not_share_the_callers_arrays():
    """Writing to the arrays a Model was built from, or to any array's base, cannot change the model."""
    import dataclasses

    model = random_scene(np.random.default_rng(1104))
    kw = {f.name: getattr(model, f.name) for f in dataclasses.fields(model)}
    mine = {name: np.array(getattr(model, name)) for name in ARRAYS}
    rebuilt = type(model)(**{**kw, **mine})
    for name in ARRAYS:
        mine[name][...] = 0
        base = getattr(rebuilt, name).base
        while isinstance(base, np.ndarray):
            with pytest.raises(ValueError):
                base.setflags(write=True)
            base = base.base
    _assert_immutable(rebuilt, model)


def test_model_is_frozen():
    """Model attributes cannot be rebound."""
    model = random_scene(np.random.default_rng(1102))
    with pytest.raises(AttributeError):
        model.gravity = 0.0


def test_state_copies():
    """model.state() returns fresh writable copies; changing them leaves the model untouched."""
    model = random_scene(np.random.default_rng(1103))
    s = model.state()
    q0 = model.particle_q.copy()
    assert s.particle_q is not model.particle_q and s.particle_q.flags.writeable
    s.particle_q += 1.0
    s.particle_qd += 1.0
    np.testing.assert_array_equal(model.particle_q, q0)
    s2 = model.state()
    np.testing.assert_array_equal(s2.particle_q, q0)
    c = s2.copy()
    c.particle_q[0] = 99.0
    assert s2.particle_q[0, 0] != 99.0


def test_counts_and_free_dofs():
    """Counts, free particles and the DOF count follow the fixed flags."""
    model = random_scene(np.random.default_rng(1104), n=9, fixed=3)
    assert model.particle_count == 9 and model.free_count == 6 and model.dof_count == 18
    np.testing.assert_array_equal(model.free_particles, np.flatnonzero(~model.particle_fixed))


def test_rest_length_none_is_initial_distance():
    """rest_length=None (or NaN in bulk) takes the initial distance; a given value is kept."""
    b = ModelBuilder()
    b.add_particles(np.array([[0.0, 0, 0], [3.0, 4.0, 0], [0, 0, 2.0]]), None, 1.0)
    b.add_spring(0, 1, ke=10.0)
    b.add_spring(0, 2, ke=10.0, rest_length=0.5)
    b.add_springs([[1, 2], [0, 1]], 10.0, 0.0, [np.nan, 0.0])
    model = b.finalize()
    np.testing.assert_allclose(model.spring_rest_length, [5.0, 0.5, np.sqrt(9 + 16 + 4), 0.0])


def test_bulk_add_matches_single_adds():
    """add_particles/add_springs/add_gravitationals give the same model as one-by-one adds."""
    rng = np.random.default_rng(1105)
    n = 6
    pos, vel = rng.normal(size=(n, 3)), rng.normal(size=(n, 3))
    mass, drag = rng.uniform(0.1, 1, n), rng.uniform(0, 1, n)
    fixed = np.array([True, False, False, True, False, False])
    ij = np.array([[0, 1], [1, 2], [2, 3], [4, 5], [5, 0]])
    ke, kd = rng.uniform(1, 10, 5), rng.uniform(0, 1, 5)
    l0 = np.array([np.nan, 0.3, np.nan, 1.0, 0.0])
    gij, gG = np.array([[1, 4], [2, 5]]), np.array([0.5, 2.0])

    single = ModelBuilder(gravity=-3.0)
    for k in range(n):
        single.add_particle(pos[k], vel[k], mass[k], drag=drag[k], fixed=bool(fixed[k]))
    for k in range(5):
        single.add_spring(*ij[k], ke=ke[k], kd=kd[k], rest_length=None if np.isnan(l0[k]) else l0[k])
    for k in range(2):
        single.add_gravitational(*gij[k], G=gG[k])
    bulk = ModelBuilder(gravity=-3.0)
    bulk.add_particles(pos, vel, mass, drag=drag, fixed=fixed)
    bulk.add_springs(ij, ke, kd, l0)
    bulk.add_gravitationals(gij, gG)
    a, b = single.finalize(), bulk.finalize()
    for name in ARRAYS:
        np.testing.assert_array_equal(getattr(a, name), getattr(b, name), err_msg=name)


def test_fixed_particles_have_zero_velocity():
    """A fixed particle's initial velocity is forced to zero."""
    b = ModelBuilder()
    b.add_particle((0, 0, 0), (1.0, 2.0, 3.0), mass=1.0, fixed=True)
    b.add_particle((1, 0, 0), (1.0, 2.0, 3.0), mass=1.0)
    model = b.finalize()
    np.testing.assert_array_equal(model.particle_qd, [[0, 0, 0], [1.0, 2.0, 3.0]])


@pytest.mark.parametrize("name", sorted(INTEGRATORS))
def test_fixed_particles_never_move(name):
    """Under every registered integrator, fixed particles keep their position and zero velocity."""
    rng = np.random.default_rng(1106)
    model = random_scene(rng, n=8, fixed=3, ke=(10.0, 50.0), G=(0.01, 0.05), speed=0.5)
    opts = {"on_nonconvergence": "ignore"} if INTEGRATORS[name].implicit else {}
    tr = simulate(model, make_integrator(name, model, **opts), 0.005, 20)
    fixed = model.particle_fixed
    assert np.all(tr.q[:, fixed] == model.particle_q[fixed])
    assert np.all(tr.qd[:, fixed] == 0.0)
    assert np.abs(tr.q[-1, ~fixed] - model.particle_q[~fixed]).max() > 0  # the others do move


def test_fingerprints_of_existing_models_are_unchanged():
    """The fingerprint of a model is the one it had before force terms declared their data (saved trajectories and
    the reference cache record it): the former fields are hashed first, in their order, whatever is registered."""
    from springsim.scene import benchmark_cloth

    b = ModelBuilder()
    i = b.add_particle((0, 0, 1), mass=0.1, fixed=True)
    j = b.add_particle((0, 0, 0), mass=0.1, drag=0.2)
    b.add_spring(i, j, stiffness=100.0, damping=0.5)
    b.add_gravitational(0, 1, G=1.0)
    assert b.finalize().fingerprint() == "745df68cb61f2ca0cf8f511a2619fc719176585df47e921b9361c2d28911e0ea"
    assert benchmark_cloth(8).fingerprint().startswith("39348fa4421e5cc3")


def test_models_pickled_before_term_data_load():
    """A model pickled by an earlier springsim (``_rebuild`` with the former fields, ``particle_drag``, ``spring_*``,
    ``gravitational_*``, as keywords) unpickles to the same model, fingerprint included."""
    from springsim.model import FINGERPRINT_V1, _rebuild

    model = random_scene(np.random.default_rng(1106))
    old = {name: np.array(getattr(model, name)) for name in FINGERPRINT_V1}
    old.update(gravity=model.gravity, up_axis=model.up_axis, pair_epsilon=model.pair_epsilon,
               cloth_grids=model.cloth_grids, metadata=dict(model.metadata))
    clone = _rebuild(type(model), old)
    assert clone.fingerprint() == model.fingerprint()
    _assert_immutable(clone, model)
