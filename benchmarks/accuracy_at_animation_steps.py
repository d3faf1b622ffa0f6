"""Accuracy at animation time steps: implicit Euler vs BDF2 vs TR-BDF2 (fixed and adaptive steps).

The issue-7 benchmark cloth (``benchmark_cloth(n, ke=1e3, ke_shear=1e3, ke_bend=1e2)``: 1 m,
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

The reference at each n is TR-BDF2 with ``ref_steps`` steps (Newton tol 1e-8); its own
error is estimated by the difference to a run with half as many steps and printed.

Usage::

    python benchmarks/accuracy_at_animation_steps.py                 # n = 32 and 64
    python benchmarks/accuracy_at_animation_steps.py --sizes 16 --ref-steps 1170
    python benchmarks/accuracy_at_animation_steps.py --sizes 64 --ref-steps 585 --validate-n 0 --no-sweep

Writes ``benchmarks/results/accuracy_at_animation_steps_*.csv``.
"""

from __future__ import annotations

import argparse
import csv
import time
import warnings
from pathlib import Path

import numpy as np

from springsim import ModelBuilder, make_integrator, simulate
from springsim.adaptive import simulate_adaptive
from springsim.forces import make_force_terms
from springsim.integrators import ImplicitIntegrator, StepStats
from springsim.reference import reference_trajectory
from springsim.scene.gallery import benchmark_cloth

RESULTS = Path(__file__).resolve().parent / "results"
T_END = 1.17
H_ANIM = 1.0 / 60.0
METHODS = ("implicit_euler", "bdf2", "tr_bdf2")
#: Newton iteration limit of every run (the seed's 5 leaves 13-18 of 70 steps unconverged on the
#: n = 32 cloth at h = 1/60 s for implicit Euler and BDF2; 20 converges them, so errors are the methods')
NEWTON_MAXITER = 20


class Trapezoidal(ImplicitIntegrator):
    """Trapezoidal rule as one Newton stage (benchmark-only comparison, not registered).

    ``q1 = q + h/2 (v + v1)``, ``v1 = v + h/2 (a + a1)``: ``c = h/2``, ``q_hat = q + c v``,
    ``v_hat = v + c a``.
    """

    name = "trapezoidal"
    order = 2

    def step(self, state_in, state_out, dt):
        stats = StepStats(dt)
        q, v = state_in.particle_q, state_in.particle_qd
        c = 0.5 * dt
        a = self.acceleration(q, v)
        q1, v1 = self.solve_stage(q + c * v, v + c * a, c, v + dt * a, stats)
        state_out.particle_q[...] = q1
        state_out.particle_qd[...] = v1
        return stats


def cloth(n):
    return benchmark_cloth(n, ke=1e3, ke_shear=1e3, ke_bend=1e2)


def integrator(name, model, **kw):
    kw.setdefault("on_nonconvergence", "ignore")
    kw.setdefault("newton_maxiter", NEWTON_MAXITER)
    if name == "trapezoidal":
        return Trapezoidal(model, **kw)
    return make_integrator(name, model, **kw)


def fixed_run(model, name, steps, **kw):
    """Final state and CPU seconds of ``steps`` fixed steps over T_END."""
    integ = integrator(name, model, **kw)
    t0 = time.process_time()
    tr = simulate(model, integ, T_END / steps, steps, record=False)
    cpu = time.process_time() - t0
    return tr.q[-1], tr.qd[-1], cpu, tr


def adaptive_run(model, name, tol):
    t0 = time.process_time()
    tr = simulate_adaptive(model, name, T_END, time_rtol=tol, time_atol=tol, on_nonconvergence="ignore",
                           newton_maxiter=NEWTON_MAXITER)
    return tr.q[-1], tr.qd[-1], time.process_time() - t0, tr


def rms(a, b):
    return float(np.sqrt(np.mean(np.sum((a - b) ** 2, axis=-1))))


def energy(model, q, v):
    """Kinetic + potential energy [J]."""
    terms = make_force_terms(model, skip_fixed=False)
    return 0.5 * float(np.sum(model.particle_mass[:, None] * v * v)) + sum(t.potential_energy(q) for t in terms)


def table(title, header, rows):
    print(f"\n## {title}\n")
    print("| " + " | ".join(header) + " |")
    print("|" + "---|" * len(header))
    for r in rows:
        print("| " + " | ".join(f"{x:.3g}" if isinstance(x, float) else str(x) for x in r) + " |")


def write_csv(name, header, rows):
    RESULTS.mkdir(parents=True, exist_ok=True)
    with open(RESULTS / f"accuracy_at_animation_steps_{name}.csv", "w", newline="") as fh:
        w = csv.writer(fh)
        w.writerow(header)
        w.writerows(rows)


def validate_reference(n, ref_steps):
    model = cloth(n)
    t0 = time.process_time()
    radau = reference_trajectory(model, [0.0, T_END])
    t_radau = time.process_time() - t0
    rows = []
    for steps in (ref_steps // 2, ref_steps):
        q, _, cpu, _ = fixed_run(model, "tr_bdf2", steps, newton_tol=1e-8, newton_maxiter=20)
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


def run_size(n, ref_steps, sweep_steps, tols, sweep=True, only_adaptive=None):
    model = cloth(n)
    print(f"\n# n = {n}: {model.particle_count} particles, {model.spring_count} springs", flush=True)
    q_ref, v_ref, cpu_ref, _ = fixed_run(model, "tr_bdf2", ref_steps, newton_tol=1e-8, newton_maxiter=20)
    if only_adaptive:
        ref_err = float("nan")
    else:
        q_half, _, _, _ = fixed_run(model, "tr_bdf2", ref_steps // 2, newton_tol=1e-8, newton_maxiter=20)
        ref_err = rms(q_half, q_ref)
    print(f"reference: TR-BDF2, {ref_steps} steps, cpu {cpu_ref:.1f} s; |ref(h) - ref(2h)|_rms = {ref_err:.2e} m",
          flush=True)
    q0, v0 = model.particle_q, model.particle_qd
    E0 = energy(model, q0, v0)
    E_ref = energy(model, q_ref, v_ref)
    z_ref = q_ref[:, 2].min()

    if only_adaptive:
        sweep = []
        for tol in tols:
            q, _, cpu, tr = adaptive_run(model, only_adaptive, tol)
            sweep.append([n, f"{only_adaptive}+adaptive", tol, T_END / max(tr.adaptive_stats["accepted"], 1),
                          rms(q, q_ref), cpu / T_END])
            print("  ", sweep[-1], tr.adaptive_stats, flush=True)
        header = ["n", "method", "h_or_tol", "mean_h_s", "rms_err_m", "cpu_per_sim_s"]
        table(f"n = {n}: adaptive {only_adaptive}", header, sweep)
        write_csv(f"adaptive_{only_adaptive}_n{n}", header, sweep)
        return
    # 1. h = 1/60 error and energy
    rows = []
    for name in METHODS + ("trapezoidal",):
        q, v, cpu, tr = fixed_run(model, name, int(round(T_END / H_ANIM)))
        newton = sum(s.newton_iterations for s in tr.stats) / len(tr.stats)
        fails = sum(not s.newton_converged for s in tr.stats)
        rows.append([n, name, rms(q, q_ref), float(q[:, 2].min()), float(z_ref), energy(model, q, v) - E0,
                     E_ref - E0, cpu / T_END, newton, fails])
    header = ["n", "method", "rms_err_m", "min_z_m", "min_z_ref_m", "E_end-E0_J", "E_ref-E0_J", "cpu_per_sim_s",
              "newton_per_step", "newton_failures"]
    base = rows[0][2]
    table(f"n = {n}: h = 1/60 s over {T_END} s (reference error ~{ref_err:.1e} m; IE/BDF2 error ratio "
          f"{base / rows[1][2]:.1f}, IE/TR-BDF2 {base / rows[2][2]:.1f})", header, rows)
    write_csv(f"h60_n{n}", header, rows)
    if not sweep:
        return

    # 2. cost to reach 1 cm and 1 mm
    sweep = []
    for name in METHODS:
        for steps in sweep_steps:
            q, _, cpu, _ = fixed_run(model, name, steps)
            sweep.append([n, name, "fixed", T_END / steps, rms(q, q_ref), cpu / T_END])
            print("  ", sweep[-1], flush=True)
            if sweep[-1][4] < 1e-3:
                break
    for name in ("bdf2", "tr_bdf2"):
        for tol in tols:
            q, _, cpu, tr = adaptive_run(model, name, tol)
            s = tr.adaptive_stats
            sweep.append([n, f"{name}+adaptive", tol, T_END / max(s["accepted"], 1), rms(q, q_ref), cpu / T_END])
            print("  ", sweep[-1], s, flush=True)
            if sweep[-1][4] < 1e-3:
                break
    header = ["n", "method", "h_or_tol", "mean_h_s", "rms_err_m", "cpu_per_sim_s"]
    write_csv(f"sweep_n{n}", header, sweep)
    rows = []
    for name in list(METHODS) + ["bdf2+adaptive", "tr_bdf2+adaptive"]:
        r = [n, name]
        for target in (1e-2, 1e-3):
            r.append(cost_to_reach([x for x in sweep if x[1] == name], target))
        rows.append(r)
    table(f"n = {n}: CPU seconds per simulated second to reach an RMS error (cheapest swept run)",
          ["n", "method", "cpu_1cm", "cpu_1mm"], rows)
    write_csv(f"cost_n{n}", ["n", "method", "cpu_per_sim_s_1cm", "cpu_per_sim_s_1mm"], rows)


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
    a = p.parse_args(argv)
    warnings.simplefilter("ignore")
    print(f"accuracy at animation steps: T = {T_END} s, h_anim = 1/60 s, CPU = time.process_time()")
    if not a.only_adaptive:
        spring_energy()
    if a.validate_n and not a.only_adaptive:
        validate_reference(a.validate_n, a.ref_steps)
    for n in a.sizes:
        run_size(n, a.ref_steps, a.sweep_steps, a.tols, sweep=not a.no_sweep, only_adaptive=a.only_adaptive)


if __name__ == "__main__":
    main()
