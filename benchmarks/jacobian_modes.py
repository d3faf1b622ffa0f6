"""Newton at animation steps: which Jacobian mode and linear solver, at what cost and error.

The accuracy cloth of ``benchmarks/accuracy.py`` (same scene, horizon and cached
TR-BDF2 reference), run at a fixed step with each ``solver:jacobian[:noescalate]``
configuration (``jacobian`` ``default`` = the integrator's choice for that solver) and each
method. Reported per run: CPU seconds per step, Newton and Krylov iterations per step, steps
whose Newton iteration missed its limit, direct-solver fallbacks, Jacobian escalations and
the RMS position error at ``T`` against the reference.

Example (docs/accuracy.md, "Newton, the Jacobian mode and the linear solver")::

    python -m benchmarks jacobian-modes --n 64 --ref-steps 1170 --methods tr_bdf2 bdf2 \\
        --configs auto:default auto:default:noescalate direct:exact amg-gmres:exact amg-cg:exact
"""

from __future__ import annotations

import argparse
import time
import warnings

from . import accuracy as acc
from springsim.integrators import make_integrator
from springsim.run.driver import simulate

HEADER = ["n", "method", "solver", "jacobian", "escalate", "escalate_after", "steps", "cpu_per_step_s", "newton_per_step",
          "krylov_per_step", "steps_at_limit", "fallbacks", "escalations", "rms_error_m"]


def run(model, method, solver, jacobian, escalate, steps, q_ref, newton_maxiter=50, rtol=1e-6, escalate_after=None):
    """One fixed-step run over ``acc.T_END``; the table row (without ``n``)."""
    kw = dict(solver=solver, solver_options={"rtol": rtol}, on_nonconvergence="ignore", stage_solver="residual",
              newton_maxiter=newton_maxiter, escalate_jacobian=escalate, escalate_after=escalate_after)
    if jacobian != "default":
        kw["jacobian"] = jacobian
    integ = make_integrator(method, model, **kw)
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")  # fallbacks are counted below
        t0 = time.process_time()
        tr = simulate(model, integ, acc.T_END / steps, steps, record=False)
        cpu = time.process_time() - t0
    st = tr.stats
    return [method, solver, integ.jacobian, escalate, escalate_after or newton_maxiter, steps, cpu / steps,
            sum(s.newton_iterations for s in st) / steps, sum(s.linear_iterations for s in st) / steps,
            sum(not s.newton_converged for s in st), sum(len(s.fallbacks) for s in st),
            sum(s.extra.get("jacobian_escalations", 0) for s in st), acc.rms(tr.q[-1], q_ref)]


def main(argv=None):
    p = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    p.add_argument("--n", type=int, default=64)
    p.add_argument("--steps", type=int, default=70, help="fixed steps over T (70: h = 1/60 s)")
    p.add_argument("--ref-steps", type=int, default=1170, help="TR-BDF2 reference steps (cached)")
    p.add_argument("--ref-solver", default="amg-cg", help="linear solver of the reference if computed")
    p.add_argument("--methods", nargs="+", default=["tr_bdf2", "bdf2"])
    p.add_argument("--configs", nargs="+", default=["auto:default", "direct:exact", "amg-cg:exact"],
                   help="solver:jacobian[:noescalate]")
    p.add_argument("--newton-maxiter", type=int, default=50)
    p.add_argument("--escalate-after", type=int, nargs="+", default=[None],
                   help="Newton iterations with the projected Jacobian before the exact one (default: the limit)")
    a = p.parse_args(argv)
    acc.SOLVER["ref_name"] = a.ref_solver
    model = acc.cloth(a.n)
    q_ref, _, _, _ = acc.reference(model, a.n, a.ref_steps)
    rows = []
    for method in a.methods:
        for config in a.configs:
            parts = config.split(":")
            if len(parts) not in (2, 3) or (len(parts) == 3 and parts[2] != "noescalate"):
                p.error(f"--configs: expected solver:jacobian[:noescalate], got {config!r}")
            for after in a.escalate_after:
                row = [a.n] + run(model, method, parts[0], parts[1], len(parts) == 2, a.steps, q_ref,
                                  newton_maxiter=a.newton_maxiter, escalate_after=after)
                rows.append(row)
                print("   ", row, flush=True)
    acc.table(f"n = {a.n}: Newton configurations, h = {acc.T_END / a.steps * 1e3:.3g} ms", HEADER, rows)
    acc.write_csv(f"newton_jacobian_modes_n{a.n}", HEADER, rows)


if __name__ == "__main__":
    main()
