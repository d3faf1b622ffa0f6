"""The immutable :class:`Model` (what is constant during a run) and the :class:`State`.

Symbols used throughout springsim: ``N`` particles, ``q`` positions and ``qd``
velocities of shape (N, 3) [m], [m/s]; ``M`` the diagonal mass matrix.
"""

from __future__ import annotations

import hashlib
from dataclasses import dataclass, field, fields
from typing import NamedTuple

import numpy as np

__all__ = ["Model", "State", "ClothGrid", "AXES"]

#: Names of the coordinate axes, as accepted for ``up_axis``.
AXES = ("x", "y", "z")


def _frozen_data(a: np.ndarray) -> bool:
    """Whether ``a`` is a read-only C-contiguous view of an immutable ``bytes`` object (made by :func:`_readonly`)."""
    base = a
    while isinstance(base, np.ndarray):
        base = base.base
    return type(base) is bytes and not a.flags.writeable and a.flags.c_contiguous


def _readonly(a: np.ndarray) -> np.ndarray:
    """``a`` as a C-contiguous array over a private, immutable copy of its data.

    The data lives in a ``bytes`` object, so neither ``setflags(write=True)`` (numpy refuses it for an
    array whose base is read-only) nor writing through the caller's array can change it.
    """
    if _frozen_data(a):
        return a  # already private and immutable (a shallow copy of a model shares it)
    a = np.ascontiguousarray(a)
    return np.frombuffer(a.tobytes(), dtype=a.dtype).reshape(a.shape)


def _rebuild(cls, kwargs: dict):
    """Unpickle (or copy) a :class:`Model`: through ``__init__``, so that its arrays are frozen again."""
    return cls(**kwargs)


class ClothGrid(NamedTuple):
    """A cloth grid inside a model: particle ``(i, j)`` is ``start + j*nx + i``."""

    start: int
    nx: int
    ny: int


@dataclass(frozen=True, eq=False)
class Model:
    """A validated mass-spring system; build it with :class:`springsim.ModelBuilder`.

    All arrays are read-only, over private copies of the data that nothing can make writable (not
    ``setflags(write=True)``, not writing to the arrays the model was built from); pickling and
    copying (``copy.copy``, ``copy.deepcopy``) give models that are just as immutable. Integrators
    never write to a model.

    Attributes
    ----------
    particle_q : ndarray, shape (N, 3)
        Initial positions [m].
    particle_qd : ndarray, shape (N, 3)
        Initial velocities [m/s] (zero for fixed particles).
    particle_mass : ndarray, shape (N,)
        Masses [kg], all > 0.
    particle_radius : ndarray, shape (N,)
        Radii [m] used only for drawing (NaN where not given).
    particle_drag : ndarray, shape (N,)
        Linear drag coefficients beta [N s/m] of ``F = -beta qd``.
    particle_fixed : ndarray of bool, shape (N,)
        Fixed particles never move.
    spring_indices : ndarray of int64, shape (S, 2)
    spring_stiffness : ndarray, shape (S,)
        ke [N/m].
    spring_damping : ndarray, shape (S,)
        kd [N s/m] of the damping force along the spring (PA2 eq. 8).
    spring_rest_length : ndarray, shape (S,)
        l0 [m].
    gravitational_indices : ndarray of int64, shape (P, 2)
    gravitational_G : ndarray, shape (P,)
        Gravitational constant of each pair [N m^2/kg^2].
    gravitational_softening : ndarray, shape (P,)
        Softening length of each pair [m]: below it the attraction has a linear core (see
        :mod:`springsim.forces.gravitational`; default :func:`springsim.builder.default_softening`).
    gravity : float
        Acceleration along the up axis [m/s^2] (default -9.81).
    up_axis : int
        0, 1 or 2 for x, y, z.
    pair_epsilon : float
        Distance [m] below which a spring's direction is treated as undefined (see
        :mod:`springsim.forces.spring`).
    cloth_grids : tuple of ClothGrid
        The cloth grids added by :meth:`springsim.ModelBuilder.add_cloth_grid` (for drawing and
        export: their quads are faces).
    metadata : dict
        Free-form information (``name``, ``source``) carried along; not used by the numerics.
    """

    particle_q: np.ndarray
    particle_qd: np.ndarray
    particle_mass: np.ndarray
    particle_radius: np.ndarray
    particle_drag: np.ndarray
    particle_fixed: np.ndarray
    spring_indices: np.ndarray
    spring_stiffness: np.ndarray
    spring_damping: np.ndarray
    spring_rest_length: np.ndarray
    gravitational_indices: np.ndarray
    gravitational_G: np.ndarray
    gravitational_softening: np.ndarray
    gravity: float = -9.81
    up_axis: int = 2
    pair_epsilon: float = 1e-9
    cloth_grids: tuple = ()
    metadata: dict = field(default_factory=dict)

    def __post_init__(self):
        for f in fields(self):
            v = getattr(self, f.name)
            if isinstance(v, np.ndarray):
                object.__setattr__(self, f.name, _readonly(v))

    def __reduce__(self):
        # The default would restore the fields without __post_init__: unpickled arrays would be writable.
        return _rebuild, (type(self), {f.name: getattr(self, f.name) for f in fields(self)})

    # -- counts ---------------------------------------------------------------
    @property
    def particle_count(self) -> int:
        return int(self.particle_mass.shape[0])

    @property
    def spring_count(self) -> int:
        return int(self.spring_indices.shape[0])

    @property
    def gravitational_count(self) -> int:
        return int(self.gravitational_indices.shape[0])

    @property
    def free_particles(self) -> np.ndarray:
        """Indices of the particles that move, shape (F,)."""
        return np.flatnonzero(~self.particle_fixed)

    @property
    def free_count(self) -> int:
        return int(self.particle_count - np.count_nonzero(self.particle_fixed))

    @property
    def dof_count(self) -> int:
        """Degrees of freedom of the implicit system (3 per free particle)."""
        return 3 * self.free_count

    @property
    def gravity_vector(self) -> np.ndarray:
        g = np.zeros(3)
        g[self.up_axis] = self.gravity
        return g

    def state(self) -> "State":
        """A fresh :class:`State` initialised from the model."""
        return State(self.particle_q.copy(), self.particle_qd.copy())

    def fingerprint(self) -> str:
        """SHA-256 (hex) of everything that determines the motion: every array, ``gravity``,
        ``up_axis``, ``pair_epsilon`` and the cloth grids, not ``metadata``.

        Two models with equal fingerprints simulate identically; the value is the same on every
        machine (arrays are hashed as little-endian bytes with their dtype and shape). Saved
        trajectories record it (:meth:`springsim.driver.Trajectory.save`).
        """
        h = hashlib.sha256()
        for f in fields(self):
            if f.name == "metadata":
                continue
            v = getattr(self, f.name)
            h.update(f.name.encode())
            if isinstance(v, np.ndarray):
                a = np.ascontiguousarray(v, dtype=v.dtype.newbyteorder("<"))
                h.update(f"{a.dtype.str}{a.shape}".encode())
                h.update(a.tobytes())
            else:
                v = tuple(tuple(int(x) for x in g) for g in v) if f.name == "cloth_grids" else float(v)
                h.update(repr(v).encode())
        return h.hexdigest()

    def __repr__(self) -> str:
        return (
            f"Model(particles={self.particle_count}, fixed={int(self.particle_fixed.sum())}, "
            f"springs={self.spring_count}, gravitational={self.gravitational_count})"
        )


@dataclass
class State:
    """Positions and velocities of all particles.

    Attributes
    ----------
    particle_q : ndarray, shape (N, 3)
        Positions [m].
    particle_qd : ndarray, shape (N, 3)
        Velocities [m/s].
    """

    particle_q: np.ndarray
    particle_qd: np.ndarray

    def copy(self) -> "State":
        return State(self.particle_q.copy(), self.particle_qd.copy())

    def is_finite(self) -> bool:
        return bool(np.isfinite(self.particle_q).all() and np.isfinite(self.particle_qd).all())
