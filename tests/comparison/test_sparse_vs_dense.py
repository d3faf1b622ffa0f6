"""Sparse path (assembler + ``direct``) against the naive dense path: same solution, same trajectory."""

from __future__ import annotations

import numpy as np
import pytest

from helpers import random_scene
from springsim import simulate
from springsim.assembly import SystemAssembler, dense_system, free_dofs
from springsim.forces import JACOBIAN_MODES, make_force_terms
from springsim.integrators import make_integrator
from springsim.linsolve import make_linear_solver


@pytest.mark.parametrize("mode", JACOBIAN_MODES)
def test_sparse_solution_equals_dense_solve(mode):
    """``direct`` on the sparse system equals np.linalg.solve on the dense identity-row system (<= 1e-10)."""
    rng = np.random.default_rng(1021)
    solver = make_linear_solver("direct")
    for _ in range(5):
        model = random_scene(rng, n=int(rng.integers(6, 14)), fixed=int(rng.integers(2, 4)))
        q = model.particle_q + rng.uniform(-0.1, 0.1, model.particle_q.shape)
        qd = np.where(model.particle_fixed[:, None], 0.0, rng.normal(size=q.shape))
        h = 0.02
        rhs = rng.normal(size=3 * model.particle_count)
        A, r = dense_system(model, q, qd, h * h, h, rhs=rhs, mode=mode)
        x_dense = np.linalg.solve(A, r)
        asm = SystemAssembler(model, make_force_terms(model))
        free = free_dofs(model.particle_fixed)
        res = solver.solve(asm.assemble(q, qd, h * h, h, mode), rhs[free])
        assert res.converged
        x_sparse = np.zeros_like(x_dense)
        x_sparse[free] = res.x
        assert np.linalg.norm(x_sparse - x_dense) <= 1e-10 * np.linalg.norm(x_dense)


def _trajectory(model, name, solver, dt, steps, **options):
    integ = make_integrator(name, model, solver=solver, **options)
    return simulate(model, integ, dt, steps)


@pytest.mark.parametrize("jacobian", ["exact", "spd"])
@pytest.mark.parametrize("name", ["linearized_implicit", "implicit_euler"])
def test_trajectory_direct_equals_dense(name, jacobian):
    """A 100-step trajectory with ``direct`` equals the ``dense`` one (rel. diff <= 1e-9)."""
    rng = np.random.default_rng(1022 if jacobian == "exact" else 1023)
    for _ in range(2):
        # modest stiffness and weak gravitational pairs (no close encounters), so Newton
        # converges on every step and the comparison is not dominated by chaos
        model = random_scene(rng, n=8, ke=(10.0, 60.0), G=(0.01, 0.05), speed=0.3)
        opts = dict(jacobian=jacobian, on_nonconvergence="ignore")
        sparse = _trajectory(model, name, "direct", 0.01, 100, **opts)
        dense = _trajectory(model, name, "dense", 0.01, 100, **opts)
        assert sparse.q.shape == (101, model.particle_count, 3)
        for a, b in ((sparse.q, dense.q), (sparse.qd, dense.qd)):
            assert np.linalg.norm(a - b) <= 1e-9 * np.linalg.norm(b)
        assert all(s.newton_converged for s in sparse.stats)
        # both paths took the same Newton decisions
        assert [s.newton_iterations for s in sparse.stats] == [s.newton_iterations for s in dense.stats]
        assert [s.newton_converged for s in sparse.stats] == [s.newton_converged for s in dense.stats]
