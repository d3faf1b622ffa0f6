"""Mechanical energy of a model, and the energy bound the drivers use to detect blow-ups.

Every force springsim models either conserves energy (gravity, springs, gravitational
pairs: each has a potential) or dissipates it (drag, spring damping). So along the exact
motion the total energy ``E = T + V`` never exceeds its initial value ``E0``.

Blow-up detection without NaN
-----------------------------
An unstable integrator can grow the state geometrically for many steps before anything
overflows (``|q|`` of 1e217 m stays finite). :class:`EnergyBound` checks a cheap consequence
of ``E <= E0`` after every step. Spring potentials are >= 0 and a softened gravitational
pair's potential is >= ``-3 c / (2 eps)`` (its value at zero distance), so::

    W = T + V_gravity <= E0 + sum_pairs 3 c / (2 eps) = W_max

where ``T`` is the kinetic energy and ``V_gravity = -sum_i m_i g . q_i``: two O(N) sums per
step, no pair loop. A step with ``W > W_max + growth * E_scale`` has created energy the
forces cannot supply; the drivers stop there like on a NaN. ``E_scale`` is the energy
scale of the start: ``|E0| + T0 + sum |V_term(q0)| + m_total |g| L`` with ``L`` the
diagonal of the initial bounding box (at least 1 m) and the pairs' ``sum 3c/(2 eps)``.
"""

from __future__ import annotations

import numpy as np

from ..forces import make_force_terms

__all__ = ["kinetic_energy", "potential_energy", "total_energy", "EnergyBound"]


def kinetic_energy(model, qd: np.ndarray) -> np.ndarray | float:
    """``T = sum_i m_i |qd_i|^2 / 2`` [J] of one state (N, 3) or of frames (F, N, 3).

    Parameters
    ----------
    model : Model
        Supplies the particle masses [kg], shape (N,).
    qd : ndarray, shape (N, 3) or (F, N, 3)
        Velocities [m/s] of one state or of F frames.

    Returns
    -------
    float or ndarray, shape (F,)
        Kinetic energy [J].
    """
    qd = np.asarray(qd, dtype=np.float64)
    return 0.5 * np.einsum("i,...ij,...ij->...", model.particle_mass, qd, qd)


def potential_energy(model, q: np.ndarray, terms=None) -> np.ndarray | float:
    """Sum of every force term's potential [J] at one state (N, 3) or at frames (F, N, 3).

    ``terms`` defaults to all the model's terms, pairs between fixed particles included.

    Parameters
    ----------
    model : Model
        The model whose force terms are summed.
    q : ndarray, shape (N, 3) or (F, N, 3)
        Positions [m] of one state or of F frames.
    terms : list of ForceTerm, optional
        Terms to sum; default: :func:`springsim.forces.make_force_terms` of ``model`` with ``skip_fixed=False``.

    Returns
    -------
    float or ndarray, shape (F,)
        Potential energy [J].
    """
    terms = make_force_terms(model, skip_fixed=False) if terms is None else terms
    q = np.asarray(q, dtype=np.float64)
    if q.ndim == 2:
        return float(sum(t.potential_energy(q) for t in terms))
    return np.array([sum(t.potential_energy(x) for t in terms) for x in q])


def total_energy(model, q: np.ndarray, qd: np.ndarray, terms=None) -> np.ndarray | float:
    """``T + V`` [J] of one state or of frames (see :func:`kinetic_energy`, :func:`potential_energy`).

    Parameters
    ----------
    model : Model
        The model.
    q, qd : ndarray, shape (N, 3) or (F, N, 3)
        Positions [m] and velocities [m/s] of one state or of F frames.
    terms : list of ForceTerm, optional
        As for :func:`potential_energy`.

    Returns
    -------
    float or ndarray, shape (F,)
        Total mechanical energy [J].
    """
    return kinetic_energy(model, qd) + potential_energy(model, q, terms)


class EnergyBound:
    """The blow-up check of the module docstring for runs of ``model`` from ``(q0, qd0)``.

    Parameters
    ----------
    model : Model
    q0, qd0 : ndarray (N, 3)
        Initial state.
    growth : float
        Allowed excess over the bound, in units of the energy scale (default 10).
    system : System, optional
        The states checked are then the state arrays of this system (:mod:`springsim.system`), and the sums
        are over every process.
    """

    def __init__(self, model, q0: np.ndarray, qd0: np.ndarray, *, growth: float = 10.0, system=None):
        if system is not None and not getattr(system, "whole_model", True):
            self._from_system(system, q0, qd0, growth)
            return
        terms = make_force_terms(model, skip_fixed=False)
        floors = [t.potential_floor() for t in terms]
        # terms without a finite lower bound (uniform gravity) are evaluated every step, in W
        self._unbounded = [t for t, f in zip(terms, floors) if not np.isfinite(f)]
        floor = sum(f for f in floors if np.isfinite(f))  # <= 0
        self._mass = model.particle_mass
        self._sqrt_mass = np.repeat(np.sqrt(self._mass), 3).reshape(-1, 3)
        self._scaled = np.empty_like(self._sqrt_mass)
        parts = [float(t.potential_energy(q0)) for t in terms]
        t0 = float(kinetic_energy(model, qd0))
        self.e0 = t0 + sum(parts)
        self.w_max = self.e0 - floor
        extent = float(np.linalg.norm(np.ptp(q0, axis=0))) if q0.shape[0] else 0.0
        scale = (abs(self.e0) + t0 + sum(abs(p) for p in parts) - floor
                 + float(self._mass.sum()) * abs(model.gravity) * max(extent, 1.0))
        #: The energy scale of the start [J] (module docstring).
        self.scale = scale
        self.limit = self.w_max + growth * scale
        # the work W of the state arrays of a system (:mod:`springsim.system`): its particles' kinetic energy and
        # unbounded potentials, summed over every process, plus the constant part of the particles it leaves out
        self._system, self._offset = system, 0.0
        if system is not None:
            self._unbounded = [t for t in system.terms if not t.pairwise and not np.isfinite(t.potential_floor())]
            self._sqrt_mass = np.repeat(np.sqrt(system.particle_mass), 3).reshape(-1, 3)
            self._scaled = np.empty_like(self._sqrt_mass)
            if not system.holds_fixed:
                fixed = model.particle_fixed[:, None]
                full = [t for t, f in zip(terms, floors) if not np.isfinite(f)]
                self._offset = float(sum(t.potential_energy(np.where(fixed, q0, 0.0)) for t in full))

    def _from_system(self, system, q0, qd0, growth: float) -> None:
        """The bound of a system that holds no whole model (a distributed scene built per rank): its sums over every
        process (:meth:`springsim.distributed.DistributedSystem.energy_start`) instead of the model's terms."""
        s = system.energy_start(q0, qd0)
        parts = list(s["parts"].values())
        self.e0 = s["kinetic"] + sum(parts)
        self.w_max = self.e0 - s["floor"]
        self.scale = (abs(self.e0) + s["kinetic"] + sum(abs(p) for p in parts) - s["floor"]
                      + s["mass"] * abs(system.model.gravity) * max(s["extent"], 1.0))
        self.limit = self.w_max + growth * self.scale
        self._system, self._offset = system, s["fixed_unbounded"]
        self._unbounded = [t for t in system.terms if not t.pairwise and not np.isfinite(t.potential_floor())]
        self._sqrt_mass = np.repeat(np.sqrt(system.particle_mass), 3).reshape(-1, 3)
        self._scaled = np.empty_like(self._sqrt_mass)

    def work(self, q: np.ndarray, qd: np.ndarray) -> float:
        """``W = T + V_gravity`` [J] of a state (the state arrays of ``system`` when one was given).

        Parameters
        ----------
        q, qd : ndarray, shape (N, 3)
            Positions [m] and velocities [m/s] (of the system's particles when a system was given).

        Returns
        -------
        float
            ``W`` [J]: the kinetic energy plus the potentials without a lower bound (uniform gravity).
        """
        # T = |sqrt(m) qd|^2 / 2: one elementwise product into a buffer and one dot, several times faster than a
        # three-operand einsum on large states (it runs after every step)
        v = np.multiply(qd, self._sqrt_mass, out=self._scaled).reshape(-1)
        kinetic = 0.5 * float(np.dot(v, v))
        w = kinetic + float(sum(t.potential_energy(q) for t in self._unbounded))
        return w if self._system is None else self._system.sum(w) + self._offset

    def exceeded(self, q: np.ndarray, qd: np.ndarray) -> float | None:
        """``W`` when it is above the limit (or not a number: the sums overflowed), else None.

        Parameters
        ----------
        q, qd : ndarray, shape (N, 3)
            Positions [m] and velocities [m/s] after a step.

        Returns
        -------
        float or None
            ``W`` [J] (possibly inf or NaN) when above ``limit``, else None.
        """
        with np.errstate(over="ignore", invalid="ignore"):
            w = self.work(q, qd)
        return None if w <= self.limit else w
