"""Independent reference trajectories from :func:`scipy.integrate.solve_ivp`.

The first-order system over free DOFs ``y = (q_f, v_f)``::

    dy/dt = ( v_f , M^-1 F(q, v) )          J = [[0, I], [M^-1 dF/dq, M^-1 dF/dqd]]

is integrated with an implicit Runge-Kutta (Radau) or BDF method at tight
tolerances; the sparse Jacobian ``J`` comes from springsim's force terms (exact
mode). This shares no time-stepping code with springsim's integrators.
"""

from __future__ import annotations

import numpy as np
import scipy.sparse as sp
from scipy.integrate import solve_ivp

from ..assembly import SystemAssembler
from ..forces import eval_forces, make_force_terms
from ..run.driver import Trajectory

__all__ = ["reference_trajectory"]


def reference_trajectory(model, t_eval, *, state=None, method: str = "Radau", rtol: float = 1e-10,
                         atol: float = 1e-12, max_step: float = np.inf) -> Trajectory:
    """Reference solution of ``model`` at the times ``t_eval`` (starting at ``t_eval[0]``).

    Parameters
    ----------
    model : Model
    t_eval : array_like (F,)
        Increasing output times [s]; the initial state is at ``t_eval[0]``.
    state : State, optional
        Initial state (default ``model.state()``).
    method : {"Radau", "BDF", ...}
        ``solve_ivp`` method (implicit ones use the sparse Jacobian).
    rtol, atol : float
        ``solve_ivp`` tolerances.
    max_step : float
        ``solve_ivp``'s largest step [s]; default unbounded.

    Returns
    -------
    Trajectory
        Frames at ``t_eval`` (``stats`` is empty; ``wall_s`` is the solve time).

    Raises
    ------
    RuntimeError
        ``solve_ivp`` failed (its message is included).
    """
    import time

    t_eval = np.asarray(t_eval, dtype=np.float64)
    s0 = model.state() if state is None else state
    terms = make_force_terms(model)
    free = model.free_particles
    nf = 3 * free.size
    inv_m = np.repeat(1.0 / model.particle_mass[free], 3)
    q_full = s0.particle_q.copy()
    v_full = np.zeros_like(q_full)
    f = np.zeros_like(q_full)
    asm = SystemAssembler(model, terms)

    def unpack(y):
        q_full[free] = y[:nf].reshape(-1, 3)
        v_full[free] = y[nf:].reshape(-1, 3)
        return q_full, v_full

    def rhs(t, y):
        q, v = unpack(y)
        eval_forces(terms, q, v, out=f)
        return np.concatenate([y[nf:], inv_m * f[free].reshape(-1)])

    eye = sp.identity(nf, format="csr")
    Minv = sp.diags(inv_m)

    def jac(t, y):
        q, v = unpack(y)
        # A(a, b) = M - a dF/dq - b dF/dqd, so dF/dq = M - A(1, 0) and dF/dqd = M - A(0, 1)
        Mq = sp.diags(np.repeat(model.particle_mass[free], 3))
        dfdq = Mq - asm.assemble(q, v, 1.0, 0.0, "exact").tocsr().copy()
        dfdqd = Mq - asm.assemble(q, v, 0.0, 1.0, "exact").tocsr().copy()
        return sp.bmat([[None, eye], [Minv @ dfdq, Minv @ dfdqd]], format="csc")

    y0 = np.concatenate([s0.particle_q[free].reshape(-1), s0.particle_qd[free].reshape(-1)])
    t0 = time.perf_counter()
    kw = dict(jac=jac) if method in ("Radau", "BDF", "LSODA") else {}
    sol = solve_ivp(rhs, (t_eval[0], t_eval[-1]), y0, method=method, t_eval=t_eval, rtol=rtol, atol=atol,
                    max_step=max_step, **kw)
    if not sol.success:
        raise RuntimeError(f"reference solve failed: {sol.message}")
    F = t_eval.size
    q = np.broadcast_to(s0.particle_q, (F,) + s0.particle_q.shape).copy()
    qd = np.zeros_like(q)
    q[:, free] = sol.y[:nf].T.reshape(F, -1, 3)
    qd[:, free] = sol.y[nf:].T.reshape(F, -1, 3)
    return Trajectory(t_eval.copy(), q, qd, [], time.perf_counter() - t0)
