"""``springsim plot`` and ``springsim render``: pictures of a run (matplotlib, the ``plot`` extra).

``springsim plot SCENE [run options] [--out FILE.png]``
    run the scene and draw its ``plot:`` block (one coordinate of one particle over time);
``springsim render SCENE|TRAJ.npz [--scene SCENE] [run options] (--frame K | --every M) --out FILE.png|FILE.gif``
    draw one frame as a PNG or every M-th frame as an animated GIF.

Both run a scene through the same path and with the same options as ``springsim run``
(:mod:`springsim.cli.runner`), including its failure reports and exit statuses.
"""

from __future__ import annotations

import argparse
import sys
from pathlib import Path

from ..errors import SceneError, SimulationError, SimulationInterrupted, SpringsimError
from ..io._atomic import check_output_path
from .argtypes import int_at_least
from .runner import add_run_options, execute, load_and_configure, load_trajectory_for, warn_failed_steps
from .session import _Exit, _stopped_by, interrupt_status

#: The pictures each command writes (``--out`` must end in one of these).
PICTURE_SUFFIXES = {"plot": (".png",), "render --frame": (".png",), "render --every": (".gif",)}

__all__ = ["plot_command", "render_command"]


def _run_scene(args):
    """``(scene, trajectory)`` of the scene ``args.scene`` run as ``springsim run`` would (exit 1/130 on failure)."""
    scene, cfg = load_and_configure(args)
    try:
        _, traj = execute(scene, cfg)
    except (SimulationError, SimulationInterrupted) as e:
        interrupted = isinstance(e, SimulationInterrupted)
        print(f"springsim: {_stopped_by() if interrupted else 'error'}: {e}", file=sys.stderr)
        raise _Exit(interrupt_status() if interrupted else 1) from None
    warn_failed_steps(traj)
    return scene, traj


class _PlotCommand:
    help = "run a scene and plot its plot: block (a coordinate over time) as a PNG"

    def add_arguments(self, p: argparse.ArgumentParser) -> None:
        p.add_argument("scene", help="scene YAML file")
        add_run_options(p)
        p.add_argument("--out", help="output PNG (default <scene>_plot.png)")

    def run(self, args) -> int:
        from ..io.viz import plot_dof, require_matplotlib, run_title

        require_matplotlib()
        out = args.out if args.out else f"{Path(args.scene).stem}_plot.png"  # a str: Path() drops a trailing "/"
        check_output_path(out, suffixes=PICTURE_SUFFIXES["plot"], inputs=(args.scene,))  # before the run
        scene, traj = _run_scene(args)
        if scene.plot is None:
            raise SceneError("plot", "the scene has no plot: block (particle_id, dof, y_range)")
        plot_dof(traj, scene.plot.particle_id, scene.plot.dof, scene.plot.y_range, out,
                 title=run_title(traj, scene.name))
        print(f"wrote {out}")
        return 0


class _RenderCommand:
    help = "render a scene or a trajectory: one frame as PNG, or every M-th frame as an animated GIF"

    def add_arguments(self, p: argparse.ArgumentParser) -> None:
        p.add_argument("scene", metavar="source", help="scene YAML file, or a trajectory .npz (then --scene is needed)")
        p.add_argument("--scene", dest="scene_of_npz", help="scene YAML giving the springs of a trajectory .npz")
        add_run_options(p)
        g = p.add_mutually_exclusive_group()
        g.add_argument("--frame", type=int, help="frame index to draw (default: the last; negative counts back)")
        g.add_argument("--every", type=int_at_least(1), help="draw every M-th frame into an animated GIF")
        p.add_argument("--out", required=True, help="output FILE.png (--frame) or FILE.gif (--every)")
        p.add_argument("--fps", type=int_at_least(1, 1000), default=20, help="GIF frames per second (default 20)")

    def run(self, args) -> int:
        from ..io.viz import render_frame, render_gif, require_matplotlib, run_title
        from ..scene import load_scene

        require_matplotlib()
        out = args.out  # a str: Path() drops a trailing "/"
        # before the run: the same rules as `run --out` (atomic, never a directory, device or an input file)
        check_output_path(out, suffixes=PICTURE_SUFFIXES["render --every" if args.every is not None else "render --frame"],
                          inputs=[p for p in (args.scene, args.scene_of_npz) if p])
        src = Path(args.scene)
        if src.suffix == ".npz":
            if not args.scene_of_npz:
                raise SpringsimError("render: a trajectory .npz needs --scene SCENE.yaml for its springs")
            from ..scene.shipped import resolve_scene

            scene = load_scene(resolve_scene(args.scene_of_npz))
            traj = load_trajectory_for(src, scene, args.scene_of_npz)
        else:
            scene, traj = _run_scene(args)
        if args.every is not None:
            render_gif(scene.model, traj, out, every=args.every, fps=args.fps, title=run_title(traj, scene.name))
        else:
            k = traj.frame_count - 1 if args.frame is None else args.frame
            if not -traj.frame_count <= k < traj.frame_count:
                raise SpringsimError(f"render: --frame must be in [0, {traj.frame_count}), got {k}")
            k %= traj.frame_count
            render_frame(scene.model, traj.q[k], out, title=f"{run_title(traj, scene.name)}\nt = {traj.t[k]:.3f} s")
        print(f"wrote {out}")
        return 0


#: ``springsim plot``.
plot_command = _PlotCommand()
#: ``springsim render``.
render_command = _RenderCommand()
