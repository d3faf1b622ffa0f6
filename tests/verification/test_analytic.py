"""Integrators against analytic solutions: free fall, a mass on a spring, drag decay; observed orders."""

from __future__ import annotations

import numpy as np
import pytest

from helpers import observed_errors
from springsim import ModelBuilder, simulate
from springsim.integrators import INTEGRATORS, make_integrator

G = -9.81
IMPLICIT_OPTS = dict(solver="direct", newton_tol=1e-12, force_rtol=1e-12, newton_maxiter=20)


def _integrator(name, model):
    """``name`` with its stages solved far below the tolerances the tests check (each stage rule's own option)."""
    cls = INTEGRATORS[name]
    options = {k: v for k, v in IMPLICIT_OPTS.items() if k not in cls.unused_options}
    if cls.implicit:
        rule = make_integrator(name, model, **{k: v for k, v in options.items() if k in ("solver",)})
        options = {k: v for k, v in options.items() if k not in rule.ignored_options()}
    return make_integrator(name, model, **options)


def _free_fall_model(v0=(1.0, -0.5, 3.0)):
    b = ModelBuilder(gravity=G)
    b.add_particle((0.1, 0.2, 0.3), v0, mass=0.7)
    b.add_particle((5.0, 5.0, 5.0), mass=1.0, fixed=True)
    return b.finalize()


@pytest.mark.parametrize("name", sorted(INTEGRATORS))
def test_free_fall(name):
    """Free fall q(t) = q0 + v0 t + g t^2 / 2, v(t) = v0 + g t: every integrator within |g| h t / 2 (+ round-off)."""
    model = _free_fall_model()
    h, steps = 0.01, 50
    tr = simulate(model, _integrator(name, model), h, steps)
    t = tr.t[:, None]
    g = np.array([0.0, 0.0, G])
    q0, v0 = model.particle_q[0], model.particle_qd[0]
    q_exact = q0 + v0 * t + 0.5 * g * t**2
    v_exact = v0 + g * t
    assert np.abs(tr.qd[:, 0] - v_exact).max() <= 1e-12
    # one-step methods for a constant force: q_n = q_exact + c g h t with |c| <= 1/2
    assert np.abs(tr.q[:, 0] - q_exact).max() <= 0.5 * abs(G) * h * tr.t[-1] * (1 + 1e-9) + 1e-12


@pytest.mark.parametrize("name, c", [("explicit_euler", -0.5), ("symplectic_euler", 0.5), ("midpoint", 0.0),
                                     ("implicit_euler", 0.5), ("linearized_implicit", 0.5)])
def test_free_fall_error_closed_form(name, c):
    """Free-fall position error is exactly c g h t (explicit -1/2, symplectic/implicit +1/2, midpoint 0)."""
    model = _free_fall_model()
    h = 0.02
    tr = simulate(model, _integrator(name, model), h, 40)
    q_exact = model.particle_q[0] + model.particle_qd[0] * tr.t[:, None] + 0.5 * np.array([0, 0, G]) * tr.t[:, None] ** 2
    err = tr.q[:, 0] - q_exact
    np.testing.assert_allclose(err[:, 2], c * G * h * tr.t, rtol=0, atol=1e-11)
    np.testing.assert_allclose(err[:, :2], 0.0, atol=1e-12)


def _spring_model(k=40.0, m=0.25, amplitude=0.1):
    """A mass on a spring along x, anchored at a fixed particle, no gravity: x(t) = A cos(omega t)."""
    b = ModelBuilder(gravity=0.0)
    b.add_particle((0.0, 0.0, 0.0), mass=1.0, fixed=True)
    b.add_particle((1.0 + amplitude, 0.0, 0.0), mass=m)
    b.add_spring(0, 1, ke=k, rest_length=1.0)
    return b.finalize()


def _period(t, x):
    """Mean period from the upward zero crossings of x(t) (linear interpolation)."""
    i = np.flatnonzero((x[:-1] < 0) & (x[1:] >= 0))
    tc = t[i] - x[i] * (t[i + 1] - t[i]) / (x[i + 1] - x[i])
    return (tc[-1] - tc[0]) / (tc.size - 1)


@pytest.mark.parametrize("name", ["symplectic_euler", "midpoint", "implicit_euler", "linearized_implicit"])
def test_spring_period(name):
    """A mass m on a spring k oscillates with omega = sqrt(k/m): measured period within 1e-3 of 2 pi/omega."""
    k, m = 40.0, 0.25
    model = _spring_model(k, m)
    omega = np.sqrt(k / m)   # omega = sqrt(k/m) = 12.65 rad/s, period 0.497 s
    h = 0.03 / omega         # omega h = 0.03: period errors O((omega h)^2) <= 3e-4
    steps = int(3.2 * 2 * np.pi / omega / h)
    tr = simulate(model, _integrator(name, model), h, steps)
    x = tr.q[:, 1, 0] - 1.0
    assert abs(_period(tr.t, x) * omega / (2 * np.pi) - 1.0) <= 1e-3
    assert np.abs(tr.q[:, 1, 1:]).max() == 0.0  # motion stays on the axis


def test_spring_trajectory_midpoint():
    """Midpoint follows x(t) = A cos(omega t) to O(h^2) over one period."""
    k, m, A = 40.0, 0.25, 0.1
    model = _spring_model(k, m, A)
    omega = np.sqrt(k / m)
    h = 1e-3
    tr = simulate(model, _integrator("midpoint", model), h, int(2 * np.pi / omega / h))
    x_exact = A * np.cos(omega * tr.t)
    assert np.abs(tr.q[:, 1, 0] - 1.0 - x_exact).max() <= 2 * A * (omega * h) ** 2 * omega * tr.t[-1]


def _drag_model(beta=0.6, m=0.4, v0=(2.0, -1.0, 0.5)):
    b = ModelBuilder(gravity=0.0)
    b.add_particle((0.0, 0.0, 0.0), v0, mass=m, drag=beta)
    return b.finalize()


@pytest.mark.parametrize("name, factor", [
    ("explicit_euler", lambda r: 1 - r),           # v_{n+1} = (1 - h beta/m) v_n
    ("symplectic_euler", lambda r: 1 - r),
    ("midpoint", lambda r: 1 - r + r * r / 2),      # RK2 amplification of v' = -beta/m v
    ("implicit_euler", lambda r: 1 / (1 + r)),      # v_{n+1} = v_n / (1 + h beta/m)
    ("linearized_implicit", lambda r: 1 / (1 + r)),
])
def test_drag_decay(name, factor):
    """Drag: v(t) = v0 exp(-beta t/m); each method matches its discrete amplification factor exactly."""
    beta, m = 0.6, 0.4
    model = _drag_model(beta, m)
    v0 = model.particle_qd[0]
    h, steps = 0.05, 60
    tr = simulate(model, _integrator(name, model), h, steps)
    n = np.arange(steps + 1)[:, None]
    np.testing.assert_allclose(tr.qd[:, 0], v0 * factor(h * beta / m) ** n, rtol=1e-12, atol=1e-14)
    v_exact = v0 * np.exp(-beta * tr.t[:, None] / m)
    assert np.abs(tr.qd[:, 0] - v_exact).max() <= h * beta / m * np.abs(v0).max()
    # position of the exact solution: q(t) = q0 + v0 m/beta (1 - exp(-beta t/m))
    q_exact = v0 * m / beta * (1 - np.exp(-beta * tr.t[:, None] / m))
    assert np.abs(tr.q[:, 0] - q_exact).max() <= 2 * h * np.abs(v0).max()


@pytest.mark.parametrize("name, order, hs", [
    ("explicit_euler", 1, [0.002, 0.001, 0.0005]),
    ("symplectic_euler", 1, [0.002, 0.001, 0.0005]),
    ("midpoint", 2, [0.01, 0.005, 0.0025]),
])
def test_explicit_orders(name, order, hs):
    """Observed order on a smooth damped chain: explicit/symplectic Euler 1, midpoint 2 (within 0.2)."""
    e = observed_errors(name, hs)
    orders = np.log2(e[:-1] / e[1:])
    assert np.all(np.abs(orders - order) <= 0.2), orders
