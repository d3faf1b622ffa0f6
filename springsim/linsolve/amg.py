"""``amg``: smoothed-aggregation algebraic multigrid (pyamg) as a preconditioner, with hierarchy reuse.

One V-cycle of a smoothed-aggregation hierarchy (Vanek, Mandel and Brezina 1996) built for the
implicit system's 3x3 block structure:

* **near-null space**: the six rigid-body modes at the current positions (three translations,
  three infinitesimal rotations about the centroid); rotations cost a spring system no elastic
  energy, so they are near-null for it (Tamstorf, Jones and McCormick 2015). The three
  translations alone (``near_nullspace="translations"``) need about twice the iterations.
* **format**: BSR with 3x3 blocks, so that the three components of a particle are aggregated
  together (``fmt="csr"`` aggregates scalar unknowns).
* **smoothing**: block Gauss-Seidel on the 3x3 blocks, one forward sweep before and one backward
  sweep after, a symmetric V-cycle as CG needs. With pyamg's kernels the backward sweep runs as a
  forward sweep on a reversed copy of each level's matrix (:class:`BlockGaussSeidel`): pyamg's
  backward kernel is about half as fast as its forward one; the compiled kernels sweep backwards in
  place at the forward speed.
* **prolongation**: Jacobi-smoothed aggregation (``omega = 4/3`` over the spectral radius of
  ``D^-1 A`` with the 3x3 block diagonal ``D``), symmetric strength ``theta = 0.1``; for
  symmetric systems the setup of :mod:`springsim.linsolve._sa` (a short Lanczos estimate of the
  spectral radius, warm-started from the previous matrix's Ritz vectors, and aggregates kept per
  matrix pattern), else pyamg's own setup.
* **kernels**: with numba installed (the ``accel`` extra), the setup's sparse products keep their
  patterns across rebuilds and compute only values, and the V-cycle (block Gauss-Seidel sweeps,
  residuals, transfers) and the matrix-vector products of the Krylov method (``amg-cg``,
  ``amg-gmres``) and of the Lanczos estimate run, in kernels compiled for the block sizes
  (:mod:`springsim.linsolve._kernels`; the same hierarchy, cycle and products as the pure path to
  round-off); ``kernels="numpy"`` keeps scipy's products and pyamg's cycle (the values of ``kernels`` are
  those of every ``kernels`` option, :mod:`springsim._runtime.accel`; ``"scipy"`` is a deprecated alias of
  ``"numpy"``).
* **coarsest level**: at most ``max_coarse`` block rows, solved by a dense pseudo-inverse (the
  coarse operator of a flat cloth is exactly singular in its rotation modes).
* **reuse**: a hierarchy is kept for repeated solves with the same matrix and tried on the next
  matrices with the same pattern while a solve stays within ``rebuild_factor * baseline +
  rebuild_slack`` iterations (``baseline``: the count right after the build). A solve that exceeds
  it (or breaks down) is stopped, the hierarchy rebuilt and the solve continued from the iterate
  reached. After such a stale rebuild the next ``cooldown`` matrices get fresh hierarchies at once;
  the cooldown doubles after every stale rebuild (up to ``max_cooldown``) and resets when reuse
  succeeds, so a fast-moving phase wastes one attempt per doubling. A matrix *near* the hierarchy's
  own (relative Frobenius change at most ``nearby``, estimated on an evenly strided sample of at most
  about 32,768 blocks) is tried even during a cooldown. The Newton iterations of one implicit stage serve
  each other's hierarchies once the iterate is close (on the benchmark cloth at n = 64, with the ``mixed``
  Jacobian: changes of 1e-5-4e-5 cost the same CG iterations as a fresh hierarchy, at ke = 1e4 and 1e6),
  but not in the first iterations: changes of 1e-3-6e-3 (small in norm, but in the low-energy transverse
  part of the matrix) cost 3-10x the iterations; consecutive steps of a falling cloth change it by
  3-10e-2 (and a hierarchy does not serve them).

The measurements behind these choices are in the linear-solver notes of BENCHMARKS.md#cloth-grid
("AMG design choices"); the current step times in BENCHMARKS.md#cloth-grid.
"""

from __future__ import annotations

import time

import numpy as np

from ..progress import logger, phase
from ._preconditioner import Preconditioner

_log = logger.getChild("linsolve")

__all__ = ["AMGPreconditioner", "BlockGaussSeidel", "rigid_body_modes", "translation_modes"]

#: Seed of NumPy's global random state during a pyamg setup (restored afterwards).
_PYAMG_SEED = 20_240_611


def rigid_body_modes(positions: np.ndarray) -> np.ndarray:
    """The six rigid-body modes of particles at ``positions`` (F, 3) [m], as a (3F, 6) array.

    Columns 0-2 are unit translations; 3-5 the infinitesimal rotations ``omega x (x - c)``
    about the axes through the centroid ``c`` (centring keeps the columns well conditioned).

    Parameters
    ----------
    positions : ndarray, shape (F, 3)
        Particle positions [m].

    Returns
    -------
    ndarray, shape (3F, 6)
    """
    F = positions.shape[0]
    B = np.zeros((F, 3, 6))
    B[:, 0, 0] = B[:, 1, 1] = B[:, 2, 2] = 1.0
    x, y, z = (positions - positions.mean(axis=0)).T
    B[:, 0, 3], B[:, 1, 3] = -y, x     # about z
    B[:, 1, 4], B[:, 2, 4] = -z, y     # about x
    B[:, 0, 5], B[:, 2, 5] = z, -x     # about y
    return B.reshape(3 * F, 6)


def translation_modes(F: int) -> np.ndarray:
    """The three unit translations of ``F`` particles, (3F, 3).

    Parameters
    ----------
    F : int
        Number of particles.

    Returns
    -------
    ndarray, shape (3F, 3)
    """
    return np.tile(np.eye(3), (F, 1))


class BlockGaussSeidel:
    """One block Gauss-Seidel sweep on a BSR matrix, forward or backward, as a pyamg smoother.

    ``kernels="numba"``: the compiled kernels of :mod:`springsim.linsolve._kernels`, walking the
    block rows forwards or backwards on the matrix's own arrays. ``kernels="numpy"``: pyamg's
    kernel; its backward sweep then runs as a forward sweep on a copy of the matrix with its block
    rows and columns in reverse order (pyamg's backward walk runs at about half the speed of its
    forward one; the copy costs one pass over the matrix data per hierarchy build). Every variant
    is the sweep of pyamg's ``block_gauss_seidel(..., sweep=...)`` up to round-off.

    Called as a pyamg smoother, ``smoother(A, x, b)``, updating ``x`` in place; ``A`` must be the
    matrix given at construction.

    Parameters
    ----------
    A : scipy.sparse.bsr_matrix, shape (n, n)
        The level matrix, 3x3 blocks.
    sweep : {"forward", "backward"}
        Direction of the sweep.
    kernels : {"numpy", "numba"}
        pyamg's kernel or the compiled one.
    """

    def __init__(self, A, sweep: str = "forward", kernels: str = "numpy"):
        from pyamg.util.utils import get_block_diag

        if sweep not in ("forward", "backward"):
            raise ValueError(f"sweep must be 'forward' or 'backward', got {sweep!r}")
        bs = A.blocksize[0]
        nb = A.shape[0] // bs
        self.bs, self.nb, self.backward, self.kernels = bs, nb, sweep == "backward", kernels
        dinv = get_block_diag(A, blocksize=bs, inv_flag=True)
        self.reversed = self.backward and kernels != "numba"
        if self.reversed:
            nnzb = A.indices.size
            self.indptr = np.ascontiguousarray(nnzb - A.indptr[::-1])
            self.indices = np.ascontiguousarray((nb - 1 - A.indices)[::-1])
            self.data = np.ascontiguousarray(A.data[::-1])
            self.dinv = np.ascontiguousarray(dinv[::-1])
        else:
            self.indptr, self.indices = A.indptr, A.indices
            self.data, self.dinv = np.ascontiguousarray(A.data), np.ascontiguousarray(dinv)

    def __call__(self, A, x, b):
        from ._kernels import block_gauss_seidel_backward, block_gauss_seidel_forward

        if not self.reversed:
            sweep = block_gauss_seidel_backward if self.backward else block_gauss_seidel_forward
            sweep(self.indptr, self.indices, self.data, x, b, self.dinv, self.kernels)
            return
        xr = x.reshape(self.nb, self.bs)[::-1].ravel()  # a reversed copy
        br = b.reshape(self.nb, self.bs)[::-1].ravel()
        block_gauss_seidel_forward(self.indptr, self.indices, self.data, xr, br, self.dinv, self.kernels)
        x[...] = xr.reshape(self.nb, self.bs)[::-1].ravel()


class AMGPreconditioner(Preconditioner):
    """Smoothed-aggregation AMG V-cycle with hierarchy reuse (``"amg"``; module docstring).

    Parameters
    ----------
    near_nullspace : {"rigid", "translations"}
        Candidate vectors ``B``: six rigid-body modes at the current positions, or the three translations.
    fmt : {"bsr", "csr"}
        Matrix format handed to pyamg.
    symmetry : {"hermitian", "nonsymmetric"}
        pyamg's symmetry flag (``"nonsymmetric"`` for GMRES-type methods).
    smoother : str
        pyamg relaxation for pre- and post-smoothing (symmetric sweep).
    max_coarse : int
        Coarsest level size in block rows (pyamg's convention).
    rebuild_factor, rebuild_slack : float, int
        Stale when a solve needs more than ``rebuild_factor * baseline + rebuild_slack`` iterations.
    reuse : bool
        Keep the hierarchy across matrices with the same pattern (False: rebuild for every new matrix).
    cooldown, max_cooldown : int
        Fresh hierarchies after a stale rebuild before reuse is tried again, and its doubled maximum.
    nearby : float
        Relative change of the matrix (Frobenius, sampled) up to which reuse is tried during a cooldown
        (0 turns it off).
    kernels : {"auto", "numba", "numpy"}
        The setup's sparse products and the V-cycle: compiled kernels, the products with cached patterns
        (``"numba"``; ``"auto"`` when numba is installed), or scipy's and pyamg's (``"numpy"``; the former
        ``"scipy"`` is a deprecated alias; module docstring, :mod:`springsim._runtime.accel`).
    sa_options : dict, optional
        Extra keywords for :func:`pyamg.smoothed_aggregation_solver` (then pyamg's setup is used).
    """

    name = "amg"

    def __init__(self, *, near_nullspace: str = "rigid", fmt: str = "bsr", symmetry: str = "hermitian",
                 smoother: str = "block_gauss_seidel", max_coarse: int = 50, rebuild_factor: float = 2.0,
                 rebuild_slack: int = 4, reuse: bool = True, cooldown: int = 4, max_cooldown: int = 64,
                 nearby: float = 2e-4, kernels: str = "auto", sa_options: dict | None = None):
        from ._kernels import resolve_kernels

        super().__init__()
        self.kernels = resolve_kernels(kernels)
        if symmetry not in ("hermitian", "nonsymmetric"):
            raise ValueError(f"symmetry must be 'hermitian' or 'nonsymmetric', got {symmetry!r}")
        if near_nullspace not in ("rigid", "translations"):
            raise ValueError(f"near_nullspace must be 'rigid' or 'translations', got {near_nullspace!r}")
        if fmt not in ("bsr", "csr"):
            raise ValueError(f"fmt must be 'bsr' or 'csr', got {fmt!r}")
        self.near_nullspace = near_nullspace
        self.fmt = fmt
        self.symmetry = symmetry
        self.smoother = smoother
        self.max_coarse = int(max_coarse)
        self.rebuild_factor = float(rebuild_factor)
        self.rebuild_slack = int(rebuild_slack)
        self.reuse = bool(reuse)
        self.cooldown = int(cooldown)
        self.max_cooldown = max(int(max_cooldown), self.cooldown)
        if not nearby >= 0.0:
            raise ValueError(f"nearby must be >= 0, got {nearby!r}")
        self.nearby = float(nearby)
        self.nearby_reuses = 0
        self._next_cooldown = self.cooldown
        self._skip = 0
        self._trial = False
        self._aggregates, self._ritz, self._products, self._aggregates_key = None, None, None, None
        self.version = None
        self.stale_rebuilds = 0
        self.sa_options = dict(sa_options or {})
        self.ml = None
        self.cycle = None
        self.key = None
        self.baseline: int | None = None
        self.builds = 0
        self._precond = None

    def invalidate(self, stale: bool = False) -> None:
        """Forget the hierarchy (the next :meth:`setup` rebuilds); ``stale``
        also starts the cooldown during which new matrices get fresh hierarchies.

        Parameters
        ----------
        stale : bool
            The hierarchy went stale on a new matrix (starts the cooldown).
        """
        self.ml = None
        self.key = None
        self.baseline = None
        if stale:
            self.stale_rebuilds += 1
            self._skip = self._next_cooldown
            self._next_cooldown = min(2 * max(self._next_cooldown, 1), self.max_cooldown)

    def build(self, A):
        """A fresh hierarchy for ``A`` (no reuse): its V-cycle ``r -> M^-1 r``.

        Parameters
        ----------
        A : SystemMatrix
            The matrix.

        Returns
        -------
        callable
            ``r -> M^-1 r`` on arrays of shape (n,).
        """
        self._build(A, None)
        return self._precond

    def setup(self, A):
        """``(apply, setup_s, fresh)`` for the system ``A``: a V-cycle ``r -> M^-1 r``.

        ``fresh`` is True when the hierarchy was (re)built for this call.

        Parameters
        ----------
        A : SystemMatrix
            The matrix of the next solve.

        Returns
        -------
        apply : callable
            ``r -> M^-1 r``.
        setup_s : float
            Seconds spent building the hierarchy (0 on reuse).
        fresh : bool
        """
        key = (id(A.pattern), A.shape) if A.pattern is not None else None
        if self.ml is not None and key is not None and key == self.key:
            if A.version == self.version:  # the very matrix the hierarchy was built for
                return self._precond, 0.0, False
            # a reuse attempt on a new matrix (record() judges it): outside a cooldown, or during one when the
            # matrix is close to the hierarchy's own
            if self.reuse and (self._skip == 0 or self._near(A)):
                self.nearby_reuses += self._skip > 0
                self._trial = True
                return self._precond, 0.0, False
            self._skip = max(self._skip - 1, 0)
        t0 = time.perf_counter()
        self.ml = self._precond = None  # free the old hierarchy first: only one is alive at the peak
        with phase(f"AMG hierarchy of {A.shape[0]} DOFs (build {self.builds + 1})", _log, announce=False):
            self._build(A, key)
        self.key = key
        self.version = A.version
        return self._precond, time.perf_counter() - t0, True

    def operator(self, A):
        """``A``'s BSR matrix, applied by the compiled block kernel with ``kernels="numba"``.

        Parameters
        ----------
        A : SystemMatrix
            The matrix.

        Returns
        -------
        scipy.sparse.bsr_matrix or BsrOperator
        """
        from ._kernels import bsr_operator

        return bsr_operator(A.bsr, self.kernels)

    def _near(self, A) -> bool:
        """Whether ``A`` differs from the matrix the hierarchy was built for by at most ``nearby`` (relative
        Frobenius norm over every ``s``-th block, ``s`` the smallest odd number >= ``max(8, nnzb // 32768)``:
        a sample of at most about 32,768 blocks, so that the check costs the same at any size; odd, so that the
        sample does not keep to one slot of equally long block rows)."""
        if self.nearby <= 0.0 or self.fmt != "bsr":
            return False
        old = getattr(self.ml.levels[0].A, "data", None)
        new = A.bsr.data
        if old is None or old.shape != new.shape:
            return False
        stride = max(8, old.shape[0] // 32768) | 1
        o = old[::stride]
        d = new[::stride] - o
        scale = float(np.vdot(o, o))
        return scale > 0.0 and float(np.vdot(d, d)) <= self.nearby ** 2 * scale

    def _build(self, A, key=None):
        # pyamg's setup draws from NumPy's global random state (the spectral-radius estimate of its
        # prolongation smoother): run it from a fixed seed, so that the hierarchy (and the solve) is
        # the same on every run, and give the caller's global state back untouched
        state = np.random.get_state()
        np.random.seed(_PYAMG_SEED)
        try:
            self._build_seeded(A, key)
        finally:
            np.random.set_state(state)

    def _build_seeded(self, A, key):
        import pyamg

        # a snapshot: the assembler updates its matrix in place, and a hierarchy whose finest
        # operator changed under it (with the old smoother diagonals and coarse levels) is
        # no longer a symmetric positive definite preconditioner; CG then diverges
        M = (A.bsr if self.fmt == "bsr" else A.tocsr()).copy()
        F = A.shape[0] // 3
        if self.near_nullspace == "rigid" and A.positions is not None and F >= 2:
            B = rigid_body_modes(np.asarray(A.positions, dtype=np.float64))
        else:
            B = translation_modes(F)
        if "gauss_seidel" in self.smoother:
            pre, post = (self.smoother, {"sweep": "forward"}), (self.smoother, {"sweep": "backward"})
        else:
            pre = post = (self.smoother, {})
        ml = None
        if self.symmetry == "hermitian" and self.fmt == "bsr" and not self.sa_options:
            ml = self._build_own(M, B, key, A.pattern, pre, post)
        if ml is None:
            opts = dict(B=B, symmetry=self.symmetry, max_coarse=self.max_coarse, coarse_solver="pinv",
                        presmoother=pre, postsmoother=post, improve_candidates=None,
                        strength=("symmetric", {"theta": 0.1}),
                        smooth=("jacobi", {"omega": 4.0 / 3.0, "weighting": "block"}))
            # pyamg wants ("method", {kwargs}) tuples; YAML/JSON give lists
            opts.update({k: tuple(v) if isinstance(v, list) and len(v) == 2 and isinstance(v[0], str) else v
                         for k, v in self.sa_options.items()})
            ml = pyamg.smoothed_aggregation_solver(M, **opts)
        self.ml = ml
        own_cycle = (self.kernels == "numba" and self.smoother == "block_gauss_seidel" and len(ml.levels) > 1
                     and not {"presmoother", "postsmoother"} & set(self.sa_options)
                     and all(lv.A.format == "bsr" for lv in ml.levels))
        self.cycle = "compiled" if own_cycle else "pyamg"
        if own_cycle:
            from ._kernels import CompiledVCycle

            cycle = CompiledVCycle(ml.levels, ml.coarse_solver)
        elif self.smoother == "block_gauss_seidel":
            for level in ml.levels[:-1]:
                if level.A.format != "bsr":
                    continue
                if "presmoother" not in self.sa_options:
                    level.presmoother = BlockGaussSeidel(level.A, "forward", self.kernels)
                if "postsmoother" not in self.sa_options:
                    level.postsmoother = BlockGaussSeidel(level.A, "backward", self.kernels)

        vcycle = getattr(ml, "_MultilevelSolver__solve", None)

        def apply(r):
            if own_cycle:
                return cycle(r)
            if vcycle is None or len(ml.levels) == 1:
                return ml.solve(r, x0=np.zeros_like(r), maxiter=1, tol=1e-300, cycle="V")
            # one V-cycle from zero; MultilevelSolver.solve would add two residual matvecs
            x = np.zeros_like(r)
            vcycle(0, x, r, "V", 1)
            return x

        if own_cycle:
            cycle.prepare()  # the coarse solver's factorisation; the rest is set up
        else:
            apply(np.ones(A.shape[0]))  # pyamg finishes smoother and coarse-LU setup lazily on first use
        self._precond = apply
        self.baseline = None
        self.builds += 1

    def _build_own(self, M, B, key, A_pattern, pre, post):
        """The hierarchy from :func:`~springsim.linsolve._sa.smoothed_aggregation_levels`
        (Lanczos spectral radius, aggregates and Ritz vectors kept per matrix pattern); None when its
        spectral-radius estimate breaks down (``M`` not SPD: pyamg's setup takes over)."""
        from pyamg.multilevel import MultilevelSolver
        from pyamg.relaxation.smoothing import change_smoothers

        from ._sa import smoothed_aggregation_levels

        M.symmetry = "hermitian"
        self._pattern_ref = A_pattern  # held, so that its id (part of ``key``) is not reused
        same = self._aggregates_key == key
        try:
            levels, used = smoothed_aggregation_levels(M, B, max_coarse=self.max_coarse,
                                                       aggregates=self._aggregates if same else None,
                                                       ritz=self._ritz if same else None,
                                                       kernels=self.kernels,
                                                       products=self._products if same else None)
        except (ArithmeticError, np.linalg.LinAlgError):
            return None
        self._aggregates, self._aggregates_key = used, key
        self._ritz = [lv.ritz for lv in levels[:-1]]
        self._products = [lv.products for lv in levels[:-1]]
        ml = MultilevelSolver(levels, coarse_solver="pinv")
        change_smoothers(ml, pre, post)
        return ml

    def record(self, iterations: int, fresh: bool, ok: bool) -> None:
        """Remember the iteration count right after a build (the stale-signal baseline).

        Parameters
        ----------
        iterations : int
            Krylov iterations of the solve.
        fresh : bool
            The hierarchy was built for it.
        ok : bool
            The solve converged.
        """
        if fresh and ok:
            self.baseline = int(iterations)
        elif not fresh and ok and self._trial:  # reuse worked on a new matrix: back to the short cooldown
            self._next_cooldown = self.cooldown
        self._trial = False

    def budget(self, maxiter: int, fresh: bool) -> int:
        """Iterations a solve may take with this hierarchy before it is declared stale.

        A reused hierarchy gets ``rebuild_factor * baseline + rebuild_slack`` (the stale
        signal); a fresh one, or one without a baseline yet, the full ``maxiter``.

        Parameters
        ----------
        maxiter : int
            The solver's iteration limit.
        fresh : bool
            The hierarchy was built for this solve.

        Returns
        -------
        int
        """
        if fresh or self.baseline is None:
            return maxiter
        return min(maxiter, int(self.rebuild_factor * self.baseline + self.rebuild_slack))

    def describe(self) -> dict:
        """Level sizes and complexity of the current hierarchy (for statistics).

        Returns
        -------
        dict
            ``levels`` (rows per level), ``operator_complexity``, ``cycle``, and the counts ``builds``,
            ``stale_rebuilds``, ``nearby_reuses``; empty before the first set-up.
        """
        if self.ml is None:
            return {}
        return {"levels": [int(lv.A.shape[0]) for lv in self.ml.levels],
                "operator_complexity": float(self.ml.operator_complexity()), "cycle": self.cycle, "builds": self.builds,
                "stale_rebuilds": self.stale_rebuilds, "nearby_reuses": self.nearby_reuses}

    def default_maxiter(self, n: int) -> int:
        """Default Krylov iteration limit with an AMG V-cycle: 500, whatever the size.

        Parameters
        ----------
        n : int
            Number of unknowns.

        Returns
        -------
        int
        """
        return 500
