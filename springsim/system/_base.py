"""The system interface: everything an integrator needs from a backend, and nothing else.

An integrator (:mod:`springsim.integrators`) is written once against :class:`System`, as scipy's
``OdeSolver`` sees only ``fun`` and ``jac`` and PETSc's ``TS`` only ``Vec`` and ``Mat``. A system owns the
force terms, the assembly of the stage matrix ``A = M - a dF/dq - b dF/dqd``, the linear solver, and every
reduction (norms, sums, finiteness, equality), so that the same integrator code runs serially
(:class:`~springsim.system.SerialSystem`: the assembler and a linear solver on one process) and distributed
(:class:`springsim.distributed.DistributedSystem`: PETSc matrices and KSP over MPI ranks).

Layouts
-------
* **State arrays** ``(n, 3)``: positions, velocities, forces of the particles this process holds. Serially
  ``n`` is every particle and :attr:`System.fixed` indexes the fixed ones (the integrators hold them); in a
  distributed system ``n`` is the particles this rank owns, all free (fixed particles never move, so no rank
  owns them). Elementwise numpy operations on state arrays are the same on every backend; anything that
  combines values across particles goes through the system (:meth:`System.norm`, :meth:`System.sum`, ...), so
  that every rank takes the same decision.
* **DOF vectors** ``(3 F_local,)``: the unknowns of the linear systems, three per free particle held here
  (:meth:`System.gather`, :meth:`System.scatter_add`).

Every reduction is over free particles only: a fixed particle's residual (the force that holds it) is not an
unknown.
"""

from __future__ import annotations

from abc import ABC, abstractmethod

import numpy as np

__all__ = ["System"]


class System(ABC):
    """A backend for the integrators: forces, stage matrices, solves and reductions over state arrays.

    Attributes
    ----------
    model : Model
        The model being simulated (the same on every rank).
    terms : list of ForceTerm
        The force terms this process evaluates (serially every term the model uses).
    particle_mass : ndarray, shape (n,)
        Masses [kg] of the particles of the state layout.
    fixed : ndarray of int, shape (k,)
        Indices of fixed particles in the state layout (empty in a distributed system).
    is_root : bool
        Whether this process gathers frames and reports (always True serially).
    size : int
        Number of processes the system spans (1 serially).
    """

    model = None
    #: Whether the fixed particles are rows of the state arrays (serially) or not (distributed).
    holds_fixed: bool = True
    #: Whether :attr:`model` is the whole Model. A distributed system built from a rank's share of a scene
    #: (:class:`springsim.distributed.scene.ScenePart`) has no whole model anywhere: it then provides
    #: ``initial_state()`` (its state arrays at the start), ``energy_start(q, qd)`` (the energy bound's sums) and
    #: ``frame_energy(q, qd)`` (a frame's total energy, for the growth check), and the driver uses them.
    whole_model: bool = True
    terms: list = []
    particle_mass: np.ndarray
    fixed: np.ndarray
    is_root: bool = True
    size: int = 1

    # -- set-up -------------------------------------------------------------------------------------------------
    def metadata(self) -> dict:
        """What a trajectory's ``meta`` records of the backend (``backend``, and its own keys).

        Returns
        -------
        dict
            ``{"backend": "serial"}`` here; a backend overrides it with its own (the PETSc one: ``"petsc"``, ``ranks``,
            ``partitioner``).
        """
        return {"backend": "serial"}

    @abstractmethod
    def local_state(self, q: np.ndarray, qd: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """The state arrays of this process from full (N, 3) positions [m] and velocities [m/s] (copies).

        Parameters
        ----------
        q : ndarray, shape (N, 3)
            Positions [m] of every particle of the model.
        qd : ndarray, shape (N, 3)
            Velocities [m/s] of every particle of the model.

        Returns
        -------
        q, qd : ndarray, shape (n, 3)
            Float64 copies of the rows this process holds.
        """

    @abstractmethod
    def gather_state(self, q: np.ndarray, qd: np.ndarray) -> tuple[np.ndarray | None, np.ndarray | None]:
        """Full (N, 3) copies of the state arrays ``(q, qd)`` on the root process, ``(None, None)`` elsewhere.

        Collective: every process calls it. Fixed particles take their positions from the model.

        Parameters
        ----------
        q : ndarray, shape (n, 3)
            Positions [m] of this process's state layout.
        qd : ndarray, shape (n, 3)
            Velocities [m/s] of this process's state layout.

        Returns
        -------
        q, qd : ndarray, shape (N, 3), or None
            Every particle's positions and velocities on the root process; None on the others.
        """

    # -- linear algebra set-up ----------------------------------------------------------------------------------
    @property
    @abstractmethod
    def linear_rtol(self) -> float:
        """The relative residual the linear solves reach by default (the floor of inexact Newton's forcing)."""

    @abstractmethod
    def default_jacobian(self) -> str:
        """The Jacobian mode integrators use when none is given: ``"spd"`` where the solver needs a symmetric
        positive definite matrix, else ``"exact"``.

        Returns
        -------
        {"spd", "exact"}
        """

    # -- forces -------------------------------------------------------------------------------------------------
    @abstractmethod
    def forces(self, q: np.ndarray, qd: np.ndarray, out: np.ndarray, *,
               damping_geometry: np.ndarray | None = None) -> np.ndarray:
        """Total force [N] on the particles of the state layout at ``(q, qd)``, into ``out``; returns ``out``.

        Parameters
        ----------
        q : ndarray, shape (n, 3)
            Positions [m].
        qd : ndarray, shape (n, 3)
            Velocities [m/s].
        out : ndarray, shape (n, 3)
            Output array, overwritten with the force [N].
        damping_geometry : ndarray, shape (n, 3), optional
            Positions [m] at which the dissipative terms take their geometry (the spring directions) instead
            of ``q`` (:meth:`springsim.forces.ForceTerm.eval_force`).

        Returns
        -------
        ndarray, shape (n, 3)
            ``out``.
        """

    @abstractmethod
    def forces_discrete(self, q0: np.ndarray, q1: np.ndarray, qd: np.ndarray, out: np.ndarray) -> np.ndarray:
        """The energy-momentum force over the step from ``q0`` to ``q1`` with the velocity ``qd``
        (:meth:`springsim.forces.ForceTerm.eval_force_discrete`), into ``out``.

        Parameters
        ----------
        q0, q1 : ndarray, shape (n, 3)
            Positions [m] at the start and the end of the step.
        qd : ndarray, shape (n, 3)
            Midpoint velocity [m/s].
        out : ndarray, shape (n, 3)
            Output array, overwritten with the force [N].

        Returns
        -------
        ndarray, shape (n, 3)
            ``out``.
        """

    @abstractmethod
    def potential_energy(self, q: np.ndarray) -> float:
        """Potential energy [J] of the conservative terms at ``q``, summed over every process.

        Pairs between fixed particles are left out (a constant), so only differences are meaningful.

        Parameters
        ----------
        q : ndarray, shape (n, 3)
            Positions [m].

        Returns
        -------
        float
            Potential energy [J].
        """

    @abstractmethod
    def dissipation(self, geometry: np.ndarray, qd: np.ndarray) -> float:
        """Rayleigh dissipation function ``1/2 qd^T D qd`` [W] of the dissipative terms with their geometry at
        ``geometry``, summed over every process (:meth:`springsim.forces.ForceTerm.dissipation`).

        Parameters
        ----------
        geometry : ndarray, shape (n, 3)
            Positions [m] that give the dissipative terms their geometry.
        qd : ndarray, shape (n, 3)
            Velocities [m/s].

        Returns
        -------
        float
            Dissipation function [W].
        """

    def stage_terms(self, q: np.ndarray, qd: np.ndarray, out: np.ndarray, geometry: np.ndarray) -> tuple[float, float]:
        """:meth:`forces` with ``damping_geometry=geometry`` into ``out``, and ``(potential_energy(q),
        dissipation(geometry, qd))``: what a minimisation stage evaluates at each trial (a backend may share the
        work of the three, as the PETSc one shares its ghost exchange).

        Parameters
        ----------
        q : ndarray, shape (n, 3)
            Positions [m] of the trial.
        qd : ndarray, shape (n, 3)
            Velocities [m/s] of the trial.
        out : ndarray, shape (n, 3)
            Output array, overwritten with the force [N].
        geometry : ndarray, shape (n, 3)
            Positions [m] that give the dissipative terms their geometry.

        Returns
        -------
        potential : float
            :meth:`potential_energy` at ``q`` [J].
        dissipation : float
            :meth:`dissipation` at ``(geometry, qd)`` [W].
        """
        self.forces(q, qd, out, damping_geometry=geometry)
        return self.potential_energy(q), self.dissipation(geometry, qd)

    @abstractmethod
    def curvature_forces(self, q0: np.ndarray, q1: np.ndarray, out: np.ndarray) -> np.ndarray | None:
        """The forces [N] of the terms' length remainders between ``q0`` and ``q1``
        (:meth:`springsim.forces.ForceTerm.curvature_remainder`) into ``out``, or None where no term (on any
        process) has such lengths.

        Parameters
        ----------
        q0, q1 : ndarray, shape (n, 3)
            Positions [m] of the linearisation and of the trial.
        out : ndarray, shape (n, 3)
            Output array, overwritten with the force [N] when some term has curved lengths.

        Returns
        -------
        ndarray, shape (n, 3), or None
            ``out``, or None (``out`` untouched) when no term has such lengths.
        """

    # -- stage matrices and solves ------------------------------------------------------------------------------
    @abstractmethod
    def assemble(self, q: np.ndarray, qd: np.ndarray, a: float, b: float, mode: str, *,
                 q_start: np.ndarray | None = None, damping_geometry: np.ndarray | None = None):
        """``A = M - a dF/dq - b dF/dqd`` at ``(q, qd)`` over the free DOFs.

        The returned matrix supports ``A @ x`` on DOF vectors and is valid until the next assembly.

        Parameters
        ----------
        q : ndarray, shape (n, 3)
            Positions [m] at which the Jacobians are evaluated.
        qd : ndarray, shape (n, 3)
            Velocities [m/s] at which the Jacobians are evaluated.
        a : float
            Coefficient [s^2] of the position Jacobian ``dF/dq`` (implicit Euler: ``h^2``).
        b : float
            Coefficient [s] of the velocity Jacobian ``dF/dqd`` (implicit Euler: ``h``).
        mode : {"exact", "symmetric", "spd", "mixed"}
            Jacobian mode (:data:`springsim.forces.JACOBIAN_MODES`).
        q_start : ndarray, shape (n, 3), optional
            Selects the energy-momentum Jacobians over the step from ``q_start`` to ``2 q - q_start``
            (:meth:`springsim.assembly.SystemAssembler.assemble`).
        damping_geometry : ndarray, shape (n, 3), optional
            Positions [m] at which the dissipative terms take their geometry for ``dF/dqd``.

        Returns
        -------
        matrix
            The stage matrix [kg] (serially a :class:`~springsim.assembly.SystemMatrix`, distributed a PETSc
            ``Mat``), reused by the next assembly.
        """

    @abstractmethod
    def linearize_at(self, q: np.ndarray) -> None:
        """Make ``q`` the previous linearisation of the ``mixed`` Jacobian mode
        (:meth:`springsim.assembly.SystemAssembler.linearize_at`): a step's stages then depend only on its input.

        Parameters
        ----------
        q : ndarray, shape (n, 3)
            Positions [m] of the linearisation.
        """

    @property
    @abstractmethod
    def last_assembly_s(self) -> float:
        """Wall time of the last assembly [s]."""

    @abstractmethod
    def solve(self, A, rhs: np.ndarray, *, x0: np.ndarray | None = None, rtol: float | None = None):
        """Solve ``A x = rhs`` (DOF vectors): a :class:`~springsim.linsolve.LinearSolveResult` whose ``x`` is a
        DOF vector. ``rtol`` overrides :attr:`linear_rtol` for this solve.

        Parameters
        ----------
        A : matrix
            A stage matrix from :meth:`assemble`.
        rhs : ndarray, shape (3 F_local,)
            Right-hand side (DOF vector).
        x0 : ndarray, shape (3 F_local,), optional
            Initial guess of the iterative solvers; default zero.
        rtol : float, optional
            Relative residual tolerance of this solve; default :attr:`linear_rtol`.

        Returns
        -------
        LinearSolveResult
            The solution ``x`` (DOF vector) and the solve's statistics.
        """

    @abstractmethod
    def precision_loss(self, A) -> float:
        """Relative precision to which ``A`` holds the particle masses, max over processes
        (:meth:`springsim.assembly.SystemAssembler.precision_loss`).

        Parameters
        ----------
        A : matrix
            A stage matrix from :meth:`assemble`.

        Returns
        -------
        float
            ``u max_i max|D_i| / m_i``; above 1 the masses are lost in rounding.
        """

    # -- layouts ------------------------------------------------------------------------------------------------
    @abstractmethod
    def gather(self, x: np.ndarray) -> np.ndarray:
        """The DOF vector of the free particles of a state array ``x`` (n, 3).

        Parameters
        ----------
        x : ndarray, shape (n, 3)
            A state array.

        Returns
        -------
        ndarray, shape (3 F_local,)
            Its free rows, flattened (a view where possible).
        """

    @abstractmethod
    def scatter_add(self, target: np.ndarray, dx: np.ndarray, scale: float = 1.0) -> None:
        """``target[free] += scale * dx`` for a state array ``target`` and a DOF vector ``dx``.

        Parameters
        ----------
        target : ndarray, shape (n, 3)
            State array, added to in place.
        dx : ndarray, shape (3 F_local,)
            DOF vector.
        scale : float
            Factor of ``dx``; default 1.
        """

    # -- reductions (collective) --------------------------------------------------------------------------------
    @abstractmethod
    def sum(self, value: float) -> float:
        """``value`` summed over every process.

        Parameters
        ----------
        value : float
            This process's part.

        Returns
        -------
        float
            The sum, the same on every process.
        """

    @abstractmethod
    def max(self, value: float) -> float:
        """The largest ``value`` over every process.

        Parameters
        ----------
        value : float
            This process's value.

        Returns
        -------
        float
            The maximum, the same on every process.
        """

    @abstractmethod
    def all(self, flag: bool) -> bool:
        """Whether ``flag`` holds on every process.

        Parameters
        ----------
        flag : bool
            This process's flag.

        Returns
        -------
        bool
            The conjunction, the same on every process.
        """

    @abstractmethod
    def free_rows(self, x: np.ndarray) -> np.ndarray:
        """The rows of the free particles of a state array (``x`` itself where every row is free).

        Parameters
        ----------
        x : ndarray, shape (n, 3)
            A state array.

        Returns
        -------
        ndarray, shape (F_local, 3)
            The free rows (a copy when some rows are fixed).
        """

    @property
    @abstractmethod
    def free_dof_count(self) -> int:
        """Free DOFs of the whole system (every process)."""

    def norm(self, x: np.ndarray) -> float:
        """2-norm over the free particles of a state array, or of a DOF vector, over every process.

        Parameters
        ----------
        x : ndarray, shape (n, 3) or (3 F_local,)
            A state array or a DOF vector.

        Returns
        -------
        float
            The 2-norm, the same on every process.
        """
        y = (self.free_rows(x) if x.ndim == 2 else x).reshape(-1)
        return float(np.sqrt(self.sum(float(np.dot(y, y)))))

    def dot(self, x: np.ndarray, y: np.ndarray) -> float:
        """Inner product over the free particles of two state arrays (or of two DOF vectors), over every process.

        Parameters
        ----------
        x, y : ndarray, shape (n, 3) or (3 F_local,)
            Two state arrays or two DOF vectors.

        Returns
        -------
        float
            The inner product, the same on every process.
        """
        if x.ndim == 2:
            x, y = self.free_rows(x), self.free_rows(y)
        return self.sum(float(np.dot(x.reshape(-1), y.reshape(-1))))

    def all_finite(self, *arrays: np.ndarray) -> bool:
        """Whether every array is finite on every process.

        Parameters
        ----------
        *arrays : ndarray
            Arrays of this process (every entry counts, fixed rows included).

        Returns
        -------
        bool
            The same on every process.
        """
        return self.all(all(bool(np.all(np.isfinite(a))) for a in arrays))

    def all_equal(self, x: np.ndarray, y: np.ndarray) -> bool:
        """Whether two state arrays are equal on every process.

        Parameters
        ----------
        x, y : ndarray, shape (n, 3)
            State arrays.

        Returns
        -------
        bool
            The same on every process.
        """
        return self.all(bool(np.array_equal(x, y)))
