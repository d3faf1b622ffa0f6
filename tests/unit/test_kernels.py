"""The compiled AMG setup products (springsim.linsolve._kernels, numba) against scipy's, the pure path."""

from __future__ import annotations

import numpy as np
import pytest
import scipy.sparse as sp

from springsim.linsolve import _kernels
from springsim.linsolve._kernels import BsrProduct, bsr_matmat, resolve_kernels
from springsim.linsolve._sa import smoothed_aggregation_levels
from springsim.linsolve.amg import AMGPreconditioner, rigid_body_modes

numba = pytest.importorskip("numba")  # the `accel` extra; the test extra installs it, so CI runs these


def _random_bsr(rows, cols, blocksize, density, seed):
    R, C = blocksize
    rng = np.random.default_rng(seed)
    pattern = sp.random(rows, cols, density=density, format="csr", random_state=seed)
    pattern.data[:] = 1.0
    data = rng.standard_normal((pattern.nnz, R, C))
    return sp.bsr_matrix((data, pattern.indices, pattern.indptr), shape=(rows * R, cols * C))


@pytest.mark.parametrize("R, K, N", [(3, 3, 6), (6, 3, 6), (6, 6, 6), (2, 3, 4)])
def test_product_matches_scipy(R, K, N):
    """Every block size (the three compiled specialisations and the generic kernel): the values of scipy's
    product, bitwise on its blocks, zero on the blocks of the pattern that scipy does not store."""
    X = _random_bsr(40, 30, (R, K), 0.1, 1)
    Y = _random_bsr(30, 20, (K, N), 0.1, 2)
    plan = BsrProduct(X, Y)
    C = plan(X, Y)
    assert C.blocksize == (R, N) and C.has_sorted_indices
    ref = (X @ Y).tobsr(blocksize=(R, N))
    np.testing.assert_array_equal(C.toarray(), ref.toarray())
    # new values on the same patterns: the plan serves them
    X2 = sp.bsr_matrix((-2.0 * X.data, X.indices, X.indptr), shape=X.shape)
    assert plan.matches(X2, Y)
    np.testing.assert_array_equal(plan(X2, Y).toarray(), (X2 @ Y).toarray())


@pytest.mark.parametrize("K, N", [(3, 6), (6, 6), (2, 4)])
def test_symmetric_galerkin_product(K, N):
    """``P^T (A P)`` with ``symmetric=True`` (the specialised 6x3x6 and 6x6x6 kernels and the generic one):
    the general product's entries on and above the diagonal bitwise, their mirror images below it, so
    exactly symmetric and equal to scipy's product to round-off; a non-square product is refused."""
    S = _random_bsr(30, 30, (K, K), 0.15, 3)
    A = (S + S.T).tobsr(blocksize=(K, K))
    P = _random_bsr(30, 12, (K, N), 0.2, 4)
    R = P.T.tobsr(blocksize=(N, K))
    AP = BsrProduct(A, P)(A, P)
    general = BsrProduct(R, AP)(R, AP)
    plan = BsrProduct(R, AP, symmetric=True)
    C = plan(R, AP)
    np.testing.assert_array_equal(C.indptr, general.indptr)
    np.testing.assert_array_equal(C.indices, general.indices)
    dense = C.toarray()
    np.testing.assert_array_equal(np.triu(dense), np.triu(general.toarray()))
    np.testing.assert_array_equal(dense, dense.T)
    ref = (R @ (A @ P)).toarray()
    np.testing.assert_allclose(dense, ref, rtol=0, atol=1e-13 * np.abs(ref).max())
    C2, plan2 = bsr_matmat(R, AP, "numba", plan, symmetric=True)
    assert plan2 is plan and np.array_equal(C2.toarray(), dense)
    with pytest.raises(ValueError, match="square"):
        BsrProduct(A, P, symmetric=True)


@pytest.mark.parametrize("bs", [2, 3, 6])
def test_block_diagonal_inverse_matches_lapack(bs):
    """The compiled diagonal blocks and inverses (specialised 3 and 6, generic 2) equal the blocks
    bitwise and numpy's inverses to round-off; a missing (zero) or singular block raises as numpy does."""
    from springsim.linsolve._kernels import block_diagonal_inverse

    S = _random_bsr(25, 25, (bs, bs), 0.2, bs)
    A = (S + S.T + 10 * sp.eye(25 * bs)).tobsr(blocksize=(bs, bs))
    D_ref, inv_ref = block_diagonal_inverse(A, "numpy")
    D, inv = block_diagonal_inverse(A, "numba")
    np.testing.assert_array_equal(D, D_ref)
    np.testing.assert_allclose(inv, inv_ref, rtol=0, atol=1e-13 * np.abs(inv_ref).max())
    hole = sp.bsr_matrix((S.data, S.indices, S.indptr), shape=S.shape)  # a random pattern: some rows lack a diagonal
    assert (sp.csr_matrix((np.ones(S.indices.size), S.indices, S.indptr)).diagonal() == 0).any()
    for kernels in ("numpy", "numba"):
        with pytest.raises(np.linalg.LinAlgError):
            block_diagonal_inverse(hole, kernels)


def test_plan_is_rebuilt_when_a_pattern_changes():
    X = _random_bsr(40, 30, (3, 3), 0.1, 1)
    Y = _random_bsr(30, 20, (3, 6), 0.1, 2)
    _, plan = bsr_matmat(X, Y, "numba")
    Y2 = _random_bsr(30, 20, (3, 6), 0.15, 5)
    assert not plan.matches(X, Y2)
    C2, plan2 = bsr_matmat(X, Y2, "numba", plan)
    assert plan2 is not plan
    np.testing.assert_array_equal(C2.toarray(), (X @ Y2).toarray())
    _, plan3 = bsr_matmat(X, Y2, "numba", plan2)
    assert plan3 is plan2
    assert bsr_matmat(X, Y, "numpy")[1] is None


def test_kernels_option_values(monkeypatch):
    """The AMG preconditioner's ``kernels`` takes the values of every ``kernels`` option, checked by one function;
    its former ``"scipy"`` is a deprecated alias of ``"numpy"``."""
    from springsim._runtime.accel import KERNELS
    from springsim.forces.spring import ForceSpring

    assert _kernels.KERNELS == ForceSpring.KERNELS == KERNELS == ("auto", "numba", "numpy")
    assert resolve_kernels("numpy") == "numpy"
    assert resolve_kernels("auto") == "numba"
    with pytest.raises(ValueError, match="kernels must be one of 'auto', 'numba', 'numpy', got 'fortran'"):
        resolve_kernels("fortran")
    with pytest.warns(DeprecationWarning, match="kernels='scipy' is deprecated; use 'numpy'"):
        assert resolve_kernels("scipy") == "numpy"
    with pytest.warns(DeprecationWarning, match="kernels='scipy' is deprecated"):
        assert AMGPreconditioner(kernels="scipy").kernels == "numpy"
    monkeypatch.setattr(_kernels, "numba_available", lambda: False)
    assert resolve_kernels("auto") == "numpy"       # the core works without numba
    with pytest.raises(ValueError, match=r"needs numba.*springsim\[accel\]"):
        AMGPreconditioner(kernels="numba")


def _cloth_system(n=16, seed=3):
    from springsim.assembly import SystemAssembler
    from springsim.forces import make_force_terms
    from springsim.scene.gallery import benchmark_cloth

    rng = np.random.default_rng(seed)
    model = benchmark_cloth(n)
    q = 1.1 * model.particle_q + rng.uniform(-0.02, 0.02, model.particle_q.shape)
    qd = rng.uniform(-1.0, 1.0, q.shape)
    h = 1.0 / 60.0
    A = SystemAssembler(model, make_force_terms(model)).assemble(q, qd, h * h, h, "spd")
    return A.bsr.copy(), rigid_body_modes(np.asarray(A.positions)), A


def test_hierarchy_matches_scipy_products_and_reuses_its_plans():
    """The same aggregates: every level's operators equal to round-off (the products sum in scipy's order;
    the smoothers see sorted rows), and a second setup with the plans reuses all of them."""
    M, B, _ = _cloth_system()
    ref, aggs = smoothed_aggregation_levels(M, B, max_coarse=10, kernels="numpy")
    got, _ = smoothed_aggregation_levels(M, B, max_coarse=10, kernels="numba", aggregates=aggs)
    assert [lv.A.shape for lv in got] == [lv.A.shape for lv in ref] and len(got) >= 3
    for a, b in zip(ref, got):
        scale = abs(a.A).max()
        assert abs(a.A - b.A).max() <= 1e-13 * scale
        if hasattr(a, "P"):
            assert abs(a.P - b.P).max() <= 1e-13 * abs(a.P).max()
    plans = [lv.products for lv in got[:-1]]
    assert all(set(p) == {"AT", "AP", "RAP"} and all(v is not None for v in p.values()) for p in plans)
    again, _ = smoothed_aggregation_levels(1.5 * M, B, max_coarse=10, kernels="numba", aggregates=aggs,
                                           products=plans)
    for old, new in zip(plans, (lv.products for lv in again[:-1])):
        assert all(new[k] is old[k] for k in old)
    for a, b in zip(again, smoothed_aggregation_levels(1.5 * M, B, max_coarse=10, kernels="numpy",
                                                       aggregates=aggs)[0]):
        assert abs(a.A - b.A).max() <= 1e-13 * abs(b.A).max()


def test_smoothed_prolongator_matches_scipy():
    """The compiled Jacobi smoothing of the tentative prolongator of a cloth equals the scaled blocks and
    scipy's difference to round-off; a tentative block outside the pattern of ``A T`` is refused."""
    from pyamg.aggregation.aggregate import standard_aggregation
    from pyamg.aggregation.tentative import fit_candidates
    from pyamg.strength import symmetric_strength_of_connection

    from springsim.linsolve._kernels import block_diagonal_inverse, smoothed_prolongator

    M, B, _ = _cloth_system()
    T, _ = fit_candidates(standard_aggregation(symmetric_strength_of_connection(M, theta=0.1))[0], B)
    _, Dinv = block_diagonal_inverse(M, "numpy")
    ref = smoothed_prolongator(bsr_matmat(M, T, "numpy")[0], T, Dinv, 0.7, "numpy")
    P = smoothed_prolongator(bsr_matmat(M, T, "numba")[0], T, Dinv, 0.7, "numba")
    assert P.blocksize == ref.blocksize == (3, 6)
    np.testing.assert_allclose(P.toarray(), ref.toarray(), rtol=0, atol=1e-14 * abs(ref).max())
    ones = np.ones((2, 3, 6))
    C = sp.bsr_matrix((ones, [1, 1], [0, 1, 2]), shape=(6, 12))  # T's blocks are in block column 0
    T2 = sp.bsr_matrix((ones, [0, 0], [0, 1, 2]), shape=(6, 12))
    with pytest.raises(ValueError, match="outside the pattern"):
        smoothed_prolongator(C, T2, np.tile(np.eye(3), (2, 1, 1)), 0.7, "numba")


@pytest.mark.parametrize("solver, jacobian, kd, steps", [("amg-cg", "spd", 0.0, 8), ("amg-gmres", "exact", 5.0, 10)])
def test_simulation_with_compiled_setup_matches_the_pure_path(solver, jacobian, kd, steps):
    """A fall of the 16 x 16 cloth with AMG-CG, and with AMG-GMRES on the damped cloth's non-symmetric exact
    Jacobian (rtol 1e-10; steps of about 0.15 m, so at most about 1e-10 m per step): compiled and scipy
    kernels (setup products, V-cycle) give the same trajectory to 1e-9 m and the same iteration counts within
    one."""
    from springsim.integrators import make_integrator
    from springsim.scene.gallery import BENCHMARK_DT, benchmark_cloth

    runs = {}
    for kernels in ("numpy", "numba"):
        model = benchmark_cloth(16, kd=kd)
        integ = make_integrator("linearized_implicit", model, solver=solver, jacobian=jacobian,
                                solver_options={"rtol": 1e-10, "kernels": kernels})
        s0, s1 = model.state(), model.state()
        its = []
        for _ in range(steps):
            st = integ.step(s0, s1, BENCHMARK_DT)
            assert st.ok
            its.append(st.linear_iterations)
            s0, s1 = s1, s0
        cycle = integ.solver.preconditioner.describe()["cycle"]
        assert cycle == ("compiled" if kernels == "numba" else "pyamg")
        runs[kernels] = (s0.particle_q.copy(), its)
    (q_ref, it_ref), (q, it) = runs["numpy"], runs["numba"]
    assert np.abs(q_ref - benchmark_cloth(16).particle_q).max() > 0.05  # it fell
    assert np.max(np.abs(q - q_ref)) < 1e-9
    assert np.max(np.abs(np.subtract(it, it_ref))) <= 1


def test_compiled_vcycle_matches_pyamg_cycle_and_is_symmetric():
    """The compiled V-cycle equals pyamg's cycle over the same levels (block Gauss-Seidel forward before,
    backward after) to round-off, and is a symmetric operator (CG's requirement)."""
    from pyamg.multilevel import MultilevelSolver

    from springsim.linsolve._kernels import CompiledVCycle
    from springsim.linsolve.amg import BlockGaussSeidel

    M, B, _ = _cloth_system()
    levels, _ = smoothed_aggregation_levels(M, B, max_coarse=10, kernels="numba")
    ml = MultilevelSolver(levels, coarse_solver="pinv")
    for lv in ml.levels[:-1]:
        lv.presmoother = BlockGaussSeidel(lv.A, "forward", "numpy")
        lv.postsmoother = BlockGaussSeidel(lv.A, "backward", "numpy")
    cycle = CompiledVCycle(ml.levels, ml.coarse_solver)
    rng = np.random.default_rng(7)
    r, u, v = rng.standard_normal((3, M.shape[0]))
    expected = np.zeros_like(r)
    ml._MultilevelSolver__solve(0, expected, r, "V", 1)
    got = cycle(r)
    assert np.linalg.norm(got - expected) <= 1e-13 * np.linalg.norm(expected)
    assert abs(u @ cycle(v) - v @ cycle(u)) <= 1e-12 * abs(u @ cycle(v))
    r0 = r.copy()
    cycle(r)
    np.testing.assert_array_equal(r, r0)  # the right-hand side is untouched


def test_amg_uses_the_compiled_cycle_only_with_numba_kernels():
    """``kernels="numba"`` runs the compiled cycle, ``"numpy"`` pyamg's; both precondition CG alike."""
    from springsim.linsolve import make_linear_solver

    _, _, A = _cloth_system()
    b = np.random.default_rng(2).standard_normal(A.shape[0])
    iterations = {}
    for kernels, cycle in (("numba", "compiled"), ("numpy", "pyamg")):
        pre = AMGPreconditioner(kernels=kernels)
        pre.build(A)
        assert pre.describe()["cycle"] == cycle
        res = make_linear_solver("amg-cg", rtol=1e-10, kernels=kernels).solve(A, b)
        assert res.converged and res.residual <= 1e-10
        iterations[kernels] = res.iterations
    assert abs(iterations["numba"] - iterations["numpy"]) <= 1


@pytest.mark.parametrize("bs", [2, 3, 6])
def test_backward_sweep_matches_pyamg_and_the_reversed_forward_sweep(bs):
    """The compiled backward block Gauss-Seidel sweep in place (the specialised block sizes 3 and 6 and the
    generic kernel) equals pyamg's backward sweep to round-off, and bitwise the forward sweep on the matrix
    with its block rows and columns reversed (what the pure path runs)."""
    from pyamg.relaxation.relaxation import block_gauss_seidel

    from springsim.linsolve.amg import BlockGaussSeidel

    S = _random_bsr(40, 40, (bs, bs), 0.15, 5)
    A = (S + S.T + 40 * bs * sp.eye(40 * bs)).tobsr(blocksize=(bs, bs))  # block diagonally dominant
    D, Dinv = _kernels.block_diagonal_inverse(A, "numpy")
    rng = np.random.default_rng(bs)
    b, x0 = rng.standard_normal((2, A.shape[0]))
    expected = x0.copy()
    block_gauss_seidel(A, expected, b, sweep="backward", blocksize=bs)
    x = x0.copy()
    _kernels.block_gauss_seidel_backward(A.indptr, A.indices, np.ascontiguousarray(A.data), x, b, Dinv, "numba")
    np.testing.assert_allclose(x, expected, rtol=1e-13, atol=1e-13)
    reversed_copy = BlockGaussSeidel(A, "backward", "numba")
    reversed_copy.reversed = True  # the pure path's layout, swept by the compiled forward kernel
    nnzb, nb = A.indices.size, A.shape[0] // bs
    reversed_copy.indptr = np.ascontiguousarray(nnzb - A.indptr[::-1])
    reversed_copy.indices = np.ascontiguousarray((nb - 1 - A.indices)[::-1])
    reversed_copy.data = np.ascontiguousarray(A.data[::-1])
    reversed_copy.dinv = np.ascontiguousarray(Dinv[::-1])
    y = x0.copy()
    reversed_copy(A, y, b)
    np.testing.assert_array_equal(x, y)


@pytest.mark.parametrize("R, C", [(3, 3), (6, 6), (3, 6), (2, 4)])
def test_bsr_operator_matches_scipy(R, C):
    """The compiled matrix-vector product equals scipy's to round-off (every specialised block shape and the
    generic kernel); 2-D operands, other dtypes and wrong lengths go through scipy (which checks them);
    ``kernels="numpy"`` and non-BSR matrices keep the matrix."""
    A = _random_bsr(30, 25, (R, C), 0.2, 6)
    op = _kernels.bsr_operator(A, "numba")
    assert isinstance(op, _kernels.BsrOperator) and op.shape == A.shape
    x = np.random.default_rng(1).standard_normal(A.shape[1])
    ref = A @ x
    for y in (op @ x, op.matvec(x), op.dot(x)):
        np.testing.assert_allclose(y, ref, rtol=1e-13, atol=1e-13 * np.abs(ref).max())
    X = np.random.default_rng(2).standard_normal((A.shape[1], 2))
    np.testing.assert_array_equal(op @ X, A @ X)
    np.testing.assert_array_equal(op @ x.astype(np.float32), A @ x.astype(np.float32))
    with pytest.raises(ValueError):
        op @ np.ones(A.shape[1] + 1)
    assert _kernels.bsr_operator(A, "numpy") is A
    C_ = A.tocsr()
    assert _kernels.bsr_operator(C_, "numba") is C_


@pytest.mark.parametrize("solver", ["amg-cg", "amg-gmres"])
def test_lanczos_and_krylov_products_use_the_compiled_kernel(solver):
    """With numba kernels the spectral-radius estimate and the Krylov method (CG, and GMRES through scipy's
    ``aslinearoperator``) apply the matrix through the compiled product: the same estimate and the same
    iterations as with scipy's products, to round-off."""
    from springsim.linsolve import make_linear_solver
    from springsim.linsolve._sa import lanczos_rho

    M, _, A = _cloth_system()
    D, Dinv = _kernels.block_diagonal_inverse(M, "numpy")
    rho = {k: lanczos_rho(M, D, Dinv, steps=12, kernels=k) for k in ("numba", "numpy")}
    assert rho["numba"] == pytest.approx(rho["numpy"], rel=1e-12)
    assert isinstance(AMGPreconditioner(kernels="numba").operator(A), _kernels.BsrOperator)
    assert AMGPreconditioner(kernels="numpy").operator(A) is A.bsr
    b = np.random.default_rng(4).standard_normal(A.shape[0])
    results = {k: make_linear_solver(solver, rtol=1e-10, kernels=k).solve(A, b) for k in ("numba", "numpy")}
    for res in results.values():
        assert res.converged and res.fallback is None and res.residual <= 1e-10
    assert abs(results["numba"].iterations - results["numpy"].iterations) <= 1
    np.testing.assert_allclose(results["numba"].x, results["numpy"].x, rtol=0, atol=1e-8 * np.abs(b).max())


@pytest.mark.parametrize("R, K, upper", [(3, 3, False), (6, 3, False), (6, 6, False), (6, 3, True), (6, 6, True)])
def test_scalar_held_products_equal_the_generic_loop(R, K, upper):
    """The product kernels for inner sizes 3 and 6 (the block of X held in scalars) give bitwise the values of
    the generic loop, general and upper-triangle (a symmetric Galerkin product ``P^T (A P)``) alike."""
    from springsim.linsolve import _numba_kernels as nk

    N = 6
    if upper:
        S = _random_bsr(24, 24, (K, K), 0.2, 7)
        A = (S + S.T).tobsr(blocksize=(K, K))
        P = _random_bsr(24, 30, (K, N), 0.2, 8)
        X, Y = P.T.tobsr(blocksize=(N, K)), BsrProduct(A, P)(A, P)
    else:
        X, Y = _random_bsr(30, 24, (R, K), 0.15, 7), _random_bsr(24, 20, (K, N), 0.2, 8)
    plan = BsrProduct(X, Y, symmetric=upper)
    operands = (X.indptr, X.indices, np.ascontiguousarray(X.data), Y.indptr, Y.indices,
                np.ascontiguousarray(Y.data), plan.indptr, plan.indices)
    generic = np.zeros((plan.indices.size, R, N))
    nk._matmat(*operands, generic, np.zeros_like(plan._marker), R, K, N, upper)
    special = np.zeros_like(generic)
    if K == 3:
        nk._matmat_k3(*operands, special, np.zeros_like(plan._marker), R, N, upper)
    else:
        nk._matmat_k6(*operands, special, np.zeros_like(plan._marker), N, upper)
    np.testing.assert_array_equal(special, generic)


def test_nearby_check_samples_large_matrices():
    """The nearby-reuse check on a matrix of 300,000 blocks (an odd stride above 8): a uniform 1 % change is
    near (``nearby`` 0.02), 5 % is not, and a change of shape is never near."""
    from types import SimpleNamespace

    rng = np.random.default_rng(9)
    old = rng.standard_normal((300_000, 3, 3))
    pre = AMGPreconditioner(kernels="numpy", nearby=0.02)
    pre.ml = SimpleNamespace(levels=[SimpleNamespace(A=SimpleNamespace(data=old))])
    near = lambda data: pre._near(SimpleNamespace(bsr=SimpleNamespace(data=data)))  # noqa: E731
    assert near(1.01 * old)
    assert not near(1.05 * old)
    assert not near(old[:-1])
