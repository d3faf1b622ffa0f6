"""Contract: a force term is one class plus one registry line.

Two throwaway terms are registered inside the tests (the registry is restored after each): a per-pair linear
``tether`` (``F = -k d``) and a ``wind`` with a per-particle area and a per-model pressure vector. With nothing
but their class and a registry entry they must reach the YAML loader (keys, values, one-line errors naming the
field), the builder, the model (attributes, pickling), the fingerprint (changed by their data only), the forces
(``make_force_terms``, the naive reference), random scenes and the partition on 2 ranks.
"""

from __future__ import annotations

import pickle

import numpy as np
import pytest

from helpers import fd_jacobians, random_scene
from springsim import ModelBuilder
from springsim.distributed.partition import partition
from springsim.errors import SceneError, SceneTypeError
from springsim.forces import FORCE_TERMS, ArraySpec, BlockLayout, Blocks, ForceTerm, dense_jacobians, eval_forces
from springsim.forces import make_force_terms
from springsim.forces._base import PairIncidence, active_pairs
from springsim.forces.naive import naive_forces
from springsim.scene import load_scene


class ForceTether(ForceTerm):
    """Linear tethers ``F = -k (q_i - q_j)`` (zero rest length): a throwaway pair term."""

    name = "tether"
    pairwise = True
    conservative = True
    yaml_key = "tethers"
    data = (ArraySpec("k", per="pair", unit="N/m", lo=0.0, required=True, sample=(1.0, 10.0), doc="stiffness"),)

    def __init__(self, pairs, k):
        self.pairs, self.k = pairs, k
        self.incidence = PairIncidence(pairs)
        self.layout_q = BlockLayout.pairs(pairs)
        self._blocks = -k[:, None, None] * np.eye(3)

    @classmethod
    def from_model(cls, model, *, skip_fixed=True, kernels="auto"):
        keep = active_pairs(model.tether_indices, model.particle_fixed, skip_fixed)
        keep = keep[model.tether_k[keep] > 0]
        return cls(model.tether_indices[keep], model.tether_k[keep]) if keep.size else None

    @classmethod
    def naive_force(cls, model, q, qd):
        f = np.zeros_like(q)
        ij = model.tether_indices
        ft = -model.tether_k[:, None] * (q[ij[:, 0]] - q[ij[:, 1]])
        np.add.at(f, ij[:, 0], ft)
        np.add.at(f, ij[:, 1], -ft)
        return f

    def eval_force(self, q, qd, f_out, *, damping_geometry=None):
        self.incidence.scatter(-self.k[:, None] * self.incidence.diff(q), f_out)

    def eval_jacobians(self, q, qd, mode="exact", *, work=None, damping_geometry=None):
        return Blocks(self.layout_q, self._blocks), None

    def potential_energy(self, q):
        d = self.incidence.diff(q)
        return 0.5 * float(np.dot(self.k, np.einsum("ij,ij->i", d, d)))


class ForceWind(ForceTerm):
    """A constant wind: ``F_i = a_i p`` with a per-particle area ``a_i`` and a per-model pressure vector ``p``."""

    name = "wind"
    external = True
    conservative = True
    data = (ArraySpec("wind_area", per="particle", unit="m^2", lo=0.0, sample=(0.1, 1.0), doc="area"),
            ArraySpec("pressure", per="model", shape=(3,), unit="N/m^2", yaml_key="pressure", sample=(-2.0, 2.0),
                      doc="pressure vector"))

    def __init__(self, index, force):
        self.index, self.force = index, force

    @classmethod
    def from_model(cls, model, *, skip_fixed=True, kernels="auto"):
        use = model.particle_wind_area > 0
        if skip_fixed:
            use &= ~model.particle_fixed
        index = np.flatnonzero(use)
        if index.size == 0 or not np.any(model.wind_pressure):
            return None
        return cls(index, model.particle_wind_area[index, None] * model.wind_pressure)

    @classmethod
    def naive_force(cls, model, q, qd):
        return model.particle_wind_area[:, None] * model.wind_pressure[None, :]

    def eval_force(self, q, qd, f_out, *, damping_geometry=None):
        f_out[self.index] += self.force

    def potential_energy(self, q):
        return -float(np.sum(self.force * q[self.index]))

    def potential_floor(self):
        return -np.inf


@pytest.fixture
def registered(monkeypatch):
    """The throwaway terms registered (one line each, as a new term would be); the registry restored after."""
    monkeypatch.setitem(FORCE_TERMS, "tether", ForceTether)
    monkeypatch.setitem(FORCE_TERMS, "wind", ForceWind)
    yield
    assert "tether" in FORCE_TERMS  # monkeypatch removes them after the test


SCENE = """
solver: {type: implicit_euler, timestep: 0.01, gravity: 0}
particles:
  - {pos: [0, 0, 0], mass: 1, fixed: true}
  - {pos: [1, 0, 0], mass: 2, wind_area: 0.5}
  - {pos: [1, 1, 0], mass: 1, drag: 0.1}
springs:
  - {particle_ids: [0, 1], stiffness: 10}
tethers:
  - {particle_ids: [1, 2], k: 3}
  - {particle_ids: [0, 2], k: 4.5}
wind: {pressure: [1, 0, -2]}
"""


def _built():
    """The model of SCENE through the builder."""
    b = ModelBuilder(gravity=0.0)
    b.add_particles([[0, 0, 0], [1, 0, 0], [1, 1, 0]], None, [1, 2, 1], fixed=[True, False, False],
                    wind_area=[0, 0.5, 0], drag=[0, 0, 0.1])
    b.add_springs([[0, 1]], 10.0)
    assert b.add_pairs("tether", [[1, 2], [0, 2]], k=[3.0, 4.5]) == range(0, 2)
    assert b.pair_count("tether") == 2
    b.set_term_data("wind", pressure=[1.0, 0.0, -2.0])
    return b.finalize()


def test_yaml_loader_reads_the_terms_keys(registered):
    """The term's YAML keys come from its declarations: a pair list, a particle key, a per-model mapping."""
    m = load_scene(SCENE).model
    np.testing.assert_array_equal(m.tether_indices, [[1, 2], [0, 2]])
    np.testing.assert_array_equal(m.tether_k, [3.0, 4.5])
    assert m.tether_count == 2 and m.spring_count == 1
    np.testing.assert_array_equal(m.particle_wind_area, [0.0, 0.5, 0.0])
    np.testing.assert_array_equal(m.wind_pressure, [1.0, 0.0, -2.0])
    assert set(m.terms) >= {"tether", "wind"} and m.terms["tether"]["k"] is m.tether_k
    assert not m.tether_k.flags.writeable and not m.wind_pressure.flags.writeable
    assert repr(m).endswith("tethers=2)")


def test_run_summary_counts_the_terms_pairs(registered):
    """The run summary lists every term with a pair list, by its label (default its YAML key)."""
    from springsim.cli.runner import _model_rows

    rows = dict(_model_rows(load_scene(SCENE)))
    assert rows["tethers"] == "2" and rows["springs"] == "1" and rows["gravitational pairs"] == "0"


@pytest.mark.parametrize("edit, message", [
    (("k: 3}", "k: -3}"), "tethers[0].k: must be >= 0, got -3"),
    (("k: 3}", "k: .nan}"), "tethers[0].k: must be finite, got nan"),
    (("k: 3}", "k: soft}"), "tethers[0].k: must be a number, got a string 'soft'"),
    (("{particle_ids: [1, 2], k: 3}", "{particle_ids: [1, 2]}"), "tethers[0]: missing required key 'k'"),
    (("k: 3}", "k: 3, rest: 1}"), "tethers[0]: unknown key 'rest'; allowed: particle_ids, k"),
    (("[1, 2], k: 3", "[1, 7], k: 3"), "tethers[0].particle_ids: particle id out of range [0, 3), got [1, 7]"),
    (("wind_area: 0.5", "wind_area: -1"), "particles[1].wind_area: must be >= 0, got -1"),
    (("wind_area: 0.5", "wind_area: [1]"), "particles[1].wind_area: must be a number, got a list [1]"),
    (("[1, 0, -2]", "[1, 0]"), "wind.pressure: must have 3 components, got 2"),
    (("[1, 0, -2]", "[1, .inf, -2]"), "wind.pressure: must be finite, got [1, inf, -2]"),
    (("{pressure: [1, 0, -2]}", "{pressur: 1}"), "wind: unknown key 'pressur'; allowed: pressure"),
])
def test_yaml_errors_name_the_field(registered, edit, message):
    """A bad value of the term is a one-line SceneError naming the field, as for the built-in terms."""
    with pytest.raises(SceneError) as e:
        load_scene(SCENE.replace(*edit))
    text = str(e.value)
    assert "\n" not in text and text.startswith(message), text


def test_unknown_top_level_key_lists_the_terms_keys(registered):
    with pytest.raises(SceneError, match=r"allowed: solver, particles, springs, gravitational, tethers, wind, plot"):
        load_scene(SCENE + "tethrs: []\n")


def test_builder_takes_the_terms_data(registered):
    """The builder's generic calls give the model the YAML gives; their errors name the field."""
    m = _built()
    assert m.fingerprint() == load_scene(SCENE).model.fingerprint()
    b = ModelBuilder()
    b.add_particles(np.zeros((2, 3)), None, 1.0)
    with pytest.raises(SceneTypeError, match=r"^tethers\.k: missing: give k"):
        b.add_pairs("tether", [[0, 1]])
    with pytest.raises(TypeError, match="unexpected keyword argument 'kk'"):
        b.add_pairs("tether", [[0, 1]], kk=1.0)
    with pytest.raises(TypeError, match="unexpected keyword argument 'area'"):
        b.add_particles(np.zeros((1, 3)), area=1.0)
    with pytest.raises(ValueError, match="not a registered force term with per-pair data"):
        b.add_pairs("wind", [[0, 1]])
    with pytest.raises(SceneError, match=r"^wind\.pressure: must have shape \(3,\)"):
        b.set_term_data("wind", pressure=[1.0, 2.0])
    b.add_pairs("tether", [[0, 1], [1, 0]], k=[1.0, -2.0])
    with pytest.raises(SceneError, match=r"^tethers\[1\]\.k: must be >= 0, got -2$"):
        b.finalize()


def test_model_keeps_the_terms_data_through_pickle_and_keywords(registered):
    m = _built()
    clone = pickle.loads(pickle.dumps(m))
    assert clone.fingerprint() == m.fingerprint() and not clone.tether_k.flags.writeable
    np.testing.assert_array_equal(clone.wind_pressure, m.wind_pressure)
    again = type(m)(m.particle_q, m.particle_qd, m.particle_mass, m.particle_radius, m.particle_fixed,
                    spring_indices=m.spring_indices, spring_stiffness=m.spring_stiffness,
                    spring_damping=m.spring_damping, spring_rest_length=m.spring_rest_length,
                    particle_drag=m.particle_drag, tether_indices=m.tether_indices, tether_k=m.tether_k,
                    particle_wind_area=m.particle_wind_area, wind_pressure=m.wind_pressure, gravity=0.0)
    assert again.fingerprint() == m.fingerprint()


def test_fingerprint_hashes_a_terms_data_only_where_a_model_has_some(monkeypatch):
    """Registering a term leaves the fingerprint of every model without its data as it was; its data changes it."""
    plain = random_scene(np.random.default_rng(5))
    before = plain.fingerprint()
    monkeypatch.setitem(FORCE_TERMS, "tether", ForceTether)
    monkeypatch.setitem(FORCE_TERMS, "wind", ForceWind)
    rebuilt = random_scene(np.random.default_rng(5), select=lambda cls: cls not in (ForceTether, ForceWind))
    assert rebuilt.tether_count == 0 and not rebuilt.particle_wind_area.any()
    assert plain.fingerprint() == rebuilt.fingerprint() == before
    m = _built()
    kw = dict(particle_q=m.particle_q, particle_qd=m.particle_qd, particle_mass=m.particle_mass,
              particle_fixed=m.particle_fixed, gravity=0.0)
    terms = {name: dict(data) for name, data in m.terms.items()}
    without = type(m)(**kw, terms={k: v for k, v in terms.items() if k not in ("tether", "wind")})
    unused = without.fingerprint()
    prints = {m.fingerprint(), unused,
              type(m)(**kw, terms={**terms, "tether": dict(terms["tether"], k=[3.0, 4.0])}).fingerprint(),
              type(m)(**kw, terms={**terms, "wind": dict(terms["wind"], pressure=[1.0, 0.0, 2.0])}).fingerprint(),
              type(m)(**kw, terms={**terms, "wind": dict(terms["wind"], wind_area=[0, 0.5, 0.1])}).fingerprint()}
    assert len(prints) == 5
    monkeypatch.delitem(FORCE_TERMS, "tether")
    monkeypatch.delitem(FORCE_TERMS, "wind")
    assert without.fingerprint() == unused == type(m)(**kw, terms={k: v for k, v in terms.items()
                                                                   if k not in ("tether", "wind")}).fingerprint()


def test_forces_and_the_naive_reference_include_the_terms(registered):
    m = _built()
    terms = make_force_terms(m)
    assert [t.name for t in terms] == ["drag", "spring", "tether", "wind"]
    q = m.particle_q + np.random.default_rng(3).normal(scale=0.1, size=m.particle_q.shape)
    qd = np.random.default_rng(4).normal(size=q.shape)
    free = ~m.particle_fixed
    np.testing.assert_allclose(eval_forces(terms, q, qd)[free], naive_forces(m, q, qd)[free], rtol=0, atol=1e-12)
    tether = [t for t in terms if t.name == "tether"]
    for J, F in zip(dense_jacobians(tether, q, qd), fd_jacobians(tether, q, qd)):
        np.testing.assert_allclose(J, F, rtol=0, atol=1e-7)


def test_random_scenes_exercise_the_terms(registered):
    """random_scene draws a registered term's data from its declarations: every term is present."""
    m = random_scene(np.random.default_rng(11))
    names = {t.name for t in make_force_terms(m)}
    assert {"tether", "wind", "spring", "gravitational", "drag", "gravity"} <= names
    internal = random_scene(np.random.default_rng(11), select=lambda cls: not cls.external)
    assert {t.name for t in make_force_terms(internal)} == {"spring", "gravitational", "tether"}


@pytest.mark.parametrize("size", [2])
def test_partition_keeps_the_terms_on_every_rank(registered, size):
    """On 2 ranks every tether is owned by one rank (re-indexed with its arrays), the wind data follow their
    particles, and the ranks' forces add up to the serial ones."""
    m = random_scene(np.random.default_rng(12), n=10)
    q = m.particle_q + np.random.default_rng(13).normal(scale=0.05, size=m.particle_q.shape)
    qd = np.random.default_rng(14).normal(size=q.shape)
    ref = eval_forces(make_force_terms(m), q, qd)
    total = np.zeros_like(ref)
    owned_tethers = []
    for r in range(size):
        p = partition(m, size, r)
        pm, om = p.pair_model, p.particle_model
        sel = p.owned_pairs["tether"]
        owned_tethers.append(sel)
        np.testing.assert_array_equal(p.local_particles[pm.tether_indices], m.tether_indices[sel])
        np.testing.assert_array_equal(pm.tether_k, m.tether_k[sel])
        own = p.local_particles[:p.n_own]
        np.testing.assert_array_equal(om.particle_wind_area, m.particle_wind_area[own])
        np.testing.assert_array_equal(om.wind_pressure, m.wind_pressure)
        assert not pm.particle_wind_area.any() and om.tether_count == 0
        ql, vl = q[p.local_particles], qd[p.local_particles]
        f = np.zeros_like(ql)
        for t in make_force_terms(pm):
            assert t.pairwise
            t.eval_force(ql, vl, f)
        for t in make_force_terms(om):
            assert not t.pairwise
            t.eval_force(ql[:p.n_own], vl[:p.n_own], f[:p.n_own])
        np.add.at(total, p.local_particles[:p.n_local_free], f[:p.n_local_free])
    fixed = m.particle_fixed
    ij = m.tether_indices
    active = np.flatnonzero(~(fixed[ij[:, 0]] & fixed[ij[:, 1]]))
    assert active.size and np.array_equal(np.sort(np.concatenate(owned_tethers)), active)
    free = ~fixed
    assert np.abs(total[free] - ref[free]).max() <= 1e-12 * np.abs(ref).max()
    assert any(t.name == "wind" for t in make_force_terms(m))


def test_registry_rejects_clashing_data_names(monkeypatch):
    """Two terms claiming one model attribute are refused when the model's names are resolved."""
    class Clash(ForceWind):
        name = "clash"

    monkeypatch.setitem(FORCE_TERMS, "wind", ForceWind)
    monkeypatch.setitem(FORCE_TERMS, "clash", Clash)
    with pytest.raises(ValueError, match="'particle_wind_area' is already taken by wind"):
        ModelBuilder().finalize()
    monkeypatch.delitem(FORCE_TERMS, "clash")

    class Free(ForceTether):
        name = "free"

    monkeypatch.setitem(FORCE_TERMS, "free", Free)  # free_count is the model's own
    with pytest.raises(ValueError, match="'free_count' is already taken by the model"):
        ModelBuilder().finalize()


def test_dissipation_coefficients_are_declared(registered):
    """``Model.dissipates`` reads the arrays declared ``dissipative`` (spring damping, drag), whatever the terms."""
    assert _built().dissipates()  # the drag of particle 2
    b = ModelBuilder()
    b.add_particles(np.eye(3), None, 1.0, wind_area=0.3)
    b.add_springs([[0, 1]], 10.0)
    b.add_pairs("tether", [[1, 2]], k=1.0)
    assert not b.finalize().dissipates()
    b.add_springs([[1, 2]], 10.0, 0.5)
    assert b.finalize().dissipates()


def test_benchmark_reference_key_sees_the_terms_data(registered):
    """The benchmarks' reference-cache key covers a new term's data (a cached reference never answers for a model
    that differs only in it), and stays what it was for models without such data."""
    from benchmarks.common import _model_key

    m = _built()
    assert [name for name, _ in m.data_beyond_v1()] == ["tether.indices", "tether.k", "wind.wind_area",
                                                        "wind.pressure"]
    terms = {name: dict(data) for name, data in m.terms.items()}
    other = type(m)(m.particle_q, m.particle_qd, m.particle_mass, particle_fixed=m.particle_fixed, gravity=0.0,
                    terms={**terms, "wind": dict(terms["wind"], pressure=[0.0, 1.0, 0.0])})
    assert _model_key(m, 1.0, "auto", 1e-10) != _model_key(other, 1.0, "auto", 1e-10)
    assert random_scene(np.random.default_rng(5), select=lambda c: c not in (ForceTether, ForceWind)
                        ).data_beyond_v1() == []


def test_yaml_keys_of_terms_must_be_free(monkeypatch):
    """A term whose YAML key the format (or another term) already uses is a registration error, not a silent
    shadowing."""
    class Plot(ForceTether):
        name = "plotter"
        yaml_key = "plot"

    monkeypatch.setitem(FORCE_TERMS, "plotter", Plot)
    with pytest.raises(ValueError, match="top-level YAML key 'plot'"):
        load_scene(SCENE)
