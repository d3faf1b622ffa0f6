"""Accuracy at animation time steps: implicit Euler vs BDF2 vs TR-BDF2 (fixed and adaptive steps).

The accuracy cloth (``accuracy_cloth(n)`` = ``benchmark_cloth(n, ke=1e3, ke_shear=1e3, ke_bend=1e2)``: 1 m,
1 kg, edge y = 0 pinned, released horizontal, no damping) over ``T = 1.17 s``. Reported:

1. validation of the reference: a fine-step TR-BDF2 run against scipy's Radau (rtol 1e-10)
   at a small n (Radau at n >= 32 is too slow on this machine: see the printed timing);
2. RMS position error at ``T`` against the reference, at h = 1/60 s, for implicit Euler,
   BDF2, TR-BDF2 and (for the energy comparison only) the trapezoidal rule;
3. total energy (kinetic + spring + gravity) at ``T`` relative to the start, on the cloth
   and on an undamped spring;
4. CPU time per simulated second each method needs to reach 1 cm and 1 mm RMS error
   (fixed steps swept over h = T/N, adaptive runs swept over the time tolerance; a sweep
   stops once it is below 1 mm). When no swept run reaches a target the cost is
   extrapolated on log-log axes through the two most accurate runs and marked ``~ (extrap.)``.

The reference at each n is TR-BDF2 with ``ref_steps`` steps (Newton tol 1e-8, linear rtol
1e-10); its own error is estimated by the difference to a run with half as many steps (the
"twin") and, assuming second-order convergence, by Richardson: ``|ref - twin| / 3``. Both runs
are saved to ``benchmarks/results/accuracy_reference_n{n}_steps{ref_steps}.npz`` and loaded
from there on the next run (``--recompute-ref`` forces a new one).

Linear solver: ``--solver`` (default ``direct``) for the method runs, ``--ref-solver`` (default:
the same) for the reference. ``amg-cg``/``auto`` are several times faster at n >= 32 and small
steps, but use the ``spd`` Jacobian, with which Newton misses its limit on a few h = 1/60 s steps
(order reduction to implicit Euler): use ``direct`` (exact Jacobian) for the h = 1/60 table.
Method runs use ``--linear-rtol`` (default 1e-6), the reference 1e-10 (``direct`` is exact).

Usage::

    python -m benchmarks accuracy                 # n = 32 and 64
    python -m benchmarks accuracy --sizes 16 --ref-steps 1170
    python -m benchmarks accuracy --sizes 64 --ref-steps 1170 --validate-n 0 --no-sweep \
        --skip-spring --solver direct --ref-solver amg-cg --h60-methods implicit_euler bdf2 tr_bdf2
    python -m benchmarks accuracy --sizes 32 --ref-steps 4680 --validate-n 0 --solver amg-cg \
        --skip-h60 --sweep-steps 70 140 280 560 1170 2340 4680           # 1 cm and 1 mm costs

``--t-end T`` changes the horizon (output files and the saved reference get a ``_T<T>`` suffix);
``--sensitivity N STEPS`` only measures how a 1e-9 m perturbation of the start grows.

Writes ``benchmarks/results/accuracy_at_animation_steps_*.csv``.
"""

from __future__ import annotations

import argparse
import time
import warnings
from pathlib import Path

import numpy as np

from springsim import ModelBuilder, make_integrator, simulate
from springsim.analysis.reference import reference_trajectory
from springsim.cli.argtypes import positive_float
from springsim.integrators import ImplicitIntegrator, StepStats
from springsim.run.adaptive import simulate_adaptive
from springsim.run.energy import total_energy
from springsim.scene.gallery import accuracy_cloth

from . import common
from .common import markdown_table

RESULTS = common.RESULTS_DIR
T_DEFAULT = 1.17
#: horizon [s] (``--t-end``)
T_END = T_DEFAULT
H_MAX = None  # step cap of the adaptive runs [s] (--h-max; None: the driver's default)
H_ANIM = 1.0 / 60.0
METHODS = ("implicit_euler", "bdf2", "tr_bdf2", "energy_momentum")
#: Newton iteration limit of every run (PA2's 5 leaves 13-18 of 70 steps unconverged on the
#: n = 32 cloth at h = 1/60 s for implicit Euler and BDF2; 20 converges them, so errors are the methods')
NEWTON_MAXITER = NEWTON_DEFAULT = 20
#: linear solver of every run (set from the command line): name, rtol of method runs, rtol of the reference
SOLVER = {"name": "direct", "rtol": 1e-6, "ref_name": "direct", "ref_rtol": 1e-10}
#: settings of every reference-quality run (reference, its twin, validation, sensitivity)
REF_KW = dict(ref=True, newton_tol=1e-8, newton_maxiter=20)


class Trapezoidal(ImplicitIntegrator):
    """Trapezoidal rule as one Newton stage (benchmark-only comparison, not registered).

    ``q1 = q + h/2 (v + v1)``, ``v1 = v + h/2 (a + a1)``: ``c = h/2``, ``q_hat = q + c v``,
    ``v_hat = v + c a``.
    """

    name = "trapezoidal"
    order = 2

    def advance(self, q, v, h, stats):
        c = 0.5 * h
        a = self.acceleration(q, v)
        q1, v1, _ = self.solve_stage(q + c * v, v + c * a, c, v + h * a, stats)
        return q1, v1


def cloth(n):
    """:func:`springsim.scene.gallery.accuracy_cloth`."""
    return accuracy_cloth(n)


def integrator(name, model, ref=False, **kw):
    kw.setdefault("on_nonconvergence", "ignore")
    kw.setdefault("solver", SOLVER["ref_name" if ref else "name"])
    kw.setdefault("solver_options", {"rtol": SOLVER["ref_rtol" if ref else "rtol"]})
    kw.setdefault("newton_maxiter", NEWTON_MAXITER)
    if name == "trapezoidal":
        return Trapezoidal(model, **kw)
    return make_integrator(name, model, **kw)


def fixed_run(model, name, steps, ref=False, **kw):
    """Final state and CPU seconds of ``steps`` fixed steps over T_END (``ref``: reference linear tolerance)."""
    integ = integrator(name, model, ref=ref, **kw)
    t0 = time.process_time()
    tr = simulate(model, integ, T_END / steps, steps, record=False)
    cpu = time.process_time() - t0
    return tr.q[-1], tr.qd[-1], cpu, tr


def adaptive_run(model, name, tol):
    """Final state, CPU seconds and trajectory of an adaptive run of ``name`` (``NAME/filtered``,
    ``NAME/unfiltered``: with or without the stiff filter of the error estimate; plain ``NAME``: its default)."""
    name, _, variant = name.partition("/")
    if variant not in ("", "filtered", "unfiltered"):
        raise ValueError(f"unknown variant {variant!r} of {name!r} (filtered or unfiltered)")
    kw = {"filter_estimates": variant == "filtered"} if variant else {}
    t0 = time.process_time()
    tr = simulate_adaptive(model, name, T_END, time_rtol=tol, time_atol=tol, on_nonconvergence="ignore",
                           h_max=H_MAX, newton_maxiter=NEWTON_MAXITER, solver=SOLVER["name"],
                           solver_options={"rtol": SOLVER["rtol"]}, **kw)
    return tr.q[-1], tr.qd[-1], time.process_time() - t0, tr


def rms(a, b):
    return float(np.sqrt(np.mean(np.sum((a - b) ** 2, axis=-1))))


def energy(model, q, v):
    """Kinetic + potential energy [J] (:func:`springsim.run.energy.total_energy`)."""
    return float(total_energy(model, q, v))


def table(title, header, rows):
    print(f"\n## {title}\n")
    print(markdown_table(rows, header))


def horizon_tag():
    """File-name suffix of a non-default horizon (``--t-end``)."""
    return "" if T_END == T_DEFAULT else f"_T{T_END:g}"


def write_csv(name, header, rows):
    tag = horizon_tag() + ("" if H_MAX is None else f"_hmax{H_MAX:g}")
    common.write_csv(RESULTS / f"accuracy_at_animation_steps_{name}{tag}.csv", rows, header)


def validate_reference(n, ref_steps):
    model = cloth(n)
    t0 = time.process_time()
    radau = reference_trajectory(model, [0.0, T_END])
    t_radau = time.process_time() - t0
    rows = []
    for steps in (ref_steps // 2, ref_steps):
        q, _, cpu, _ = fixed_run(model, "tr_bdf2", steps, **REF_KW)
        rows.append([n, steps, T_END / steps, rms(q, radau.q[-1]), cpu, t_radau])
    header = ["n", "steps", "h_s", "rms_vs_radau_m", "cpu_s", "radau_cpu_s"]
    table(f"Reference validation: fine TR-BDF2 vs Radau (rtol 1e-10), n = {n}", header, rows)
    write_csv(f"reference_n{n}", header, rows)


def spring_energy():
    """Energy ratio after 10 s of an undamped 1 kg / 100 N/m spring at h = 0.05 s and 1/60 s."""
    b = ModelBuilder(gravity=0.0)
    b.add_particle((0.0, 0.0, 0.0), fixed=True)
    b.add_particle((1.2, 0.0, 0.0), mass=1.0)
    b.add_spring(0, 1, ke=100.0, kd=0.0, rest_length=1.0)
    model = b.finalize()
    rows = []
    for h in (0.05, H_ANIM):
        steps = int(round(10.0 / h))
        row = [h]
        for name in METHODS + ("trapezoidal",):
            tr = simulate(model, integrator(name, model, newton_tol=1e-12, newton_maxiter=20), h, steps,
                          record=False)
            row.append(energy(model, tr.q[-1], tr.qd[-1]) / energy(model, tr.q[0], tr.qd[0]))
        rows.append(row)
    header = ["h_s"] + [f"E_end/E0_{m}" for m in METHODS + ("trapezoidal",)]
    table("Undamped spring (omega = 10 rad/s), energy after 10 s relative to the start", header, rows)
    write_csv("spring_energy", header, rows)


def reference(model, n, ref_steps, recompute=False):
    """TR-BDF2 reference and its half-step twin at ``T_END``, cached in ``RESULTS``.

    The twin is the saved reference with ``ref_steps // 2`` steps when there is one (the
    same computation), so refining a reference by halving its step costs one new run.
    Returns ``q_ref, v_ref, q_twin, info`` (``info``: CPU seconds, solver, steps).
    """
    def cached(steps):
        path = RESULTS / f"accuracy_reference_n{n}_steps{steps}{horizon_tag()}.npz"
        if not path.exists() or recompute:
            return path, None
        d = np.load(path)
        return path, (d["q_ref"], d["v_ref"], d["q_twin"],
                      {k: d[k].item() for k in ("cpu_ref", "cpu_twin", "solver", "ref_steps")})

    path, hit = cached(ref_steps)
    if hit is not None:
        print(f"reference loaded from {path.name} (computed with solver {hit[3]['solver']})", flush=True)
        return hit
    q_ref, v_ref, cpu_ref, tr = fixed_run(model, "tr_bdf2", ref_steps, **REF_KW)
    fails = sum(not s.newton_converged for s in tr.stats)
    twin_path, twin = cached(ref_steps // 2)
    if twin is not None:
        q_twin, cpu_twin = twin[0], twin[3]["cpu_ref"]
        print(f"twin loaded from {twin_path.name}", flush=True)
    else:
        q_twin, _, cpu_twin, tr2 = fixed_run(model, "tr_bdf2", ref_steps // 2, **REF_KW)
        fails += sum(not s.newton_converged for s in tr2.stats)
    if fails:
        print(f"WARNING: {fails} reference steps missed the Newton tolerance", flush=True)
    info = {"cpu_ref": cpu_ref, "cpu_twin": cpu_twin, "solver": SOLVER["ref_name"], "ref_steps": ref_steps}
    RESULTS.mkdir(parents=True, exist_ok=True)
    np.savez(path, q_ref=q_ref, v_ref=v_ref, q_twin=q_twin, **info)
    print(f"reference saved to {path.name}", flush=True)
    return q_ref, v_ref, q_twin, info


def run_size(n, ref_steps, sweep_steps, tols, sweep=True, only_adaptive=None, h60=True, h60_methods=None,
             fixed_methods=METHODS, adaptive_methods=("bdf2", "tr_bdf2"), recompute_ref=False):
    model = cloth(n)
    print(f"\n# n = {n}: {model.particle_count} particles, {model.spring_count} springs, "
          f"solver {SOLVER['name']}", flush=True)
    q_ref, v_ref, q_half, info = reference(model, n, ref_steps, recompute_ref)
    ref_err = rms(q_half, q_ref)
    print(f"reference: TR-BDF2, {ref_steps} steps (h = {T_END / ref_steps * 1e3:.3g} ms), cpu {info['cpu_ref']:.1f} s "
          f"(twin {info['cpu_twin']:.1f} s); |ref(h) - ref(2h)|_rms = {ref_err:.2e} m, "
          f"Richardson estimate of the reference's error {ref_err / 3:.1e} m", flush=True)
    if only_adaptive:
        sweep = []
        for tol in tols:
            q, _, cpu, tr = adaptive_run(model, only_adaptive, tol)
            sweep.append([n, f"{only_adaptive}+adaptive", tol, T_END / max(tr.adaptive_stats["accepted"], 1),
                          rms(q, q_ref), cpu / T_END, tr.adaptive_stats["newton_failures"]])
            print("  ", sweep[-1], tr.adaptive_stats, flush=True)
        header = ["n", "method", "h_or_tol", "mean_h_s", "rms_err_m", "cpu_per_sim_s", "newton_failures"]
        table(f"n = {n}: adaptive {only_adaptive}", header, sweep)
        write_csv(f"adaptive_{only_adaptive.replace('/', '-')}_n{n}", header, sweep)
        return
    if h60:
        h60_table(model, n, q_ref, v_ref, ref_err, h60_methods or METHODS + ("trapezoidal",))
    if not sweep:
        return

    # 2. cost to reach 1 cm and 1 mm
    sweep = []
    for name in fixed_methods:
        for steps in sweep_steps:
            if name == "tr_bdf2" and steps >= ref_steps // 2:
                # the reference itself or its twin: their difference is the reference's error, not a measurement
                print(f"   skipped tr_bdf2 with {steps} steps (too close to the reference's {ref_steps})", flush=True)
                break
            q, _, cpu, tr = fixed_run(model, name, steps)
            fails = sum(not s.newton_converged for s in tr.stats)
            sweep.append([n, name, "fixed", T_END / steps, rms(q, q_ref), cpu / T_END, fails])
            print("  ", sweep[-1], flush=True)
            if sweep[-1][4] < 1e-3:
                break
    for name in adaptive_methods:
        for tol in tols:
            q, _, cpu, tr = adaptive_run(model, name, tol)
            s = tr.adaptive_stats
            sweep.append([n, f"{name}+adaptive", tol, T_END / max(s["accepted"], 1), rms(q, q_ref), cpu / T_END,
                          s["newton_failures"]])
            print("  ", sweep[-1], s, flush=True)
            if sweep[-1][4] < 1e-3:
                break
    header = ["n", "method", "h_or_tol", "mean_h_s", "rms_err_m", "cpu_per_sim_s", "newton_failures"]
    table(f"n = {n}: sweep (solver {SOLVER['name']}, reference error ~{ref_err / 3:.1e} m)", header, sweep)
    write_csv(f"sweep_n{n}", header, sweep)
    rows = []
    for name in list(fixed_methods) + [f"{m}+adaptive" for m in adaptive_methods]:
        r = [n, name]
        for target in (1e-2, 1e-3):
            r.append(cost_to_reach([x for x in sweep if x[1] == name], target))
        rows.append(r)
    table(f"n = {n}: CPU seconds per simulated second to reach an RMS error (cheapest swept run)",
          ["n", "method", "cpu_1cm", "cpu_1mm"], rows)
    write_csv(f"cost_n{n}", ["n", "method", "cpu_per_sim_s_1cm", "cpu_per_sim_s_1mm"], rows)


def h60_table(model, n, q_ref, v_ref, ref_err, methods):
    """RMS error, lowest point, energy change and cost at h = 1/60 s."""
    q0, v0 = model.particle_q, model.particle_qd
    E0 = energy(model, q0, v0)
    E_ref = energy(model, q_ref, v_ref)
    z_ref = q_ref[:, 2].min()
    rows = []
    for name in methods:
        q, v, cpu, tr = fixed_run(model, name, int(round(T_END / H_ANIM)))
        newton = sum(s.newton_iterations for s in tr.stats) / len(tr.stats)
        fails = sum(not s.newton_converged for s in tr.stats)
        rows.append([n, name, rms(q, q_ref), float(q[:, 2].min()), float(z_ref), energy(model, q, v) - E0,
                     E_ref - E0, cpu / T_END, newton, fails])
    header = ["n", "method", "rms_err_m", "min_z_m", "min_z_ref_m", "E_end-E0_J", "E_ref-E0_J", "cpu_per_sim_s",
              "newton_per_step", "newton_failures"]
    err = {r[1]: r[2] for r in rows}
    ratios = "; ".join(f"IE/{m} error ratio {err['implicit_euler'] / err[m]:.1f}" for m in err
                       if m != "implicit_euler" and "implicit_euler" in err)
    table(f"n = {n}: h = 1/60 s over {T_END} s (|ref - twin| = {ref_err:.1e} m; {ratios})", header, rows)
    tag = "" if NEWTON_MAXITER == NEWTON_DEFAULT else f"_newton{NEWTON_MAXITER}"
    write_csv(f"h60_n{n}{tag}", header, rows)


def sensitivity(n, steps, delta=1e-9, method="tr_bdf2", frames=10):
    """How fast a tiny perturbation of the start grows: the same ``method`` at the same step
    (``T_END / steps``) from the released state and from it with every free particle moved by
    ``delta`` [m] (random directions), RMS difference at ``frames`` times. When it grows to the
    mm level by ``T_END``, no reference can resolve errors that small on this scene."""
    model = cloth(n)
    rng = np.random.default_rng(1)
    state = model.state()
    dq = rng.standard_normal(state.particle_q.shape)
    dq[model.particle_fixed] = 0.0
    dq *= delta / np.sqrt(np.mean(np.sum(dq ** 2, axis=1)))
    perturbed = state.copy()
    perturbed.particle_q += dq
    every = max(steps // frames, 1)
    a = simulate(model, integrator(method, model, **REF_KW), T_END / steps, steps, frame_every=every)
    b = simulate(model, integrator(method, model, **REF_KW), T_END / steps, steps, state=perturbed,
                 frame_every=every)
    rows = [[n, method, T_END / steps, float(t), rms(qa, qb)] for t, qa, qb in zip(a.t, a.q, b.q)]
    header = ["n", "method", "h_s", "t_s", "rms_diff_m"]
    table(f"n = {n}: growth of a {delta:g} m perturbation of the start ({method}, h = {T_END / steps * 1e3:.3g} ms)",
          header, rows)
    write_csv(f"sensitivity_n{n}_delta{delta:g}", header, rows)


def cost_to_reach(runs, target):
    """CPU per simulated second to reach ``target`` RMS error: cheapest measured run meeting it, else a
    log-log extrapolation through the two most accurate runs (marked ``~``, ``extrap.``)."""
    ok = [x[5] for x in runs if x[4] <= target]
    if ok:
        return min(ok)
    pts = sorted(runs, key=lambda x: x[4])[:2]
    if len(pts) < 2 or pts[0][4] == pts[1][4] or pts[0][5] == pts[1][5]:
        return "not reached"
    (e1, c1), (e2, c2) = [(np.log(x[4]), np.log(x[5])) for x in pts]
    slope = (c1 - c2) / (e1 - e2)
    if slope >= 0:
        return "not reached"
    return f"~{np.exp(c1 + slope * (np.log(target) - e1)):.3g} (extrap.)"


def main(argv=None):
    p = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    p.add_argument("--sizes", type=int, nargs="+", default=[32, 64])
    p.add_argument("--ref-steps", type=int, default=1170, help="TR-BDF2 steps of the reference over 1.17 s")
    p.add_argument("--validate-n", type=int, default=8, help="cloth size for the Radau validation (0: skip)")
    p.add_argument("--sweep-steps", type=int, nargs="+", default=[70, 140, 280, 560])
    p.add_argument("--only-adaptive", metavar="NAME", help="only the adaptive sweep of NAME (skips the rest)")
    p.add_argument("--no-sweep", action="store_true", help="only the h = 1/60 table (large n)")
    p.add_argument("--tols", type=float, nargs="+", default=[1e-2, 3e-3, 1e-3, 3e-4, 1e-4])
    p.add_argument("--solver", default="direct", help="linear solver of every run (auto, amg-cg, direct, ...)")
    p.add_argument("--ref-solver", help="linear solver of the reference runs (default: --solver)")
    p.add_argument("--linear-rtol", type=float, default=1e-6, help="linear rtol of the method runs (reference: 1e-10)")
    p.add_argument("--skip-h60", action="store_true", help="skip the h = 1/60 table")
    p.add_argument("--h60-methods", nargs="+", default=list(METHODS) + ["trapezoidal"])
    p.add_argument("--methods", nargs="*", default=list(METHODS),
                   help="fixed-step methods of the sweep (none: adaptive only)")
    p.add_argument("--adaptive-methods", nargs="*", default=["bdf2", "tr_bdf2"],
                   help="adaptive methods of the sweep (NAME/filtered, NAME/unfiltered: with or without the stiff "
                        "filter of the error estimate)")
    p.add_argument("--recompute-ref", action="store_true", help="ignore a saved reference")
    p.add_argument("--skip-spring", action="store_true", help="skip the undamped-spring energy table")
    p.add_argument("--newton-maxiter", type=int, default=NEWTON_DEFAULT,
                   help=f"Newton iteration limit of the method runs (default {NEWTON_DEFAULT})")
    p.add_argument("--t-end", type=positive_float, default=T_DEFAULT,
                   help=f"horizon [s] (default {T_DEFAULT}; other values tag the output files _T<t>)")
    p.add_argument("--sensitivity", type=int, nargs=2, metavar=("N", "STEPS"),
                   help="only the perturbation-growth run of the N x N cloth with STEPS steps over T")
    p.add_argument("--delta", type=float, default=1e-9, help="perturbation of --sensitivity [m] (default 1e-9)")
    p.add_argument("--h-max", type=positive_float, help="step cap of the adaptive runs [s] (default: T / 10; tags the CSV "
                                               "files _hmax<h>)")
    a = p.parse_args(argv)
    global T_END, NEWTON_MAXITER, H_MAX
    NEWTON_MAXITER = a.newton_maxiter
    T_END = a.t_end
    H_MAX = a.h_max
    SOLVER.update(name=a.solver, rtol=a.linear_rtol, ref_name=a.ref_solver or a.solver)
    warnings.simplefilter("ignore")
    print(f"accuracy at animation steps: T = {T_END} s, h_anim = 1/60 s, CPU = time.process_time()")
    if a.sensitivity:
        sensitivity(*a.sensitivity, delta=a.delta)
        return
    if not (a.only_adaptive or a.skip_spring):
        spring_energy()
    if a.validate_n and not a.only_adaptive:
        validate_reference(a.validate_n, a.ref_steps)
    for n in a.sizes:
        run_size(n, a.ref_steps, a.sweep_steps, a.tols, sweep=not a.no_sweep, only_adaptive=a.only_adaptive,
                 h60=not a.skip_h60, h60_methods=a.h60_methods, fixed_methods=a.methods,
                 adaptive_methods=a.adaptive_methods, recompute_ref=a.recompute_ref)


if __name__ == "__main__":
    main()
