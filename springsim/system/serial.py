"""The serial system: the force terms, the block assembler and a linear solver on one process.

State arrays are every particle's ``(N, 3)`` arrays; the fixed particles are in :attr:`SerialSystem.fixed`
and every reduction skips them. The assembler (the symbolic phase: pattern and scatter map) is built on the
first assembly, so explicit integrators never pay for it.
"""

from __future__ import annotations

import numpy as np

from ..assembly import SystemAssembler
from ..forces import eval_forces, eval_forces_discrete, make_force_terms
from ..linsolve import make_linear_solver
from ..progress import logger, phase
from ._base import System

__all__ = ["SerialSystem"]

_log = logger.getChild("system")


class SerialSystem(System):
    """The serial backend of the integrators.

    Parameters
    ----------
    model : Model
    terms : list of ForceTerm, optional
        Force terms (default: those the model uses, :func:`springsim.forces.make_force_terms`).
    force_kernels : {"auto", "numba", "numpy"}
        Compiled force passes where numba is installed, or the pure numpy path; used only when ``terms`` is
        not given.
    solver : str or LinearSolver
        Linear solver name (:data:`springsim.linsolve.LINEAR_SOLVERS`) or instance, default ``"auto"``.
    solver_options : dict, optional
        Passed to the solver's constructor (e.g. ``{"rtol": 1e-6}``).
    """

    def __init__(self, model, *, terms=None, force_kernels: str = "auto", solver="auto",
                 solver_options: dict | None = None):
        self.model = model
        self.terms = make_force_terms(model, kernels=force_kernels) if terms is None else list(terms)
        self.particle_mass = model.particle_mass
        self.fixed = np.flatnonzero(model.particle_fixed)  # an index array: several times faster than the mask
        self.free = model.free_particles
        self._all_free = self.fixed.size == 0
        self._solver_spec = (solver, dict(solver_options or {}))
        self._solver = None
        self._assembler: SystemAssembler | None = None

    # -- set-up -------------------------------------------------------------------------------------------------
    @property
    def solver(self):
        """The linear solver (built on first use: explicit integrators never need one)."""
        if self._solver is None:
            name, options = self._solver_spec
            self._solver = make_linear_solver(name, **options)
        return self._solver

    @property
    def assembler(self) -> SystemAssembler:
        """The block assembler (the symbolic phase runs on first use)."""
        if self._assembler is None:
            with phase(f"sparsity pattern of {3 * self.model.free_count} DOFs", _log, announce=False):
                self._assembler = SystemAssembler(self.model, self.terms)
        return self._assembler

    def local_state(self, q, qd):
        return np.array(q, dtype=np.float64), np.array(qd, dtype=np.float64)

    def gather_state(self, q, qd):
        return np.array(q, copy=True), np.array(qd, copy=True)

    @property
    def linear_rtol(self) -> float:
        return self.solver.rtol

    def default_jacobian(self) -> str:
        return "spd" if self.solver.needs_spd_for(3 * self.model.free_count) else "exact"

    # -- forces -------------------------------------------------------------------------------------------------
    def forces(self, q, qd, out, *, damping_geometry=None):
        return eval_forces(self.terms, q, qd, out=out, damping_geometry=damping_geometry)

    def forces_discrete(self, q0, q1, qd, out):
        return eval_forces_discrete(self.terms, q0, q1, qd, out)

    def potential_energy(self, q) -> float:
        return float(sum(t.potential_energy(q) for t in self.terms if t.conservative))

    def dissipation(self, geometry, qd) -> float:
        return float(sum(t.dissipation(geometry, qd) for t in self.terms if t.dissipative))

    def curvature_forces(self, q0, q1, out):
        curved = [t for t in self.terms if t.curved]
        if not curved:
            return None
        out.fill(0.0)
        for t in curved:
            t.curvature_remainder(q0, q1, out)
        return out

    # -- stage matrices and solves ------------------------------------------------------------------------------
    def assemble(self, q, qd, a, b, mode, *, q_start=None, damping_geometry=None):
        return self.assembler.assemble(q, qd, a, b, mode, q_start=q_start, damping_geometry=damping_geometry)

    def linearize_at(self, q):
        self.assembler.linearize_at(q)

    @property
    def last_assembly_s(self) -> float:
        return self.assembler.last_time_s

    def solve(self, A, rhs, *, x0=None, rtol=None):
        return self.solver.solve(A, rhs, x0=x0, rtol=rtol)

    def precision_loss(self, A) -> float:
        return self.assembler.precision_loss(A)

    # -- layouts and reductions ---------------------------------------------------------------------------------
    def gather(self, x):
        return (x if self._all_free else x[self.free]).reshape(-1)

    def scatter_add(self, target, dx, scale=1.0):
        if self._all_free:
            target += scale * dx.reshape(-1, 3)
        else:
            target[self.free] += scale * dx.reshape(-1, 3)

    def free_rows(self, x):
        return x if self._all_free else x[self.free]

    @property
    def free_dof_count(self) -> int:
        return 3 * int(self.free.size)

    def sum(self, value):
        return float(value)

    def max(self, value):
        return float(value)

    def all(self, flag):
        return bool(flag)
