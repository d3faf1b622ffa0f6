"""Smoothed-aggregation AMG hierarchies for the implicit system, and their reuse.

Choices, measured on the benchmark cloth at n = 64 (12,096 DOFs), linearized implicit
Euler, step 20 of the fall (stiff and deformed, ``h^2 k / m ~ 1e4``), CG to 1e-6
(``benchmarks/cloth_grid.py``; see docs/solvers.md for the tables):

* near-null space: the six rigid-body modes at the current positions (3 translations
  + 3 rotations) need 10 CG iterations; the three translations (pyamg's default for
  BSR 3x3, ``B=None``) 22; scalar aggregation (CSR, one constant) 239. Rotations are
  near-null for springs (a rotated cloth has no elastic energy), as Tamstorf, Jones and
  McCormick (2015) argue for cloth; so ``near_nullspace="rigid"`` is the default.
* format: BSR 3x3 aggregates the three components of a particle together; with the
  same six modes CSR needed 49 iterations against 10 for BSR.
* smoother: block Gauss-Seidel on the 3x3 blocks, one forward sweep before and one
  backward sweep after (a symmetric V-cycle, as CG needs): 20 iterations against 16 for
  pyamg's symmetric sweeps, at half the smoothing work; Chebyshev degree 3 took 184
  (its eigenvalue bound is poor on these stretched spectra). The backward sweep runs as
  a forward sweep on a reversed copy of each level's matrix
  (:class:`BackwardBlockGaussSeidel`): pyamg's backward kernel is twice as slow as its
  forward one (n = 256: one V-cycle 85 ms -> 68 ms).
* prolongator and strength: Jacobi-smoothed aggregation (``omega = 4/3``) with
  symmetric strength ``theta = 0.1`` (drops the weak bending links from the
  aggregates). The Jacobi step is weighted by the inverse 3x3 block diagonal
  (``weighting="block"``) rather than the scalar diagonal: measured at step 15 of the
  fall, 8 CG iterations instead of 13-14 at n = 128 and 256, and a cheaper setup
  (n = 256: 1.7 s instead of 2.2 s; its spectral-radius estimate converges faster);
  ``weighting="local"`` (no eigenvalue estimate) needed 15, filtering the smoothing by
  the strength graph 13, ``theta = 0.25`` made aggregates too long for CG (300+). Unsmoothed aggregation (``smooth=None``, ``theta = 0``) costs 0.04 s of
  setup instead of 0.08 s at n = 64, but its iteration count grows with the grid
  (24, 35, 64 iterations at n = 64, 128, 256) while the smoothed one stays at 12-13
  (n = 128, 256): at n = 256 4.3 s per step against 6.8 s. pyamg's candidate
  improvement (``improve_candidates``, 4 Gauss-Seidel sweeps on each of the 6
  candidates) is off: the rigid modes are already the right ones (16 vs 17
  iterations, setup halved).
* coarse level: pyamg counts ``max_coarse`` in block rows (6x6 blocks below the finest
  level), so the default 50 gives a coarsest level of at most ~300 DOFs, solved by a
  dense pseudo-inverse (``pinv``): the coarse operator is exactly singular on the flat
  cloth (rotation candidates with zero energy), where sparse LU fails.
* reuse: on the falling cloth a hierarchy one time step old already needs 2-5x the
  iterations of a fresh one (n = 32: 22, 59, 134, 245 iterations for hierarchies 1-4
  steps old, against 9-14 fresh), while a setup costs about three iterations. A
  Galerkin refresh with the old prolongator was worse still. So: the hierarchy is reused
  for repeated solves with the same matrix and across matrices while a solve stays
  within ``rebuild_factor * baseline + rebuild_slack`` iterations (``baseline`` = count
  right after the build); a solve that exceeds it (or breaks down) is stopped there,
  the hierarchy rebuilt and the solve continued from the iterate reached. After such a
  stale rebuild the next ``cooldown`` matrices get a fresh hierarchy right away (no
  wasted attempt), then reuse is tried again. The cooldown doubles after every stale
  rebuild (up to ``max_cooldown``) and returns to ``cooldown`` once a reused hierarchy
  serves a new matrix within budget, so a fast-moving phase wastes one attempt per
  doubling instead of one every ``cooldown`` steps (n = 128 fall, steps 1-30: 2 wasted
  attempts instead of 6). In quasi-static phases (slow motion) reuse holds for many steps.
"""

from __future__ import annotations

import time

import numpy as np

#: Seed of NumPy's global random state during a pyamg setup (restored afterwards).
_PYAMG_SEED = 20_240_611

__all__ = ["AMGHierarchy", "AMGKrylovSolver", "BackwardBlockGaussSeidel", "rigid_body_modes", "translation_modes"]


def rigid_body_modes(positions: np.ndarray) -> np.ndarray:
    """The six rigid-body modes of particles at ``positions`` (F, 3) [m], as a (3F, 6) array.

    Columns 0-2 are unit translations; 3-5 the infinitesimal rotations ``omega x (x - c)``
    about the axes through the centroid ``c`` (centring keeps the columns well conditioned).
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
    """The three unit translations of ``F`` particles, (3F, 3)."""
    return np.tile(np.eye(3), (F, 1))


class BackwardBlockGaussSeidel:
    """One backward block Gauss-Seidel sweep on a BSR matrix, run as a forward sweep on
    the matrix with its block rows and columns in reverse order.

    The same sweep as pyamg's ``block_gauss_seidel(..., sweep="backward")`` (equal up to
    round-off), but pyamg's compiled kernel walks the rows backwards at about half the
    speed of its forward walk (n = 256 benchmark cloth, 195,840 DOFs: 36.6 ms against
    18.7 ms per sweep including the two vector reversals; one matrix-vector product 7 ms).
    The reversed copy costs one pass over the matrix data per hierarchy build.

    Called as a pyamg smoother, ``smoother(A, x, b)``, updating ``x`` in place.
    """

    def __init__(self, A):
        from pyamg.util.utils import get_block_diag

        bs = A.blocksize[0]
        nb = A.shape[0] // bs
        nnzb = A.indices.size
        self.bs, self.nb = bs, nb
        self.indptr = np.ascontiguousarray(nnzb - A.indptr[::-1])
        self.indices = np.ascontiguousarray((nb - 1 - A.indices)[::-1])
        self.data = np.ascontiguousarray(A.data[::-1]).ravel()
        self.dinv = np.ascontiguousarray(get_block_diag(A, blocksize=bs, inv_flag=True)[::-1]).ravel()

    def __call__(self, A, x, b):
        from pyamg import amg_core

        xr = x.reshape(self.nb, self.bs)[::-1].ravel()  # a reversed copy
        br = b.reshape(self.nb, self.bs)[::-1].ravel()
        amg_core.block_gauss_seidel(self.indptr, self.indices, self.data, xr, br, self.dinv,
                                    0, self.nb, 1, self.bs)
        x[...] = xr.reshape(self.nb, self.bs)[::-1].ravel()


class AMGHierarchy:
    """Builds a pyamg smoothed-aggregation hierarchy and decides when to rebuild it.

    Parameters
    ----------
    near_nullspace : {"rigid", "translations"}
        Candidate vectors ``B`` (see the module notes).
    fmt : {"bsr", "csr"}
        Matrix format handed to pyamg.
    symmetry : {"hermitian", "nonsymmetric"}
        pyamg's symmetry flag (``"nonsymmetric"`` for GMRES-type solvers).
    smoother : str
        pyamg relaxation for pre- and post-smoothing (symmetric sweep).
    max_coarse : int
        Coarsest level size in block rows (pyamg's convention).
    rebuild_factor, rebuild_slack : float, int
        Stale when a solve needs more than ``rebuild_factor * baseline + rebuild_slack``
        iterations, ``baseline`` being the count of the first solve after the last build.
    reuse : bool
        Keep the hierarchy across matrices with the same pattern (False: rebuild for every
        new matrix).
    cooldown : int
        After a stale rebuild, build afresh for this many new matrices before trying reuse
        again; doubled after each further stale rebuild, reset when reuse succeeds.
    max_cooldown : int
        Upper bound of the doubled cooldown.
    sa_options : dict, optional
        Extra keywords for :func:`pyamg.smoothed_aggregation_solver`.
    """

    def __init__(self, *, near_nullspace: str = "rigid", fmt: str = "bsr", symmetry: str = "hermitian",
                 smoother: str = "block_gauss_seidel", max_coarse: int = 50, rebuild_factor: float = 2.0,
                 rebuild_slack: int = 4, reuse: bool = True, cooldown: int = 4, max_cooldown: int = 64,
                 sa_options: dict | None = None):
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
        self._next_cooldown = self.cooldown
        self._skip = 0
        self._trial = False
        self._aggregates, self._aggregates_key = None, None
        self.version = None
        self.stale_rebuilds = 0
        self.sa_options = dict(sa_options or {})
        self.ml = None
        self.key = None
        self.baseline: int | None = None
        self.builds = 0
        self._precond = None

    def invalidate(self, stale: bool = False) -> None:
        """Forget the hierarchy (the next :meth:`preconditioner` call rebuilds); ``stale``
        also starts the cooldown during which new matrices get fresh hierarchies."""
        self.ml = None
        self.key = None
        self.baseline = None
        if stale:
            self.stale_rebuilds += 1
            self._skip = self._next_cooldown
            self._next_cooldown = min(2 * max(self._next_cooldown, 1), self.max_cooldown)

    def preconditioner(self, A):
        """``(apply, setup_s, fresh)`` for the system ``A``: a V-cycle ``r -> M^-1 r``.

        ``fresh`` is True when the hierarchy was (re)built for this call.
        """
        key = (id(A.pattern), A.shape) if A.pattern is not None else None
        if self.ml is not None and key is not None and key == self.key:
            if A.version == self.version:  # the very matrix the hierarchy was built for
                return self._precond, 0.0, False
            if self.reuse and self._skip == 0:
                self._trial = True  # a reuse attempt on a new matrix; record() judges it
                return self._precond, 0.0, False
            self._skip = max(self._skip - 1, 0)
        t0 = time.perf_counter()
        self.ml = self._precond = None  # free the old hierarchy first: only one is alive at the peak
        self._build(A, key)
        self.key = key
        self.version = A.version
        return self._precond, time.perf_counter() - t0, True

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
        if self.smoother == "block_gauss_seidel" and "postsmoother" not in self.sa_options:
            for level in ml.levels[:-1]:
                if level.A.format == "bsr":
                    level.postsmoother = BackwardBlockGaussSeidel(level.A)

        vcycle = getattr(ml, "_MultilevelSolver__solve", None)

        def apply(r):
            if vcycle is None or len(ml.levels) == 1:
                return ml.solve(r, x0=np.zeros_like(r), maxiter=1, tol=1e-300, cycle="V")
            # one V-cycle from zero; MultilevelSolver.solve would add two residual matvecs
            x = np.zeros_like(r)
            vcycle(0, x, r, "V", 1)
            return x

        apply(np.ones(A.shape[0]))  # pyamg finishes smoother and coarse-LU setup lazily on first use
        self._precond = apply
        self.baseline = None
        self.builds += 1

    def _build_own(self, M, B, key, A_pattern, pre, post):
        """The hierarchy from :func:`~springsim.linsolve._sa.smoothed_aggregation_levels`
        (Lanczos spectral radius, aggregates kept per matrix pattern); None when its
        spectral-radius estimate breaks down (``M`` not SPD: pyamg's setup takes over)."""
        from pyamg.multilevel import MultilevelSolver
        from pyamg.relaxation.smoothing import change_smoothers

        from ._sa import smoothed_aggregation_levels

        M.symmetry = "hermitian"
        self._pattern_ref = A_pattern  # held, so that its id (part of ``key``) is not reused
        aggregates = self._aggregates if self._aggregates_key == key else None
        try:
            levels, used = smoothed_aggregation_levels(M, B, max_coarse=self.max_coarse, aggregates=aggregates)
        except (ArithmeticError, np.linalg.LinAlgError):
            return None
        self._aggregates, self._aggregates_key = used, key
        ml = MultilevelSolver(levels, coarse_solver="pinv")
        change_smoothers(ml, pre, post)
        return ml

    def record(self, iterations: int, fresh: bool, ok: bool) -> None:
        """Remember the iteration count right after a build (the stale-signal baseline)."""
        if fresh and ok:
            self.baseline = int(iterations)
        elif not fresh and ok and self._trial:  # reuse worked on a new matrix: back to the short cooldown
            self._next_cooldown = self.cooldown
        self._trial = False

    def budget(self, maxiter: int, fresh: bool) -> int:
        """Iterations a solve may take with this hierarchy before it is declared stale.

        A reused hierarchy gets ``rebuild_factor * baseline + rebuild_slack`` (the stale
        signal); a fresh one, or one without a baseline yet, the full ``maxiter``.
        """
        if fresh or self.baseline is None:
            return maxiter
        return min(maxiter, int(self.rebuild_factor * self.baseline + self.rebuild_slack))

    def describe(self) -> dict:
        """Level sizes and complexity of the current hierarchy (for statistics)."""
        if self.ml is None:
            return {}
        return {"levels": [int(lv.A.shape[0]) for lv in self.ml.levels],
                "operator_complexity": float(self.ml.operator_complexity()), "builds": self.builds,
                "stale_rebuilds": self.stale_rebuilds}


class AMGKrylovSolver:
    """Mixin for the AMG-preconditioned Krylov solvers (``amg-cg``, ``amg-gmres``): their
    shared options, the hierarchy (``self.amg``) and the stale-hierarchy protocol.

    Subclasses (placed before :class:`~springsim.linsolve._krylov.IterativeSolver` in the
    bases) set ``amg_symmetry`` and implement ``_krylov(A, b, precond, x0, maxiter) -> (x, KrylovInfo)``;
    their ``_solve`` calls :meth:`_amg_solve`.

    Parameters
    ----------
    near_nullspace : {"rigid", "translations"}
        AMG candidate vectors: six rigid-body modes at the current positions, or the
        three translations.
    fmt : {"bsr", "csr"}
        Matrix format given to pyamg.
    smoother : str
        pyamg smoother (default symmetric ``"block_gauss_seidel"``).
    reuse : bool
        Reuse the hierarchy across solves (False: rebuild on every solve).
    rebuild_factor, rebuild_slack, cooldown, max_cooldown
        Stale-hierarchy signal and policy, see :class:`AMGHierarchy`.
    max_coarse : int
        Coarsest AMG level size in block rows (pyamg's convention).
    sa_options : dict, optional
        Extra keywords for :func:`pyamg.smoothed_aggregation_solver`.
    """

    amg_symmetry = "hermitian"

    def __init__(self, *, near_nullspace: str = "rigid", fmt: str = "bsr", smoother: str = "block_gauss_seidel",
                 reuse: bool = True, rebuild_factor: float = 2.0, rebuild_slack: int = 4, max_coarse: int = 50,
                 cooldown: int = 4, max_cooldown: int = 64, sa_options: dict | None = None, **kw):
        super().__init__(**kw)
        self.amg = AMGHierarchy(near_nullspace=near_nullspace, fmt=fmt, symmetry=self.amg_symmetry,
                                smoother=smoother, max_coarse=max_coarse, rebuild_factor=rebuild_factor,
                                rebuild_slack=rebuild_slack, reuse=reuse, cooldown=cooldown,
                                max_cooldown=max_cooldown, sa_options=sa_options)

    def _amg_solve(self, A, b, x0, maxiter: int):
        """Krylov solve with the current (or a fresh) hierarchy; a reused hierarchy that
        exceeds its iteration budget or breaks down is rebuilt and the solve continued
        from the iterate reached. Returns the solver's result (fallback applied)."""
        precond, setup_s, fresh = self.amg.preconditioner(A)
        t0 = time.perf_counter()
        x, info = self._krylov(A, b, precond, x0, self.amg.budget(maxiter, fresh))
        rebuilt = False
        if not fresh and info.breakdown is not None:  # stale: too many iterations, or breakdown
            self.amg.invalidate(stale=True)
            precond = None  # drop the old hierarchy before the new one is built (peak memory)
            precond, s2, fresh = self.amg.preconditioner(A)
            setup_s += s2
            t0 += s2
            restart = x if (np.all(np.isfinite(x)) and info.residual < 1.0) else x0
            x, info2 = self._krylov(A, b, precond, restart, maxiter)
            self.amg.record(info2.iterations, fresh, info2.breakdown is None)
            info2.iterations += info.iterations
            info, rebuilt = info2, True
        else:
            self.amg.record(info.iterations, fresh, info.breakdown is None)
        solve_s = time.perf_counter() - t0
        details = dict(self.amg.describe(), rebuilt=fresh, stale_rebuild=rebuilt, warm_start=x0 is not None)
        return self._finish(A, b, x, info, setup_s, solve_s, details)
