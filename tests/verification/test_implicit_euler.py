"""Implicit Euler: Newton's quadratic convergence, linearized = one Newton step, first order."""

from __future__ import annotations

import numpy as np
import pytest

from helpers import damped_chain, observed_errors
from springsim import simulate
from springsim.assembly import dense_system
from springsim.forces import eval_forces, make_force_terms
from springsim.integrators import StepStats, make_integrator


def _newton_residuals(integ, model, h, iterations):
    """Residual norms |R(v_k)| of plain Newton from v_0 = qd^n, k = 0..iterations."""
    s = model.state()
    free = ~model.particle_fixed
    q, v = s.particle_q, s.particle_qd
    f = eval_forces(integ.terms, q + h * v, v)
    res = [np.linalg.norm((h * f)[free])]  # R(v_0) = h F(q + h v_0, v_0) - M (v_0 - v_0)
    for k in range(1, iterations + 1):
        st = StepStats(h)
        integ.solve_stage(q, v, h, v, st, maxiter=k, converge=False)
        assert st.newton_iterations == k
        res.append(st.residual_norm)
    return np.array(res)


@pytest.mark.parametrize("h", [0.02, 0.05])
def test_newton_converges_quadratically(h):
    """Plain Newton residuals satisfy e_{k+1} <= C e_k^2 (C = 1 N^-1 s^-1) down to round-off."""
    model = damped_chain()
    integ = make_integrator("implicit_euler", model, solver="direct", jacobian="exact", line_search=False)
    e = _newton_residuals(integ, model, h, 6)
    floor = 1e-12 * e[0]
    above = np.flatnonzero(e[:-1] > floor)
    assert above.size >= 3
    # e_{k+1} <= C e_k^2 for every iteration before round-off ...
    assert np.all(e[above + 1] <= 1.0 * e[above] ** 2)
    # ... including the asymptotic ones (a linear rate could not meet it there)
    assert e[above].min() < 1e-4
    assert e[-1] <= 1e-13 * e[0]


def test_newton_step_rule_and_statistics():
    """Full implicit Euler stops on |dv|_2 < newton_tol and reports iterations, step and residual."""
    model = damped_chain()
    integ = make_integrator("implicit_euler", model, solver="direct", jacobian="exact", newton_tol=1e-5)
    s0, s1 = model.state(), model.state()
    st = integ.step(s0, s1, 0.02)
    assert st.newton_converged and 1 <= st.newton_iterations <= 5
    assert st.newton_step_norm < 1e-5
    assert st.residual_norm < 1e-8
    assert st.linear_solves == st.newton_iterations


def test_linearized_equals_one_newton_iteration():
    """Linearized implicit Euler equals implicit Euler with one plain Newton iteration."""
    model = damped_chain()
    lin = make_integrator("linearized_implicit", model, solver="direct", jacobian="exact")
    one = make_integrator("implicit_euler", model, solver="direct", jacobian="exact", newton_maxiter=1,
                          line_search=False, retake_halvings=0, on_nonconvergence="ignore")
    a = simulate(model, lin, 0.02, 20)
    b = simulate(model, one, 0.02, 20)
    np.testing.assert_allclose(a.q, b.q, rtol=0, atol=1e-14)
    np.testing.assert_allclose(a.qd, b.qd, rtol=0, atol=1e-14)
    # linearized implicit Euler skips the residual at the returned state (nothing judges it): one
    # force evaluation per step fewer, the same trajectory
    assert all(np.isnan(s.residual_norm) for s in a.stats)
    assert all(np.isfinite(s.residual_norm) for s in b.stats)


@pytest.mark.parametrize("mode", ["exact", "symmetric", "spd"])
def test_linearized_is_seed_equation_3(mode):
    """One linearized step equals seed eqs. (3)-(4) solved densely with identity rows for fixed DOFs."""
    model = damped_chain()
    h = 0.03
    q, v = model.particle_q.copy(), model.particle_qd.copy()
    terms = make_force_terms(model, skip_fixed=False)
    qs = q + h * v
    rhs = h * eval_forces(terms, qs, v).reshape(-1)
    A, r = dense_system(model, qs, v, h * h, h, rhs=rhs, mode=mode, terms=terms)
    dv = np.linalg.solve(A, r).reshape(-1, 3)
    v1 = v + dv
    q1 = q + h * v1
    integ = make_integrator("linearized_implicit", model, solver="direct", jacobian=mode)
    s0, s1 = model.state(), model.state()
    integ.step(s0, s1, h)
    np.testing.assert_allclose(s1.particle_qd, v1, rtol=1e-12, atol=1e-12)
    np.testing.assert_allclose(s1.particle_q, q1, rtol=1e-12, atol=1e-12)
    assert np.all(s1.particle_q[model.particle_fixed] == q[model.particle_fixed])


@pytest.mark.parametrize("name", ["implicit_euler", "linearized_implicit"])
def test_implicit_euler_is_first_order(name):
    """Halving h halves the error against a fine reference: observed order in [0.8, 1.2]."""
    # Newton driven to 1e-10 so that only the time discretisation error remains
    e = observed_errors(name, [0.02, 0.01, 0.005], solver="direct", jacobian="exact", newton_tol=1e-10,
                        newton_maxiter=20)
    orders = np.log2(e[:-1] / e[1:])
    assert np.all((orders >= 0.8) & (orders <= 1.2)), orders


def test_nonconvergence_is_reported():
    """A step whose Newton misses its limit is reported, never silently: in StepStats (ok False, the reason), by one
    ConvergenceWarning per run from simulate (not one per step), or as SolverError with on_nonconvergence='raise'."""
    import warnings

    from springsim.errors import ConvergenceWarning, SimulationError, SolverError
    from springsim.run.driver import simulate

    model = damped_chain()
    integ = make_integrator("implicit_euler", model, solver="direct", stage_solver="residual", newton_tol=1e-14,
                            newton_maxiter=1, retake_halvings=0)
    st = integ.step(model.state(), model.state(), 0.05)
    assert not st.ok and not st.newton_converged and st.newton_iterations == 1
    assert st.failures and st.failures[0].startswith("Newton did not converge in 1 iterations")
    with warnings.catch_warnings(record=True) as caught:
        warnings.simplefilter("always")
        tr = simulate(model, integ, 0.05, 10)
    assert sum(not s.ok for s in tr.stats) == 10 and tr.summary()["failed_steps"] == 10
    conv = [w for w in caught if issubclass(w.category, ConvergenceWarning)]
    assert len(conv) == 1 and "10 of 10 step(s)" in str(conv[0].message)
    integ = make_integrator("implicit_euler", model, solver="direct", stage_solver="residual", newton_tol=1e-14,
                            newton_maxiter=1, retake_halvings=0, on_nonconvergence="raise")
    with pytest.raises(SolverError, match="did not converge"):
        integ.step(model.state(), model.state(), 0.05)
    with pytest.raises(SimulationError, match="step 1 .*did not converge") as err:
        simulate(model, integ, 0.05, 10)
    assert isinstance(err.value.__cause__, SolverError) and err.value.trajectory.frame_count == 1
    quiet = make_integrator("implicit_euler", model, solver="direct", stage_solver="residual", newton_tol=1e-14,
                            newton_maxiter=1, retake_halvings=0, on_nonconvergence="ignore")
    with warnings.catch_warnings():
        warnings.simplefilter("error")
        assert simulate(model, quiet, 0.05, 3).summary()["failed_steps"] == 3


@pytest.mark.parametrize("name", ["implicit_euler", "bdf2", "tr_bdf2"])
def test_projected_jacobian_escalates_to_exact_when_newton_stalls(name):
    """Newton with the ``spd`` Jacobian (linear convergence on the damped chain) that reaches
    its limit continues with the exact Jacobian and converges; without escalation it stalls.
    The exact mode never escalates."""
    model = damped_chain()
    s0 = model.state()
    kw = dict(solver="direct", stage_solver="residual", newton_tol=1e-11, newton_maxiter=4, retake_halvings=0,
              on_nonconvergence="ignore")
    results = {}
    for mode, escalate in [("spd", True), ("spd", False), ("exact", True)]:
        if mode == "exact":
            kw["newton_maxiter"] = 8
        integ = make_integrator(name, model, jacobian=mode, escalate_jacobian=escalate, **kw)
        st = integ.step(s0, model.state(), 0.05)
        results[mode, escalate] = st
    on, off, exact = results["spd", True], results["spd", False], results["exact", True]
    assert not off.newton_converged and "jacobian_escalations" not in off.extra
    assert on.newton_converged and on.extra["jacobian_escalations"] >= 1
    assert on.residual_norm < 1e-3 * off.residual_norm
    assert exact.newton_converged and "jacobian_escalations" not in exact.extra


def test_escalate_after_switches_early_and_is_validated():
    """``escalate_after=k``: k iterations with the projected Jacobian, then the exact one; fewer
    iterations in total than escalating at the limit; bad values are a clear error."""
    from springsim.errors import SceneError

    model = damped_chain()
    kw = dict(solver="direct", jacobian="spd", stage_solver="residual", newton_tol=1e-11, newton_maxiter=30,
              on_nonconvergence="ignore")
    late = make_integrator("implicit_euler", model, **kw).step(model.state(), model.state(), 0.05)
    early = make_integrator("implicit_euler", model, escalate_after=2, **kw).step(model.state(), model.state(), 0.05)
    assert early.newton_converged and early.extra["jacobian_escalations"] == 1
    assert early.newton_iterations < late.newton_iterations
    for bad in (0, 1.5):
        with pytest.raises(SceneError, match="escalate_after"):
            make_integrator("implicit_euler", model, escalate_after=bad, **kw)
