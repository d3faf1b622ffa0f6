"""Export trajectories to the mesh formats of ParaView and Blender, written by meshio.

meshio (https://github.com/nschloe/meshio) is an optional extra: ``pip install
'springsim[mesh]'``. The geometry of a frame is the particle positions, the cloth grids'
cells as quads (``model.cloth_grids``) and the springs as line cells; the velocity is point
data where the format holds it. Formats (:data:`EXPORT_FORMATS`):

``vtu`` (default)
    VTK XML unstructured grid, one file per frame, quads + lines + ``velocity``; a
    ``<stem>.vtu.series`` JSON index (ParaView 5.5+) gives the frame times.
``vtk``
    Legacy VTK unstructured grid, the same content, with a ``<stem>.vtk.series`` index.
``xdmf``
    One XDMF time series (``<stem>.xdmf``, data inline as XML, no HDF5 needed) on the initial
    positions, with ``displacement`` (from the initial positions) and ``velocity`` per frame;
    in ParaView apply *Warp By Vector* with ``displacement`` to see the motion. Its cells are
    the cloth quads when every spring belongs to a cloth grid, otherwise every spring as a line
    (meshio's time series holds one cell type).
``ply``
    Binary PLY per frame: vertices, quad faces, spring edges, ``vx``/``vy``/``vz``.
``obj``
    Wavefront OBJ per frame: vertices and quad faces only (OBJ holds no line cells in
    meshio); a scene without a cloth has nothing to write and is refused.

Every file is written to a temporary name in the output directory, fsync'ed and renamed into
place (:func:`springsim.io._atomic.write_atomic`, as for trajectories), so no file is ever
half-written; a new file gets ``0o666`` less the umask, a replaced one keeps its mode. See ``docs/file-formats.md``.
"""

from __future__ import annotations

import json
from pathlib import Path
from typing import NamedTuple

import numpy as np

from ..errors import SpringsimError
from ..model.topology import cloth_quads as grid_quads
from ..model.topology import springs_outside_grids
from ._atomic import write_atomic

__all__ = ["EXPORT_FORMATS", "ExportFormat", "cloth_quads", "export_trajectory", "require_meshio"]


class ExportFormat(NamedTuple):
    """An export format: file extension, one-line description, whether it is one file per frame.

    Attributes
    ----------
    ext : str
        File extension, with its dot (``".vtu"``).
    description : str
        One line for the help of ``springsim export``.
    per_frame : bool
        One file per frame (plus a ``.series`` index for VTK), or one file for the whole trajectory.
    """

    ext: str
    description: str
    per_frame: bool


#: Format name -> :class:`ExportFormat`.
EXPORT_FORMATS = {
    "vtu": ExportFormat(".vtu", "VTK XML per frame + .vtu.series (ParaView)", True),
    "vtk": ExportFormat(".vtk", "legacy VTK per frame + .vtk.series (ParaView, VisIt)", True),
    "xdmf": ExportFormat(".xdmf", "one XDMF time series with displacement and velocity (ParaView)", False),
    "ply": ExportFormat(".ply", "binary PLY per frame with faces and spring edges (Blender, MeshLab)", True),
    "obj": ExportFormat(".obj", "Wavefront OBJ per frame, cloth faces only (Blender)", True),
}


def require_meshio(fmt: str):
    """The meshio module, or a one-line :class:`SpringsimError` with the install hint.

    Parameters
    ----------
    fmt : str
        The export format that needs meshio, for the message.

    Returns
    -------
    module
        The imported ``meshio``.

    Raises
    ------
    SpringsimError
        meshio is not installed.
    """
    try:
        import meshio
    except ImportError:
        raise SpringsimError(f"export: format {fmt!r} needs meshio: pip install 'springsim[mesh]'") from None
    return meshio


def cloth_quads(model) -> np.ndarray:
    """Quads (Q, 4) of the model's cloth grids (``model.cloth_grids``); (0, 4) if none.

    Parameters
    ----------
    model : Model
        A model whose ``cloth_grids`` records its grids ``(start, nx, ny)``.

    Returns
    -------
    ndarray of int64, shape (Q, 4)
        Particle indices of each quad, counter-clockwise.
    """
    quads = [np.zeros((0, 4), dtype=np.int64)] + [grid_quads(*g) for g in model.cloth_grids]
    return np.concatenate(quads)


def _atomic(path: Path, write) -> Path:
    """Write ``path`` atomically with ``write(tmp)`` (:func:`springsim.io._atomic.write_atomic`: the same rule for the
    file mode as trajectories, ``0o666`` less the umask for a new file)."""
    write_atomic(path, write)
    return path


def _series(path: Path, names: list[str], times) -> Path:
    series = {"file-series-version": "1.0",
              "files": [{"name": n, "time": float(t)} for n, t in zip(names, times)]}
    return _atomic(path, lambda tmp: Path(tmp).write_text(json.dumps(series, indent=1)))


def export_trajectory(model, traj, out_dir, *, fmt: str = "vtu", stem: str = "frame", every: int = 1) -> list[Path]:
    """Write every ``every``-th frame of ``traj`` (and always the last) to ``out_dir`` in format ``fmt``.

    Parameters
    ----------
    model : Model
        Gives the springs and (for a cloth) the faces.
    traj : Trajectory
        ``t`` (F,) [s], ``q`` and ``qd`` (F, N, 3).
    out_dir : path
        Created if missing.
    fmt : str
        A key of :data:`EXPORT_FORMATS`.
    stem : str
        File name prefix: frames are ``<stem>_<frame:04d><ext>``.
    every : int
        Frame stride (>= 1).

    Returns
    -------
    list of Path
        The files written (frames, then the ``.series`` index; or the one XDMF file).

    Raises
    ------
    SpringsimError
        One line: unknown format, bad stride, a trajectory of another particle count, no meshio,
        or OBJ for a scene without cloth faces.
    """
    if fmt not in EXPORT_FORMATS:
        raise SpringsimError(f"export.format: must be one of {', '.join(EXPORT_FORMATS)}, got {fmt!r}")
    if isinstance(every, bool) or int(every) != every or every < 1:
        raise SpringsimError(f"export.every: must be an integer >= 1, got {every!r}")
    if traj.q.shape[1] != model.particle_count:
        raise SpringsimError(f"export: trajectory has {traj.q.shape[1]} particles, the scene "
                             f"{model.particle_count}")
    meshio = require_meshio(fmt)
    quads = cloth_quads(model)
    lines = np.asarray(model.spring_indices, dtype=np.int64).reshape(-1, 2)
    if fmt == "obj" and not len(quads):
        raise SpringsimError("export: OBJ holds faces only and this scene has no cloth; use ply or vtu for springs")
    if traj.q.shape[0] == 0:
        raise SpringsimError("export: the trajectory has no frames")
    frames = list(range(0, traj.q.shape[0], int(every)))
    if frames[-1] != traj.q.shape[0] - 1:
        frames.append(traj.q.shape[0] - 1)
    out = Path(out_dir)
    out.mkdir(parents=True, exist_ok=True)
    spec = EXPORT_FORMATS[fmt]
    if fmt == "xdmf":
        return [_write_xdmf(meshio, model, traj, frames, quads, lines, out / f"{stem}{spec.ext}")]
    cells = [("quad", quads)] if len(quads) else []
    if fmt != "obj" and len(lines):
        cells.append(("line", lines))
    if fmt == "ply":  # PLY stores 32-bit indices (meshio would cast, with a warning on stderr)
        if model.particle_count >= 2**31:
            raise SpringsimError("export: PLY indices are 32-bit; this scene has too many particles, use vtu")
        cells = [(kind, c.astype(np.int32)) for kind, c in cells]
    files = []
    for k in frames:
        v = np.asarray(traj.qd[k], dtype=np.float64)
        if fmt == "ply":
            point_data = {"vx": v[:, 0], "vy": v[:, 1], "vz": v[:, 2]}
        elif fmt == "obj":
            point_data = {}
        else:
            point_data = {"velocity": v}
        mesh = meshio.Mesh(np.asarray(traj.q[k], dtype=np.float64), cells, point_data=point_data)
        path = out / f"{stem}_{k:04d}{spec.ext}"
        files.append(_atomic(path, lambda tmp: _write(meshio, tmp, mesh, fmt)))
    if fmt in ("vtu", "vtk"):
        files.append(_series(out / f"{stem}{spec.ext}.series", [f.name for f in files],
                             [traj.t[k] for k in frames]))
    return files


def _write(meshio, path: str, mesh, fmt: str) -> None:
    if fmt in ("ply", "vtk"):
        meshio.write(path, mesh, file_format=fmt, binary=True)
    else:
        meshio.write(path, mesh, file_format=fmt)


def _write_xdmf(meshio, model, traj, frames, quads, lines, path: Path) -> Path:
    if len(quads) and not springs_outside_grids(model).size:
        cells = [("quad", quads)]
    elif len(lines):
        cells = [("line", lines)]
    else:
        cells = [("vertex", np.arange(model.particle_count, dtype=np.int64)[:, None])]
    q0 = np.asarray(traj.q[0], dtype=np.float64)

    def write(tmp):
        # meshio's writer opens ``tmp`` itself (inline XML data: no companion .h5 file)
        with meshio.xdmf.TimeSeriesWriter(tmp, data_format="XML") as w:
            w.write_points_cells(q0, cells)
            for k in frames:
                w.write_data(float(traj.t[k]), point_data={
                    "displacement": np.asarray(traj.q[k], dtype=np.float64) - q0,
                    "velocity": np.asarray(traj.qd[k], dtype=np.float64)})

    return _atomic(path, write)
