"""Inexact Newton with Eisenstat-Walker forcing terms: the rule, the per-solve tolerance, and the same
trajectory as the fixed-tolerance path to the Newton tolerance."""

from __future__ import annotations

import numpy as np
import pytest

from springsim import SceneError, simulate
from springsim.integrators import make_integrator
from springsim.integrators._implicit import forcing_term
from springsim.linsolve import make_linear_solver
from springsim.run.options import SolverConfig
from springsim.scene.gallery import benchmark_cloth


def test_forcing_term_rule():
    """Eisenstat-Walker choice 2: eta_max first, 0.9 (|R_k|/|R_k-1|)^2 after, safeguarded, capped, floored."""
    kw = dict(eta_max=0.1, floor=1e-6)
    assert forcing_term(0, 5.0, 0.0, 0.0, **kw) == 0.1
    assert forcing_term(1, 1e-2, 1.0, 0.1, **kw) == pytest.approx(0.9e-4)           # quadratic phase
    assert forcing_term(1, 0.9, 1.0, 0.1, **kw) == 0.1                               # slow decrease: capped
    assert forcing_term(2, 1e-6, 1.0, 0.5, eta_max=0.5, floor=1e-6) == pytest.approx(0.9 * 0.25)  # safeguard
    assert forcing_term(3, 1e-9, 1.0, 1e-3, **kw) == 1e-6                            # never below the solver's rtol
    assert forcing_term(1, float("nan"), 1.0, 0.1, **kw) == 0.1


def test_stage_forcing_confirms_a_loose_update_before_the_stage_ends():
    """A stage's schedule: the solver's own rtol under "fixed"; under Eisenstat-Walker a loose update that passes
    the stopping rule is not certified, and the next solve is to the floor."""
    from springsim.integrators._implicit import StageForcing

    fixed = StageForcing("fixed", eta_max=0.1, floor=1e-6)
    assert fixed.rtol(1.0) is None and fixed.certified(0.5)
    ew = StageForcing("eisenstat-walker", eta_max=0.1, floor=1e-6)
    assert ew.rtol(1.0) == 0.1 and ew.rtol(0.1) == pytest.approx(0.009)
    assert not ew.certified(0.009)
    assert ew.rtol(1e-4) == 1e-6 and ew.certified(9e-7)


def _system(n=14):
    from springsim.assembly import SystemAssembler
    from springsim.forces import make_force_terms

    model = benchmark_cloth(n)
    rng = np.random.default_rng(1)
    q = 1.05 * model.particle_q + rng.uniform(-0.01, 0.01, model.particle_q.shape)
    A = SystemAssembler(model, make_force_terms(model)).assemble(q, model.particle_qd, 1 / 3600, 1 / 60, "spd")
    return A, rng.standard_normal(A.shape[0])


@pytest.mark.parametrize("name", ["amg-cg", "cg", "auto"])
def test_per_solve_rtol_is_honoured_and_never_stored(name):
    """A per-solve ``rtol`` is met and passed down as an argument: neither the solver's own ``rtol`` nor (for ``auto``)
    its sub-solvers' change, even during the solve (a solver shared by two threads keeps its tolerance)."""
    A, b = _system()
    solver = make_linear_solver(name, rtol=1e-10, **({"direct_max_dofs": 10} if name == "auto" else {}))
    own = {k: s.rtol for k, s in getattr(solver, "_solvers", {}).items()}
    seen = []
    if name == "auto":  # the sub-solver's rtol as seen from inside its solve
        amg = solver._solvers["amg-cg"]
        original = amg._solve
        amg._solve = lambda *args: (seen.append(amg.rtol), original(*args))[1]
    loose = solver.solve(A, b, rtol=1e-2)
    assert loose.converged and loose.residual <= 1e-2 * (1 + 1e-8)
    assert solver.rtol == 1e-10
    if name == "auto":
        assert {k: s.rtol for k, s in solver._solvers.items()} == own and seen == [1e-10]
    tight = solver.solve(A, b)
    assert tight.converged and tight.residual <= 1e-10 * (1 + 1e-8)
    assert loose.iterations < tight.iterations
    with pytest.raises(ValueError, match="rtol"):
        solver.solve(A, b, rtol=-1.0)


@pytest.mark.parametrize("method, solver, jacobian, rule", [
    ("implicit_euler", "amg-cg", "spd", "residual"), ("tr_bdf2", "amg-cg", "spd", "residual"),
    ("bdf2", "amg-cg", "spd", "residual"),
    # minimize stages (to a force balance of 1e-10 of the stage's forces)
    ("implicit_euler", "amg-cg", "mixed", "minimize"), ("tr_bdf2", "amg-cg", "mixed", "minimize"),
    # the discrete-gradient stage's Jacobian is not symmetric: GMRES on the exact one
    ("energy_momentum", "amg-gmres", "exact", "residual")])
def test_eisenstat_walker_gives_the_fixed_trajectory_with_fewer_krylov_iterations(method, solver, jacobian, rule):
    """Same converged stages (to the Newton tolerance 1e-8 m/s, or a force balance of 1e-10, set here: positions
    within 1e-8 m over 0.25 s), every step ok with no fallback solve, fewer Krylov iterations in total."""
    model = benchmark_cloth(16)
    runs = {}
    tol = dict(newton_tol=1e-8) if rule == "residual" else dict(force_rtol=1e-10)
    for forcing in ("fixed", "eisenstat-walker"):
        integ = make_integrator(method, model, solver=solver, jacobian=jacobian, stage_solver=rule, newton_maxiter=50,
                                forcing=forcing, solver_options={"rtol": 1e-8}, **tol)
        tr = simulate(model, integ, 1 / 60, 15)
        assert all(s.ok and s.newton_converged and not s.fallbacks for s in tr.stats)
        runs[forcing] = tr
    fixed, ew = runs["fixed"], runs["eisenstat-walker"]
    np.testing.assert_allclose(ew.q, fixed.q, rtol=0, atol=1e-8)
    its = {k: sum(s.linear_iterations for s in tr.stats) for k, tr in runs.items()}
    assert its["eisenstat-walker"] < its["fixed"], its
    # looser solves early in a stage: the largest linear residual of a step is the forcing term's
    assert max(s.linear_residual for s in ew.stats) > 1e-6


def test_forcing_is_validated_and_unused_by_linearized_implicit():
    model = benchmark_cloth(4)
    with pytest.raises(SceneError, match="forcing"):
        make_integrator("implicit_euler", model, forcing="sometimes")
    with pytest.raises(SceneError, match="forcing_max"):
        make_integrator("implicit_euler", model, forcing="eisenstat-walker", forcing_max=1.5)
    with pytest.raises(SceneError, match="solver.forcing"):
        SolverConfig(integrator="implicit_euler", dt=0.01, forcing="sometimes")
    cfg = SolverConfig(integrator="linearized_implicit", dt=0.01, forcing="eisenstat-walker")
    assert cfg.unused() == ["forcing"]
    assert SolverConfig(integrator="tr_bdf2", dt=0.01, forcing="eisenstat-walker").integrator_options() == {
        "forcing": "eisenstat-walker"}
