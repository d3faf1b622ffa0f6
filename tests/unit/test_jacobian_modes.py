"""Jacobian modes: ``exact``, ``symmetric`` (no damping position term) and ``spd``
(projected local blocks) on scenes with compressed springs and close gravitational pairs."""

from __future__ import annotations

import numpy as np
import pytest

from springsim.assembly import SystemAssembler
from springsim.forces import dense_jacobians, make_force_terms
from springsim.model.builder import ModelBuilder

H = 1.0 / 60.0


def _compressed_scene(rng, n=10):
    """Random particles, springs compressed to half their rest length, close gravitational pairs."""
    b = ModelBuilder(gravity=-9.81)
    pos = rng.uniform(-0.5, 0.5, (n, 3))
    b.add_particles(pos, rng.uniform(-1, 1, (n, 3)), rng.uniform(0.01, 0.1, n))
    i = np.arange(n)
    pairs = np.concatenate([np.stack([i, (i + 1) % n], 1), np.stack([i, (i + 3) % n], 1)])
    rest = 2.0 * np.linalg.norm(pos[pairs[:, 0]] - pos[pairs[:, 1]], axis=1)
    b.add_springs(pairs, rng.uniform(1e3, 1e4, len(pairs)), rng.uniform(0.5, 5.0, len(pairs)), rest)
    b.add_gravitationals(np.stack([i, (i + 2) % n], 1), 50.0)
    return b.finalize()


def _system(model, mode, a=H * H, b=H):
    asm = SystemAssembler(model, make_force_terms(model))
    return asm.assemble(model.particle_q, model.particle_qd, a, b, mode)


@pytest.mark.parametrize("seed", [11, 23, 57, 89, 123])
def test_spd_mode_is_spd_where_exact_is_not(seed):
    """spd yields a symmetric positive definite A (smallest eigenvalue > 0) on stiff compressed scenes."""
    rng = np.random.default_rng(seed)
    model = _compressed_scene(rng)
    a = 100 * H * H  # large step: the indefinite parts dominate the mass
    A = _system(model, "spd", a).toarray()
    assert np.allclose(A, A.T, rtol=0, atol=1e-12 * np.abs(A).max())
    assert np.linalg.eigvalsh(A).min() > 0
    S = _system(model, "symmetric", a).toarray()
    assert np.allclose(S, S.T, rtol=0, atol=1e-12 * np.abs(S).max())
    assert np.linalg.eigvalsh(S).min() < 0  # the scene really is indefinite without projection


@pytest.mark.parametrize("seed", [13, 31])
def test_minus_dfdq_is_psd_per_term_in_spd_mode(seed):
    """In spd mode -dF/dq of every term is positive semi-definite."""
    rng = np.random.default_rng(seed)
    model = _compressed_scene(rng)
    for term in make_force_terms(model):
        jq, _ = term.eval_jacobians(model.particle_q, model.particle_qd, "spd")
        if jq is None:
            continue
        K = -jq.toarray(model.particle_count)
        assert np.allclose(K, K.T, atol=1e-9 * max(np.abs(K).max(), 1.0))
        assert np.linalg.eigvalsh(K).min() >= -1e-9 * np.abs(K).max()


def test_exact_is_nonsymmetric_with_damping_and_symmetric_drops_only_that():
    """exact differs from symmetric only by the damping position term (zero without damping)."""
    rng = np.random.default_rng(77)
    model = _compressed_scene(rng)
    E = _system(model, "exact").toarray()
    S = _system(model, "symmetric").toarray()
    assert np.abs(E - E.T).max() > 1e-8
    terms = make_force_terms(model)
    dq_e, _ = dense_jacobians(terms, model.particle_q, model.particle_qd, "exact")
    dq_s, _ = dense_jacobians(terms, model.particle_q, model.particle_qd, "symmetric")
    # the difference is antisymmetric-ish damping only: it vanishes with zero velocity
    zero = np.zeros_like(model.particle_qd)
    e0, _ = dense_jacobians(terms, model.particle_q, zero, "exact")
    s0, _ = dense_jacobians(terms, model.particle_q, zero, "symmetric")
    assert np.abs(dq_e - dq_s).max() > 0
    assert np.allclose(e0, s0, rtol=0, atol=1e-12 * np.abs(e0).max())


def test_spd_equals_symmetric_for_stretched_springs():
    """Without compression or gravitational pairs the spd projection changes nothing."""
    b = ModelBuilder(gravity=0.0)
    rng = np.random.default_rng(5)
    pos = rng.uniform(-1, 1, (6, 3))
    b.add_particles(pos, None, 1.0)
    pairs = np.array([[0, 1], [1, 2], [2, 3], [3, 4], [4, 5], [0, 5]])
    rest = 0.5 * np.linalg.norm(pos[pairs[:, 0]] - pos[pairs[:, 1]], axis=1)
    b.add_springs(pairs, 100.0, 0.0, rest)
    model = b.finalize()
    np.testing.assert_array_equal(_system(model, "spd").toarray(), _system(model, "symmetric").toarray())
