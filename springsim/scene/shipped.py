"""The scenes shipped with springsim (``scenes/*.yaml`` of the repository), found by name.

An installed springsim carries them as package data in ``springsim/scene/data/`` (the build maps the
repository's ``scenes/`` directory there, see ``setup.py``); run from a source checkout, they are read from
``scenes/`` itself. So ``springsim run cloth_16`` and ``load_scene(shipped_scene("cloth_16"))`` work
wherever springsim is installed, and ``springsim scenes`` lists them.
"""

from __future__ import annotations

import os
import re
from dataclasses import dataclass
from pathlib import Path

from ..errors import SceneError

__all__ = ["scene_directory", "shipped_scenes", "shipped_scene", "resolve_scene", "SceneInfo", "scene_info"]

_HERE = Path(__file__).resolve().parent


def scene_directory() -> Path | None:
    """The directory of the shipped scenes: the package data of an installed springsim, else a checkout's ``scenes/``.

    Returns
    -------
    pathlib.Path or None
        The first of the two that holds a ``*.yaml`` file; None when neither does.
    """
    for d in (_HERE / "data", _HERE.parents[1] / "scenes"):
        if d.is_dir() and any(d.glob("*.yaml")):
            return d
    return None


def shipped_scenes() -> dict[str, Path]:
    """Name (the file's stem) -> path of every shipped scene, sorted by name.

    Returns
    -------
    dict of str to pathlib.Path
        In natural order (``cloth_8`` before ``cloth_16``); empty without :func:`scene_directory`.
    """
    d = scene_directory()
    if d is None:
        return {}
    natural = lambda p: [int(t) if t.isdigit() else t for t in re.split(r"(\d+)", p.stem)]  # noqa: E731
    return {p.stem: p for p in sorted(d.glob("*.yaml"), key=natural)}


def shipped_scene(name: str) -> Path:
    """The path of the shipped scene ``name`` (``"cloth_16"`` or ``"cloth_16.yaml"``).

    Parameters
    ----------
    name : str
        The scene's name, with or without ``.yaml`` (or ``.yml``).

    Returns
    -------
    pathlib.Path

    Raises
    ------
    SceneError
        When there is no shipped scene of that name (the message lists them).
    """
    scenes = shipped_scenes()
    stem = name[: -len(Path(name).suffix)] if Path(name).suffix in (".yaml", ".yml") else name
    if stem not in scenes:
        raise SceneError(name, f"no shipped scene of that name; shipped: {', '.join(scenes) or 'none'}")
    return scenes[stem]


def resolve_scene(arg) -> Path:
    """The scene file of a command-line argument: an existing path, else the shipped scene of that bare name.

    A name with a directory part (``scenes/x.yaml``) is always a path.

    Parameters
    ----------
    arg : str or PathLike
        A file path or the name of a shipped scene (:func:`shipped_scene`).

    Returns
    -------
    pathlib.Path
        The path (not checked further when the file exists or ``arg`` has a directory part).

    Raises
    ------
    SceneError
        ``"<arg>: no such file ..."``: a missing file that is not the name of a shipped scene.
    """
    path = Path(arg)
    text = os.fspath(arg)
    if path.exists() or os.sep in text or (os.altsep and os.altsep in text):
        return path
    try:
        return shipped_scene(text)
    except SceneError:
        raise SceneError(text, "no such file, nor the name of a shipped scene (`springsim scenes` lists "
                               "them)") from None


@dataclass(frozen=True)
class SceneInfo:
    """One row of ``springsim scenes``.

    Attributes
    ----------
    name : str
        The file's stem.
    particles, springs : int
        Particle and spring counts of the scene's model.
    description : str
        One line: the scene's ``description:``, else the file's first comment line, else empty.
    path : pathlib.Path
        The scene file.
    """

    name: str
    particles: int
    springs: int
    description: str
    path: Path


def _first_comment_line(path: Path) -> str:
    with open(path, encoding="utf-8") as fh:
        for line in fh:
            if line.startswith("#"):
                return line.lstrip("#").strip()
            if line.strip():
                break
    return ""


def scene_info(path) -> SceneInfo:
    """Name, particle and spring counts and the one-line description (``description:``, else the file's
    first comment line) of a scene file.

    Parameters
    ----------
    path : str or PathLike
        A scene file; it is loaded (:func:`~springsim.scene.load_scene`).

    Returns
    -------
    SceneInfo

    Raises
    ------
    SceneError
        The file is missing, unreadable or not a valid scene (:func:`~springsim.scene.load_scene`).
    """
    from .yaml_io import load_scene

    path = Path(path)
    s = load_scene(path)
    text = " ".join(str(s.metadata.get("description") or "").split()) or _first_comment_line(path)
    return SceneInfo(name=path.stem, particles=s.model.particle_count, springs=s.model.spring_count,
                     description=text, path=path)
