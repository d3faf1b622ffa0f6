"""Contract tests of every registered linear solver (parametrised over LINEAR_SOLVERS).

Systems come from real scenes: the 8 x 8 benchmark cloth (damped, deformed and
compressed) assembled in the three Jacobian modes: ``spd`` (symmetric positive
definite), ``symmetric`` at a stiff compressed state (symmetric indefinite) and
``exact`` with damping (non-symmetric). Each solver must match the dense solve within
its tolerance, or report the documented fallback.
"""

from __future__ import annotations

import warnings

import numpy as np
import pytest

from springsim.assembly import SystemAssembler
from springsim.forces import make_force_terms
from springsim.linsolve import LINEAR_SOLVERS, LinearSolveResult, make_linear_solver
from springsim.scene.gallery import benchmark_cloth

SOLVERS = sorted(LINEAR_SOLVERS)
KINDS = ["spd", "indefinite", "nonsymmetric"]
RTOL = 1e-9


def _system(kind: str):
    """(SystemMatrix, b, dense A) of the given kind from the damped 8 x 8 cloth."""
    rng = np.random.default_rng(2024)
    model = benchmark_cloth(8, kd=2.0)
    q = 0.8 * model.particle_q + rng.uniform(-0.01, 0.01, model.particle_q.shape)   # compressed
    qd = rng.uniform(-1.0, 1.0, q.shape)
    asm = SystemAssembler(model, make_force_terms(model))
    h = 1.0 / 60.0
    mode, a = {"spd": ("spd", h * h), "indefinite": ("symmetric", 50 * h * h), "nonsymmetric": ("exact", h * h)}[kind]
    A = asm.assemble(q, qd, a, h, mode)
    b = rng.standard_normal(A.shape[0])
    return A, b, A.toarray()


_CACHE: dict = {}


def _cached(kind):
    if kind not in _CACHE:
        _CACHE[kind] = _system(kind)
    return _CACHE[kind]


def test_system_kinds_are_what_they_claim():
    """The fixtures are SPD, symmetric indefinite and non-symmetric respectively."""
    A, _, D = _cached("spd")
    assert A.symmetric and np.linalg.eigvalsh(D).min() > 0
    A, _, D = _cached("indefinite")
    assert A.symmetric and np.allclose(D, D.T) and np.linalg.eigvalsh(D).min() < 0
    A, _, D = _cached("nonsymmetric")
    assert not A.symmetric and np.abs(D - D.T).max() > 1e-6 * np.abs(D).max()


@pytest.mark.parametrize("kind", KINDS)
@pytest.mark.parametrize("name", SOLVERS, ids=[f"cloth8-{s}" for s in SOLVERS])
def test_solution_matches_dense_or_falls_back(name, kind):
    """Each solver matches the dense solve within its tolerance, or reports a fallback."""
    A, b, D = _cached(kind)
    x_ref = np.linalg.solve(D, b)
    solver = make_linear_solver(name, rtol=RTOL)
    with warnings.catch_warnings(record=True) as caught:
        warnings.simplefilter("always")
        res = solver.solve(A, b)
    assert isinstance(res, LinearSolveResult)
    assert res.converged and np.all(np.isfinite(res.x))
    assert res.residual <= 10 * RTOL
    assert np.linalg.norm(D @ res.x - b) <= 10 * RTOL * np.linalg.norm(b)
    cond = np.linalg.cond(D)
    assert np.linalg.norm(res.x - x_ref) <= 10 * cond * RTOL * np.linalg.norm(x_ref)
    assert res.setup_s >= 0 and res.solve_s >= 0 and res.iterations >= 0
    assert name in res.method
    assert res.failure is None
    if res.fallback is not None:  # a fallback is reported in method and reason (the drivers warn once per run)
        assert "->direct" in res.method and res.fallback.startswith(f"{name}: ")
    assert not caught  # a solver never warns per solve
    if kind == "spd" and name in ("cg", "amg-cg", "amg-gmres"):
        assert res.fallback is None and res.iterations > 0


@pytest.mark.parametrize("name", ["cg", "amg-cg"], ids=["cloth8-cg", "cloth8-amg-cg"])
def test_cg_breakdown_is_reported_without_fallback(name):
    """With fallback='none', CG on an indefinite matrix reports breakdown: converged=False, the reason in failure."""
    A, b, _ = _cached("indefinite")
    res = make_linear_solver(name, rtol=RTOL, fallback="none").solve(A, b)
    assert not res.converged
    assert res.fallback is None and res.failure is not None
    assert any(k in res.failure for k in ("curvature", "indefinite", "non-convergence", "singular"))
    assert res.method == name


@pytest.mark.parametrize("name", SOLVERS, ids=[f"cloth8-{s}" for s in SOLVERS])
def test_zero_rhs_and_plain_matrices(name):
    """Zero right-hand side gives zero; a plain scipy matrix is accepted."""
    A, b, D = _cached("spd")
    solver = make_linear_solver(name, rtol=RTOL)
    res = solver.solve(A, np.zeros_like(b))
    assert np.all(res.x == 0)
    res = solver.solve(A.tocsr().copy(), b)
    assert np.linalg.norm(D @ res.x - b) <= 10 * RTOL * np.linalg.norm(b)


@pytest.mark.parametrize("name", ["cg", "amg-cg", "amg-gmres"])
def test_warm_start_used_only_when_valid(name):
    """A good x0 is used (fewer iterations); a bad one (residual > |b|) is ignored."""
    A, b, D = _cached("spd")
    x_ref = np.linalg.solve(D, b)
    solver = make_linear_solver(name, rtol=1e-8)
    cold = solver.solve(A, b)
    warm = solver.solve(A, b, x0=x_ref + 1e-6 * np.abs(x_ref).max())
    assert warm.info["warm_start"] and warm.iterations < cold.iterations
    bad = solver.solve(A, b, x0=1e6 * np.ones_like(b))
    assert not bad.info["warm_start"] and bad.converged
    assert np.linalg.norm(bad.x - x_ref) <= 1e-6 * np.linalg.norm(x_ref) * np.linalg.cond(D)


def test_tolerance_is_configurable():
    """A looser rtol gives fewer iterations and a residual within it."""
    A, b, _ = _cached("spd")
    loose = make_linear_solver("amg-cg", rtol=1e-3).solve(A, b)
    tight = make_linear_solver("amg-cg", rtol=1e-10).solve(A, b)
    assert loose.residual <= 1e-3 and tight.residual <= 1e-10
    assert loose.iterations < tight.iterations


def test_needs_spd_flags():
    """CG-type solvers ask integrators for the spd Jacobian mode; direct methods do not."""
    assert LINEAR_SOLVERS["cg"].needs_spd and LINEAR_SOLVERS["amg-cg"].needs_spd
    assert not LINEAR_SOLVERS["direct"].needs_spd and not LINEAR_SOLVERS["dense"].needs_spd
    assert not LINEAR_SOLVERS["amg-gmres"].needs_spd


def test_auto_choice_by_size_and_symmetry():
    """auto uses direct below its crossover, amg-cg for symmetric and amg-gmres for non-symmetric above."""
    A, b, _ = _cached("nonsymmetric")
    S, bs, _ = _cached("spd")
    small = make_linear_solver("auto")
    assert small.choose(A) == "direct" and small.choose(S) == "direct"
    big = make_linear_solver("auto", direct_max_dofs=10, rtol=RTOL)
    assert big.choose(A) == "amg-gmres" and big.choose(S) == "amg-cg"
    res = big.solve(S, bs)
    assert res.method == "auto:amg-cg" and res.converged


def test_auto_factors_after_slow_amg_cg_solves_and_backs_off():
    """An AMG-CG solve above ``switch_iterations`` hands the next ``cooldown`` symmetric solves to direct; AMG-CG is
    then tried again (on a hierarchy of its own matrix: the old one is dropped at the switch), the cooldown doubling
    while it stays slow (up to ``max_cooldown``) and returning to its start when a try is fast; every answer meets its
    criterion."""
    S, b, D = _cached("spd")
    x_ref = np.linalg.solve(D, b)
    auto = make_linear_solver("auto", direct_max_dofs=10, rtol=RTOL, switch_iterations=1, cooldown=2, max_cooldown=4)
    choices = []
    for _ in range(12):
        res = auto.solve(S, b)
        assert res.converged and np.linalg.norm(res.x - x_ref) <= 1e-6 * np.linalg.norm(x_ref)
        choices.append(res.info["auto_choice"])
    c, d = "amg-cg", "direct"
    assert choices == [c, d, d, c, d, d, d, d, c, d, d, d]  # cooldowns 2, 4, 4 (the maximum)
    assert auto.switches == 3 and "amg-cg needed" in auto.last_reason
    assert auto._solvers["amg-cg"].preconditioner.ml is None  # the hierarchy is dropped while direct answers
    auto.switch_iterations = 1000  # the next try is fast: back to AMG-CG, the cooldown to its start
    for _ in range(2):
        auto.solve(S, b)
    assert auto.last_choice == c and auto._next_cooldown == 2
    A, bn, _ = _cached("nonsymmetric")  # non-symmetric systems go to amg-gmres, whatever the switch
    assert auto.choose(A) == "amg-gmres"
    off = make_linear_solver("auto", direct_max_dofs=10, rtol=RTOL, switch_iterations=1, stiff_direct_max_dofs=0)
    assert {off.solve(S, b).info["auto_choice"] for _ in range(3)} == {c} and off.switches == 0


@pytest.mark.parametrize("options, field", [(dict(switch_iterations=0), "switch_iterations"),
                                            (dict(cooldown=0), "cooldown"),
                                            (dict(stiff_direct_max_dofs=-1), "stiff_direct_max_dofs")])
def test_auto_switch_options_are_checked(options, field):
    """Invalid switch options are a ValueError naming them."""
    with pytest.raises(ValueError, match=field):
        make_linear_solver("auto", **options)


@pytest.mark.parametrize("kernels", ["numpy", "numba"])
@pytest.mark.parametrize("sweep", ["forward", "backward"])
@pytest.mark.parametrize("bs", [2, 3, 6])
def test_block_gauss_seidel_matches_pyamg(bs, sweep, kernels):
    """Both sweeps, with pyamg's kernel and the compiled one (every block size: the specialised 3 and 6
    and the generic kernel), equal pyamg's block Gauss-Seidel sweep (with pyamg's kernel the backward one
    runs forward on a reversed copy; the compiled one sweeps backwards in place)."""
    import scipy.sparse as sp
    from pyamg.relaxation.relaxation import block_gauss_seidel

    from springsim.linsolve.amg import BlockGaussSeidel

    if kernels == "numba":
        pytest.importorskip("numba")  # the accel extra; the test extra installs it
    rng = np.random.default_rng(bs)
    nb = 40
    R = sp.random(nb, nb, density=0.15, random_state=rng) + sp.eye(nb)
    R = (R + R.T).tocsr()
    blocks = rng.standard_normal((R.nnz, bs, bs))
    A = sp.bsr_matrix((blocks, R.indices, R.indptr), shape=(nb * bs, nb * bs))
    A = (A + A.T + 10 * nb * sp.eye(nb * bs)).tobsr(blocksize=(bs, bs))  # SPD, block diagonally dominant
    b, x0 = rng.standard_normal(nb * bs), rng.standard_normal(nb * bs)
    expected = x0.copy()
    block_gauss_seidel(A, expected, b, sweep=sweep, blocksize=bs)
    x = x0.copy()
    BlockGaussSeidel(A, sweep, kernels)(A, x, b)
    np.testing.assert_allclose(x, expected, rtol=1e-12, atol=1e-12)
    with pytest.raises(ValueError, match="sweep must be"):
        BlockGaussSeidel(A, "symmetric")


def test_amg_reuse_cooldown_backs_off_and_resets():
    """Each stale rebuild doubles the cooldown (capped); a successful reuse resets it."""
    from springsim.linsolve.amg import AMGPreconditioner

    h = AMGPreconditioner(cooldown=2, max_cooldown=8)
    skips = []
    for _ in range(4):
        h.invalidate(stale=True)
        skips.append(h._skip)
    assert skips == [2, 4, 8, 8]
    h._trial = True  # a reused hierarchy served a new matrix within budget
    h.record(5, fresh=False, ok=True)
    h.invalidate(stale=True)
    assert h._skip == 2


def test_auto_asks_for_spd_only_where_it_uses_cg():
    """Residual-rule stages default to ``exact`` with ``auto`` on systems its direct solver takes, ``spd`` above;
    minimize stages (the default) always use the projected ``mixed`` Hessian, whatever the solver."""
    from springsim.integrators import make_integrator

    model = benchmark_cloth(8)  # 168 free DOFs
    res = dict(stage_solver="residual")
    assert make_integrator("implicit_euler", model, solver="auto", **res).jacobian == "exact"
    small = make_integrator("implicit_euler", model, solver="auto", solver_options={"direct_max_dofs": 100}, **res)
    assert small.jacobian == "spd"
    assert make_integrator("implicit_euler", model, solver="amg-cg", **res).jacobian == "spd"
    assert make_integrator("implicit_euler", model, solver="direct", **res).jacobian == "exact"
    for solver in ("auto", "amg-cg", "direct"):
        assert make_integrator("implicit_euler", model, solver=solver).jacobian == "mixed"


def test_direct_reports_the_fill_of_its_factors():
    """``info["nnz_LU"]`` (read from SuperLU without copying the factors) is nnz(L) + nnz(U)."""
    import scipy.sparse.linalg as spla

    A, b, _ = _system("nonsymmetric")
    res = make_linear_solver("direct").solve(A, b)
    lu = spla.splu(A.tocsc(), permc_spec="MMD_AT_PLUS_A", diag_pivot_thresh=0.0, options=dict(SymmetricMode=True))
    assert res.info["nnz_LU"] == lu.L.nnz + lu.U.nnz > A.bsr.nnz


@pytest.mark.parametrize("krylov, preconditioner", [("cg", "none"), ("cg", "jacobi"), ("gmres", "block-jacobi"),
                                                    ("gmres", "none"), ("cg", "amg")])
def test_composed_iterative_solver(krylov, preconditioner):
    """Any Krylov method with any preconditioner solves the SPD system to its tolerance; the presets are these
    compositions (amg-cg is CG + AMG, cg is CG + block Jacobi)."""
    from springsim.linsolve import LinearSolverIterative

    A, b, D = _cached("spd")
    res = LinearSolverIterative(krylov, preconditioner, rtol=RTOL, fallback="none", maxiter=5000).solve(A, b)
    assert res.converged and res.fallback is None and res.iterations > 0
    assert np.linalg.norm(D @ res.x - b) <= 10 * RTOL * np.linalg.norm(b)
    amg_cg, cg = make_linear_solver("amg-cg"), make_linear_solver("cg")
    assert amg_cg.krylov.name == "cg" and amg_cg.preconditioner.name == "amg"
    assert cg.krylov.name == "cg" and cg.preconditioner.name == "block-jacobi"


def test_fallback_is_an_object():
    """The fallback is any solver passed in: here dense answers for CG, which breaks down on an indefinite matrix."""
    from springsim.linsolve import LinearSolverDense, LinearSolverIterative

    A, b, D = _cached("indefinite")
    res = LinearSolverIterative("cg", "block-jacobi", rtol=RTOL, fallback=LinearSolverDense()).solve(A, b)
    assert res.converged and res.method == "iterative->dense" and res.fallback.startswith("iterative: ")
    np.testing.assert_allclose(D @ res.x, b, rtol=0, atol=1e-9 * np.abs(b).max())
    with pytest.raises(ValueError, match="unknown Krylov method"):
        LinearSolverIterative("bicg")
    with pytest.raises(ValueError, match="unknown preconditioner"):
        LinearSolverIterative("cg", "ilu")


@pytest.mark.parametrize("name", ["none", "jacobi", "block-jacobi", "amg"])
def test_every_preconditioner_builds_an_operator(name):
    """build(A) gives an operator r -> M^-1 r that every preconditioner implements (abstract in the base)
    and that reduces the residual of the SPD system in one application from zero."""
    from springsim.linsolve.preconditioners import Preconditioner, make_preconditioner

    A, b, D = _cached("spd")
    pre = make_preconditioner(name)
    assert isinstance(pre, Preconditioner)
    apply = pre.build(A)
    x = apply(b)
    assert x.shape == b.shape and np.all(np.isfinite(x))
    if name == "amg":
        assert np.linalg.norm(b - D @ x) < np.linalg.norm(b)


def test_direct_reuses_factors_only_to_its_backward_tolerance():
    """``reuse_factors``: a nearby matrix (the next Newton iterate's) is solved with the previous factors by
    refinement, to the same backward error as a fresh factorisation and the same solution; a far one (another
    step size), another shape or ``reuse_factors=0`` is factored afresh."""
    import scipy.sparse as sp

    rng = np.random.default_rng(5)
    model = benchmark_cloth(8, kd=2.0)
    asm = SystemAssembler(model, make_force_terms(model))
    q, qd = 0.9 * model.particle_q, rng.uniform(-1.0, 1.0, model.particle_q.shape)
    h = 1.0 / 60.0
    b = rng.standard_normal(3 * model.free_count)
    solver, fresh = make_linear_solver("direct", reuse_factors=8), make_linear_solver("direct")
    for k, (dq, a) in enumerate([(0.0, h * h), (1e-4, h * h), (2e-4, h * h), (0.0, 400 * h * h)]):
        A = asm.assemble(q + dq * rng.standard_normal(q.shape), qd, a, h, "exact")
        res, ref = solver.solve(A, b), fresh.solve(A, b)
        assert res.converged and res.backward_error <= solver.backward_tol
        assert res.info["reused_factors"] is (k in (1, 2)) and not ref.info["reused_factors"]
        assert np.linalg.norm(res.x - ref.x) <= 1e-9 * np.linalg.norm(ref.x)
    small = sp.identity(6, format="csr") * 2.0
    res = solver.solve(small, np.ones(6))
    assert not res.info["reused_factors"] and np.allclose(res.x, 0.5)
    with pytest.raises(ValueError, match="reuse_factors"):
        make_linear_solver("direct", reuse_factors=-1)


def test_direct_factor_reuse_keeps_the_trajectory():
    """TR-BDF2 on the 8 x 8 cloth with reused factors: every solve meets the same backward error, so 30 steps at
    1/60 s follow the plain path's trajectory to 1e-9 (relative) with the same Newton iterations."""
    from springsim import make_integrator, simulate

    model = benchmark_cloth(8)
    # a tight Newton tolerance: the stopping decisions fall where the updates drop quadratically, far from the edge
    runs = [simulate(model, make_integrator("tr_bdf2", model, solver="direct", solver_options=so, force_rtol=1e-10),
                     1 / 60, 30) for so in ({}, {"reuse_factors": 8})]
    plain, reused = runs
    assert np.abs(reused.q - plain.q).max() <= 1e-9 * np.abs(plain.q).max()
    assert [s.newton_iterations for s in reused.stats] == [s.newton_iterations for s in plain.stats]
