"""Implicit stages as minimisations on stiff cloth at animation steps: every step converges, the stretch stays
bounded, no energy is created, the gradient criterion holds at the result, failed steps are retaken in substeps,
and the seed's rule still reproduces the course code (PA2 eqs. 1-2)."""

from __future__ import annotations

import numpy as np
import pytest

from helpers import damped_chain
from springsim import simulate
from springsim.assembly import dense_system
from springsim.forces import eval_forces, make_force_terms
from springsim.integrators import INTEGRATORS, StepStats, make_integrator
from springsim.run.energy import total_energy
from springsim.scene import benchmark_cloth

CONVERGING = [name for name, cls in INTEGRATORS.items() if cls.implicit and name != "linearized_implicit"]
IMPLICIT = [name for name, cls in INTEGRATORS.items() if cls.implicit]
H = 1.0 / 60


def _stretch(model, traj) -> float:
    """Largest ratio of a spring's length to its rest length over the frames."""
    i, j = model.spring_indices.T
    return max(float(np.max(np.linalg.norm(q[i] - q[j], axis=1) / model.spring_rest_length)) for q in traj.q)


@pytest.mark.parametrize("ke", [1e6, 1e8])
@pytest.mark.parametrize("name", IMPLICIT)
def test_stiff_cloth_every_step_converges_bounded_and_creates_no_energy(name, ke):
    """Benchmark cloth (8 x 8, undamped) at h = 1/60 s with the defaults: every step meets its criteria (after any
    substep retakes), the structural stretch stays <= 1.1 and the energy never rises above its initial value
    (E0 = 0 J at release; 1e-6 of the weight's energy scale, m g (1 m) = 9.81 J, as slack)."""
    model = benchmark_cloth(8, stiffness=ke)
    traj = simulate(model, make_integrator(name, model), H, 15)
    assert all(s.ok for s in traj.stats), [s.failures for s in traj.stats if not s.ok][:1]
    assert _stretch(model, traj) <= 1.1
    energy = total_energy(model, traj.q, traj.qd)
    assert energy.max() <= energy[0] + 1e-6 * 9.81
    assert traj.q[-1][:, 2].min() < -0.05  # it fell


@pytest.mark.parametrize("name", ["implicit_euler", "bdf2", "tr_bdf2"])
def test_damped_stiff_cloth_steps_converge_and_dissipate(name):
    """With spring damping (a dissipation potential frozen at the inertial predictor) the stiff cloth's steps
    converge and its energy never rises (ke = 1e7, kd = 10 N s/m, 8 x 8)."""
    model = benchmark_cloth(8, stiffness=1e7, damping=10.0)
    traj = simulate(model, make_integrator(name, model), H, 15)
    assert all(s.ok for s in traj.stats)
    energy = total_energy(model, traj.q, traj.qd)
    assert np.all(np.diff(energy) <= 1e-6 * 9.81) if name == "implicit_euler" else energy.max() <= 1e-6 * 9.81


def test_minimize_stage_meets_the_gradient_criterion_at_its_result():
    """The implicit Euler step returned by a minimize stage balances its forces: the gradient of the incremental
    potential, recomputed here from the result (``grad E = M (v1 - v0)/h - F(q1, v1)`` with the damping along the
    directions of the predictor ``q0 + h v0``), is within the stage's own tolerance, ``force_rtol`` times the
    forces it balances (1e-3 by default; damped 8 x 8 cloth, ke = 1e6, from a perturbed state)."""
    model = benchmark_cloth(8, stiffness=1e6, damping=2.0)
    rng = np.random.default_rng(2718)
    s0, s1 = model.state(), model.state()
    free = ~model.particle_fixed
    s0.particle_q[free] += 0.002 * rng.standard_normal((int(free.sum()), 3))
    s0.particle_qd[free] = 0.3 * rng.standard_normal((int(free.sum()), 3))
    integ = make_integrator("implicit_euler", model)
    st = integ.step(s0, s1, H)
    assert st.ok and integ.stage_solver == "minimize" and integ.jacobian == "mixed" and "substeps" not in st.extra
    assert "roundoff_stops" not in st.extra
    q0, v0, q1, v1 = s0.particle_q, s0.particle_qd, s1.particle_q, s1.particle_qd
    f = np.zeros_like(q1)
    for term in make_force_terms(model):
        term.eval_force(q1, v1, f, damping_geometry=q0 + H * v0)
    m = model.particle_mass[:, None]
    grad = (m * (v1 - v0) / H - f)[free]
    scale = np.linalg.norm((m * (v1 - v0))[free]) / H + np.linalg.norm(f[free]) + np.linalg.norm(
        (m * model.gravity_vector)[free])
    assert integ.options.force_rtol == 1e-3
    assert np.linalg.norm(grad) <= integ.options.force_rtol * scale * 1.001
    assert np.linalg.norm(grad) == pytest.approx(st.extra["gradient_norm"], rel=1e-6, abs=1e-12)


def test_line_search_is_nonmonotone_over_five_iterates():
    """The Armijo test of a minimise stage compares with the largest E of the last five iterates: on a stiff cloth
    (6 x 6, ke = 1e8, four steps) some accepted iterates raise E (full steps through the curved valley of the turned
    springs), yet none exceeds the largest of its five predecessors, and every stage converges."""
    from springsim.integrators._stage import _NONMONOTONE

    model = benchmark_cloth(6, stiffness=1e8)
    integ = make_integrator("implicit_euler", model, retake_halvings=0)
    s0, s1 = model.state(), model.state()
    integ.stage.trace = []
    rises = 0
    for _ in range(4):
        st = integ.step(s0, s1, H)
        assert st.ok
        s0, s1 = s1, s0
    stages, stage = [], []
    for it, _alpha, _g, _tol, E in integ.stage.trace:
        if it == 0 and stage:  # a stage starts (its starting point's E)
            stages.append(stage)
            stage = []
        stage.append(E)
    stages.append(stage)
    for E in stages:
        for k in range(1, len(E)):
            ref = max(E[max(0, k - _NONMONOTONE):k])
            assert E[k] <= ref + 1e-9 * abs(ref)  # Armijo against the window's largest E (within E's round-off)
            rises += E[k] > E[k - 1]
    assert rises >= 1


def test_failed_step_is_retaken_in_substeps_then_reported():
    """A step whose stage cannot converge within its limit (2 Newton iterations, ke = 1e8) is retaken in 2, 4, 8
    substeps, the first attempt that succeeds kept and the abandoned ones listed; with no retakes allowed the same
    step is reported as failed, never passed off as converged (``force_rtol`` 1e-5: a stage 2 iterations cannot
    finish)."""
    model = benchmark_cloth(6, stiffness=1e8)
    s0, s1 = model.state(), model.state()
    retaking = make_integrator("implicit_euler", model, newton_maxiter=2, force_rtol=1e-5, on_nonconvergence="ignore")
    st = retaking.step(s0, s1, H)
    assert st.ok and st.extra["substeps"] in (2, 4, 8) and st.extra["retaken"]
    assert "did not converge" in st.extra["retaken"][0]
    s2 = model.state()
    single = make_integrator("implicit_euler", model, newton_maxiter=2, force_rtol=1e-5, retake_halvings=0,
                             on_nonconvergence="ignore")
    st = single.step(s0, s2, H)
    assert not st.ok and not st.newton_converged and "substeps" not in st.extra
    assert any("did not converge" in f for f in st.failures)


def test_substeps_are_remembered_then_relaxed():
    """After a step retaken in n substeps the next step starts in n substeps (recorded as remembered, nothing
    retaken for it); after RETAKE_MEMORY steps that succeed at their first attempt, one level fewer; a failed step
    is remembered at its last level; ``reset`` forgets."""
    from springsim.integrators._implicit import RETAKE_MEMORY

    model = benchmark_cloth(6, stiffness=1e8)
    integ = make_integrator("implicit_euler", model, newton_maxiter=2, force_rtol=1e-5, on_nonconvergence="ignore")
    s0, s1 = model.state(), model.state()
    first = integ.step(s0, s1, H)
    n = first.extra["substeps"]
    assert first.ok and first.extra["retaken"] and "remembered_substeps" not in first.extra
    second = integ.step(s1, model.state(), H)
    assert second.extra["remembered_substeps"] == n and second.extra["substeps"] >= n
    integ.reset()
    assert integ._start_level == 0
    integ._remember(0, 2, True)  # the rule itself: a step retaken down to level 2 ...
    for _ in range(RETAKE_MEMORY - 1):  # ... then clean steps at level 2 keep it ...
        integ._remember(2, 2, True)
        assert integ._start_level == 2
    integ._remember(2, 2, True)
    assert (integ._start_level, integ._clean_steps) == (1, 0)  # ... until RETAKE_MEMORY of them relax one level
    integ._remember(1, 3, True)
    assert integ._start_level == 3  # a deeper retake is remembered at once
    integ._remember(3, 3, False)
    assert integ._start_level == 3


def test_tr_bdf2_step_that_creates_energy_is_retaken_as_implicit_euler():
    """A stiff pendulum (k = 1e8 N/m, m = 1 kg, h = 0.1 s: omega h = 1000) released 1 mm stretched: TR-BDF2's
    converged stages would lift the energy from 50 J to 100 J in the first step; the step is retaken as implicit
    Euler (recorded as ``order_reduced``) and the energy never rises."""
    from springsim import ModelBuilder

    b = ModelBuilder()
    b.add_particle((0.0, 0.0, 0.0), mass=1.0, fixed=True)
    b.add_particle((1.001, 0.0, 0.0), vel=(0.0, 0.5, 0.0), mass=1.0)
    b.add_spring(0, 1, 1e8, 0.0, 1.0)
    model = b.finalize()
    traj = simulate(model, make_integrator("tr_bdf2", model), 0.1, 10)
    assert "created" in traj.stats[0].extra["order_reduced"]
    energy = total_energy(model, traj.q, traj.qd)
    assert energy.max() <= energy[0] * (1 + 1e-9)


def _course_implicit_euler(model, q, v, h, *, tol=1e-5, maxiter=5):
    """The course code's implicit Euler step (PA2 eqs. 1-2), written densely: the full 3N system with identity rows
    for fixed DOFs, Newton from qd^n, no line search, stop when |dqd|_2 < tol or after ``maxiter`` iterations."""
    terms = make_force_terms(model, skip_fixed=False)
    m = np.repeat(model.particle_mass, 3)
    vi = v.copy()
    for _ in range(maxiter):
        qs = q + h * vi
        rhs = -m * (vi - v).reshape(-1) + h * eval_forces(terms, qs, vi).reshape(-1)
        A, r = dense_system(model, qs, vi, h * h, h, rhs=rhs, mode="exact", terms=terms)
        dv = np.linalg.solve(A, r).reshape(-1, 3)
        vi = vi + dv
        if np.linalg.norm(dv) < tol:
            break
    return q + h * vi, vi


def test_pa2_rule_reproduces_the_course_code():
    """``stage_solver="pa2"`` is the seed's Newton exactly: 30 steps of the damped chain agree with the dense course
    code to 1e-7 m (a direct solve of the eliminated system against the full system with identity rows)."""
    model = damped_chain()
    h = 0.02
    integ = make_integrator("implicit_euler", model, solver="direct", stage_solver="pa2")
    assert integ.jacobian == "exact" and integ.newton_maxiter == 5
    traj = simulate(model, integ, h, 30)
    q, v = model.particle_q.copy(), model.particle_qd.copy()
    for k in range(30):
        q, v = _course_implicit_euler(model, q, v, h)
        np.testing.assert_allclose(traj.q[k + 1], q, rtol=0, atol=1e-7)


def test_pa2_rule_ignores_the_other_rules_options():
    """The seed's rule takes no line search and no residual test: an iteration limit of 1 stops after one plain
    iteration however large the residual, and its step is reported unconverged when |dqd| is above the tolerance."""
    model = damped_chain()
    integ = make_integrator("implicit_euler", model, solver="direct", stage_solver="pa2", newton_maxiter=1,
                            retake_halvings=0, on_nonconvergence="ignore")
    st = StepStats(0.05)
    s = model.state()
    _, _, ok = integ.solve_stage(s.particle_q, s.particle_qd, 0.05, s.particle_qd, st)
    assert st.newton_iterations == 1 and ok == (st.newton_step_norm < 1e-5)
    assert "min_line_search_step" in st.extra and st.extra["min_line_search_step"] == 1.0


def test_readme_builder_example_runs_clean_with_every_implicit_integrator():
    """The README's builder example (a pendulum bob, and a cloth held at two corners and in the middle: slack,
    buckling, its springs compressed) at 16 x 16 instead of 32 x 32 to keep the suite short: every implicit
    integrator at its defaults takes 10 steps of 1/60 s that all meet their criteria (after any substep retakes)."""
    import springsim as ss

    b = ss.ModelBuilder(gravity=-9.81, up_axis="z")
    top = b.add_particle((0, 0, 1), mass=0.1, fixed=True)
    bob = b.add_particle((0, 0, 0), mass=0.1, drag=0.01)
    b.add_spring(top, bob, stiffness=100.0, damping=0.5)
    b.add_cloth_grid(16, 16, origin=(2, 0, 1), size=(1, 1), total_mass=1.0, pin=["top-left", "top-right"])
    b.fix_box((2.4, 0.4, 0.9), (2.6, 0.6, 1.1))
    model = b.finalize()
    for name in IMPLICIT:
        traj = simulate(model, make_integrator(name, model), H, 10, record=False)
        assert traj.summary()["failed_steps"] == 0, name


def _falling_run(name, guesses: bool, steps=12, solver="direct"):
    """``steps`` steps of the 10 x 10 benchmark cloth (ke = 1e6) at 1/60 s; with ``guesses`` False the integrator
    offers no predictor."""
    model = benchmark_cloth(10, stiffness=1e6)
    integ = make_integrator(name, model, solver=solver)
    if not guesses:
        integ.predict = lambda v, dt: []
    return integ, simulate(model, integ, H, steps)


@pytest.mark.parametrize("name", ["implicit_euler", "bdf2", "tr_bdf2"])
def test_predicted_start_converges_to_the_same_step(name):
    """A stage started from the predictor (the input velocity advanced with the last step's acceleration, taken
    where it has the lower incremental potential) converges to the same minimiser as one started from the input
    velocity: the trajectories agree to the stages' tolerance, and the predictor is taken on the falling cloth."""
    _, with_guess = _falling_run(name, True)
    _, without = _falling_run(name, False)
    assert all(s.ok for s in with_guess.stats) and all(s.ok for s in without.stats)
    taken = [sum(s.extra.get("predicted_starts", 0) for s in t.stats) for t in (with_guess, without)]
    assert taken[0] > taken[1]  # (TR-BDF2's second stage has its own, from the first stage)
    np.testing.assert_allclose(with_guess.q, without.q, rtol=0, atol=1e-6)


def test_predictor_follows_the_steps_taken():
    """``predict`` offers nothing before the first step and after ``reset``; after a step it is the velocity
    advanced with that step's mean acceleration."""
    model = benchmark_cloth(6)
    integ = make_integrator("implicit_euler", model, solver="direct")
    state, out = model.state(), model.state()
    assert integ.predict(state.particle_qd, H) == []
    integ.step(state, out, H)
    a = (out.particle_qd - state.particle_qd) / H
    (guess,) = integ.predict(out.particle_qd, 0.5 * H)
    np.testing.assert_allclose(guess, out.particle_qd + 0.5 * H * a, rtol=1e-12, atol=1e-15)
    integ.reset()
    assert integ.predict(out.particle_qd, H) == []


def test_minimize_linear_solves_are_no_tighter_than_the_stopping_rule_needs():
    """With AMG-CG, a minimize stage's solves run at the solver's ``rtol`` while the gradient is far above the
    stopping tolerance and looser (up to 0.1) near it; every step still meets the gradient criterion."""
    model = benchmark_cloth(10, stiffness=1e4)
    integ = make_integrator("implicit_euler", model, solver="amg-cg")
    seen = []
    solve = integ.system.solve

    def spy(A, b, *, x0=None, rtol=None):
        seen.append(rtol)
        return solve(A, b, x0=x0, rtol=rtol)

    integ.system.solve = spy
    traj = simulate(model, integ, H, 6)
    assert all(s.ok for s in traj.stats)
    assert all(s.extra["gradient_norm"] <= s.extra["gradient_tol"] for s in traj.stats)
    floor = integ.system.linear_rtol
    given = [r for r in seen if r is not None]
    assert given and all(floor < r <= 0.1 for r in given)
    assert max(given) > 1e3 * floor  # the last solves of a stage are loose


def test_solve_share_falls_as_the_inverse_square_root_of_the_stiffness_ratio():
    """The residual share of a minimize stage's loosened solves is 0.5 up to the stiffness ratio S = 1.6e7 and
    0.5 sqrt(1.6e7 / S) above it (S read from the matrix's precision loss, S times the unit round-off)."""
    from springsim.integrators._stage import solve_share

    u = np.finfo(np.float64).eps
    assert solve_share(0.0) == solve_share(1e4 * u) == solve_share(1.6e7 * u) == 0.5
    assert solve_share(1.6e9 * u) == pytest.approx(0.05)
    assert solve_share(1.6e11 * u) == pytest.approx(0.005)


def test_minimize_solves_on_very_stiff_cloth_leave_a_smaller_share(monkeypatch):
    """On a very stiff cloth (10 x 10, ke = 1e9, AMG-CG: stiffness ratio about 1e8) the loosened solves stop at
    ``solve_share(S) tol / |grad E|`` with a share below 0.5, and every step meets the gradient criterion."""
    from springsim.integrators._stage import StageSolver, solve_share

    model = benchmark_cloth(10, stiffness=1e9)
    integ = make_integrator("implicit_euler", model, solver="amg-cg")
    seen = []
    original = StageSolver._solve_rtol

    def spy(self, rtol, gnorm, tol):
        got = original(self, rtol, gnorm, tol)
        seen.append((got, gnorm, tol, self._precision_loss))
        return got

    monkeypatch.setattr(StageSolver, "_solve_rtol", spy)
    traj = simulate(model, integ, H, 4)
    assert all(s.ok for s in traj.stats)
    assert all(s.extra["gradient_norm"] <= s.extra["gradient_tol"] for s in traj.stats)
    loosened = [(r, g, tol, pl) for (r, by_need), g, tol, pl in seen if by_need]
    assert loosened
    for r, g, tol, pl in loosened:
        assert r == pytest.approx(min(solve_share(pl) * tol / g, 0.1), rel=1e-12)
    assert min(solve_share(pl) for *_, pl in loosened) < 0.45


@pytest.mark.parametrize("name", ["implicit_euler", "tr_bdf2"])
def test_auto_factoring_after_slow_amg_solves_keeps_every_stage_converged(name, monkeypatch):
    """``auto`` handing a stiff cloth's solves to ``direct`` after slow AMG-CG ones (10 x 10, ke = 1e9, AMG-CG
    from 100 DOFs, a switch at 5 CG iterations): both solvers answer stages, every step meets the gradient
    criterion, the stretch stays bounded and no energy is created."""
    from springsim.linsolve import LinearSolverAuto

    model = benchmark_cloth(10, stiffness=1e9)
    integ = make_integrator(name, model, solver_options=dict(direct_max_dofs=100, switch_iterations=5, cooldown=2))
    chosen = []
    original = LinearSolverAuto._solve

    def spy(self, A, b, x0, rtol):
        res = original(self, A, b, x0, rtol)
        chosen.append(res.info["auto_choice"])
        return res

    monkeypatch.setattr(LinearSolverAuto, "_solve", spy)
    traj = simulate(model, integ, H, 6)
    assert all(s.ok for s in traj.stats)
    assert all(s.extra["gradient_norm"] <= s.extra["gradient_tol"] for s in traj.stats)
    assert set(chosen) == {"amg-cg", "direct"} and integ.system.solver.switches > 0
    assert _stretch(model, traj) <= 1.1
    energy = total_energy(model, traj.q, traj.qd)
    assert energy.max() <= energy[0] + 1e-6 * 9.81


@pytest.mark.parametrize("name", ["implicit_euler", "tr_bdf2"])
def test_curved_steps_are_taken_on_very_stiff_cloth(name):
    """At ke = 1e8 full Newton steps that turn springs raise E; the nonmonotone search accepts most of them as they
    are, and those above its window are corrected along the springs' arcs (the second-order correction: implicit
    Euler's first step here). Every step converges to the gradient criterion."""
    model = benchmark_cloth(10, stiffness=1e8)
    traj = simulate(model, make_integrator(name, model, solver="direct"), H, 10)
    assert all(s.ok for s in traj.stats)
    if name == "implicit_euler":
        assert sum(s.extra.get("corrected_steps", 0) for s in traj.stats) > 0
    assert all(s.extra["gradient_norm"] <= s.extra["gradient_tol"] for s in traj.stats)


def _compliant_newton(model, fixed, q0, v0, c, iterations):
    """``iterations`` full Newton steps on the compliant form of the implicit Euler stage (dense reference):
    unknowns the free velocities ``v`` and every spring's tension ``s``, residuals
    ``c (f_gravity - sum_s s grad C_s) - M (v - v0)`` and ``C_s(q) - s / k_s`` with ``q = q0 + c v`` and ``C = l - l0``.
    The geometric term ``s (I - n n^T) / l`` is clamped at ``s >= 0`` as the projected modes clamp it; the tensions
    start from the linear prediction off ``q0`` (the ``mixed`` mode's continuation from the step's input)."""
    i, j = model.spring_indices.T
    k, rest, m = model.spring_stiffness, model.spring_rest_length, model.particle_mass
    N, P = m.size, i.size
    keep = np.repeat(~fixed, 3)
    F = int(keep.sum())
    d0 = q0[i] - q0[j]
    l0 = np.linalg.norm(d0, axis=1)
    v = np.where(fixed[:, None], 0.0, v0)
    d = (q0 + c * v)[i] - (q0 + c * v)[j]
    s = k * (l0 - rest + np.einsum("pa,pa->p", d0 / l0[:, None], d - d0))
    for _ in range(iterations):
        q = q0 + c * v
        d = q[i] - q[j]
        l = np.linalg.norm(d, axis=1)
        n = d / l[:, None]
        f = m[:, None] * model.gravity_vector
        np.add.at(f, i, -s[:, None] * n)
        np.add.at(f, j, s[:, None] * n)
        G = (np.maximum(s, 0.0) / l)[:, None, None] * (np.eye(3) - n[:, :, None] * n[:, None, :])
        J = np.zeros((N, 3, N, 3))
        for a, b, sign in ((i, i, 1.0), (j, j, 1.0), (i, j, -1.0), (j, i, -1.0)):
            np.add.at(J, (a, slice(None), b, slice(None)), -sign * c * c * G)
        J = J.reshape(3 * N, 3 * N) - np.diag(np.repeat(m, 3))
        B = np.zeros((N, 3, P))
        B[i, :, np.arange(P)] = -c * n
        B[j, :, np.arange(P)] = c * n
        B = B.reshape(3 * N, P)
        kkt = np.block([[J[np.ix_(keep, keep)], B[keep]], [-B[keep].T, -np.diag(1.0 / k)]])
        rhs = -np.concatenate([(c * f - m[:, None] * (v - v0)).ravel()[keep], l - rest - s / k])
        step = np.linalg.solve(kkt, rhs)
        dv = np.zeros(3 * N)
        dv[keep] = step[:F]
        v = v + dv.reshape(N, 3)
        s = s + step[F:]
    return v


@pytest.mark.parametrize("iterations", [1, 2, 4])
def test_mixed_mode_iterations_are_newton_on_the_compliant_form(iterations):
    """The ``mixed`` Jacobian's plain Newton iterations are Newton's method on the compliant form of the stiff
    springs, their tensions kept as unknowns (Servin, Lacoursiere and Melin 2006; Tournier et al. 2015): with the
    tension update eliminated, the right-hand side is the primal one and the geometric stiffness takes the tension's
    linear prediction (module docstring of :mod:`springsim.forces.spring`). Checked on a 5 x 5 cloth at ke = 1e8 N/m
    in motion (8 implicit Euler steps from release), against a dense Newton solve of the saddle-point system, to 1e-7
    of the velocity scale (measured: 1e-12; the ``spd`` mode's iterates differ from them by 1e-2 to 6e-2 of it)."""
    model = benchmark_cloth(5, stiffness=1e8)
    integ = make_integrator("implicit_euler", model, solver="direct", jacobian="mixed")
    s0, s1 = model.state(), model.state()
    for _ in range(8):
        assert integ.step(s0, s1, H).ok
        s0, s1 = s1, s0
    q0, v0 = s0.particle_q.copy(), s0.particle_qd.copy()
    integ.system.linearize_at(q0)
    _, v, _ = integ.solve_stage(q0, v0, H, v0, StepStats(H), maxiter=iterations, converge=False)
    reference = _compliant_newton(model, model.particle_fixed, q0, v0, H, iterations)
    scale = float(np.abs(reference).max())
    assert float(np.abs(v - reference).max()) <= 1e-7 * scale
