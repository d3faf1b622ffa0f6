"""The ``plot``, ``render`` and ``export`` subcommands (registered in :data:`springsim.cli.COMMANDS`).

``springsim plot SCENE [--out FILE.png] [--steps N]``
    run the scene and draw its ``plot:`` block (one coordinate of one particle over time);
``springsim render SCENE|TRAJ.npz [--scene SCENE] (--frame K | --every M) --out FILE.png|FILE.gif``
    draw one frame as a PNG or every M-th frame as an animated GIF;
``springsim export TRAJ.npz SCENE --format vtk|obj|ply --out DIR [--every M]``
    write one file per frame for ParaView (VTK) or Blender (OBJ, PLY).

Each command object has ``add_arguments(parser)``, ``run(args) -> int`` and ``help``.
"""

from __future__ import annotations

import argparse
import warnings
from pathlib import Path

from ._argtypes import int_at_least, positive_float
from .errors import SceneError, SpringsimError

__all__ = ["plot_command", "render_command", "export_command", "load_trajectory"]


def load_trajectory(path):
    """Read a trajectory ``.npz`` written by :meth:`Trajectory.save` (see :meth:`Trajectory.load`)."""
    from .driver import Trajectory

    return Trajectory.load(path)


def _simulate_scene(scene, steps, dt=None, frame_every: int = 1):
    """Run a loaded scene with its solver settings; returns the Trajectory."""
    from .driver import simulate
    from .integrators import make_integrator

    cfg = scene.config if dt is None else scene.config.with_overrides(dt=dt)
    if steps is None:
        steps = cfg.steps if cfg.steps is not None else 100
    integ = make_integrator(cfg.integrator, scene.model, **cfg.integrator_options())
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        return simulate(scene.model, integ, cfg.dt, int(steps), frame_every=frame_every)


_positive_int = int_at_least(1, 10**12)


class _PlotCommand:
    help = "run a scene and plot its plot: block (a coordinate over time) as a PNG"

    def add_arguments(self, p: argparse.ArgumentParser) -> None:
        p.add_argument("scene", help="scene YAML file")
        p.add_argument("--out", help="output PNG (default <scene>_plot.png)")
        p.add_argument("--steps", type=_positive_int, help="number of steps (default: the scene's)")
        p.add_argument("--dt", type=positive_float, help="time step [s] (default: the scene's)")

    def run(self, args) -> int:
        from .scene.yaml_io import load_scene
        from .viz import plot_dof, require_matplotlib

        require_matplotlib()
        scene = load_scene(Path(args.scene))
        if scene.plot is None:
            raise SceneError("plot", "the scene has no plot: block (particle_id, dof, y_range)")
        traj = _simulate_scene(scene, args.steps, args.dt)
        out = Path(args.out) if args.out else Path(f"{Path(args.scene).stem}_plot.png")
        plot_dof(traj, scene.plot.particle_id, scene.plot.dof, scene.plot.y_range, out, title=scene.name)
        print(f"wrote {out}")
        return 0


class _RenderCommand:
    help = "render a scene or a trajectory: one frame as PNG, or every M-th frame as an animated GIF"

    def add_arguments(self, p: argparse.ArgumentParser) -> None:
        p.add_argument("source", help="scene YAML file, or a trajectory .npz (then --scene is needed)")
        p.add_argument("--scene", help="scene YAML giving the springs of a trajectory .npz")
        g = p.add_mutually_exclusive_group()
        g.add_argument("--frame", type=int, help="frame index to draw (default: the last; negative counts back)")
        g.add_argument("--every", type=_positive_int, help="draw every M-th frame into an animated GIF")
        p.add_argument("--out", required=True, help="output FILE.png (--frame) or FILE.gif (--every)")
        p.add_argument("--steps", type=_positive_int, help="steps to simulate for a scene (default: the scene's)")
        p.add_argument("--fps", type=_positive_int, default=20, help="GIF frames per second")

    def run(self, args) -> int:
        from .scene.yaml_io import load_scene
        from .viz import render_frame, render_gif, require_matplotlib

        require_matplotlib()
        src = Path(args.source)
        if src.suffix == ".npz":
            if not args.scene:
                raise SpringsimError("render: a trajectory .npz needs --scene SCENE.yaml for its springs")
            scene = load_scene(Path(args.scene))
            traj = load_trajectory(src)
            if traj.q.shape[1] != scene.model.particle_count:
                raise SpringsimError(f"render: {src} has {traj.q.shape[1]} particles, {args.scene} has "
                                     f"{scene.model.particle_count}")
        else:
            scene = load_scene(src)
            traj = _simulate_scene(scene, args.steps)
        out = Path(args.out)
        if args.every is not None:
            if out.suffix.lower() != ".gif":
                raise SpringsimError("render: --every writes an animated GIF; give --out FILE.gif")
            render_gif(scene.model, traj, out, every=args.every, fps=args.fps)
        else:
            k = traj.frame_count - 1 if args.frame is None else args.frame
            if not -traj.frame_count <= k < traj.frame_count:
                raise SpringsimError(f"render: --frame must be in [0, {traj.frame_count}), got {k}")
            k %= traj.frame_count
            render_frame(scene.model, traj.q[k], out, title=f"{scene.name}, t = {traj.t[k]:.3f} s")
        print(f"wrote {out}")
        return 0


class _ExportCommand:
    help = "export a trajectory .npz to per-frame VTK (ParaView), OBJ or PLY (Blender) files"

    def add_arguments(self, p: argparse.ArgumentParser) -> None:
        from .export import EXPORT_FORMATS

        p.add_argument("trajectory", help="trajectory .npz (springsim run --out)")
        p.add_argument("scene", help="scene YAML the trajectory was computed from")
        p.add_argument("--format", choices=list(EXPORT_FORMATS), default="vtk")
        p.add_argument("--out", required=True, help="output directory")
        p.add_argument("--every", type=_positive_int, default=1, help="export every M-th frame")

    def run(self, args) -> int:
        from .export import export_trajectory
        from .scene.yaml_io import load_scene

        scene = load_scene(Path(args.scene))
        traj = load_trajectory(args.trajectory)
        files = export_trajectory(scene.model, traj, args.out, fmt=args.format, stem=scene.name, every=args.every)
        print(f"wrote {len(files)} file(s) to {args.out}")
        return 0


#: ``springsim plot``.
plot_command = _PlotCommand()
#: ``springsim render``.
render_command = _RenderCommand()
#: ``springsim export``.
export_command = _ExportCommand()
