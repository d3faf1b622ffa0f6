"""One iterative solver composed of a Krylov method, a preconditioner and a fallback solver.

:class:`LinearSolverIterative` takes the three as parameters (as scikit-fem's
``solver_iter_krylov(krylov, M)`` and scipy's ``_isolve`` do): a Krylov method from
:data:`~springsim.linsolve.krylov.KRYLOV_METHODS`, a preconditioner from
:data:`~springsim.linsolve.preconditioners.PRECONDITIONERS` and any
:class:`~springsim.linsolve.LinearSolver` as fallback. The registered names are presets:

=============  ============  ================  ===========================================
name           Krylov        preconditioner    for
=============  ============  ================  ===========================================
``cg``         CG            block Jacobi      SPD systems, the Baraff-Witkin baseline
``amg-cg``     CG            AMG (symmetric)   large SPD systems (the ``spd`` Jacobian)
``amg-gmres``  GMRES(30)     AMG (non-sym.)    large non-symmetric systems (damping, exact)
=============  ============  ================  ===========================================

A solve uses the caller's initial guess when it is better than zero, runs the Krylov method
with the preconditioner's operator, and, when a *reused* operator breaks down or exceeds the
preconditioner's iteration budget, rebuilds it and continues from the iterate reached. A solve
that still breaks down or misses ``rtol`` is handed to the fallback (default ``direct``), or,
without one, returned with ``converged=False`` and the reason in ``failure``.
"""

from __future__ import annotations

import inspect
import time

import numpy as np

from ..errors import registered
from ._base import DEFAULT_RTOL, LinearSolver, LinearSolveResult
from .krylov import KRYLOV_METHODS, KrylovInfo, KrylovMethod
from .preconditioners import Preconditioner, make_preconditioner

__all__ = ["LinearSolverIterative", "LinearSolverCG", "LinearSolverAMGCG", "LinearSolverAMGGMRES"]


def _fallback(spec) -> LinearSolver | None:
    if spec == "direct":
        from .direct import LinearSolverDirect

        return LinearSolverDirect()
    if spec is None or spec == "none":
        return None
    if not isinstance(spec, LinearSolver):
        raise ValueError(f"fallback must be a LinearSolver, 'direct' or 'none', got {spec!r}")
    return spec


class LinearSolverIterative(LinearSolver):
    """A Krylov method with a preconditioner and a fallback solver.

    Parameters
    ----------
    krylov : str or KrylovMethod
        ``"cg"``, ``"gmres"`` or an instance (e.g. ``GMRES(restart=50)``).
    preconditioner : str or Preconditioner
        ``"none"``, ``"jacobi"``, ``"block-jacobi"``, ``"amg"`` or an instance.
    rtol, atol : float
        Stop when the true residual ``|b - A x| <= max(rtol |b|, atol)`` (default rtol
        :data:`~springsim.linsolve._base.DEFAULT_RTOL`).
    maxiter : int or None
        Krylov iteration limit (default: the preconditioner's, e.g. ``max(1000, n)`` for
        Jacobi-type, 500 for AMG).
    fallback : LinearSolver, "direct", "none" or None
        Answers when the Krylov method breaks down or misses its tolerance; its result is
        returned with ``method = "<name>-><fallback>"`` and the reason in ``fallback``.
    warm_start : bool
        Use the caller's ``x0`` when its residual is smaller than ``|b|``.
    """

    name = "iterative"

    def __init__(self, krylov: str | KrylovMethod = "cg", preconditioner: str | Preconditioner = "block-jacobi", *,
                 rtol: float = DEFAULT_RTOL, atol: float = 0.0, maxiter: int | None = None,
                 fallback: LinearSolver | str | None = "direct", warm_start: bool = True):
        super().__init__(rtol=rtol, atol=atol, maxiter=maxiter)
        if isinstance(krylov, str):
            krylov = registered(KRYLOV_METHODS, krylov, param="krylov", what="Krylov method")()
        if not isinstance(krylov, KrylovMethod):
            raise TypeError(f"krylov must be a KrylovMethod or a name, got {type(krylov).__name__}")
        self.krylov = krylov
        self.needs_spd = krylov.needs_spd  # CG needs SPD matrices (the presets also say it as a class attribute)
        self.preconditioner = make_preconditioner(preconditioner)
        self.fallback = _fallback(fallback)
        self.warm_start = bool(warm_start)


    def _initial_guess(self, A, b, x0):
        """``x0`` if it is a better start than zero (``|b - A x0| < |b|``), else None."""
        if not self.warm_start or x0 is None or x0.shape != b.shape or not np.all(np.isfinite(x0)):
            return None
        return x0 if np.linalg.norm(b - A @ x0) < np.linalg.norm(b) else None

    def _solve(self, A, b, x0, rtol):
        x0 = self._initial_guess(A, b, x0)
        P = self.preconditioner
        maxiter = int(self.maxiter) if self.maxiter is not None else P.default_maxiter(b.size)
        apply, setup_s, fresh = P.setup(A)
        t0 = time.perf_counter()
        op = P.operator(A)
        if apply is None:  # e.g. a singular diagonal block: not an SPD matrix
            x, info = np.zeros_like(b), KrylovInfo(0, 1.0, "singular diagonal")
        else:
            x, info = self.krylov(op, b, apply, x0, rtol=rtol, atol=self.atol,
                                  maxiter=P.budget(maxiter, fresh))
        stale = False
        if not fresh and info.breakdown is not None:  # a reused operator too slow or broken: rebuild, continue
            stale = True
            P.invalidate(stale=True)
            apply = None  # drop the old operator before the new one is built (peak memory)
            apply, s2, fresh = P.setup(A)
            setup_s += s2
            t0 += s2
            restart = x if (np.all(np.isfinite(x)) and info.residual < 1.0) else x0
            x, info2 = self.krylov(op, b, apply, restart, rtol=rtol, atol=self.atol, maxiter=maxiter)
            fresh_iterations = info2.iterations  # the new hierarchy's own count: its baseline
            info2.iterations += info.iterations
            info = info2
        P.record(fresh_iterations if stale else info.iterations, fresh, info.breakdown is None)
        details = dict(P.describe(), rebuilt=fresh, stale_rebuild=stale, warm_start=x0 is not None,
                       breakdown=info.breakdown)
        return self._finish(A, b, x, info, setup_s, time.perf_counter() - t0, details, rtol)

    def _finish(self, A, b, x, info: KrylovInfo, setup_s: float, solve_s: float, details: dict,
                rtol: float) -> LinearSolveResult:
        """The result of a Krylov run, handed to the fallback on breakdown."""
        if info.breakdown is None:
            return LinearSolveResult(x, True, info.iterations, info.residual, self.name, setup_s, solve_s,
                                     info=details)
        reason = f"{info.breakdown} after {info.iterations} iterations (relative residual {info.residual:.1e})"
        if self.fallback is None:
            return LinearSolveResult(x, False, info.iterations, info.residual, self.name, setup_s, solve_s,
                                     failure=reason, info=details)
        t0 = time.perf_counter()
        d = self.fallback._solve(A, b, None, rtol)  # A is already wrapped, and the thread policy applied, by solve()
        details.update(fallback_info=d.info, krylov_residual=info.residual)
        return LinearSolveResult(d.x, d.converged, info.iterations, d.residual, f"{self.name}->{d.method}",
                                 setup_s + d.setup_s, solve_s + (time.perf_counter() - t0) - d.setup_s,
                                 failure=d.failure, fallback=f"{self.name}: {reason}",
                                 backward_error=d.backward_error, info=details)


def _amg_options(options: dict) -> dict:
    """Pop the AMG preconditioner's keyword options out of ``options``."""
    from .amg import AMGPreconditioner

    names = set(inspect.signature(AMGPreconditioner).parameters) - {"symmetry"}
    return {k: options.pop(k) for k in list(options) if k in names}


class LinearSolverCG(LinearSolverIterative):
    """Preset ``cg``: CG preconditioned by ``"block-jacobi"`` (or ``preconditioner="jacobi"``).

    Parameters
    ----------
    preconditioner : str or Preconditioner
        ``"block-jacobi"`` (default), ``"jacobi"``, ``"none"`` or an instance.
    **options
        Options of :class:`LinearSolverIterative` (``rtol``, ``atol``, ``maxiter``, ``fallback``, ...).
    """

    name = "cg"
    needs_spd = True

    def __init__(self, *, preconditioner: str | Preconditioner = "block-jacobi", **options):
        super().__init__("cg", preconditioner, **options)


class LinearSolverAMGCG(LinearSolverIterative):
    """Preset ``amg-cg``: CG preconditioned by a symmetric AMG V-cycle (for the ``spd`` Jacobian).

    Keyword options of :class:`~springsim.linsolve.amg.AMGPreconditioner` (``near_nullspace``,
    ``reuse``, ``sa_options``, ...) configure the preconditioner; the others the solver.

    Parameters
    ----------
    **options
        Options of :class:`~springsim.linsolve.amg.AMGPreconditioner` and of :class:`LinearSolverIterative`.
    """

    name = "amg-cg"
    needs_spd = True

    def __init__(self, **options):
        from .amg import AMGPreconditioner

        amg = AMGPreconditioner(symmetry="hermitian", **_amg_options(options))
        super().__init__("cg", amg, **options)


class LinearSolverAMGGMRES(LinearSolverIterative):
    """Preset ``amg-gmres``: GMRES(``restart``) preconditioned by a non-symmetric AMG V-cycle, at most 300
    inner iterations by default (non-symmetric systems: the ``exact`` Jacobian with damping).

    Parameters
    ----------
    restart : int
        GMRES restart length.
    maxiter : int, optional
        Iteration limit; default 300.
    **options
        Options of :class:`~springsim.linsolve.amg.AMGPreconditioner` and of :class:`LinearSolverIterative`.
    """

    name = "amg-gmres"
    needs_spd = False

    def __init__(self, *, restart: int = 30, maxiter: int | None = None, **options):
        from .amg import AMGPreconditioner
        from .krylov import GMRES

        amg = AMGPreconditioner(symmetry="nonsymmetric", **_amg_options(options))
        super().__init__(GMRES(restart), amg, maxiter=300 if maxiter is None else maxiter, **options)
