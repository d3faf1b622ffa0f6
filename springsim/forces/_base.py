"""Force-term interface and the 3x3 block COO triplets every Jacobian is made of.

A Jacobian is a sum of 3x3 blocks at (row particle, column particle). Terms store
them compactly as :class:`Blocks`: a constant :class:`BlockLayout` (computed once
per model) plus an array of value blocks (recomputed every evaluation). A pairwise
term emits one 3x3 block ``K`` per pair, and its local 6x6 Jacobian is
``[[K, -K], [-K, K]]``: four COO triplets ``(i,i,+K) (i,j,-K) (j,i,-K) (j,j,+K)``.
:attr:`Blocks.rows`, :attr:`Blocks.cols` and :attr:`Blocks.blocks` give those
triplets expanded; the assembler uses the compact form directly.
"""

from __future__ import annotations

from abc import ABC, abstractmethod
from dataclasses import dataclass
from typing import ClassVar

import numpy as np

from ._data import ArraySpec

__all__ = ["BlockLayout", "Blocks", "ForceTerm", "JACOBIAN_MODES", "PROJECTED_MODES", "PairIncidence"]

#: Jacobian variants (see README, "Jacobian modes").
#: ``exact``: the true derivative; ``symmetric``: drops the non-symmetric position
#: derivative of spring damping; ``spd``: symmetric, with each local block projected so
#: that ``-dF/dq`` is positive semi-definite; ``mixed``: ``spd`` with each spring's tension in its
#: transverse (geometric) stiffness taken from the linearisation of the previous assembly instead of the
#: current stretch (the primal-dual Newton of the compliant-constraint form with its multiplier eliminated,
#: :mod:`springsim.forces.spring`); the first assembly of a term is ``spd``.
JACOBIAN_MODES = ("exact", "symmetric", "spd", "mixed")
#: The modes whose matrices are positive semi-definite projections (``-dF/dq >= 0``).
PROJECTED_MODES = ("spd", "mixed")


@dataclass(frozen=True, eq=False)
class BlockLayout:
    """Where value blocks go: block ``values[src[k]] * sign[k]`` is added at ``(rows[k], cols[k])``.

    Attributes
    ----------
    rows, cols : ndarray of int64, shape (k,)
        Particle indices of each triplet.
    src : ndarray of int64, shape (k,)
        Which value block each triplet takes.
    sign : ndarray of float64, shape (k,)
        +1 or -1.
    value_count : int
        Number of value blocks a :class:`Blocks` with this layout carries.
    """

    rows: np.ndarray
    cols: np.ndarray
    src: np.ndarray
    sign: np.ndarray
    value_count: int

    @classmethod
    def pairs(cls, pairs: np.ndarray) -> "BlockLayout":
        """Layout of ``[[K, -K], [-K, K]]`` for each pair ``(i, j)`` of ``pairs`` (P, 2).

        Parameters
        ----------
        pairs : ndarray of int64, shape (P, 2)
            Particle index pairs.

        Returns
        -------
        BlockLayout
            Four triplets per pair, ``value_count`` = P.
        """
        i, j = pairs[:, 0], pairs[:, 1]
        p = np.arange(pairs.shape[0], dtype=np.int64)
        one = np.ones(pairs.shape[0])
        return cls(np.concatenate([i, i, j, j]), np.concatenate([i, j, i, j]),
                   np.concatenate([p, p, p, p]), np.concatenate([one, -one, -one, one]),
                   pairs.shape[0])

    @classmethod
    def diagonal(cls, index: np.ndarray) -> "BlockLayout":
        """Layout of one diagonal block per particle of ``index`` (k,).

        Parameters
        ----------
        index : array_like of int, shape (k,)
            Particle indices.

        Returns
        -------
        BlockLayout
            One triplet per particle, ``value_count`` = k.
        """
        index = np.asarray(index, dtype=np.int64)
        k = index.shape[0]
        return cls(index, index, np.arange(k, dtype=np.int64), np.ones(k), k)


@dataclass(frozen=True, eq=False)
class Blocks:
    """3x3 block COO triplets in compact form: a layout and its value blocks (n, 3, 3).

    Attributes
    ----------
    layout : BlockLayout
        Where the value blocks go (shared between evaluations).
    values : ndarray, shape (layout.value_count, 3, 3)
        The value blocks (for a Jacobian, [N/m] or [N s/m]).
    """

    layout: BlockLayout
    values: np.ndarray

    @property
    def rows(self) -> np.ndarray:
        """Block row (particle index) of each triplet: the layout's ``rows``."""
        return self.layout.rows

    @property
    def cols(self) -> np.ndarray:
        """Block column (particle index) of each triplet: the layout's ``cols``."""
        return self.layout.cols

    @property
    def blocks(self) -> np.ndarray:
        """Expanded triplet blocks, shape (k, 3, 3)."""
        return self.values[self.layout.src] * self.layout.sign[:, None, None]

    def toarray(self, particle_count: int) -> np.ndarray:
        """Dense (3N, 3N) matrix of the summed triplets (reference and tests only).

        Parameters
        ----------
        particle_count : int
            N, the number of particles.

        Returns
        -------
        ndarray, shape (3N, 3N)
        """
        out = np.zeros((particle_count, 3, particle_count, 3))
        np.add.at(out, (self.rows, slice(None), self.cols, slice(None)), self.blocks)
        return out.reshape(3 * particle_count, 3 * particle_count)


class ForceTerm(ABC):
    """A vectorised force family (springs, drag, ...).

    Subclasses set :attr:`name`, build themselves from a model with
    :meth:`from_model` (returning ``None`` when the model does not use them) and
    implement :meth:`eval_force` and :meth:`eval_jacobians`.

    Parameters of every method: ``q`` and ``qd`` are (N, 3) positions [m] and
    velocities [m/s] of *all* particles.
    """

    #: Registry and YAML name.
    name: ClassVar[str]
    #: True for terms between pairs of particles (from the model's pair lists); False for terms acting on each
    #: particle alone (from its per-particle arrays). The distributed backend evaluates pairwise terms for the pairs
    #: a rank owns (ghost particles included) and per-particle terms for its owned particles only
    #: (:mod:`springsim.distributed.partition`).
    pairwise: ClassVar[bool] = False

    #: Whether the term's force is ``-grad V`` of its :meth:`potential_energy` (springs' elastic part, gravity,
    #: gravitational pairs). With :attr:`dissipative` this decides whether an implicit stage is a minimisation
    #: (:mod:`springsim.integrators._stage`): every term must be one or the other, or both.
    conservative: ClassVar[bool] = False
    #: Whether the term has a velocity-dependent part ``-D(q) qd``, linear in ``qd`` with ``D`` symmetric positive
    #: semi-definite, whose Rayleigh function is :meth:`dissipation` (spring damping, drag).
    dissipative: ClassVar[bool] = False

    #: Whether :meth:`curvature_remainder` adds anything (the term has lengths whose change is not linear in the
    #: positions: springs).
    curved: ClassVar[bool] = False

    #: Whether the term's forces are external: they change the total momentum (gravity, drag). Internal terms
    #: act between pairs of particles with equal and opposite forces along their difference (springs,
    #: gravitational pairs) and conserve linear and angular momentum. Tests that need a closed system select the
    #: terms by it.
    external: ClassVar[bool] = False

    #: The term's data (:class:`~springsim.forces.ArraySpec` s): per-particle, per-pair or per-model arrays that
    #: the model holds for it (:attr:`springsim.model.model.Model.terms`), and the builder, the YAML loader, the
    #: partitioner and the fingerprint handle from these declarations. A term with per-pair arrays has a pair
    #: list, ``model.<name>_indices``.
    data: ClassVar[tuple[ArraySpec, ...]] = ()
    #: The YAML key of the term's pair list (or of its per-model mapping), and the item path of its error
    #: messages (``springs[3].stiffness``); default :attr:`name`.
    yaml_key: ClassVar[str | None] = None
    #: What the term's pairs are called in run summaries (plural: ``"gravitational pairs"``); default its
    #: :attr:`yaml_key` (``"springs"``).
    pair_label: ClassVar[str | None] = None

    #: Layouts of dF/dq and dF/dqd, or None where the term does not depend on q / qd.
    layout_q: BlockLayout | None = None
    layout_qd: BlockLayout | None = None

    @classmethod
    @abstractmethod
    def from_model(cls, model, *, skip_fixed: bool = True, kernels: str = "auto") -> "ForceTerm | None":
        """The term for ``model``, or None when the model has nothing of it.

        With ``skip_fixed`` (default), items acting only between fixed particles are
        dropped: they never move anything. ``kernels`` (``"auto"``, ``"numba"`` or ``"numpy"``)
        chooses a compiled force evaluation where the term has one (:mod:`springsim._runtime.accel`); terms
        without one ignore it.

        Parameters
        ----------
        model : Model
            The model.
        skip_fixed : bool
            Drop items acting only between fixed particles.
        kernels : {"auto", "numba", "numpy"}
            Force evaluation path.

        Returns
        -------
        ForceTerm or None
        """

    @classmethod
    def complete_data(cls, data: dict, *, particle_q: np.ndarray, particle_mass: np.ndarray,
                      pair_epsilon: float) -> dict:
        """The term's data with its computed values filled in (the ``computed`` arrays' NaN) and the rules
        that involve several arrays checked, when a model is built (:meth:`springsim.ModelBuilder.finalize`).
        The default returns ``data`` unchanged.

        Parameters
        ----------
        data : dict
            Array name -> array (``"indices"`` for the pair list), each value already checked against its
            :class:`~springsim.forces.ArraySpec`.
        particle_q : ndarray, shape (N, 3)
            Initial positions [m].
        particle_mass : ndarray, shape (N,)
            Masses [kg].
        pair_epsilon : float
            The model's :attr:`~springsim.model.model.Model.pair_epsilon` [m].

        Returns
        -------
        dict
            The completed data.

        Raises
        ------
        SceneError
            A rule broken, naming the item (``gravitational[2].softening: ...``).
        """
        return data

    @classmethod
    @abstractmethod
    def naive_force(cls, model, q: np.ndarray, qd: np.ndarray) -> np.ndarray:
        """The term's force (N, 3) [N] on every particle of ``model`` (fixed ones included), written straight
        from the model's arrays with plain gathers and ``np.add.at`` scatters, sharing no code with
        :meth:`eval_force`: the independent reference of :func:`springsim.forces.naive.naive_forces`.

        Parameters
        ----------
        model : Model
            The model.
        q, qd : ndarray, shape (N, 3)
            Positions [m] and velocities [m/s].

        Returns
        -------
        ndarray, shape (N, 3)
            The term's force [N] (zero where the model has nothing of it).
        """

    @abstractmethod
    def eval_force(self, q: np.ndarray, qd: np.ndarray, f_out: np.ndarray, *,
                   damping_geometry: np.ndarray | None = None) -> None:
        """Accumulate this term's forces [N] into ``f_out`` (N, 3).

        ``damping_geometry`` (N, 3), optional: positions at which the dissipative part takes its geometry
        (a spring's direction) instead of ``q``; the implicit stages freeze it so that damping is a dissipation
        potential (:mod:`springsim.integrators._stage`). Terms whose dissipative part does not depend on the
        positions ignore it.

        Parameters
        ----------
        q : ndarray, shape (N, 3)
            Positions [m] of all particles.
        qd : ndarray, shape (N, 3)
            Velocities [m/s] of all particles.
        f_out : ndarray, shape (N, 3)
            Force accumulator [N], added to in place.
        damping_geometry : ndarray, shape (N, 3), optional
            Positions [m] that give the dissipative part its geometry; default ``q``.
        """

    def eval_jacobians(self, q: np.ndarray, qd: np.ndarray, mode: str = "exact", *,
                       work: dict | None = None,
                       damping_geometry: np.ndarray | None = None) -> tuple[Blocks | None, Blocks | None]:
        """``(dF/dq, dF/dqd)`` as :class:`Blocks` (or None where independent).

        With ``damping_geometry`` (see :meth:`eval_force`) the dissipative part is evaluated with that
        geometry: it then has no position derivative, and ``dF/dqd = -D(damping_geometry)``.

        ``mode`` is one of :data:`JACOBIAN_MODES`. ``work``: a dict owned by the caller in
        which the term may keep its large temporaries between calls (:func:`scratch`); the
        returned blocks may then live in it, valid until the next call with the same dict.
        The assembler passes one per term, so repeated assemblies allocate nothing large
        (fresh multi-MB arrays cost page faults on every call: "Assembly and page faults" in
        the linear-solver notes of BENCHMARKS.md#cloth-grid). Overrides must accept ``work``
        (a term with small temporaries may ignore it).

        Parameters
        ----------
        q : ndarray, shape (N, 3)
            Positions [m] of all particles.
        qd : ndarray, shape (N, 3)
            Velocities [m/s] of all particles.
        mode : {"exact", "symmetric", "spd"}
            Jacobian mode (:data:`JACOBIAN_MODES`).
        work : dict, optional
            Scratch space owned by the caller (:func:`scratch`).
        damping_geometry : ndarray, shape (N, 3), optional
            Positions [m] that give the dissipative part its geometry; default ``q``.

        Returns
        -------
        dq : Blocks or None
            ``dF/dq`` [N/m] in :attr:`layout_q`, None where the term does not depend on ``q``.
        dqd : Blocks or None
            ``dF/dqd`` [N s/m] in :attr:`layout_qd`, None where the term does not depend on ``qd``.
        """
        return None, None

    def linearize_at(self, q: np.ndarray, work: dict) -> None:
        """Make ``q`` the previous linearisation of the ``mixed`` Jacobian mode in ``work`` (the term's workspace,
        :meth:`eval_jacobians`); terms without such a state ignore it.

        Parameters
        ----------
        q : ndarray, shape (N, 3)
            Positions [m] of the linearisation.
        work : dict
            The term's workspace.
        """

    def eval_force_discrete(self, q0: np.ndarray, q1: np.ndarray, qd: np.ndarray, f_out: np.ndarray) -> None:
        """Accumulate this term's force over the step from ``q0`` to ``q1`` into ``f_out`` (N, 3).

        The force of the energy-momentum integrator (:mod:`springsim.integrators.energy_momentum`): its
        conservative part is a discrete gradient of :meth:`potential_energy` (Gonzalez 1996),
        ``F . (q1 - q0) = -(V(q1) - V(q0))`` exactly, its dissipative part is evaluated at the midpoint with
        the velocity ``qd``. This default, the force at the midpoint ``(q0 + q1)/2``, is exact for
        dissipative terms and for potentials at most quadratic in ``q`` (uniform gravity); terms with other
        potentials override it.

        Parameters
        ----------
        q0, q1 : ndarray, shape (N, 3)
            Positions [m] at the start and the end of the step.
        qd : ndarray, shape (N, 3)
            Midpoint velocity [m/s].
        f_out : ndarray, shape (N, 3)
            Force accumulator [N], added to in place.
        """
        self.eval_force(0.5 * (q0 + q1), qd, f_out)

    def eval_jacobians_discrete(self, q0: np.ndarray, q1: np.ndarray, qd: np.ndarray, mode: str = "exact", *,
                                work: dict | None = None) -> tuple[Blocks | None, Blocks | None]:
        """Derivatives of :meth:`eval_force_discrete` with respect to the midpoint ``q_m = (q0 + q1)/2`` (``q0``
        held, ``q1 = 2 q_m - q0``) and to ``qd``, as :meth:`eval_jacobians` gives them (same layouts, modes and
        ``work``). At ``q0 = q1`` they are the ordinary Jacobians. This default, the Jacobians at the midpoint,
        goes with the default :meth:`eval_force_discrete`.

        Parameters
        ----------
        q0, q1 : ndarray, shape (N, 3)
            Positions [m] at the start and the end of the step.
        qd : ndarray, shape (N, 3)
            Midpoint velocity [m/s].
        mode : {"exact", "symmetric", "spd"}
            Jacobian mode (:data:`JACOBIAN_MODES`).
        work : dict, optional
            Scratch space owned by the caller (:func:`scratch`).

        Returns
        -------
        dq : Blocks or None
            ``dF/dq`` [N/m] in :attr:`layout_q`, None where the term does not depend on ``q``.
        dqd : Blocks or None
            ``dF/dqd`` [N s/m] in :attr:`layout_qd`, None where the term does not depend on ``qd``.
        """
        return self.eval_jacobians(0.5 * (q0 + q1), qd, mode, work=work)

    def jacobian_symmetric_discrete(self, mode: str) -> bool:
        """:meth:`jacobian_symmetric` for :meth:`eval_jacobians_discrete`.

        Parameters
        ----------
        mode : {"exact", "symmetric", "spd"}
            Jacobian mode (:data:`JACOBIAN_MODES`).

        Returns
        -------
        bool
        """
        return self.jacobian_symmetric(mode)

    def jacobian_symmetric(self, mode: str, *, frozen_damping: bool = False) -> bool:
        """Whether this term's contribution ``-a dF/dq - b dF/dqd`` to the system matrix is symmetric
        in Jacobian ``mode`` (every ``a``, ``b``; ``frozen_damping``: with a ``damping_geometry``). Terms with a
        non-symmetric derivative override it; the assembler declares its matrix symmetric only when every term is.

        Parameters
        ----------
        mode : {"exact", "symmetric", "spd"}
            Jacobian mode (:data:`JACOBIAN_MODES`).
        frozen_damping : bool
            The damping geometry is frozen (``damping_geometry`` given).

        Returns
        -------
        bool
        """
        return True

    def constant_force(self) -> np.ndarray | None:
        """The term's force (N, 3) [N] if it does not depend on the state (uniform gravity), else None.

        :func:`springsim.forces.eval_forces` starts the sum from it instead of from zero (one pass less).
        """
        return None

    def potential_energy(self, q: np.ndarray) -> float:
        """Potential energy [J] at ``q`` (0 for dissipative terms).

        Parameters
        ----------
        q : ndarray, shape (N, 3)
            Positions [m].

        Returns
        -------
        float
            Potential energy [J].
        """
        return 0.0

    def dissipation(self, geometry: np.ndarray, qd: np.ndarray) -> float:
        """Rayleigh dissipation function ``1/2 qd^T D(geometry) qd`` [W] of the dissipative part (0 if none).

        The dissipative force is ``-D qd = -d/dqd`` of it; it is half the power the term dissipates.

        Parameters
        ----------
        geometry : ndarray, shape (N, 3)
            Positions [m] that give the dissipative part its geometry.
        qd : ndarray, shape (N, 3)
            Velocities [m/s].

        Returns
        -------
        float
            Dissipation function [W].
        """
        return 0.0

    def curvature_remainder(self, q0: np.ndarray, q1: np.ndarray, out: np.ndarray) -> None:
        """Add to ``out`` the force of the nonlinear remainder of the term's lengths between ``q0`` and ``q1``, along
        the directions at ``q0`` (the second-order correction of a minimisation stage,
        :mod:`springsim.integrators._stage`, "Curved steps"); nothing for terms without such lengths.

        Parameters
        ----------
        q0, q1 : ndarray, shape (N, 3)
            Positions [m] of the linearisation and of the trial.
        out : ndarray, shape (N, 3)
            Accumulator [N], added to in place.
        """

    def potential_floor(self) -> float:
        """A lower bound [J] of :meth:`potential_energy` over all positions, or ``-inf``.

        Terms whose potential is unbounded below must override this (uniform gravity is
        handled by the caller, see :mod:`springsim.run.energy`); the default 0 holds for
        dissipative terms and for springs.

        Returns
        -------
        float
            The bound [J].
        """
        return 0.0



def scratch(work: dict | None, name: str, shape: tuple) -> np.ndarray:
    """An uninitialised float64 array of ``shape``: ``work[name]`` when it has that shape
    (kept from an earlier call), else a new one, stored in ``work`` when given.

    Parameters
    ----------
    work : dict or None
        Scratch space owned by the caller; None: always a new array.
    name : str
        Key of the array in ``work``.
    shape : tuple of int
        Shape of the array.

    Returns
    -------
    ndarray
        Uninitialised float64 array of ``shape``.
    """
    if work is None:
        return np.empty(shape)
    a = work.get(name)
    if a is None or a.shape != shape:
        a = work[name] = np.empty(shape)
    return a


def pair_geometry(q: np.ndarray, pairs: np.ndarray, eps, work: dict | None = None):
    """Vectorised pair geometry.

    Returns ``d = q_i - q_j`` (P, 3), ``l = |d|`` (P,), ``n = d / l`` (P, 3) and a
    mask ``near`` of pairs closer than ``eps`` (a float or one per pair; there ``n`` is set to zero). With ``work``
    (see :meth:`ForceTerm.eval_jacobians`) ``d``, ``l`` and ``n`` live in it.

    Parameters
    ----------
    q : ndarray, shape (N, 3)
        Positions [m].
    pairs : ndarray of int64, shape (P, 2)
        Particle index pairs ``(i, j)``.
    eps : float or ndarray, shape (P,)
        Distance [m] below which a pair counts as coincident.
    work : dict, optional
        Scratch space owned by the caller (:func:`scratch`).

    Returns
    -------
    d : ndarray, shape (P, 3)
        ``q_i - q_j`` [m].
    l : ndarray, shape (P,)
        ``|d|`` [m].
    n : ndarray, shape (P, 3)
        Unit directions ``d / l`` (zero where ``near``).
    near : ndarray of bool, shape (P,)
        Pairs closer than ``eps``.
    """
    P = pairs.shape[0]
    d = scratch(work, "pair_d", (P, 3))
    np.take(q, pairs[:, 0], axis=0, out=d)
    d -= q[pairs[:, 1]]
    l = np.sqrt(np.einsum("ij,ij->i", d, d), out=scratch(work, "pair_l", (P,)))
    near = l < eps
    n = np.divide(d, np.where(near, 1.0, l)[:, None], out=scratch(work, "pair_n", (P, 3)))
    n[near] = 0.0
    return d, l, n, near


def step_pairs(incidence: "PairIncidence", q0: np.ndarray, q1: np.ndarray):
    """Pair vectors and lengths at both ends of a step, ``(d0, d1, l0, l1)`` (the energy-momentum forms,
    :meth:`ForceTerm.eval_force_discrete`).

    Parameters
    ----------
    incidence : PairIncidence
        The pairs.
    q0, q1 : ndarray, shape (N, 3)
        Positions [m] at the start and the end of the step.

    Returns
    -------
    d0, d1 : ndarray, shape (P, 3)
        Pair vectors [m] at ``q0`` and ``q1``.
    l0, l1 : ndarray, shape (P,)
        Their lengths [m].
    """
    d0 = incidence.diff(q0)
    d1 = incidence.diff(q1)
    return d0, d1, np.sqrt(np.einsum("ij,ij->i", d0, d0)), np.sqrt(np.einsum("ij,ij->i", d1, d1))


def outer(a: np.ndarray, b: np.ndarray, out: np.ndarray | None = None) -> np.ndarray:
    """Row-wise outer products, (P, 3) x (P, 3) -> (P, 3, 3) (into ``out`` when given).

    Parameters
    ----------
    a, b : ndarray, shape (P, 3)
        Row vectors.
    out : ndarray, shape (P, 3, 3), optional
        Output array.

    Returns
    -------
    ndarray, shape (P, 3, 3)
        ``a[p] b[p]^T`` for every row p.
    """
    return np.multiply(a[:, :, None], b[:, None, :], out=out)


class PairIncidence:
    """The signed incidence matrix ``D`` (P x N) of pairs: row p has +1 at ``i`` and -1 at ``j``.

    ``D @ x`` gives the pair differences ``x_i - x_j`` (exactly: each row adds two terms), and
    ``D.T @ f`` accumulates ``+f`` on the first particle and ``-f`` on the second. Both are
    one sparse product over an (N, 3) or (P, 3) array, several times faster than fancy-index
    gathers and ``bincount`` scatters (BENCHMARKS.md#explicit-speed). Built on first use for
    the particle count of the arrays it is given.

    Parameters
    ----------
    pairs : ndarray of int64, shape (P, 2)
        Particle index pairs ``(i, j)``.
    """

    def __init__(self, pairs: np.ndarray):
        self.pairs = pairs
        self._n = -1
        self.D = self.DT = None

    def _build(self, n: int) -> None:
        import scipy.sparse as sp

        P = self.pairs.shape[0]
        indptr = np.arange(0, 2 * P + 1, 2, dtype=np.int64)
        data = np.tile([1.0, -1.0], P)
        self.D = sp.csr_matrix((data, self.pairs.reshape(-1), indptr), shape=(P, n))
        self.DT = self.D.T.tocsr()
        self._n = n

    def diff(self, x: np.ndarray) -> np.ndarray:
        """``x[i] - x[j]`` for every pair, shape (P, 3).

        Parameters
        ----------
        x : ndarray, shape (N, 3)
            Per-particle vectors (positions [m], velocities [m/s], ...).

        Returns
        -------
        ndarray, shape (P, 3)
        """
        if x.shape[0] != self._n:
            self._build(x.shape[0])
        return self.D @ x

    def scatter(self, f: np.ndarray, out: np.ndarray) -> None:
        """Add ``f`` (P, 3) to the first particle of each pair and ``-f`` to the second, in ``out`` (N, 3).

        Parameters
        ----------
        f : ndarray, shape (P, 3)
            Per-pair vectors (forces [N]).
        out : ndarray, shape (N, 3)
            Accumulator, added to in place.
        """
        if out.shape[0] != self._n:
            self._build(out.shape[0])
        out += self.DT @ f


def active_pairs(pairs: np.ndarray, fixed: np.ndarray, skip_fixed: bool) -> np.ndarray:
    """Indices of the pairs that touch at least one free particle (all when not skipping).

    Parameters
    ----------
    pairs : ndarray of int64, shape (P, 2)
        Particle index pairs.
    fixed : ndarray of bool, shape (N,)
        Fixed particles.
    skip_fixed : bool
        Drop pairs between two fixed particles.

    Returns
    -------
    ndarray of int64, shape (k,)
        Indices into ``pairs``.
    """
    if not skip_fixed:
        return np.arange(pairs.shape[0])
    return np.flatnonzero(~(fixed[pairs[:, 0]] & fixed[pairs[:, 1]]))
