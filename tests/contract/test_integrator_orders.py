"""Every registered integrator shows the order of accuracy it declares (``Integrator.order``).

A method that claims second order but is really forward Euler passes every other contract test; this one measures
it. The damped chain (damped springs and drag, so the implicit methods' frozen damping geometry is exercised) is
integrated to 0.6 s at three step sizes against a Radau reference (rtol 1e-10), with the stages solved far below
the time discretisation error; the observed order ``log2(e(h) / e(h/2))`` must be within 0.25 of the declared one.
"""

from __future__ import annotations

import numpy as np
import pytest

from helpers import observed_errors
from springsim.integrators import INTEGRATORS

#: Step sizes per order: in the asymptotic range, above the stage tolerance's effect
STEPS = {1: [0.004, 0.002, 0.001], 2: [0.02, 0.01, 0.005]}


@pytest.mark.parametrize("name", list(INTEGRATORS))
def test_observed_order_is_the_declared_order(name):
    """log2 of the error ratio between halved steps equals the declared order within 0.25 at both halvings."""
    cls = INTEGRATORS[name]
    options = {}
    if cls.implicit:
        options = dict(solver="direct", force_rtol=1e-13, newton_tol=1e-12, newton_maxiter=50,
                       on_nonconvergence="raise")
        if name == "energy_momentum":  # residual stages only: the force tolerance is not theirs
            options.pop("force_rtol")
        elif name != "linearized_implicit":
            options.pop("newton_tol")
        else:
            options = dict(solver="direct")
    e = observed_errors(name, STEPS[cls.order], **options)
    orders = np.log2(e[:-1] / e[1:])
    assert np.all(np.abs(orders - cls.order) <= 0.25), (name, cls.order, orders)


def test_a_false_order_claim_is_caught(monkeypatch):
    """Forward Euler registered as a 'second-order' method fails the measurement: its observed order is 1."""
    from springsim.integrators import IntegratorExplicitEuler

    class FakeSecondOrder(IntegratorExplicitEuler):
        name = "fake_second_order"
        order = 2

    monkeypatch.setitem(INTEGRATORS, "fake_second_order", FakeSecondOrder)
    e = observed_errors("fake_second_order", STEPS[1])
    orders = np.log2(e[:-1] / e[1:])
    assert np.all(np.abs(orders - 1) <= 0.25) and np.all(np.abs(orders - FakeSecondOrder.order) > 0.25)
