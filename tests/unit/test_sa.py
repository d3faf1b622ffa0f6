"""The smoothed-aggregation setup of springsim.linsolve._sa against dense linear algebra and pyamg."""

from __future__ import annotations

import dataclasses

import numpy as np
import pytest
import scipy.sparse as sp

from springsim.assembly import SystemAssembler
from springsim.forces import make_force_terms
from springsim.linsolve import make_linear_solver
from springsim.linsolve.amg import AMGPreconditioner, rigid_body_modes
from springsim.linsolve._sa import bsr_block_diagonal, lanczos_rho, smoothed_aggregation_levels
from springsim.scene.gallery import benchmark_cloth


def _spd_system(n=12, seed=3):
    """(SystemMatrix, BSR copy, rhs) of a stretched, moving n x n cloth in the spd mode."""
    rng = np.random.default_rng(seed)
    model = benchmark_cloth(n)
    q = 1.1 * model.particle_q + rng.uniform(-0.02, 0.02, model.particle_q.shape)
    qd = rng.uniform(-1.0, 1.0, q.shape)
    h = 1.0 / 60.0
    A = SystemAssembler(model, make_force_terms(model)).assemble(q, qd, h * h, h, "spd")
    return A, A.bsr.copy(), rng.standard_normal(A.shape[0])


def test_block_diagonal_and_lanczos_rho_match_dense():
    _, M, _ = _spd_system()
    D = bsr_block_diagonal(M)
    dense = M.toarray()
    bs = 3
    for i in range(0, M.shape[0] // bs, 7):
        np.testing.assert_array_equal(D[i], dense[bs * i:bs * i + bs, bs * i:bs * i + bs])
    Dinv = np.linalg.inv(D)
    Dinv_dense = sp.block_diag(list(Dinv)).toarray()
    exact = np.max(np.linalg.eigvals(Dinv_dense @ dense).real)
    rho = lanczos_rho(M, D, Dinv, steps=12)
    assert rho <= exact * (1 + 1e-10)          # a Ritz value: from below
    assert rho >= 0.95 * exact                  # and close after 12 steps
    assert lanczos_rho(M, D, Dinv, steps=60) == pytest.approx(exact, rel=1e-8)


def _two_nearby_systems(n=16, moved=0.005, seed=3):
    """Two spd system matrices of one assembler (one pattern): a stretched, moving cloth and the same
    cloth with every particle moved by up to ``moved`` [m]; and a right-hand side."""
    rng = np.random.default_rng(seed)
    model = benchmark_cloth(n)
    asm = SystemAssembler(model, make_force_terms(model))
    q = 1.1 * model.particle_q + rng.uniform(-0.02, 0.02, model.particle_q.shape)
    qd = rng.uniform(-1.0, 1.0, q.shape)
    h = 1.0 / 60.0
    A = asm.assemble(q, qd, h * h, h, "spd")
    A0 = dataclasses.replace(A, bsr=A.bsr.copy(), positions=np.array(A.positions), _cache={})  # a snapshot
    A1 = asm.assemble(q + rng.uniform(-moved, moved, q.shape), qd, h * h, h, "spd")
    return A0, A1, rng.standard_normal(A1.shape[0])


def test_warm_started_lanczos_matches_cold_estimate():
    """Four Lanczos steps from the top Ritz vector of a nearby matrix estimate rho(D^-1 A) as well as
    twelve from a random start (a few per cent, from below); a levels' setup hands the vectors on."""
    A0, A1, _ = _two_nearby_systems()
    M0, M1 = A0.bsr, A1.bsr
    D0, D1 = bsr_block_diagonal(M0), bsr_block_diagonal(M1)
    rho0, y = lanczos_rho(M0, D0, np.linalg.inv(D0), steps=12, return_vector=True)
    assert y.shape == (M0.shape[0],)
    # the same run; the two LAPACK tridiagonal eigensolvers agree to round-off, not bitwise
    assert rho0 == pytest.approx(lanczos_rho(M0, D0, np.linalg.inv(D0), steps=12), rel=1e-13)
    D1inv = np.linalg.inv(D1)
    exact = lanczos_rho(M1, D1, D1inv, steps=200)
    warm = lanczos_rho(M1, D1, D1inv, steps=4, start=y)
    assert exact * (1 + 1e-10) >= warm >= 0.97 * exact
    assert lanczos_rho(M1, D1, D1inv, steps=12) >= 0.95 * exact
    levels, _ = smoothed_aggregation_levels(M0.copy(), rigid_body_modes(np.asarray(A0.positions)), max_coarse=10)
    assert len(levels) >= 3
    assert all(lv.ritz is not None and lv.ritz.shape == (lv.A.shape[0],) for lv in levels[:-1])


def test_warm_started_hierarchy_solves_like_a_cold_one():
    """The AMG preconditioner's second build on a matrix of the same pattern (aggregates and Ritz vectors
    handed on) gives the solution of a cold build to the solver's tolerance, in as many iterations +- 1."""
    A0, A1, b = _two_nearby_systems()
    x_ref = np.linalg.solve(A1.toarray(), b)
    warm = make_linear_solver("amg-cg", rtol=1e-10, max_coarse=10, reuse=False)
    warm.solve(A0, b)
    res_w = warm.solve(A1, b)
    assert warm.preconditioner._ritz is not None and warm.preconditioner.builds == 2
    res_c = make_linear_solver("amg-cg", rtol=1e-10, max_coarse=10, reuse=False).solve(A1, b)
    for res in (res_w, res_c):
        assert res.converged and res.fallback is None
        np.testing.assert_allclose(res.x, x_ref, rtol=0, atol=1e-7 * np.abs(x_ref).max())
    assert abs(res_w.iterations - res_c.iterations) <= 1


def test_lanczos_rho_reports_breakdown_on_indefinite_matrix():
    _, M, _ = _spd_system()
    M = M.copy()
    M.data *= -1.0  # negative definite: the D inner product is not one
    D = bsr_block_diagonal(M)
    assert np.isnan(lanczos_rho(M, D, np.linalg.inv(D)))


def test_levels_are_galerkin_and_spd():
    A, M, _ = _spd_system()
    B = rigid_body_modes(np.asarray(A.positions))
    levels, aggs = smoothed_aggregation_levels(M, B, max_coarse=10)
    assert len(levels) >= 3 and len(aggs) == len(levels) - 1
    for fine, coarse in zip(levels[:-1], levels[1:]):
        P, R = fine.P.toarray(), fine.R.toarray()
        np.testing.assert_array_equal(R, P.T)
        Ac = coarse.A.toarray()
        np.testing.assert_allclose(Ac, P.T @ fine.A.toarray() @ P, rtol=1e-10, atol=1e-10 * np.abs(Ac).max())
        np.testing.assert_allclose(Ac, Ac.T, rtol=0, atol=1e-10 * np.abs(Ac).max())
        assert np.linalg.eigvalsh(0.5 * (Ac + Ac.T)).min() > 0.0
    # every smoothed level carries its inverted block diagonal for the smoothers, equal to the
    # pseudo-inverse pyamg's get_block_diag would compute for them
    from pyamg.util.utils import get_block_diag
    for lv in levels[:-1]:
        fresh = lv.A.copy()  # without the cached attribute
        np.testing.assert_allclose(get_block_diag(lv.A, blocksize=lv.A.blocksize[0]), get_block_diag(
            fresh, blocksize=fresh.blocksize[0]), rtol=1e-10, atol=1e-12 * np.abs(lv.A.block_D_inv).max())
    # the passed-back aggregates reproduce the hierarchy exactly
    again, _ = smoothed_aggregation_levels(M, B, max_coarse=10, aggregates=aggs)
    for a, b in zip(levels, again):
        np.testing.assert_array_equal(a.A.toarray(), b.A.toarray())


def test_own_setup_matches_pyamg_setup():
    """amg-cg with springsim's setup and with pyamg's (forced by ``sa_options``): same solution
    within tolerance, iteration counts within two of each other."""
    A, _, b = _spd_system(n=16)
    x_ref = np.linalg.solve(A.toarray(), b)
    its = {}
    for label, opts in (("own", {}), ("pyamg", {"sa_options": {"max_levels": 10}})):
        solver = make_linear_solver("amg-cg", rtol=1e-10, max_coarse=10, **opts)
        res = solver.solve(A, b)
        assert res.converged and res.fallback is None
        np.testing.assert_allclose(res.x, x_ref, rtol=0, atol=1e-7 * np.abs(x_ref).max())
        its[label] = res.iterations
    assert abs(its["own"] - its["pyamg"]) <= 2, its


def test_own_setup_keeps_the_trajectory():
    """springsim's smoothed-aggregation setup (warm-started Lanczos, kept aggregates) against pyamg's (selected by
    a non-empty ``sa_options``) over 10 linearized implicit steps of the 16 x 16 fall (one solve per step, rtol
    1e-10): the same frames to 1e-9 m."""
    from springsim.integrators import make_integrator
    from springsim.run.driver import simulate
    from springsim.scene.gallery import BENCHMARK_DT

    model = benchmark_cloth(16)
    runs = {}
    for name, extra in (("own", {}), ("pyamg", {"sa_options": {"max_levels": 10}})):
        integ = make_integrator("linearized_implicit", model, solver="amg-cg", jacobian="spd",
                                solver_options={"rtol": 1e-10, **extra})
        runs[name] = simulate(model, integ, BENCHMARK_DT, 10)
        assert all(st.ok for st in runs[name].stats)
        assert integ.solver.preconditioner.builds >= 2  # rebuilt along the way: the warm paths ran
    assert np.abs(runs["own"].q[-1] - model.particle_q).max() > 0.1
    np.testing.assert_allclose(runs["own"].q, runs["pyamg"].q, rtol=0, atol=1e-9)


def test_non_spd_matrix_falls_back_to_pyamg_setup():
    """An indefinite matrix breaks the Lanczos estimate; the hierarchy is then pyamg's."""
    A, _, _ = _spd_system()
    A.bsr.data *= -1.0
    h = AMGPreconditioner()
    precond, _, fresh = h.setup(A)
    assert fresh and callable(precond) and h._aggregates is None
