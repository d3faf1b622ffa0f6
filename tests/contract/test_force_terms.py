"""Contract tests of every registered force term (parametrised over FORCE_TERMS).

A new term registered in :data:`springsim.forces.FORCE_TERMS` is checked here with
no new test code, provided :func:`helpers.random_scene` exercises it.
"""

from __future__ import annotations

import numpy as np
import pytest

from helpers import assert_matches_fd, fd_jacobians, random_scene
from springsim.forces import FORCE_TERMS, JACOBIAN_MODES, dense_jacobians, eval_forces, make_force_terms

FD_RTOL = 1e-6
TERMS = sorted(FORCE_TERMS)


def _term(name, model, skip_fixed=True):
    term = FORCE_TERMS[name].from_model(model, skip_fixed=skip_fixed)
    assert term is not None, f"random_scene must exercise the registered term {name!r} (extend tests/helpers.py)"
    return term


def _perturbed(model, rng, scale=0.05):
    """A random configuration near the model's (springs stretched and compressed)."""
    q = model.particle_q + rng.uniform(-scale, scale, model.particle_q.shape)
    qd = model.particle_qd + rng.uniform(-0.5, 0.5, model.particle_q.shape)
    return q, qd


@pytest.mark.parametrize("damping", [True, False], ids=["damped", "undamped"])
@pytest.mark.parametrize("skip_fixed", [True, False], ids=["skip_fixed", "all_pairs"])
@pytest.mark.parametrize("name", TERMS)
def test_exact_jacobians_match_finite_differences(name, skip_fixed, damping):
    """Exact dF/dq and dF/dqd equal central finite differences (rel. error <= 1e-6) on random scenes."""
    rng = np.random.default_rng(731)
    for trial in range(3):
        model = random_scene(rng, damping=damping)
        term = _term(name, model, skip_fixed)
        q, qd = _perturbed(model, rng)
        jq, jqd = dense_jacobians([term], q, qd, "exact")
        fq, fqd = fd_jacobians([term], q, qd)
        for J, F in ((jq, fq), (jqd, fqd)):
            assert_matches_fd(J, F, FD_RTOL)


@pytest.mark.parametrize("mode", [m for m in JACOBIAN_MODES if m != "exact"])
@pytest.mark.parametrize("name", TERMS)
def test_approximate_modes_are_symmetric_and_dissipative(name, mode):
    """``symmetric``/``spd`` Jacobians are symmetric; in ``spd`` mode -dF/dq and -dF/dqd are PSD."""
    rng = np.random.default_rng(732)
    model = random_scene(rng)
    term = _term(name, model)
    # strong compression exercises the clamped transverse coefficient of springs
    q, qd = _perturbed(model, rng, scale=0.3)
    jq, jqd = dense_jacobians([term], q, qd, mode)
    for J in (jq, jqd):
        scale = max(np.abs(J).max(), 1.0)
        assert np.abs(J - J.T).max() <= 1e-13 * scale
    if mode == "spd":
        for J in (jq, jqd):
            lam = np.linalg.eigvalsh(-0.5 * (J + J.T))
            assert lam.min() >= -1e-10 * max(np.abs(lam).max(), 1.0)


@pytest.mark.parametrize("name", TERMS)
def test_symmetric_mode_is_exact_when_exact_is_symmetric(name):
    """Where the exact Jacobians are already symmetric (no damping), ``symmetric`` mode equals ``exact``."""
    rng = np.random.default_rng(736)
    model = random_scene(rng, damping=False)
    term = _term(name, model)
    q, qd = _perturbed(model, rng)
    exact = dense_jacobians([term], q, qd, "exact")
    for J in exact:
        assert np.abs(J - J.T).max() <= 1e-13 * max(np.abs(J).max(), 1.0)
    for J, E in zip(dense_jacobians([term], q, qd, "symmetric"), exact):
        np.testing.assert_array_equal(J, E)


@pytest.mark.parametrize("mode", JACOBIAN_MODES)
@pytest.mark.parametrize("name", TERMS)
def test_block_shapes_and_layouts(name, mode):
    """Jacobian blocks are (k, 3, 3) on the term's constant layout, or None exactly where it has no layout."""
    rng = np.random.default_rng(733)
    model = random_scene(rng)
    term = _term(name, model)
    q, qd = _perturbed(model, rng)
    for blocks, layout in zip(term.eval_jacobians(q, qd, mode), (term.layout_q, term.layout_qd)):
        if layout is None:
            assert blocks is None
            continue
        assert blocks.layout is layout
        assert blocks.values.shape == (layout.value_count, 3, 3)
        k = layout.rows.shape[0]
        assert layout.cols.shape == layout.src.shape == layout.sign.shape == (k,)
        assert blocks.blocks.shape == (k, 3, 3)
        assert np.all(np.isfinite(blocks.values))
        n = model.particle_count
        assert layout.rows.min() >= 0 and layout.rows.max() < n and layout.cols.max() < n


@pytest.mark.parametrize("name", TERMS)
def test_no_dependence_where_no_layout(name):
    """A term without a q (qd) layout has a force independent of q (qd)."""
    rng = np.random.default_rng(734)
    model = random_scene(rng)
    term = _term(name, model)
    q, qd = _perturbed(model, rng)
    f0 = eval_forces([term], q, qd)
    q2, qd2 = _perturbed(model, rng)
    if term.layout_q is None:
        assert np.array_equal(eval_forces([term], q2, qd), f0)
    if term.layout_qd is None:
        assert np.array_equal(eval_forces([term], q, qd2), f0)


@pytest.mark.parametrize("name", TERMS)
def test_forces_finite_and_accumulated(name):
    """``eval_force`` accumulates into ``f_out`` (adds, never overwrites) and gives finite values."""
    rng = np.random.default_rng(735)
    model = random_scene(rng)
    term = _term(name, model)
    q, qd = _perturbed(model, rng)
    base = rng.normal(size=q.shape)
    out = base.copy()
    term.eval_force(q, qd, out)
    alone = np.zeros_like(q)
    term.eval_force(q, qd, alone)
    assert np.all(np.isfinite(alone))
    np.testing.assert_allclose(out, base + alone, rtol=0, atol=1e-12 * max(1.0, np.abs(alone).max()))


# -- the seed's two-particle cases -----------------------------------------------------------
SEED_CASES = {
    "spring_only": dict(ke=40.0),
    "damping_only": dict(kd=1.5),
    "spring_and_damping": dict(ke=40.0, kd=1.5),
    "gravitational": dict(G=2.0),
    "drag": dict(drag=0.8),
    "everything": dict(ke=40.0, kd=1.5, G=2.0, drag=0.8, gravity=-9.81),
}


@pytest.mark.parametrize("rest_length", [0.0, 0.7, 1.5], ids=["l0_zero", "stretched", "compressed"])
@pytest.mark.parametrize("case", sorted(SEED_CASES))
def test_two_particle_seed_cases(case, rest_length):
    """Two-particle seed cases: exact Jacobians equal finite differences (rel. error <= 1e-6)."""
    from helpers import two_particle_scene
    from springsim.forces import make_force_terms

    model = two_particle_scene(rest_length=rest_length, **SEED_CASES[case])
    terms = make_force_terms(model)
    q, qd = model.particle_q.copy(), model.particle_qd.copy()
    jq, jqd = dense_jacobians(terms, q, qd, "exact")
    fq, fqd = fd_jacobians(terms, q, qd)
    for J, F in ((jq, fq), (jqd, fqd)):
        assert_matches_fd(J, F, FD_RTOL)


@pytest.mark.parametrize("mode", JACOBIAN_MODES)
@pytest.mark.parametrize("name", list(FORCE_TERMS))
def test_declared_symmetry_is_honest(name, mode):
    """A term that declares its matrix contribution symmetric in a mode delivers a symmetric one; the assembler's
    flag is the conjunction of the declarations (damped springs in exact mode are the non-symmetric case)."""
    from springsim.assembly import SystemAssembler

    model = random_scene(np.random.default_rng(20261202))
    (term,) = [t for t in make_force_terms(model) if t.name == name]  # random_scene exercises every term
    A = SystemAssembler(model, [term]).assemble(model.particle_q, model.particle_qd, 0.3, 0.7, mode)
    D = A.toarray()
    symmetric = np.allclose(D, D.T, rtol=0, atol=1e-12 * max(np.abs(D).max(), 1.0))
    if term.jacobian_symmetric(mode):
        assert symmetric and A.symmetric
    elif name == "spring":
        assert mode == "exact" and not symmetric and not A.symmetric


@pytest.mark.parametrize("name", TERMS)
def test_naive_force_is_the_reference_of_eval_force(name):
    """Every term's ``naive_force`` (the independent reference that :func:`springsim.forces.naive.naive_forces`
    sums) equals its ``eval_force`` on every particle (items between fixed particles kept)."""
    rng = np.random.default_rng(737)
    model = random_scene(rng)
    term = _term(name, model, skip_fixed=False)
    q, qd = _perturbed(model, rng)
    ref = FORCE_TERMS[name].naive_force(model, q, qd)
    f = eval_forces([term], q, qd)
    np.testing.assert_allclose(f, ref, rtol=0, atol=1e-13 * max(np.abs(ref).max(), 1.0))


@pytest.mark.parametrize("name", TERMS)
def test_declared_data_is_consistent(name):
    """A term's declared arrays have distinct names, defaults within their bounds and a YAML key; a term with
    per-pair arrays is pairwise and external terms are not (pairwise forces are equal and opposite)."""
    cls = FORCE_TERMS[name]
    names = [s.name for s in cls.data]
    assert len(set(names)) == len(names)
    for spec in cls.data:
        assert spec.key.isidentifier() and spec.unit is not None
        if not spec.computed:
            assert spec.in_bounds(np.array([spec.default]))[0] or spec.required
        lo, hi = spec.sample_range()
        assert spec.in_bounds(np.array([lo, hi])).all()
    if any(s.per == "pair" for s in cls.data):
        assert cls.pairwise and not cls.external
