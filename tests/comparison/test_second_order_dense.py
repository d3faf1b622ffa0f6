"""Sparse (``direct``) against dense paths for the second-order integrators (BDF2, TR-BDF2, energy-momentum)."""

import numpy as np
import pytest
from helpers import random_scene

from springsim import make_integrator, simulate


@pytest.mark.parametrize("jacobian", ["exact", "spd"])
@pytest.mark.parametrize("name", ["bdf2", "tr_bdf2", "energy_momentum"])
def test_second_order_direct_equals_dense(name, jacobian):
    """A 100-step trajectory with ``direct`` equals the ``dense`` one (rel. diff <= 1e-9)."""
    rng = np.random.default_rng(7301 if jacobian == "exact" else 7302)
    for _ in range(2):
        model = random_scene(rng, n=8, ke=(10.0, 60.0), G=(0.01, 0.05), speed=0.3)
        runs = {}
        for solver in ("direct", "dense"):
            integ = make_integrator(name, model, solver=solver, jacobian=jacobian, on_nonconvergence="ignore")
            runs[solver] = simulate(model, integ, 0.01, 100)
        sparse, dense = runs["direct"], runs["dense"]
        assert sparse.q.shape == (101, model.particle_count, 3)
        for a, b in ((sparse.q, dense.q), (sparse.qd, dense.qd)):
            assert np.linalg.norm(a - b) <= 1e-9 * np.linalg.norm(b)
        assert all(s.newton_converged for s in sparse.stats)
        assert [s.newton_iterations for s in sparse.stats] == [s.newton_iterations for s in dense.stats]
