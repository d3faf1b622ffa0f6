"""Benchmark cloth: time per step, assembly, linear solve, iterations, memory.

Usage::

    python -m benchmarks cloth-grid --n 128 --steps 30 --warmup 9 --integrator linearized_implicit \
        --solver amg-cg --rtol 1e-6 [--jacobian spd] [--kd 0] [--json benchmarks/results/cloth_128.json]

Runs :func:`springsim.scene.gallery.benchmark_cloth` (n x n particles, edge y = 0 pinned,
h = 1/60 s) from rest. The first ``--warmup`` steps (symbolic phase, first AMG setup,
the nearly undeformed start) are reported separately; ``step_s``, ``assembly_s``,
``solve_s`` and ``iterations`` are medians over the remaining steps (with the default
``--steps 30 --warmup 9`` that is steps 10-30 of the fall). ``max_relres`` is the largest
relative residual of any linear solve; ``peak_rss_mb`` is ``ru_maxrss`` of the process.
``--compare-direct K`` also runs ``direct`` (same Jacobian mode) for K steps on the same
cloth and reports the relative difference of the positions after K steps (the error the
solver tolerance introduces).
"""

from __future__ import annotations

import argparse
import json
import resource
import sys
import time
from pathlib import Path

import numpy as np

from springsim.forces import JACOBIAN_MODES
from springsim.integrators import make_integrator
from springsim.scene.gallery import BENCHMARK_DT, benchmark_cloth


def run(n, steps, integrator, solver, rtol, jacobian, warmup, solver_options=None, kd=0.0, integrator_options=None):
    """Run the benchmark; returns (summary dict, final state)."""
    t0 = time.perf_counter()
    model = benchmark_cloth(n, kd=kd)
    build_s = time.perf_counter() - t0
    opts = dict(solver_options or {})
    if rtol is not None and solver not in ("dense", "direct"):
        opts["rtol"] = rtol
    t0 = time.perf_counter()
    integ = make_integrator(integrator, model, solver=solver, jacobian=jacobian, solver_options=opts,
                            **dict(integrator_options or {}))
    symbolic_s = time.perf_counter() - t0
    s0, s1 = model.state(), model.state()
    rows = []
    for _ in range(steps):
        t = time.perf_counter()
        st = integ.step(s0, s1, BENCHMARK_DT)
        wall = time.perf_counter() - t
        s0, s1 = s1, s0
        rows.append(dict(step_s=wall, assembly_s=st.assembly_s, solve_s=st.solve_s, iterations=st.linear_iterations,
                         relres=st.linear_residual, fallbacks=list(st.fallbacks), newton=st.newton_iterations,
                         newton_ok=st.newton_converged))
        if not np.all(np.isfinite(s0.particle_q)):
            raise SystemExit(f"blew up at step {len(rows)}")
    body = rows[warmup:] or rows
    med = lambda k: float(np.median([r[k] for r in body]))  # noqa: E731
    summary = dict(
        n=n, kd=kd, particles=model.particle_count, springs=model.spring_count, dofs=int(model.dof_count),
        free_dofs=int(3 * model.free_particles.size), steps=steps, warmup=warmup, integrator=integrator,
        solver=solver, jacobian=integ.jacobian, rtol=rtol,
        step_s=med("step_s"), assembly_s=med("assembly_s"), solve_s=med("solve_s"), iterations=med("iterations"),
        max_iterations=int(max(r["iterations"] for r in body)), newton_iterations=med("newton"),
        newton_failures=sum(not r["newton_ok"] for r in rows),
        max_relres=float(max(r["relres"] for r in rows)),
        warmup_step_s=[r["step_s"] for r in rows[:warmup]], build_s=build_s, symbolic_s=symbolic_s,
        per_step=[{k: r[k] for k in ("step_s", "newton", "newton_ok", "iterations")} for r in rows],
        fallbacks=sum(len(r["fallbacks"]) for r in rows),
        peak_rss_mb=resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 1024.0,
        solver_info={k: v for k, v in getattr(getattr(integ.solver, "preconditioner", None), "describe", dict)().items()},
    )
    return summary, s0


def dense_path(n, steps, kd=0.0):
    """Seconds per step of the dense seed path (linearized implicit Euler, eqs. 3-4): dense
    assembly over all 3N DOFs with identity rows for pinned ones, then ``np.linalg.solve``;
    returns (median step time, final positions)."""
    from springsim.assembly.dense import dense_system
    from springsim.forces import eval_forces, make_force_terms

    model = benchmark_cloth(n, kd=kd)
    terms = make_force_terms(model, skip_fixed=False)
    q, qd = model.particle_q.copy(), model.particle_qd.copy()
    h, times = BENCHMARK_DT, []
    for _ in range(steps):
        t = time.perf_counter()
        rhs = h * eval_forces(terms, q + h * qd, qd)
        A, r = dense_system(model, q + h * qd, qd, h * h, h, rhs, "exact", terms=terms)
        dv = np.linalg.solve(A, r).reshape(-1, 3)
        dv[model.particle_fixed] = 0.0
        qd = qd + dv
        q = q + h * qd
        times.append(time.perf_counter() - t)
    return float(np.median(times)), q


def _options(pairs):
    """``["key=value", ...]`` -> dict, values parsed as JSON when possible."""
    out = {}
    for kv in pairs:
        k, v = kv.split("=", 1)
        try:
            out[k] = json.loads(v)
        except json.JSONDecodeError:
            out[k] = v
    return out


def main(argv=None):
    p = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    p.add_argument("--n", type=int, default=64)
    p.add_argument("--steps", type=int, default=30)
    p.add_argument("--warmup", type=int, default=None, help="steps excluded from medians (default min(9, steps-1))")
    p.add_argument("--integrator", default="linearized_implicit")
    p.add_argument("--solver", default="amg-cg")
    p.add_argument("--rtol", type=float, default=None)
    p.add_argument("--jacobian", default=None, choices=list(JACOBIAN_MODES))
    p.add_argument("--kd", type=float, default=0.0, help="spring damping [N s/m] of the benchmark cloth (default 0)")
    p.add_argument("--option", action="append", default=[], metavar="KEY=VALUE",
                   help="extra solver option (value parsed as JSON when possible), e.g. near_nullspace=translations")
    p.add_argument("--integrator-option", action="append", default=[], metavar="KEY=VALUE",
                   help="extra integrator option (JSON value when possible), e.g. newton_maxiter=20")
    p.add_argument("--compare-direct", type=int, default=0, metavar="K")
    p.add_argument("--compare-modes", action="store_true",
                   help="also run the three Jacobian modes with this solver and report position differences vs exact")
    p.add_argument("--dense-path", type=int, default=0, metavar="K",
                   help="also time K steps of the dense seed path and report the speed-up")
    p.add_argument("--json", default=None)
    a = p.parse_args(argv)
    warmup = min(9, a.steps - 1) if a.warmup is None else a.warmup
    opts, iopts = _options(a.option), _options(a.integrator_option)
    common = dict(kd=a.kd, integrator_options=iopts)
    summary, state = run(a.n, a.steps, a.integrator, a.solver, a.rtol, a.jacobian, warmup, opts, **common)
    if a.compare_direct:
        s_it, q_it = run(a.n, a.compare_direct, a.integrator, a.solver, a.rtol, a.jacobian, 0, opts, **common)
        s_d, q_d = run(a.n, a.compare_direct, a.integrator, "direct", None, summary["jacobian"], 0, **common)
        disp = q_d.particle_q - benchmark_cloth(a.n).particle_q
        diff = np.linalg.norm(q_it.particle_q - q_d.particle_q) / max(np.linalg.norm(disp), 1e-300)
        summary.update(compare_steps=a.compare_direct, rel_diff_vs_direct=float(diff), direct_step_s=s_d["step_s"])
    if a.dense_path:
        dense_s, q_dense = dense_path(a.n, a.dense_path, kd=a.kd)
        summary.update(dense_step_s=dense_s, dense_speedup=dense_s / summary["step_s"])
        print(f"dense seed path: {dense_s:.4g} s/step, sparse {summary['step_s']:.4g} s/step: "
              f"speed-up {dense_s / summary['step_s']:.1f}x")
    if a.compare_modes:
        q0 = benchmark_cloth(a.n).particle_q
        finals, modes = {}, {}
        for mode in ("exact", "symmetric", "spd"):
            sm, st = run(a.n, a.steps, a.integrator, a.solver, a.rtol, mode, warmup, opts, **common)
            finals[mode] = st.particle_q
            modes[mode] = {k: sm[k] for k in ("step_s", "solve_s", "iterations", "newton_iterations", "newton_failures",
                                              "fallbacks")}
        for mode in modes:
            modes[mode]["rel_diff_vs_exact"] = float(np.linalg.norm(finals[mode] - finals["exact"])
                                                     / np.linalg.norm(finals["exact"] - q0))
        summary["modes"] = modes
        print("mode | step_s | newton_iterations | newton_failures | rel_diff_vs_exact")
        for mode, m in modes.items():
            print(f"{mode} | {m['step_s']:.4g} | {m['newton_iterations']:.3g} | {m['newton_failures']} | "
                  f"{m['rel_diff_vs_exact']:.3e}")
    keys = ["n", "kd", "particles", "springs", "dofs", "steps", "solver", "jacobian", "rtol", "step_s", "assembly_s",
            "solve_s", "iterations", "max_iterations", "newton_iterations", "max_relres", "fallbacks", "peak_rss_mb"]
    if a.compare_direct:
        keys += ["rel_diff_vs_direct", "direct_step_s"]
    print(" | ".join(f"{k}" for k in keys))
    print(" | ".join(f"{summary[k]:.4g}" if isinstance(summary[k], float) else f"{summary[k]}" for k in keys))
    print(f"warm-up steps (s): {', '.join(f'{t:.3f}' for t in summary['warmup_step_s'])}; "
          f"model build {summary['build_s']:.3f} s, symbolic {summary['symbolic_s']:.3f} s; "
          f"AMG {summary['solver_info']}")
    if a.json:
        Path(a.json).parent.mkdir(parents=True, exist_ok=True)
        Path(a.json).write_text(json.dumps(summary, indent=1))
    return 0


if __name__ == "__main__":
    sys.exit(main())
