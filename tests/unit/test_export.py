"""Export writers: VTK, OBJ and PLY files parse back with the right counts and coordinates."""

from __future__ import annotations

import argparse
import json
from pathlib import Path

import numpy as np
import pytest

from springsim.driver import Trajectory
from springsim.errors import SpringsimError
from springsim.export import cloth_quads, export_trajectory, write_obj, write_ply, write_vtk
from springsim.scene import benchmark_cloth

SCENES = Path(__file__).resolve().parents[2] / "scenes"


@pytest.fixture(scope="module")
def cloth():
    """A 4x4 benchmark cloth model and a random 3-frame trajectory for it."""
    m = benchmark_cloth(4)
    rng = np.random.default_rng(11)
    q = m.particle_q[None] + 0.01 * rng.standard_normal((3, m.particle_count, 3))
    return m, Trajectory(np.array([0.0, 0.1, 0.2]), q, np.zeros_like(q))


def test_cloth_quads():
    """A 4x4 grid has 9 quads, each a unit cell of the grid."""
    quads = cloth_quads(benchmark_cloth(4))
    assert quads.shape == (9, 4)
    assert quads[0].tolist() == [0, 1, 5, 4]


def test_vtk_counts_and_points(cloth, tmp_path):
    """The VTK file declares POINTS/LINES/POLYGONS/POINT_DATA with matching counts and the exact points."""
    m, tr = cloth
    p = write_vtk(tmp_path / "a.vtk", tr.q[1], m.spring_indices, cloth_quads(m), point_data={"v": tr.qd[1]})
    lines = p.read_text().splitlines()
    assert lines[0].startswith("# vtk DataFile Version") and lines[3] == "DATASET POLYDATA"
    assert lines[4] == f"POINTS {m.particle_count} double"
    pts = np.loadtxt(lines[5:5 + m.particle_count])
    np.testing.assert_allclose(pts, tr.q[1], rtol=1e-8)
    i = lines.index(f"LINES {m.spring_count} {3 * m.spring_count}")
    seg = np.loadtxt(lines[i + 1:i + 1 + m.spring_count], dtype=int)
    assert (seg[:, 0] == 2).all() and (seg[:, 1:] == m.spring_indices).all()
    assert "POLYGONS 9 45" in lines and f"POINT_DATA {m.particle_count}" in lines


def test_obj_counts(cloth, tmp_path):
    """The OBJ file has one v per particle, one f per quad and one l per spring, 1-based."""
    m, tr = cloth
    text = write_obj(tmp_path / "a.obj", tr.q[0], m.spring_indices, cloth_quads(m)).read_text().splitlines()
    v = [ln for ln in text if ln.startswith("v ")]
    f = [ln for ln in text if ln.startswith("f ")]
    el = [ln for ln in text if ln.startswith("l ")]
    assert (len(v), len(f), len(el)) == (m.particle_count, 9, m.spring_count)
    assert min(int(t) for ln in f for t in ln.split()[1:]) == 1


def test_ply_header_and_body(cloth, tmp_path):
    """The PLY header declares vertex/face/edge counts and the body has exactly that many rows."""
    m, tr = cloth
    text = write_ply(tmp_path / "a.ply", tr.q[0], m.spring_indices, cloth_quads(m)).read_text().splitlines()
    assert text[:2] == ["ply", "format ascii 1.0"]
    assert f"element vertex {m.particle_count}" in text and "element face 9" in text
    assert f"element edge {m.spring_count}" in text
    body = text[text.index("end_header") + 1:]
    assert len(body) == m.particle_count + 9 + m.spring_count
    np.testing.assert_allclose(np.loadtxt(body[:m.particle_count]), tr.q[0], rtol=1e-8)


def test_export_trajectory_series(cloth, tmp_path):
    """export_trajectory writes every M-th frame and, for VTK, a .vtk.series index with the times."""
    m, tr = cloth
    files = export_trajectory(m, tr, tmp_path / "vtk", fmt="vtk", every=2)
    assert [f.name for f in files] == ["frame_0000.vtk", "frame_0002.vtk", "frame.vtk.series"]
    series = json.loads(files[-1].read_text())
    assert [e["time"] for e in series["files"]] == [0.0, 0.2]
    for fmt in ("obj", "ply"):
        assert len(export_trajectory(m, tr, tmp_path / fmt, fmt=fmt)) == 3
    with pytest.raises(SpringsimError, match="export.format"):
        export_trajectory(m, tr, tmp_path, fmt="stl")


def test_export_command(tmp_path):
    """The export command turns a trajectory .npz of a scene into per-frame PLY files."""
    from springsim.cli.export import export_command

    q = np.zeros((3, 2, 3))
    q[:, 0, 2] = 1.0
    Trajectory(np.array([0.0, 0.01, 0.02]), q, np.zeros_like(q)).save(tmp_path / "t.npz")
    p = argparse.ArgumentParser()
    export_command.add_arguments(p)
    args = p.parse_args([str(tmp_path / "t.npz"), str(SCENES / "spring.yaml"), "--format", "ply",
                         "--out", str(tmp_path / "ply")])
    assert export_command.run(args) == 0
    assert len(list((tmp_path / "ply").glob("*.ply"))) == 3
