"""Export trajectories to files other tools read: legacy VTK (ParaView), OBJ and PLY (Blender).

Small ASCII writers in numpy, no extra dependency. Every frame becomes one file
``<stem>_<frame:04d>.<ext>`` holding the particle positions, the springs as line
segments and, for cloth grids (``model.cloth_grids``), the grid quads as faces. VTK frames come
with a ``<stem>.vtk.series`` JSON file (ParaView
5.5+) carrying the frame times; ParaView also groups numbered files by itself.
"""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np

from .errors import SpringsimError
from .topology import cloth_quads as grid_quads

__all__ = ["EXPORT_FORMATS", "cloth_quads", "write_vtk", "write_obj", "write_ply", "export_trajectory"]


def cloth_quads(model) -> np.ndarray:
    """Quads (Q, 4) of the model's cloth grids (``model.cloth_grids``); (0, 4) if none."""
    quads = [np.zeros((0, 4), dtype=np.int64)] + [grid_quads(*g) for g in model.cloth_grids]
    return np.concatenate(quads)


def _rows(fh, fmt: str, a: np.ndarray) -> None:
    if len(a):
        np.savetxt(fh, a, fmt=fmt)


def _geometry(q, lines, quads):
    """Positions (N, 3) float64, segments (L, 2) and quads (Q, 4) int64 from array-likes."""
    return (np.asarray(q, dtype=np.float64), np.asarray(lines, dtype=np.int64).reshape(-1, 2),
            np.asarray(quads, dtype=np.int64).reshape(-1, 4))


def write_vtk(path, q: np.ndarray, lines: np.ndarray, quads: np.ndarray, *, title: str = "springsim",
              point_data: dict | None = None) -> Path:
    """Write one legacy-VTK ASCII POLYDATA file.

    Parameters
    ----------
    path : path
    q : ndarray (N, 3)
        Positions [m].
    lines : ndarray (S, 2)
        Segments (springs) as particle index pairs.
    quads : ndarray (Q, 4)
        Faces.
    point_data : dict of str -> ndarray (N, 3) or (N,), optional
        Per-point vectors (e.g. velocity [m/s]) or scalars.
    """
    q, lines, quads = _geometry(q, lines, quads)
    path = Path(path)
    with open(path, "w") as fh:
        fh.write(f"# vtk DataFile Version 3.0\n{title}\nASCII\nDATASET POLYDATA\nPOINTS {len(q)} double\n")
        _rows(fh, "%.9g", q)
        if len(lines):
            fh.write(f"LINES {len(lines)} {3 * len(lines)}\n")
            _rows(fh, "%d", np.column_stack([np.full(len(lines), 2), lines]))
        if len(quads):
            fh.write(f"POLYGONS {len(quads)} {5 * len(quads)}\n")
            _rows(fh, "%d", np.column_stack([np.full(len(quads), 4), quads]))
        if point_data:
            fh.write(f"POINT_DATA {len(q)}\n")
            for name, v in point_data.items():
                v = np.asarray(v, dtype=np.float64)
                if v.ndim == 2:
                    fh.write(f"VECTORS {name} double\n")
                else:
                    fh.write(f"SCALARS {name} double 1\nLOOKUP_TABLE default\n")
                _rows(fh, "%.9g", v.reshape(len(q), -1))
    return path


def write_obj(path, q: np.ndarray, lines: np.ndarray, quads: np.ndarray) -> Path:
    """Write one Wavefront OBJ: ``v`` per particle, ``f`` per quad, ``l`` per segment (1-based)."""
    q, lines, quads = _geometry(q, lines, quads)
    path = Path(path)
    with open(path, "w") as fh:
        fh.write(f"# springsim export: {len(q)} vertices, {len(quads)} faces, {len(lines)} lines\n")
        _rows(fh, "v %.9g %.9g %.9g", q)
        _rows(fh, "f %d %d %d %d", quads + 1)
        _rows(fh, "l %d %d", lines + 1)
    return path


def write_ply(path, q: np.ndarray, lines: np.ndarray, quads: np.ndarray) -> Path:
    """Write one ASCII PLY with ``vertex``, ``face`` (quads) and ``edge`` (segments) elements."""
    q, lines, quads = _geometry(q, lines, quads)
    path = Path(path)
    with open(path, "w") as fh:
        fh.write("ply\nformat ascii 1.0\ncomment springsim export\n"
                 f"element vertex {len(q)}\nproperty double x\nproperty double y\nproperty double z\n"
                 f"element face {len(quads)}\nproperty list uchar int vertex_indices\n"
                 f"element edge {len(lines)}\nproperty int vertex1\nproperty int vertex2\nend_header\n")
        _rows(fh, "%.9g", q)
        _rows(fh, "%d", np.column_stack([np.full(len(quads), 4), quads]))
        _rows(fh, "%d", lines)
    return path


#: Format name -> (extension, writer).
EXPORT_FORMATS = {"vtk": (".vtk", write_vtk), "obj": (".obj", write_obj), "ply": (".ply", write_ply)}


def export_trajectory(model, traj, out_dir, *, fmt: str = "vtk", stem: str = "frame", every: int = 1) -> list[Path]:
    """Write every ``every``-th frame of ``traj`` to ``out_dir`` in format ``fmt``.

    Parameters
    ----------
    model : Model
        Gives the springs and (for a cloth) the faces.
    traj : Trajectory
        ``t`` (F,) [s], ``q`` and ``qd`` (F, N, 3).
    out_dir : path
        Created if missing.
    fmt : {"vtk", "obj", "ply"}
    stem : str
        File name prefix.
    every : int
        Frame stride (>= 1).

    Returns
    -------
    list of Path
        The frame files written (and, for VTK, the ``.vtk.series`` index last).
    """
    if fmt not in EXPORT_FORMATS:
        raise SpringsimError(f"export.format: must be one of {', '.join(EXPORT_FORMATS)}, got {fmt!r}")
    if int(every) != every or every < 1:
        raise SpringsimError(f"export.every: must be an integer >= 1, got {every!r}")
    if traj.q.shape[1] != model.particle_count:
        raise SpringsimError(f"export: trajectory has {traj.q.shape[1]} particles, the scene "
                             f"{model.particle_count}")
    ext, writer = EXPORT_FORMATS[fmt]
    out = Path(out_dir)
    out.mkdir(parents=True, exist_ok=True)
    lines = np.asarray(model.spring_indices, dtype=np.int64)
    quads = cloth_quads(model)
    files = []
    frames = range(0, traj.q.shape[0], int(every))
    for k in frames:
        p = out / f"{stem}_{k:04d}{ext}"
        if fmt == "vtk":
            write_vtk(p, traj.q[k], lines, quads, title=f"springsim t={traj.t[k]:.9g}",
                      point_data={"velocity": traj.qd[k]})
        else:
            writer(p, traj.q[k], lines, quads)
        files.append(p)
    if fmt == "vtk":
        series = {"file-series-version": "1.0",
                  "files": [{"name": f.name, "time": float(traj.t[k])} for f, k in zip(files, frames)]}
        idx = out / f"{stem}.vtk.series"
        idx.write_text(json.dumps(series, indent=1))
        files.append(idx)
    return files
