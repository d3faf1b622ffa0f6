"""``springsim export TRAJ.npz SCENE [--format FMT] --out DIR [--every M]``: mesh files of a trajectory.

VTU, legacy VTK and XDMF for ParaView, PLY and OBJ for Blender, written by meshio (the ``mesh``
extra; :mod:`springsim.io.export`).
"""

from __future__ import annotations

import argparse
from pathlib import Path

from .argtypes import int_at_least

__all__ = ["export_command"]


class _ExportCommand:
    help = "export a trajectory .npz to mesh files: VTU, VTK, XDMF (ParaView), PLY, OBJ (Blender)"

    def add_arguments(self, p: argparse.ArgumentParser) -> None:
        from ..io.export import EXPORT_FORMATS

        p.add_argument("trajectory", help="trajectory .npz (springsim run --out)")
        p.add_argument("scene", help="scene YAML the trajectory was computed from")
        formats = "; ".join(f"{k}: {v.description}" for k, v in EXPORT_FORMATS.items())
        p.add_argument("--format", choices=list(EXPORT_FORMATS), default="vtu", metavar="FMT",
                       help=f"file format, one of {', '.join(EXPORT_FORMATS)} (default vtu). {formats}")
        p.add_argument("--out", required=True, help="output directory (created if missing)")
        p.add_argument("--every", type=int_at_least(1), default=1,
                       help="export every M-th frame, and the last (default 1)")

    def run(self, args) -> int:
        from ..io.export import export_trajectory, require_meshio
        from ..scene import load_scene
        from ..scene.shipped import resolve_scene
        from .runner import load_trajectory_for

        require_meshio(args.format)  # before loading anything
        args.scene = str(resolve_scene(args.scene))
        scene = load_scene(Path(args.scene))
        traj = load_trajectory_for(args.trajectory, scene, args.scene)
        files = export_trajectory(scene.model, traj, args.out, fmt=args.format, stem=scene.name, every=args.every)
        print(f"wrote {len(files)} file(s) to {args.out}")
        return 0


#: ``springsim export``.
export_command = _ExportCommand()
