"""A square cloth held at two corners, falling into folds; rendered to a PNG and an animated GIF.

The 1 m cloth starts horizontal but pleated into three waves across its width, so that the two
corners of one edge, where it is held, are only 0.6 m apart (the springs' rest lengths are those of
the flat cloth: the pleats are slack, not compressed). It swings down under gravity, slowed by air
drag, and hangs in folds from its sagging top edge. TR-BDF2 (second order, L-stable) integrates it
at the animation step h = 1/60 s; the linear solver is ``auto`` (sparse direct at this size).

    python examples/hanging_cloth.py               # 24 x 24 cloth, 3 s of motion: ~40 s on 1 core
    python examples/hanging_cloth.py --tiny        # 6 x 6 cloth, 0.2 s (what the tests run)

Writes ``hanging_cloth.png`` (the last frame) and ``hanging_cloth.gif`` (under 500 kB) to ``--out-dir``.
"""

import argparse
import dataclasses
import logging
from pathlib import Path

import numpy as np

import springsim as ss
from springsim.io.viz import render_frame, render_gif, run_title

WIDTH = 0.6  # distance of the held corners [m]; the cloth is 1 m wide
WAVES = 3    # pleats across the cloth at the start


def pleats(s: np.ndarray, width: float = WIDTH, waves: float = WAVES) -> tuple[np.ndarray, np.ndarray]:
    """``(x, dz)`` of the points at arc length ``s`` in [0, 1] [m] along ``dz = a sin(2 pi waves x / width)``,
    the sine of ``waves`` periods over ``width`` whose amplitude ``a`` makes it 1 m long."""
    u = np.linspace(0.0, 1.0, 4001)
    lo, hi = 0.0, 1.0
    for _ in range(60):  # bisection on the amplitude: the curve's length grows with it
        a = 0.5 * (lo + hi)
        length = np.hypot(width * np.diff(u), np.diff(a * np.sin(2 * np.pi * waves * u))).sum()
        lo, hi = (a, hi) if length < 1.0 else (lo, a)
    arc = np.concatenate([[0.0], np.cumsum(np.hypot(width * np.diff(u), np.diff(a * np.sin(2 * np.pi * waves * u))))])
    uu = np.interp(s, arc / arc[-1], u)
    return 0.5 * (1.0 - width) + width * uu, a * np.sin(2 * np.pi * waves * uu)


def build(n: int) -> ss.Model:
    b = ss.ModelBuilder(gravity=-9.81, up_axis="z")
    b.add_cloth_grid(n, n, origin=(0.0, 0.0, 1.0), size=(1.0, 1.0), plane="xy",  # 1 m square, horizontal
                     total_mass=0.5, drag=2e-3, stiffness=300.0, damping=0.1,  # structural and shear springs [N/m], [N s/m]
                     stiffness_bend=0.5, pin=["top-left", "top-right"])  # the two corners of the edge y = 1 m
    b.metadata["name"] = f"hanging cloth {n}x{n}"
    flat = b.finalize()  # rest lengths from the flat cloth
    q = flat.particle_q.copy()
    q[:, 0], dz = pleats(q[:, 0])  # x is the arc length across the flat cloth
    q[:, 2] += dz
    return dataclasses.replace(flat, particle_q=q)  # the same springs, the pleated start


def main(argv=None):
    p = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    p.add_argument("--tiny", action="store_true", help="6 x 6 particles for 0.2 s")
    p.add_argument("--out-dir", type=Path, default=Path("."), help="where the pictures go")
    a = p.parse_args(argv)
    n, duration = (6, 0.2) if a.tiny else (24, 3.0)
    model = build(n)
    integrator = ss.make_integrator("tr_bdf2", model)
    dt = 1 / 60
    traj = ss.simulate(model, integrator, dt, round(duration / dt), progress=True)
    s = traj.summary()
    print(f"{model.particle_count} particles, {model.spring_count} springs: {s['steps']} steps in "
          f"{s['wall_s']:.2f} s, {s['failed_steps']} failed")
    a.out_dir.mkdir(parents=True, exist_ok=True)
    title = run_title(traj)
    render_frame(model, traj.q[-1], a.out_dir / "hanging_cloth.png", title=f"{title}\nt = {traj.t[-1]:.2f} s",
                 elev=20, azim=-50, show_particles=False)
    render_gif(model, traj, a.out_dir / "hanging_cloth.gif", every=6, fps=10, size=(4.0, 4.0), elev=20, azim=-50,
               show_particles=False)  # every 0.1 s, in real time
    print(f"wrote {a.out_dir / 'hanging_cloth.png'} and {a.out_dir / 'hanging_cloth.gif'}")
    return model, traj


if __name__ == "__main__":
    logging.basicConfig(level=logging.INFO, format="%(message)s")  # springsim logs progress and slow set-up
    main()
