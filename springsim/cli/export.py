"""``springsim export TRAJ.npz SCENE --format vtk|obj|ply --out DIR [--every M]``: one file per frame.

VTK for ParaView, OBJ and PLY for Blender (:mod:`springsim.export`).
"""

from __future__ import annotations

import argparse
from pathlib import Path

from .argtypes import int_at_least

__all__ = ["export_command"]


class _ExportCommand:
    help = "export a trajectory .npz to per-frame VTK (ParaView), OBJ or PLY (Blender) files"

    def add_arguments(self, p: argparse.ArgumentParser) -> None:
        from ..export import EXPORT_FORMATS

        p.add_argument("trajectory", help="trajectory .npz (springsim run --out)")
        p.add_argument("scene", help="scene YAML the trajectory was computed from")
        p.add_argument("--format", choices=list(EXPORT_FORMATS), default="vtk", help="file format (default vtk)")
        p.add_argument("--out", required=True, help="output directory")
        p.add_argument("--every", type=int_at_least(1), default=1, help="export every M-th frame (default 1)")

    def run(self, args) -> int:
        from ..driver import Trajectory
        from ..export import export_trajectory
        from ..scene import load_scene

        scene = load_scene(Path(args.scene))
        traj = Trajectory.load(args.trajectory)
        files = export_trajectory(scene.model, traj, args.out, fmt=args.format, stem=scene.name, every=args.every)
        print(f"wrote {len(files)} file(s) to {args.out}")
        return 0


#: ``springsim export``.
export_command = _ExportCommand()
