"""amg-cg trajectories against direct ones on a small cloth; hierarchy reuse and warm start."""

from __future__ import annotations

import numpy as np
import pytest

from springsim.integrators import make_integrator
from springsim.run.driver import simulate
from springsim.scene.gallery import BENCHMARK_DT, benchmark_cloth


def _final_q(solver, steps=50, n=8, integrator="linearized_implicit", jacobian="spd", kd=0.0, **options):
    model = benchmark_cloth(n, kd=kd)
    # converged stages solved far below their default tolerance: the solvers are compared, not Newton's stops
    newton = dict(force_rtol=1e-10) if integrator != "linearized_implicit" else {}
    integ = make_integrator(integrator, model, solver=solver, jacobian=jacobian, solver_options=options, **newton)
    traj = simulate(model, integ, BENCHMARK_DT, steps, record=False)
    return model, traj.q[-1], integ


def _rel(a, b, ref):
    return np.linalg.norm(a - b) / np.linalg.norm(ref)


@pytest.mark.filterwarnings("ignore::springsim.integrators.NewtonConvergenceWarning")
@pytest.mark.parametrize("integrator", ["linearized_implicit", "implicit_euler"])
def test_amg_cg_matches_direct_after_50_steps(integrator):
    """With rtol 1e-10, amg-cg positions match direct within 1e-6 relative after 50 steps."""
    model, q_amg, integ = _final_q("amg-cg", integrator=integrator, rtol=1e-10)
    _, q_dir, _ = _final_q("direct", integrator=integrator)
    disp = q_dir - model.particle_q
    assert np.linalg.norm(disp) > 0.1  # the cloth really moved
    assert _rel(q_amg, q_dir, disp) < 1e-6
    assert integ.solver.preconditioner.builds >= 1


def test_amg_gmres_matches_direct_with_damped_exact_jacobian():
    """amg-gmres on the non-symmetric exact Jacobian (damped cloth) matches direct within 1e-6."""
    model, q_g, _ = _final_q("amg-gmres", steps=30, jacobian="exact", kd=5.0, rtol=1e-10)
    _, q_d, _ = _final_q("direct", steps=30, jacobian="exact", kd=5.0)
    assert _rel(q_g, q_d, q_d - model.particle_q) < 1e-6


def test_cg_matches_direct():
    """Block-Jacobi CG at tight tolerance matches direct within 1e-6 after 30 steps."""
    model, q_c, _ = _final_q("cg", steps=30, rtol=1e-10)
    _, q_d, _ = _final_q("direct", steps=30)
    assert _rel(q_c, q_d, q_d - model.particle_q) < 1e-6


def test_hierarchy_reuse_and_warm_start_do_not_change_the_result():
    """Reuse + warm start vs a fresh hierarchy and cold start per solve: same trajectory within tolerance."""
    model, q_reuse, integ = _final_q("amg-cg", steps=40, rtol=1e-9)
    _, q_fresh, integ_fresh = _final_q("amg-cg", steps=40, rtol=1e-9, reuse=False, warm_start=False)
    assert _rel(q_reuse, q_fresh, q_fresh - model.particle_q) < 1e-6
    assert integ_fresh.solver.preconditioner.builds == 40
    assert integ.solver.preconditioner.builds < 40


@pytest.mark.parametrize("method", ["implicit_euler", "tr_bdf2"])
@pytest.mark.parametrize("option", ["reuse", "warm_start"])
def test_hierarchy_reuse_and_warm_start_keep_the_newton_trajectory(method, option):
    """Inside Newton (16 x 16 cloth, 15 frames of 1/60 s, Newton tolerance 1e-8, AMG-CG rtol 1e-10): reusing a
    hierarchy across the Newton iterations and steps (``nearby``), and warm-starting CG, each on its own
    against the plain solve, give the same frames to 1e-9 m and Newton iteration counts within one."""
    model = benchmark_cloth(16)
    runs = {}
    for on in (True, False):
        opts = {"rtol": 1e-10, "reuse": False, "warm_start": False, option: on}
        integ = make_integrator(method, model, solver="amg-cg", jacobian="spd", stage_solver="residual",
                                newton_tol=1e-8, newton_maxiter=50,
                                solver_options=opts)
        tr = simulate(model, integ, BENCHMARK_DT, 15)
        assert all(st.ok and st.newton_converged for st in tr.stats)
        solves = sum(st.newton_iterations for st in tr.stats)
        amg = integ.solver.preconditioner.describe()
        if option == "reuse" and on:  # the reuse really happened
            assert amg["builds"] < solves / 2 and amg["nearby_reuses"] > 0, (amg, solves)
        elif option == "reuse":
            assert amg["nearby_reuses"] == 0
        runs[on] = tr
    assert np.abs(runs[False].q[-1] - model.particle_q).max() > 0.1  # it fell
    np.testing.assert_allclose(runs[True].q, runs[False].q, rtol=0, atol=1e-9)
    its = [[st.newton_iterations for st in runs[on].stats] for on in (True, False)]
    assert np.max(np.abs(np.subtract(*its))) <= 1


def test_hierarchy_is_reused_for_slowly_changing_matrices():
    """On a slowly changing system the hierarchy is built once and reused (no rebuild)."""
    from springsim.assembly import SystemAssembler
    from springsim.forces import make_force_terms
    from springsim.linsolve import make_linear_solver

    model = benchmark_cloth(10)
    asm = SystemAssembler(model, make_force_terms(model))
    solver = make_linear_solver("amg-cg", rtol=1e-8)
    rng = np.random.default_rng(314)
    q = model.particle_q + 0.01 * rng.standard_normal(model.particle_q.shape)
    for k in range(5):
        A = asm.assemble(q + 1e-5 * k, model.particle_qd, BENCHMARK_DT ** 2, BENCHMARK_DT, "spd")
        b = rng.standard_normal(A.shape[0])
        res = solver.solve(A, b)
        assert res.converged and res.residual <= 1e-8
        assert res.info["rebuilt"] == (k == 0)
    assert solver.preconditioner.builds == 1


def test_stale_signal_triggers_rebuild_and_keeps_accuracy():
    """A zero iteration budget for reuse marks the hierarchy stale: it is rebuilt and the solve completes."""
    from springsim.assembly import SystemAssembler
    from springsim.forces import make_force_terms
    from springsim.linsolve import make_linear_solver

    model = benchmark_cloth(10)
    asm = SystemAssembler(model, make_force_terms(model))
    solver = make_linear_solver("amg-cg", rtol=1e-8, rebuild_factor=0.0, rebuild_slack=0, cooldown=0)
    rng = np.random.default_rng(271)
    for k in range(3):
        q = model.particle_q + 0.02 * rng.standard_normal(model.particle_q.shape)
        A = asm.assemble(q, model.particle_qd, BENCHMARK_DT ** 2, BENCHMARK_DT, "spd")
        b = rng.standard_normal(A.shape[0])
        res = solver.solve(A, b)
        assert res.converged and res.residual <= 1e-8
        assert res.info["stale_rebuild"] == (k > 0)
    assert solver.preconditioner.builds == 3 and solver.preconditioner.stale_rebuilds == 2


def test_stale_rebuild_records_the_new_hierarchys_own_iterations_as_baseline():
    """After a stale rebuild the baseline is the count of the rebuilt hierarchy's part of the solve, not the
    total with the stale attempt (which would inflate the next budget, and with it every later one)."""
    from springsim.assembly import SystemAssembler
    from springsim.forces import make_force_terms
    from springsim.linsolve import make_linear_solver

    model = benchmark_cloth(10)
    asm = SystemAssembler(model, make_force_terms(model))
    solver = make_linear_solver("amg-cg", rtol=1e-8, rebuild_factor=0.0, rebuild_slack=1, cooldown=0, nearby=0.0)
    rng = np.random.default_rng(5)
    for k in range(2):
        q = model.particle_q + 0.02 * rng.standard_normal(model.particle_q.shape)
        A = asm.assemble(q, model.particle_qd, BENCHMARK_DT ** 2, BENCHMARK_DT, "spd")
        res = solver.solve(A, rng.standard_normal(A.shape[0]))
        assert res.converged
    assert res.info["stale_rebuild"]
    assert solver.preconditioner.baseline == res.iterations - 1  # the stale attempt had a budget of 1


def test_nearby_matrix_reuses_the_hierarchy_during_a_cooldown():
    """During a cooldown a matrix within ``nearby`` of the hierarchy's own is tried with it (and converges
    to the tolerance); a farther one gets a fresh hierarchy."""
    from springsim.assembly import SystemAssembler
    from springsim.forces import make_force_terms
    from springsim.linsolve import make_linear_solver

    model = benchmark_cloth(10)
    asm = SystemAssembler(model, make_force_terms(model))
    rng = np.random.default_rng(9)
    q0 = model.particle_q + 0.02 * rng.standard_normal(model.particle_q.shape)
    b = rng.standard_normal(3 * model.free_count)
    results = {}
    for nearby in (0.0, 0.02):
        solver = make_linear_solver("amg-cg", rtol=1e-8, nearby=nearby)
        P = solver.preconditioner
        solver.solve(asm.assemble(q0, model.particle_qd, BENCHMARK_DT ** 2, BENCHMARK_DT, "spd"), b)
        P._skip = P.cooldown  # as after a stale rebuild
        near = solver.solve(asm.assemble(q0 + 1e-6, model.particle_qd, BENCHMARK_DT ** 2, BENCHMARK_DT, "spd"), b)
        far = solver.solve(asm.assemble(model.particle_q + 0.05 * rng.standard_normal(q0.shape), model.particle_qd,
                                        BENCHMARK_DT ** 2, BENCHMARK_DT, "spd"), b)
        assert near.converged and far.converged and near.residual <= 1e-8
        results[nearby] = (near.info["rebuilt"], far.info["rebuilt"], P.nearby_reuses)
    assert results[0.0] == (True, True, 0)
    assert results[0.02] == (False, True, 1)


@pytest.mark.parametrize("nullspace,fmt", [("translations", "bsr"), ("rigid", "csr")])
def test_amg_variants_agree(nullspace, fmt):
    """Near-null-space and format variants converge to the same solution."""
    model, q_v, _ = _final_q("amg-cg", steps=20, rtol=1e-10, near_nullspace=nullspace, fmt=fmt)
    _, q_d, _ = _final_q("direct", steps=20, jacobian="spd")
    assert _rel(q_v, q_d, q_d - model.particle_q) < 1e-6
