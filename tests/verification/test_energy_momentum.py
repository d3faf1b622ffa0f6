"""The energy-momentum method's guarantees: energy conserved without dissipation and never gained with it, linear and
angular momentum conserved without external forces, and the substep retake of a stage that does not converge."""

import numpy as np
import pytest
from helpers import conservative, internal, random_scene

from springsim import make_integrator, simulate
from springsim.run.energy import total_energy
from springsim.scene.gallery import benchmark_cloth


def _energies(model, tr):
    return np.array([total_energy(model, q, v) for q, v in zip(tr.q, tr.qd)])


def _newton_bound(model, tr, newton_tol):
    """What the Newton tolerance allows the energy to drift: per step, a velocity error of 2 newton_tol per DOF
    (``v_1 = 2 w - v_0``) times the momentum scale ``sum(m) max|v|``."""
    steps = len(tr.q) - 1
    return steps * 2.0 * np.sqrt(3.0) * newton_tol * model.particle_mass.sum() * np.abs(tr.qd).max()


def _run(model, h, steps, **options):
    options.setdefault("newton_tol", 1e-10)
    integ = make_integrator("energy_momentum", model, on_nonconvergence="raise", **options)
    return simulate(model, integ, h, steps)


@pytest.mark.parametrize("scene, solver, jacobian", [("random", "direct", "exact"), ("random", "direct", "spd"),
                                                     ("cloth", "amg-cg", "spd")])
def test_energy_conserved_without_dissipation(scene, solver, jacobian):
    """Springs, gravitational pairs (random scene), gravity and fixed particles, no damping or drag: the total energy
    stays at its initial value over 60 steps to what the Newton tolerance allows, whatever the Newton matrix."""
    if scene == "random":
        model, h = random_scene(np.random.default_rng(7401), damping=False, select=conservative, speed=0.5), 0.02
    else:  # no escalation to the exact Jacobian, which is not symmetric: CG would fall back to the direct solver
        model, h = benchmark_cloth(12), 1.0 / 60.0
    tr = _run(model, h, 60, solver=solver, jacobian=jacobian, solver_options={"rtol": 1e-12},
              escalate_jacobian=jacobian == "exact")
    e = _energies(model, tr)
    assert np.abs(e - e[0]).max() <= _newton_bound(model, tr, 1e-10) + 1e-12 * np.abs(e).max()


def test_energy_never_gained_with_dissipation():
    """With spring damping and drag the total energy decreases at every step (to what the Newton tolerance allows)."""
    rng = np.random.default_rng(7402)
    model = random_scene(rng, damping=True, drag=True, speed=0.5)
    tr = _run(model, 0.02, 60)
    e = _energies(model, tr)
    assert np.all(np.diff(e) <= _newton_bound(model, tr, 1e-10) / 60 + 1e-12 * np.abs(e).max())
    assert e[-1] < e[0] - 1e-3 * (np.abs(e).max() + 1.0)  # and it does dissipate


def test_momentum_conserved_without_external_forces():
    """Only internal terms (no gravity, drag, ...: ``ForceTerm.external`` excluded), no fixed particles: linear and
    angular momentum are constant to 1e-10 relative."""
    rng = np.random.default_rng(7403)
    model = random_scene(rng, damping=True, select=internal, fixed=0, fixed_pairs=False, speed=0.5)
    tr = _run(model, 0.02, 60)
    m = model.particle_mass[:, None]
    p = np.sum(m * tr.qd, axis=1)
    L = np.sum(np.cross(tr.q, m * tr.qd), axis=1)
    for x in (p, L):
        assert np.abs(x - x[0]).max() <= 1e-10 * (np.abs(x).max() + np.abs(m * tr.qd).sum(axis=(1, 2)).max())


def test_stiff_cloth_keeps_its_energy_at_large_steps():
    """Undamped benchmark cloth (8 x 8) at h = 0.1 s: every step converges (some only in 2-8 substeps, recorded in
    ``StepStats.extra``) and the energy stays at its initial value, where a retake as implicit Euler left unconverged
    steps that gained 200 J."""
    model = benchmark_cloth(8)
    tr = _run(model, 0.1, 30, newton_tol=1e-5)
    assert all(s.ok for s in tr.stats)
    substeps = [s.extra.get("substeps", 1) for s in tr.stats]
    assert max(substeps) >= 2 and all(n in (1, 2, 4, 8) for n in substeps)
    # substeps come from a retake of the step, or from the memory of the last retake (nothing retaken)
    assert all(("retaken" in s.extra or "remembered_substeps" in s.extra) == (n > 1)
               for s, n in zip(tr.stats, substeps))
    e = _energies(model, tr)
    assert np.abs(e - e[0]).max() <= _newton_bound(model, tr, 1e-5)  # about 1e-3 J here


def test_retake_bookkeeping(monkeypatch):
    """The retake loop, driven by a stage that fails a given number of times: the first attempt that succeeds in
    every substep is kept and recorded; after 32 failed substeps (the default ladder) the step is reported, not
    hidden."""
    from springsim.integrators.energy_momentum import IntegratorEnergyMomentum

    model = benchmark_cloth(4)
    # each failed attempt stops at its first failed substep: k forced failures end at 2**k substeps
    for failures, substeps, ok in ((0, 1, True), (1, 2, True), (2, 4, True), (3, 8, True), (5, 32, True),
                                   (1000, 32, False)):
        integ = make_integrator("energy_momentum", model, on_nonconvergence="ignore")
        real = IntegratorEnergyMomentum._substep
        calls = []

        def substep(self, q, v, h, stats, calls=calls, failures=failures):
            calls.append(h)
            q1, v1, ok_k = real(self, q, v, h, stats)
            if len(calls) <= failures:  # as a Newton stage that missed its limit
                stats.newton_converged = False
                stats.fail("forced")
                return q1, v1, False
            return q1, v1, ok_k

        monkeypatch.setattr(IntegratorEnergyMomentum, "_substep", substep)
        s0, s1 = model.state(), model.state()
        st = integ.step(s0, s1, 0.01)
        assert st.ok == ok
        assert st.extra.get("substeps", 1) == substeps
        assert len(st.extra.get("retaken", [])) == {1: 0, 2: 1, 4: 2, 8: 3, 32: 5}[substeps]
        if ok:  # the kept attempt covers the step in equal substeps
            assert calls[-substeps:] == [0.01 / substeps] * substeps
        else:
            assert "forced" in "; ".join(st.failures)
        monkeypatch.undo()


def test_rotating_spring_keeps_its_energy():
    """A stiff spring that stretches and turns (a nonlinear potential in the coordinates): the energy-momentum method
    keeps its energy at omega h = 1 where TR-BDF2 loses some."""
    from springsim import ModelBuilder

    b = ModelBuilder(gravity=0.0)
    b.add_particle((0.0, 0.0, 0.0), fixed=True)
    b.add_particle((1.2, 0.0, 0.0), vel=(0.0, 3.0, 0.0), mass=1.0)
    b.add_spring(0, 1, ke=100.0, kd=0.0, rest_length=1.0)
    model = b.finalize()
    tight = {"energy_momentum": dict(newton_tol=1e-12), "tr_bdf2": dict(force_rtol=1e-12)}
    runs = {name: simulate(model, make_integrator(name, model, newton_maxiter=50, **tight[name]), 0.1, 100)
            for name in ("energy_momentum", "tr_bdf2")}
    e = {name: _energies(model, tr) for name, tr in runs.items()}
    em = runs["energy_momentum"]
    assert np.abs(e["energy_momentum"] - e["energy_momentum"][0]).max() <= _newton_bound(model, em, 1e-12) + 1e-12
    assert e["tr_bdf2"][-1] < 0.99 * e["tr_bdf2"][0]


def test_retake_after_a_non_finite_solve(monkeypatch):
    """A linear solve with a non-finite solution (SolverError) is retaken in substeps like a failed stage; at the
    last level the error propagates."""
    from springsim.errors import SolverError
    from springsim.integrators.energy_momentum import IntegratorEnergyMomentum

    model = benchmark_cloth(4)
    real = IntegratorEnergyMomentum._substep
    for raises, expect in ((1, 2), (1000, None)):
        calls = []

        def substep(self, q, v, h, stats, calls=calls, raises=raises):
            calls.append(h)
            if len(calls) <= raises:
                raise SolverError("linear solver 'direct' failed: non-finite solution")
            return real(self, q, v, h, stats)

        monkeypatch.setattr(IntegratorEnergyMomentum, "_substep", substep)
        integ = make_integrator("energy_momentum", model, on_nonconvergence="ignore")
        if expect is None:
            with pytest.raises(SolverError):
                integ.step(model.state(), model.state(), 0.01)
        else:
            st = integ.step(model.state(), model.state(), 0.01)
            assert st.ok and st.extra["substeps"] == expect and "non-finite" in st.extra["retaken"][0]
        monkeypatch.undo()


# -- the step-doubling error estimate and adaptive stepping ---------------------------------------------------------


def _doubled_step(model, h):
    """One step of ``h`` while estimating, from the model's initial state: ``(state, stats, estimate)``."""
    integ = make_integrator("energy_momentum", model, solver="direct", newton_tol=1e-13, newton_maxiter=30,
                            on_nonconvergence="raise")
    integ.estimating = True
    out = model.state()
    st = integ.step(model.state(), out, h)
    return out, st, integ.error_estimate


def test_step_doubling_estimate_is_asymptotically_exact():
    """Against a Radau solution of the ODE, the estimate's mismatch with the true local error (of the returned
    two-half-step result) is under 5 % at h = 0.02 s and shrinks with h (measured 2.6-3.8x per halving; the local
    error itself goes like h^3), for springs, gravitational pairs, damping and drag."""
    from springsim.analysis.reference import reference_trajectory

    model = random_scene(np.random.default_rng(7404), damping=True, drag=True, speed=0.5)
    mismatch = []
    for h in (0.02, 0.01):
        out, st, (eq, ev) = _doubled_step(model, h)
        ref = reference_trajectory(model, [0.0, h], rtol=1e-13, atol=1e-14)
        for est, true in ((eq, out.particle_q - ref.q[-1]), (ev, out.particle_qd - ref.qd[-1])):
            mismatch.append(np.linalg.norm(est - true) / np.linalg.norm(true))
    assert max(mismatch) < 0.05
    assert mismatch[2] < mismatch[0] / 2 and mismatch[3] < mismatch[1] / 2


def test_step_doubling_returns_the_two_half_steps():
    """The result while estimating is exactly two fixed steps of h/2 (to the Newton tolerance): the estimate adds
    the full step only, and fixed particles have no error."""
    model = benchmark_cloth(4)
    out, st, (eq, ev) = _doubled_step(model, 0.02)
    tr = _run(model, 0.01, 2, solver="direct", newton_tol=1e-13, newton_maxiter=30)
    assert np.abs(out.particle_q - tr.q[-1]).max() <= 1e-12
    assert np.abs(out.particle_qd - tr.qd[-1]).max() <= 1e-10
    fixed = model.particle_fixed
    assert fixed.any() and not eq[fixed].any() and not ev[fixed].any() and np.abs(eq).max() > 0
    assert st.linear_solves >= 3  # three stages
    # the step's Newton statistics are those of the returned result (the second half step)
    integ = make_integrator("energy_momentum", model, solver="direct", newton_tol=1e-13, newton_maxiter=30)
    mid, half = model.state(), model.state()
    integ.step(model.state(), mid, 0.01)
    last = integ.step(mid, half, 0.01)
    assert (st.newton_step_norm, st.residual_norm) == (last.newton_step_norm, last.residual_norm)


def test_adaptive_run_keeps_the_energy():
    """Every accepted step is an energy-momentum step, whatever its size: an adaptive run of an undamped scene
    ends with its initial energy (to what the Newton tolerance allows), and the fixed-step estimating flag is
    restored afterwards."""
    from springsim.run.adaptive import simulate_adaptive

    model = random_scene(np.random.default_rng(7401), damping=False, select=conservative, speed=0.5)
    integ = make_integrator("energy_momentum", model, solver="direct", newton_tol=1e-11)
    assert not integ.estimating  # fixed steps pay for no estimate
    tr = simulate_adaptive(model, integ, 1.0, time_rtol=1e-4, time_atol=1e-4)
    assert not integ.estimating
    info = tr.adaptive_stats
    assert info["accepted"] > 10 and info["h_max"] > 2 * info["h_min"]  # the step did adapt
    e0, e1 = (total_energy(model, tr.q[k], tr.qd[k]) for k in (0, -1))  # the last frame is a step end
    bound = 2 * info["accepted"] * 2.0 * np.sqrt(3.0) * 1e-11 * model.particle_mass.sum() * np.abs(tr.qd).max()
    assert abs(e1 - e0) <= bound + 1e-12 * abs(e0)


def test_step_doubling_failure_is_reported_without_estimate(monkeypatch):
    """A stage that fails while estimating fails the step (no retake in substeps: the adaptive driver shrinks the
    step) and leaves no estimate; the adaptive driver then retries with a smaller step and finishes."""
    from springsim.integrators.energy_momentum import IntegratorEnergyMomentum
    from springsim.run.adaptive import simulate_adaptive

    model = benchmark_cloth(4)
    real = IntegratorEnergyMomentum._substep
    calls = []

    def substep(self, q, v, h, stats, w0=None):
        calls.append(h)
        q1, v1, ok = real(self, q, v, h, stats, w0)
        if len(calls) == 3:  # the first step's full-size stage
            stats.newton_converged = False
            stats.fail("forced")
            return q1, v1, False
        return q1, v1, ok

    monkeypatch.setattr(IntegratorEnergyMomentum, "_substep", substep)
    integ = make_integrator("energy_momentum", model, solver="direct", on_nonconvergence="ignore")
    integ.estimating, integ.retake = True, False  # as the adaptive driver sets them
    st = integ.step(model.state(), model.state(), 0.02)
    assert not st.ok and integ.error_estimate is None and "substeps" not in st.extra
    # a failed first half step still completes the step (both halves, no full step for the estimate)
    calls[:] = [0, 0]  # the next call is the third: the first half step
    integ.step(model.state(), model.state(), 0.02)
    assert calls[2:] == [0.01, 0.01] and integ.error_estimate is None
    calls.clear()
    tr = simulate_adaptive(model, integ, 0.05, h0=0.02, time_rtol=1e-3, time_atol=1e-3)
    assert tr.adaptive_stats["failed_attempts"] == 1 and all(s.ok for s in tr.stats)
