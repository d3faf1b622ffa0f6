"""Observed orders of implicit Euler (1), BDF2, TR-BDF2 and the energy-momentum method (2) against the Radau
reference; energy behaviour."""

import numpy as np
import pytest

from springsim import ModelBuilder, make_integrator, simulate
from springsim.analysis.reference import reference_trajectory
from springsim.scene.gallery import benchmark_cloth

T_END = 0.25
STEPS = (40, 80, 160)


@pytest.fixture(scope="module")
def cloth_case():
    """A 5x5 benchmark-style cloth (springs 1e3/1e3/1e2 N/m) and its Radau state at T_END."""
    model = benchmark_cloth(5, ke=1e3, ke_shear=1e3, ke_bend=1e2)
    ref = reference_trajectory(model, [0.0, T_END])
    return model, ref.q[-1]


def _tight(name, tol):
    """The option that solves ``name``'s stages to ``tol``: the residual rule's update tolerance for energy-momentum,
    the force balance of minimize stages for the others."""
    return dict(newton_tol=tol) if name == "energy_momentum" else dict(force_rtol=tol)


def _final_error(model, q_ref, name, steps):
    integ = make_integrator(name, model, newton_maxiter=20, **_tight(name, 1e-10))
    tr = simulate(model, integ, T_END / steps, steps, record=False)
    return float(np.sqrt(np.mean((tr.q[-1] - q_ref) ** 2)))


@pytest.mark.parametrize("name, order", [("implicit_euler", 1.0), ("bdf2", 2.0), ("tr_bdf2", 2.0),
                                         ("energy_momentum", 2.0)])
def test_observed_order(cloth_case, name, order):
    """Halving h divides the final RMS position error by 2^p: p in [0.8, 1.2] (IE) or [1.8, 2.2]."""
    model, q_ref = cloth_case
    errs = np.array([_final_error(model, q_ref, name, n) for n in STEPS])
    p = np.log2(errs[:-1] / errs[1:])
    assert np.all(np.abs(p - order) <= 0.2), (errs, p)


def _spring_energy(name, h=0.05, steps=200):
    """Total energy of an undamped 1 kg / 100 N/m spring after ``steps`` steps, relative to the start."""
    b = ModelBuilder(gravity=0.0)
    b.add_particle((0.0, 0.0, 0.0), fixed=True)
    b.add_particle((1.2, 0.0, 0.0), mass=1.0)
    b.add_spring(0, 1, ke=100.0, kd=0.0, rest_length=1.0)
    model = b.finalize()
    tr = simulate(model, make_integrator(name, model, newton_maxiter=20, **_tight(name, 1e-12)), h, steps)
    x = np.linalg.norm(tr.q[:, 1], axis=1) - 1.0
    e = 0.5 * 100.0 * x**2 + 0.5 * np.sum(tr.qd[:, 1] ** 2, axis=1)
    return e[-1] / e[0]


def test_energy_decay_ordering():
    """On an undamped spring at h = 0.05 s (omega h = 0.5), TR-BDF2 keeps more energy than BDF2, BDF2 more than IE."""
    e_ie, e_bdf2, e_tr = (_spring_energy(n) for n in ("implicit_euler", "bdf2", "tr_bdf2"))
    assert e_ie < e_bdf2 < e_tr <= 1.0 + 1e-9
    assert e_tr > 0.9


def test_energy_momentum_keeps_the_spring_energy():
    """The energy-momentum method keeps the undamped spring's energy (to the Newton tolerance) where TR-BDF2 loses
    some."""
    assert abs(_spring_energy("energy_momentum") - 1.0) <= 1e-9
