"""``springsim scenes``: list the shipped scenes (name, particles, springs, description).

``springsim run NAME`` (and ``plot``, ``render``, ``export``) take such a bare name when no file of that
name exists (:func:`springsim.scene.shipped.resolve_scene`).
"""

from __future__ import annotations

import argparse

__all__ = ["scenes_command"]


class _ScenesCommand:
    help = "list the shipped scenes: `springsim run NAME` runs one"

    def add_arguments(self, p: argparse.ArgumentParser) -> None:
        p.add_argument("--paths", action="store_true", help="also print each scene's file")

    def run(self, args) -> int:
        from ..scene.shipped import scene_info, shipped_scenes

        rows = [scene_info(path) for path in shipped_scenes().values()]
        if not rows:
            print("springsim: no shipped scenes found")
            return 1
        header = ("name", "particles", "springs", "description")
        w = [max(len(header[0]), *(len(r.name) for r in rows)),
             max(len(header[1]), *(len(str(r.particles)) for r in rows)),
             max(len(header[2]), *(len(str(r.springs)) for r in rows))]
        print(f"{header[0]:<{w[0]}}  {header[1]:>{w[1]}}  {header[2]:>{w[2]}}  {header[3]}")
        for r in rows:
            tail = f" ({r.path})" if args.paths else ""
            print(f"{r.name:<{w[0]}}  {r.particles:>{w[1]}}  {r.springs:>{w[2]}}  {r.description}{tail}")
        return 0


#: ``springsim scenes``.
scenes_command = _ScenesCommand()
