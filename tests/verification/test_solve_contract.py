"""The solve contract, provoked on purpose: a linear solve or Newton stage that missed its criterion is retried,
escalated or reported, and never used as if it had succeeded (docs/robustness.md, "Guarantees")."""

from __future__ import annotations

import warnings

import numpy as np
import pytest
import scipy.sparse as sp

from springsim.errors import ConvergenceWarning, FallbackWarning, SimulationError, SolverError
from springsim.integrators import make_integrator
from springsim.linsolve import LinearSolver, LinearSolveResult, backward_error, make_linear_solver
from springsim.linsolve.direct import LinearSolverDirect
from springsim.model.builder import ModelBuilder
from springsim.run.adaptive import simulate_adaptive
from springsim.run.driver import simulate
from springsim.scene.gallery import benchmark_cloth


class Unreliable(LinearSolver):
    """Answers with a finite but wrong solution (half the right one) on the calls listed in ``fail_on``."""

    name = "unreliable"

    def __init__(self, fail_on=(), **kw):
        super().__init__(**kw)
        self.fail_on, self.calls = set(fail_on), 0

    def _solve(self, A, b, x0, rtol):
        self.calls += 1
        x = np.linalg.solve(A.toarray(), b)
        if self.calls in self.fail_on:
            return LinearSolveResult(0.5 * x, False, 0, 0.5, self.name, failure="made to fail")
        return LinearSolveResult(x, True, 0, 0.0, self.name, backward_error=0.0)


def _pendulum():
    b = ModelBuilder()
    b.add_particle((0.0, 0.0, 1.0), mass=1.0, fixed=True)
    b.add_particle((0.3, 0.0, 0.0), mass=1.0)
    b.add_spring(0, 1, 100.0, 0.5, 1.0)
    return b.finalize()


class _Sloppy(LinearSolverDirect):
    """A direct solver whose first (diagonal-pivot) factorisation is of a perturbed matrix: ``scale`` 1e-6 makes it
    a good approximate inverse (refinement repairs it), 1.0 a useless one (only re-factoring helps)."""

    def __init__(self, scale, **kw):
        super().__init__(**kw)
        self.scale = scale

    def _factor(self, csc, pivoting):
        if pivoting:
            return super()._factor(csc, pivoting)
        noise = sp.random(*csc.shape, density=0.5, random_state=5, format="csc")
        return super()._factor((csc + self.scale * abs(csc).max() * noise).tocsc(), pivoting)


def _system():
    rng = np.random.default_rng(2718)
    A = sp.csc_matrix(rng.normal(size=(40, 40)) + 10 * np.eye(40))
    return A, rng.normal(size=40)


def test_direct_solver_refines_an_inaccurate_factorisation():
    """A factorisation that solves to a backward error of ~1e-6 is refined with the same factors until the backward
    error is below the tolerance; the refinement steps are reported."""
    A, b = _system()
    res = _Sloppy(1e-6).solve(A, b)
    assert res.converged and res.backward_error <= 1e-12 and 0 < res.info["refinements"] <= 3
    assert not res.info["pivoting"] and res.backward_error == pytest.approx(backward_error(A, res.x, b))


def test_direct_solver_refactors_with_pivoting_when_refinement_fails():
    """When refinement cannot repair the factors, the matrix is factored again with partial pivoting; if refinement is
    switched off and pivoting fails too, the result says why (converged False, failure)."""
    A, b = _system()
    res = _Sloppy(1.0).solve(A, b)
    assert res.converged and res.info["pivoting"] and res.backward_error <= 1e-12
    np.testing.assert_allclose(A @ res.x, b, rtol=1e-10, atol=1e-10)
    strict = _Sloppy(1e-6, refine=0, backward_tol=1e-300).solve(A, b)
    assert not strict.converged and "backward error" in strict.failure and "partial pivoting" in strict.failure


@pytest.mark.parametrize("name", ["direct", "dense"])
def test_singular_matrix_is_a_failure_with_its_reason(name):
    """An exactly singular matrix is converged=False with the reason in failure (never a silent NaN)."""
    A = sp.csc_matrix(np.array([[1.0, 1.0, 0.0], [1.0, 1.0, 0.0], [0.0, 0.0, 1.0]]))
    res = make_linear_solver(name).solve(A, np.array([1.0, 0.0, 1.0]))
    assert not res.converged and "singular" in res.failure


def test_krylov_failure_is_reported_or_escalated():
    """CG limited to 2 iterations misses its tolerance: without a fallback it says so (converged False, failure);
    with the default fallback the direct solver answers (converged, method cg->direct, fallback reason)."""
    from springsim.assembly import SystemAssembler
    from springsim.forces import make_force_terms

    m = benchmark_cloth(8)
    A = SystemAssembler(m, make_force_terms(m)).assemble(m.particle_q, m.particle_qd, 1e-3, 1e-2, "spd")
    b = np.random.default_rng(31).normal(size=A.shape[0])
    alone = make_linear_solver("cg", maxiter=2, fallback="none").solve(A, b)
    assert not alone.converged and "non-convergence" in alone.failure and alone.fallback is None
    helped = make_linear_solver("cg", maxiter=2).solve(A, b)
    assert helped.converged and helped.method == "cg->direct" and helped.fallback.startswith("cg: non-convergence")


def test_failed_linear_solve_fails_a_linearized_step():
    """linearized_implicit has no stopping rule to check its one solve: a failed solve (finite but wrong answer) makes
    the step not ok with the reason (no retakes allowed), the run warns once, and the later steps with good solves
    are ok; with the default retakes the step is taken again in substeps."""
    m = _pendulum()
    integ = make_integrator("linearized_implicit", m, solver=Unreliable(fail_on={1}), retake_halvings=0)
    with warnings.catch_warnings(record=True) as caught:
        warnings.simplefilter("always")
        tr = simulate(m, integ, 0.01, 5)
    first = tr.stats[0]
    assert not first.ok and first.linear_failures == 1 and "made to fail" in first.failures[0]
    assert sum(issubclass(w.category, ConvergenceWarning) for w in caught) == 1
    assert all(s.ok for s in tr.stats[1:])
    # by default the failed step is retaken in two substeps, whose solves are good
    tr = simulate(m, make_integrator("linearized_implicit", m, solver=Unreliable(fail_on={1})), 0.01, 5)
    assert all(s.ok for s in tr.stats) and "made to fail" in tr.stats[0].extra["retaken"][0]
    assert tr.stats[0].extra["substeps"] == 2


@pytest.mark.parametrize("name", ["implicit_euler", "bdf2", "tr_bdf2"])
def test_failed_linear_solve_in_a_newton_stage(name):
    """In a Newton stage a failed solve is an inexact search direction: when the stage still meets its stopping rule
    it is recovered (counted, the step ok); when Newton cannot recover (limit 1), the step is not ok, with the solve's
    reason (no retakes allowed)."""
    m = _pendulum()
    tr = simulate(m, make_integrator(name, m, solver=Unreliable(fail_on={1})), 0.01, 3)
    assert all(s.ok for s in tr.stats) and tr.stats[0].extra["recovered_linear_failures"] == 1
    tight = make_integrator(name, m, solver=Unreliable(fail_on={1}), newton_maxiter=1, retake_halvings=0,
                            on_nonconvergence="ignore")
    st = tight.step(m.state(), m.state(), 0.01)
    assert not st.ok and st.linear_failures == 1 and any("made to fail" in f for f in st.failures)


def test_failed_linear_solve_is_retried_by_the_adaptive_driver():
    """In an adaptive run a step with a failed solve is rejected and retried with a smaller step: every accepted step
    is ok, and the rejection is counted."""
    m = _pendulum()
    integ = make_integrator("tr_bdf2", m, solver=Unreliable(fail_on=set(range(1, 200, 7))))
    tr = simulate_adaptive(m, integ, 0.2, frame_dt=0.05)
    assert all(s.ok for s in tr.stats)
    assert tr.adaptive_stats["accepted"] > 0


def test_non_finite_solution_stops_the_run_with_frames():
    """A solve with no usable solution (NaN) ends the run with SimulationError caused by SolverError, frames kept."""
    class Broken(Unreliable):
        def _solve(self, A, b, x0, rtol):
            if self.calls == 2:
                return LinearSolveResult(np.full_like(b, np.nan), False, 0, np.inf, self.name, failure="broke")
            return super()._solve(A, b, x0, rtol)

    m = _pendulum()
    with pytest.raises(SimulationError) as e:
        simulate(m, make_integrator("linearized_implicit", m, solver=Broken()), 0.01, 10)
    assert isinstance(e.value.__cause__, SolverError) and "broke" in str(e.value)
    assert e.value.step == 3 and e.value.trajectory.frame_count == 3


def test_newton_false_convergence_is_caught_by_the_residual_test():
    """At dt = 1e6 s the Newton update of a damped pendulum is tiny (|dv| < 1e-5) long before the stage is solved:
    the residual test keeps Newton going, and bdf2/tr_bdf2 land on the static equilibrium z = -0.0981 m. The steps
    are still reported: at that step the matrix holds the mass only to ~2e-2 (h^2 k / m = 1e14)."""
    m = _pendulum()
    res = dict(stage_solver="residual", retake_halvings=0, on_nonconvergence="ignore")
    for name in ("bdf2", "tr_bdf2"):
        tr = simulate(m, make_integrator(name, m, **res), 1e6, 6)
        assert all(s.newton_converged and s.residual_ratio <= 1e-3 for s in tr.stats)
        assert all(s.ill_conditioned and not s.ok for s in tr.stats)
        np.testing.assert_allclose(tr.q[-1, 1], [0.0, 0.0, 1.0 - 1.0 - 9.81 / 100.0], atol=1e-6)
    # implicit Euler keeps the seed's 5-iteration limit: a stage it cannot finish is reported, never called converged
    tr = simulate(m, make_integrator("implicit_euler", m, **res), 1e6, 6)
    for s in tr.stats:
        assert s.newton_converged == (s.newton_step_norm < 1e-5 and s.residual_ratio <= 1e-3)
    # minimize stages judge the gradient itself: a stage is called converged only with its force balance met (to the
    # round-off allowance), else reported; implicit Euler and BDF2 land on the equilibrium (to 1 um with force_rtol
    # 1e-5: the static deflection is off by about force_rtol of itself)
    for name in ("implicit_euler", "bdf2", "tr_bdf2"):
        tr = simulate(m, make_integrator(name, m, force_rtol=1e-5, retake_halvings=0, on_nonconvergence="ignore"),
                      1e6, 6)
        for s in tr.stats:
            if s.newton_converged:
                assert s.extra["gradient_norm"] <= 1e3 * s.extra["gradient_tol"]
            assert s.ok or s.ill_conditioned or not s.newton_converged
        if name != "tr_bdf2":
            np.testing.assert_allclose(tr.q[-1, 1], [0.0, 0.0, 1.0 - 1.0 - 9.81 / 100.0], atol=1e-6)


def test_fallbacks_are_warned_once_per_run():
    """Solver fallbacks (right answers, slower) are reported by one FallbackWarning per run, with the count."""
    m = benchmark_cloth(6)
    integ = make_integrator("implicit_euler", m, solver="cg", solver_options={"maxiter": 2})
    with warnings.catch_warnings(record=True) as caught:
        warnings.simplefilter("always")
        tr = simulate(m, integ, 1.0 / 60, 4)
    fb = [w for w in caught if issubclass(w.category, FallbackWarning)]
    assert tr.summary()["fallbacks"] > 1 and len(fb) == 1
    assert f"{tr.summary()['fallbacks']} linear solve(s) fell back" in str(fb[0].message)
