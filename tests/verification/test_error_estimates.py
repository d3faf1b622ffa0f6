"""The local error estimates of BDF2 and TR-BDF2 against the true local error (a Radau solution of the ODE), and
Shampine's stiff filter that they pass through: the first-order resolvent ``(I - c J)^-1``, computed densely here.
(The energy-momentum method's step-doubling estimate: ``test_energy_momentum.py``.)"""

import numpy as np
import pytest
from helpers import random_scene

from springsim import make_integrator
from springsim.analysis.reference import reference_trajectory
from springsim.integrators import StepStats
from springsim.scene.gallery import benchmark_cloth


def _scene():
    """Springs, gravitational pairs, damping, drag, gravity and fixed particles."""
    return random_scene(np.random.default_rng(7404), damping=True, drag=True, speed=0.5)


def _mismatch(name, h, filtered):
    """Relative mismatch ``|estimate - true| / |true|`` of one step's positions and velocities. BDF2 steps from
    the exact state at ``h`` with the exact state at 0 as its history, so its local error is the textbook one."""
    model = _scene()
    integ = make_integrator(name, model, solver="direct", force_rtol=1e-12, newton_maxiter=30,
                            filter_estimates=filtered, on_nonconvergence="raise")
    integ.estimating = True  # as in adaptive runs
    ref = reference_trajectory(model, [0.0, h, 2 * h], rtol=1e-13, atol=1e-14)
    start = model.state()
    k = 0
    if name == "bdf2":
        k = 1
        start.particle_q[...], start.particle_qd[...] = ref.q[1], ref.qd[1]
        a1 = integ.acceleration(ref.q[1], ref.qd[1]).copy()
        integ.history.record(ref.q[0], ref.qd[0], ref.q[1], ref.qd[1], h, a1, None)
    out = model.state()
    st = integ.step(start, out, h)
    assert st.ok and not st.extra.get("bdf2_start")
    eq, ev = integ.error_estimate
    true_q, true_v = out.particle_q - ref.q[k + 1], out.particle_qd - ref.qd[k + 1]
    return (np.linalg.norm(eq - true_q) / np.linalg.norm(true_q),
            np.linalg.norm(ev - true_v) / np.linalg.norm(true_v))


@pytest.mark.parametrize("name", ["tr_bdf2", "bdf2"])
def test_estimate_matches_the_true_local_error(name):
    """At h = 5 ms the filtered estimate is within 5 % of the true local error, positions and velocities
    (measured: TR-BDF2 0.3-0.5 %, BDF2 1-2 %); at 10 ms the unfiltered one misses the velocities' error by more
    than twice as much (measured 15x and 4.5x): damping and drag make the velocity components stiff."""
    assert max(_mismatch(name, 0.005, True)) < 0.05
    filtered, raw = _mismatch(name, 0.01, True), _mismatch(name, 0.01, False)
    assert raw[1] > 2 * filtered[1]


def _dense_blocks(integ, q, v):
    """``dF/dq`` and ``dF/dqd`` over free DOFs, dense, from the assembler (its Jacobians are checked against
    finite differences in tests/contract)."""
    asm = integ.assembler
    m = np.repeat(integ.model.particle_mass[integ.model.free_particles], 3)
    Jq = np.diag(m) - asm.assemble(q, v, 1.0, 0.0, integ.jacobian).toarray()
    Jv = np.diag(m) - asm.assemble(q, v, 0.0, 1.0, integ.jacobian).toarray()
    return m, Jq, Jv


@pytest.mark.parametrize("jacobian", ["exact", "spd"])
def test_filter_is_the_first_order_resolvent(jacobian):
    """``filter_estimate`` returns ``(I - c J)^-1 e`` for the first-order system's Jacobian
    ``J = [[0, I], [M^-1 dF/dq, M^-1 dF/dqd]]``, solved densely, to round-off; fixed particles stay zero."""
    model = benchmark_cloth(5)
    rng = np.random.default_rng(11)
    integ = make_integrator("tr_bdf2", model, solver="direct", jacobian=jacobian)
    s = model.state()
    q = s.particle_q + 0.01 * rng.standard_normal(s.particle_q.shape)
    v = 0.1 * rng.standard_normal(s.particle_q.shape)
    e = (rng.standard_normal(q.shape), rng.standard_normal(q.shape))
    for arr in (q, v, *e):
        arr[model.particle_fixed] = s.particle_q[model.particle_fixed] if arr is q else 0.0
    c = 0.01
    fq, fv = integ.filter_estimate(q, v, c, e, StepStats(c))
    m, Jq, Jv = _dense_blocks(integ, q, v)
    n = m.size
    J = np.block([[np.zeros((n, n)), np.eye(n)], [Jq / m[:, None], Jv / m[:, None]]])
    x = np.linalg.solve(np.eye(2 * n) - c * J, np.concatenate([integ.assembler.gather(e[0]),
                                                              integ.assembler.gather(e[1])]))
    got = np.concatenate([integ.assembler.gather(fq), integ.assembler.gather(fv)])
    assert np.linalg.norm(got - x) <= 1e-10 * np.linalg.norm(x)
    fixed = model.particle_fixed
    assert not fq[fixed].any() and not fv[fixed].any()


def test_filter_off_and_failed_filter_solve_leave_the_estimate_raw(monkeypatch):
    """``filter_estimates=False`` returns the estimate unchanged; so does a filter solve that fails, counted in
    ``StepStats.extra["unfiltered_estimates"]`` without failing the step."""
    model = benchmark_cloth(4)
    e = (np.ones((model.particle_count, 3)), np.ones((model.particle_count, 3)))
    s = model.state()
    off = make_integrator("tr_bdf2", model, solver="direct", filter_estimates=False)
    assert off.filter_estimates is False and off.filter_estimate(s.particle_q, s.particle_qd, 0.01, e,
                                                                 StepStats(0.01)) is e
    integ = make_integrator("tr_bdf2", model, solver="direct")
    real = integ.solver.solve

    def failing(A, b, **kw):
        res = real(A, b, **kw)
        res.x[:] = np.nan
        return res

    monkeypatch.setattr(integ.solver, "solve", failing)
    st = StepStats(0.01)
    assert integ.filter_estimate(s.particle_q, s.particle_qd, 0.01, e, st) is e
    assert st.extra["unfiltered_estimates"] == 1 and st.ok


def test_filtered_estimates_cost_nothing_in_fixed_step_runs():
    """A filtered estimate costs a solve per step, so TR-BDF2 computes it only while estimating (adaptive runs);
    fixed-step runs do the same solves as without the filter and give the same trajectory. The raw BDF2 estimate
    is free and always there."""
    from springsim import simulate
    from springsim.run.adaptive import simulate_adaptive

    model = benchmark_cloth(5)
    runs = {}
    for filtered in (True, False):
        integ = make_integrator("tr_bdf2", model, solver="direct", filter_estimates=filtered)
        assert integ.estimating is not filtered
        runs[filtered] = simulate(model, integ, 0.01, 5)
        assert (integ.error_estimate is None) is filtered
    assert np.array_equal(runs[True].q, runs[False].q)
    assert [s.linear_solves for s in runs[True].stats] == [s.linear_solves for s in runs[False].stats]
    integ = make_integrator("tr_bdf2", model, solver="direct")
    tr = simulate_adaptive(model, integ, 0.05, time_rtol=1e-3, time_atol=1e-3)
    assert integ.estimating is False and tr.adaptive_stats["accepted"] > 0
    bdf2 = make_integrator("bdf2", model, solver="direct")
    assert bdf2.filter_estimates is False and bdf2.estimating
    simulate(model, bdf2, 0.01, 2)
    assert bdf2.error_estimate is not None


def test_filter_option_is_unused_where_there_is_nothing_to_filter():
    """Integrators without a filtered estimate accept the option and report it unused (a warning, not an error)."""
    model = benchmark_cloth(4)
    for name in ("implicit_euler", "linearized_implicit", "energy_momentum", "symplectic_euler"):
        with pytest.warns(UserWarning, match="filter_estimates"):
            make_integrator(name, model, filter_estimates=False)
