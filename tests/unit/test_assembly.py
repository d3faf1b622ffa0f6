"""The two-phase sparse assembler against the dense identity-row reference."""

from __future__ import annotations

import numpy as np
import pytest

from helpers import random_scene
from springsim import ModelBuilder
from springsim.assembly import (SystemAssembler, condense, dense_system, dense_system_free, expand,
                                free_dofs)
from springsim.forces import JACOBIAN_MODES, make_force_terms
from springsim.linsolve import make_linear_solver


def _assembler(model):
    return SystemAssembler(model, make_force_terms(model))


def _state(model, rng, scale=0.1):
    q = model.particle_q + rng.uniform(-scale, scale, model.particle_q.shape)
    qd = rng.normal(size=q.shape)
    qd[model.particle_fixed] = 0.0
    return q, qd


def _free_pairs(model):
    """Unique unordered free-free pairs of all pairwise items (springs and G > 0 pairs)."""
    pairs = np.concatenate([model.spring_indices, model.gravitational_indices[model.gravitational_G > 0]])
    free = ~model.particle_fixed
    pairs = pairs[free[pairs[:, 0]] & free[pairs[:, 1]]]
    return np.unique(np.sort(pairs, axis=1), axis=0)


@pytest.mark.parametrize("ab", [(1e-4, 1e-2), (1.0, 1.0)], ids=["h=0.01", "a=b=1"])
@pytest.mark.parametrize("mode", JACOBIAN_MODES)
def test_sparse_equals_dense_reference(mode, ab):
    """The assembled BSR matrix equals the dense identity-row reference on free DOFs (<= 1e-12 |A|)."""
    rng = np.random.default_rng(911)
    a, b = ab
    for _ in range(4):
        model = random_scene(rng, n=int(rng.integers(5, 12)), fixed=int(rng.integers(2, 4)))
        q, qd = _state(model, rng)
        A = _assembler(model).assemble(q, qd, a, b, mode).toarray()
        D = dense_system_free(model, q, qd, a, b, mode=mode)
        assert A.shape == D.shape == (model.dof_count, model.dof_count)
        assert np.abs(A - D).max() <= 1e-12 * np.linalg.norm(D, 2)


def test_storage_proportional_to_pairs():
    """nnzb == F + 2 * (unique free-free pairs); the matrix covers free DOFs only."""
    rng = np.random.default_rng(912)
    for _ in range(5):
        model = random_scene(rng, n=10, springs=15, fixed=3)
        asm = _assembler(model)
        F = model.free_count
        assert asm.pattern.nnzb == F + 2 * _free_pairs(model).shape[0]
        A = asm.assemble(*_state(model, rng), 1e-4, 1e-2)
        assert A.bsr.shape == (3 * F, 3 * F) and A.bsr.blocksize == (3, 3)
        assert A.bsr.data.shape == (asm.pattern.nnzb, 3, 3)
        np.testing.assert_array_equal(asm.free, np.flatnonzero(~model.particle_fixed))


def test_no_block_touches_a_fixed_particle():
    """Every stored block couples two free particles; coupling to fixed ones is dropped."""
    rng = np.random.default_rng(913)
    model = random_scene(rng, n=10, fixed=4)
    asm = _assembler(model)
    bsr = asm.assemble(*_state(model, rng), 1e-4, 1e-2).bsr
    rows = np.repeat(np.arange(bsr.shape[0] // 3), np.diff(bsr.indptr))
    stored = np.stack([asm.free[rows], asm.free[bsr.indices]], 1)
    assert not model.particle_fixed[stored].any()
    expected = {tuple(p) for p in _free_pairs(model)} | {tuple(p[::-1]) for p in _free_pairs(model)}
    expected |= {(i, i) for i in asm.free}
    assert {tuple(p) for p in stored} == expected


def _chain(extra_fixed_springs=0, duplicate=False):
    """A 5-particle chain with particles 0 and 4 fixed, optionally with fixed-fixed springs."""
    b = ModelBuilder(gravity=-9.81)
    b.add_particles(np.c_[np.arange(5.0), np.zeros(5), 0.1 * np.arange(5.0) ** 2], None,
                    [1.0, 0.5, 0.7, 0.9, 1.0], drag=0.2, fixed=[True, False, False, False, True])
    ke = np.array([30.0, 40.0, 50.0, 60.0])
    kd = np.array([0.5, 0.0, 1.0, 0.3])
    ij = np.array([[0, 1], [1, 2], [2, 3], [3, 4]])
    if duplicate:  # spring 2-3 split into two identical halves
        b.add_springs(ij, np.where(np.arange(4) == 2, ke / 2, ke), np.where(np.arange(4) == 2, kd / 2, kd), 0.9)
        b.add_spring(2, 3, ke=ke[2] / 2, kd=kd[2] / 2, rest_length=0.9)
    else:
        b.add_springs(ij, ke, kd, 0.9)
    for _ in range(extra_fixed_springs):
        b.add_spring(0, 4, ke=1e3, kd=2.0)
        b.add_gravitational(4, 0, G=5.0)
    return b.finalize()


def test_fixed_fixed_pairs_add_nothing():
    """Springs and gravitational pairs between two fixed particles change neither pattern nor values."""
    rng = np.random.default_rng(914)
    plain, extra = _chain(), _chain(extra_fixed_springs=3)
    a1, a2 = _assembler(plain), _assembler(extra)
    assert a1.pattern.nnzb == a2.pattern.nnzb
    assert a1.value_count == a2.value_count  # pruned before any value is computed
    q, qd = _state(plain, rng)
    for mode in JACOBIAN_MODES:
        np.testing.assert_array_equal(a1.assemble(q, qd, 1e-4, 1e-2, mode).toarray(),
                                      a2.assemble(q, qd, 1e-4, 1e-2, mode).toarray())


def test_duplicate_springs_sum():
    """Two identical springs between the same pair act as one with summed ke and kd."""
    rng = np.random.default_rng(915)
    single, split = _chain(), _chain(duplicate=True)
    a1, a2 = _assembler(single), _assembler(split)
    assert a1.pattern.nnzb == a2.pattern.nnzb
    q, qd = _state(single, rng)
    for mode in JACOBIAN_MODES:
        A1 = a1.assemble(q, qd, 1e-4, 1e-2, mode).toarray()
        A2 = a2.assemble(q, qd, 1e-4, 1e-2, mode).toarray()
        assert np.abs(A1 - A2).max() <= 1e-14 * np.abs(A1).max()


def test_scalar_views_follow_every_assembly():
    """tocsr() and tocsc() equal bsr.toarray() after each (re)assembly, not just the first."""
    rng = np.random.default_rng(916)
    model = random_scene(rng)
    asm = _assembler(model)
    for mode in JACOBIAN_MODES * 2:
        A = asm.assemble(*_state(model, rng), 1e-4, 1e-2, mode)
        ref = A.bsr.toarray()
        np.testing.assert_array_equal(A.tocsr().toarray(), ref)
        np.testing.assert_array_equal(A.tocsc().toarray(), ref)
        assert A.tocsr().format == "csr" and A.tocsc().format == "csc"


def test_matrix_object_and_pattern_are_reused():
    """Re-assembly updates the same SystemMatrix/BSR in place; pattern arrays never change."""
    rng = np.random.default_rng(917)
    model = random_scene(rng)
    asm = _assembler(model)
    A1 = asm.assemble(*_state(model, rng), 1e-4, 1e-2)
    bsr, data, indices, indptr = A1.bsr, A1.bsr.data, A1.bsr.indices.copy(), A1.bsr.indptr.copy()
    ids = (id(A1.bsr.indices), id(A1.bsr.indptr))
    v1, first = A1.version, A1.toarray()
    A2 = asm.assemble(*_state(model, rng), 4e-4, 2e-2)
    assert A2 is A1 and A2.bsr is bsr and A2.bsr.data is data
    assert (id(A2.bsr.indices), id(A2.bsr.indptr)) == ids
    np.testing.assert_array_equal(A2.bsr.indices, indices)
    np.testing.assert_array_equal(A2.bsr.indptr, indptr)
    assert A2.version == v1 + 1
    assert not np.array_equal(A2.toarray(), first)


def test_assemble_rejects_unknown_mode():
    """An unknown Jacobian mode is an error, not a silent default."""
    model = _chain()
    with pytest.raises(ValueError, match="jacobian mode"):
        _assembler(model).assemble(model.particle_q, model.particle_qd, 1.0, 1.0, "bogus")


@pytest.mark.parametrize("mode", JACOBIAN_MODES)
def test_condense_expand_equals_identity_rows(mode):
    """Elimination (condense, solve, expand) gives the identity-row dense solution; so does the sparse path."""
    rng = np.random.default_rng(918)
    for _ in range(3):
        model = random_scene(rng, fixed=3)
        q, qd = _state(model, rng)
        n3 = 3 * model.particle_count
        rhs = rng.normal(size=n3)
        A, r = dense_system(model, q, qd, 1e-4, 1e-2, rhs=rhs, mode=mode)
        x_identity = np.linalg.solve(A, r)
        free = free_dofs(model.particle_fixed)
        assert np.all(x_identity[np.setdiff1d(np.arange(n3), free)] == 0.0)
        x_elim = expand(np.linalg.solve(*condense(A, rhs, free)), free, n3)
        assert np.linalg.norm(x_elim - x_identity) <= 1e-12 * np.linalg.norm(x_identity)
        S = _assembler(model).assemble(q, qd, 1e-4, 1e-2, mode)
        x_sparse = expand(make_linear_solver("direct").solve(S, rhs[free]).x, free, n3)
        assert np.linalg.norm(x_sparse - x_identity) <= 1e-10 * np.linalg.norm(x_identity)


def test_gather_scatter_roundtrip():
    """gather takes the free rows of an (N, 3) array; scatter_add adds back into them only."""
    rng = np.random.default_rng(919)
    model = random_scene(rng)
    asm = _assembler(model)
    x = rng.normal(size=(model.particle_count, 3))
    g = asm.gather(x)
    np.testing.assert_array_equal(g, x[~model.particle_fixed].reshape(-1))
    y = np.zeros_like(x)
    asm.scatter_add(y, g, 2.0)
    np.testing.assert_array_equal(y[~model.particle_fixed], 2 * x[~model.particle_fixed])
    assert np.all(y[model.particle_fixed] == 0)


@pytest.mark.parametrize("damping", [True, False], ids=["damped", "undamped"])
@pytest.mark.parametrize("mode", JACOBIAN_MODES)
def test_symmetric_flag_is_truthful(mode, damping):
    """``SystemMatrix.symmetric`` is True exactly when the assembled matrix is symmetric."""
    rng = np.random.default_rng(920)
    model = random_scene(rng, damping=damping)
    A = _assembler(model).assemble(*_state(model, rng), 1e-4, 1e-2, mode)
    D = A.toarray()
    is_sym = np.abs(D - D.T).max() <= 1e-14 * np.abs(D).max()
    assert A.symmetric == is_sym
    assert A.symmetric == (mode != "exact" or not damping)


def test_spd_mode_is_positive_definite():
    """In ``spd`` mode the assembled system is symmetric positive definite (Cholesky succeeds) at any h."""
    rng = np.random.default_rng(921)
    for h in (1e-3, 0.1, 10.0):
        model = random_scene(rng)
        A = _assembler(model).assemble(*_state(model, rng, scale=0.3), h * h, h, "spd").toarray()
        np.linalg.cholesky(A)


def test_mass_only_system():
    """Without Jacobians (a = b = 0) the system is the free particles' mass matrix."""
    rng = np.random.default_rng(922)
    model = random_scene(rng)
    A = _assembler(model).assemble(*_state(model, rng), 0.0, 0.0).toarray()
    np.testing.assert_array_equal(A, np.diag(np.repeat(model.particle_mass[~model.particle_fixed], 3)))


def test_scatter_add_in_place_and_fallback():
    """``_scatter_add`` adds S @ X into Y: in place for a contiguous Y, by the public product otherwise."""
    import scipy.sparse as sp

    from springsim.assembly.assemble import _scatter_add

    rng = np.random.default_rng(0)
    S = sp.random(7, 11, density=0.4, format="csr", random_state=1)
    X = rng.standard_normal((11, 9))
    Y0 = rng.standard_normal((7, 9))
    Y = Y0.copy()
    _scatter_add(S, X, Y)
    np.testing.assert_allclose(Y, Y0 + S @ X, rtol=1e-14, atol=1e-14)
    Z = np.zeros((9, 7)).T  # not C-contiguous: the kernel would write into a copy
    _scatter_add(S, X, Z)
    np.testing.assert_allclose(Z, S @ X, rtol=1e-14, atol=1e-14)


@pytest.mark.parametrize("mode", JACOBIAN_MODES)
def test_term_workspaces_match_fresh_evaluation_and_are_reused(mode):
    """With a ``work`` dict every term's Jacobians equal a fresh evaluation, on every call and
    for changing states; the assembler's repeated assemblies reuse the same temporaries (no
    large allocation per assembly) and still equal the dense reference."""
    rng = np.random.default_rng(923)
    model = random_scene(rng, n=10)
    terms = make_force_terms(model)
    works = {id(t): {} for t in terms}
    for _ in range(3):
        q, qd = _state(model, rng)
        for t in terms:
            fresh = t.eval_jacobians(q, qd, mode)
            works[id(t)].pop("mixed_from", None)  # mixed: a first linearisation, as the fresh one
            kept = t.eval_jacobians(q, qd, mode, work=works[id(t)])
            for a, b in zip(fresh, kept):
                assert (a is None) == (b is None)
                if a is not None:
                    np.testing.assert_array_equal(a.values, b.values)
    assert any(works.values()), "no term kept a temporary"
    asm = _assembler(model)
    asm.assemble(*_state(model, rng), 1e-4, 1e-2, mode)
    buffers = {(k, name): id(a) for k, w in asm._work.items() for name, a in w.items() if name != "mixed_from"}
    assert buffers
    for _ in range(2):
        q, qd = _state(model, rng)
        if mode == "mixed":
            asm.linearize_at(q)  # continuing from q itself is the spd linearisation, as the dense reference
        A = asm.assemble(q, qd, 1e-4, 1e-2, mode).toarray()
        assert {(k, name): id(a) for k, w in asm._work.items() for name, a in w.items()
                if name != "mixed_from"} == buffers
        D = dense_system_free(model, q, qd, 1e-4, 1e-2, mode=mode)
        assert np.abs(A - D).max() <= 1e-12 * np.linalg.norm(D, 2)
