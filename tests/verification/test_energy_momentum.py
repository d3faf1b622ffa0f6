"""The energy-momentum method's guarantees: energy conserved without dissipation and never gained with it, linear and
angular momentum conserved without external forces, and the substep retake of a stage that does not converge."""

import numpy as np
import pytest
from helpers import random_scene

from springsim import make_integrator, simulate
from springsim.energy import total_energy
from springsim.scene.gallery import benchmark_cloth


def _energies(model, tr):
    return np.array([total_energy(model, q, v) for q, v in zip(tr.q, tr.qd)])


def _run(model, h, steps, **options):
    options.setdefault("newton_tol", 1e-10)
    integ = make_integrator("energy_momentum", model, on_nonconvergence="raise", **options)
    return simulate(model, integ, h, steps)


@pytest.mark.parametrize("scene, solver, jacobian", [("random", "direct", "exact"), ("random", "direct", "spd"),
                                                     ("cloth", "amg-cg", "spd")])
def test_energy_conserved_without_dissipation(scene, solver, jacobian):
    """Springs, gravitational pairs (random scene), gravity and fixed particles, no damping or drag: the total energy
    stays at its initial value to 1e-9 of the scene's energy scale over 60 steps, whatever the Newton matrix."""
    if scene == "random":
        model, h = random_scene(np.random.default_rng(7401), damping=False, drag=False, speed=0.5), 0.02
    else:  # no escalation to the exact Jacobian, which is not symmetric: CG would fall back to the direct solver
        model, h = benchmark_cloth(12), 1.0 / 60.0
    tr = _run(model, h, 60, solver=solver, jacobian=jacobian, solver_options={"rtol": 1e-12},
              escalate_jacobian=jacobian == "exact")
    e = _energies(model, tr)
    scale = np.abs(e).max() + 1.0
    assert np.abs(e - e[0]).max() <= 1e-9 * scale, np.abs(e - e[0]).max()


def test_energy_never_gained_with_dissipation():
    """With spring damping and drag the total energy decreases at every step (to 1e-9 of its scale)."""
    rng = np.random.default_rng(7402)
    model = random_scene(rng, damping=True, drag=True, speed=0.5)
    e = _energies(model, _run(model, 0.02, 60))
    scale = np.abs(e).max() + 1.0
    assert np.all(np.diff(e) <= 1e-9 * scale)
    assert e[-1] < e[0] - 1e-3 * scale  # and it does dissipate


def test_momentum_conserved_without_external_forces():
    """No gravity, drag or fixed particles, damped springs and gravitational pairs: linear and angular momentum are
    constant to 1e-10 relative."""
    rng = np.random.default_rng(7403)
    model = random_scene(rng, damping=True, drag=False, gravity=0.0, fixed=0, fixed_pairs=False, speed=0.5)
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
    assert all(("retaken" in s.extra) == (n > 1) for s, n in zip(tr.stats, substeps))
    e = _energies(model, tr)
    assert np.abs(e - e[0]).max() <= 1e-6
