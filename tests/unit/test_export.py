"""Export: every format is read back with meshio (the library users' tools share) and matches the trajectory."""

from __future__ import annotations

import json
import sys
from pathlib import Path

import meshio
import numpy as np
import pytest

from springsim import cli
from springsim.errors import SpringsimError
from springsim.io.export import EXPORT_FORMATS, cloth_quads, export_trajectory
from springsim.model.builder import ModelBuilder
from springsim.run.driver import Trajectory
from springsim.scene import benchmark_cloth

SCENES = Path(__file__).resolve().parents[2] / "scenes"


def _traj(m, frames=3, seed=11):
    rng = np.random.default_rng(seed)
    q = m.particle_q[None] + 0.01 * rng.standard_normal((frames, m.particle_count, 3))
    qd = rng.standard_normal((frames, m.particle_count, 3))
    return Trajectory(0.1 * np.arange(frames), q, qd)


@pytest.fixture(scope="module")
def cloth_and_weight():
    """A 4x3 cloth with a weight hung from a corner (a spring outside the grid) and a random 3-frame trajectory."""
    b = ModelBuilder()
    grid = b.add_cloth_grid(4, 3, pin="top")
    w = b.add_particle((0.0, 0.0, -0.5), mass=0.2)
    b.add_spring(grid[0], w, stiffness=50.0)
    m = b.finalize()
    return m, _traj(m)


def _cells(mesh):
    return {c.type: c.data for c in mesh.cells}


def test_cloth_quads():
    """A 4x4 grid has 9 quads, each a unit cell of the grid."""
    quads = cloth_quads(benchmark_cloth(4))
    assert quads.shape == (9, 4)
    assert quads[0].tolist() == [0, 1, 5, 4]


@pytest.mark.parametrize("fmt", ["vtu", "vtk", "ply"])
def test_per_frame_formats_read_back(cloth_and_weight, tmp_path, fmt):
    """VTU, VTK and PLY frames hold the exact positions (binary float64), the quads, every spring and the velocity."""
    m, tr = cloth_and_weight
    files = export_trajectory(m, tr, tmp_path, fmt=fmt, stem="c")
    frames = [f for f in files if f.suffix == EXPORT_FORMATS[fmt].ext]
    assert [f.name for f in frames] == [f"c_{k:04d}{EXPORT_FORMATS[fmt].ext}" for k in range(3)]
    for k, f in enumerate(frames):
        mesh = meshio.read(f)
        np.testing.assert_array_equal(mesh.points, tr.q[k])  # binary doubles: no rounding
        cells = _cells(mesh)
        np.testing.assert_array_equal(cells["quad"], cloth_quads(m))
        np.testing.assert_array_equal(cells["line"], m.spring_indices)
        v = (np.column_stack([mesh.point_data[c] for c in ("vx", "vy", "vz")]) if fmt == "ply"
             else mesh.point_data["velocity"])
        np.testing.assert_array_equal(v, tr.qd[k])
    if fmt != "ply":
        series = json.loads((tmp_path / f"c.{fmt}.series").read_text())
        assert series["files"] == [{"name": f.name, "time": float(t)} for f, t in zip(frames, tr.t)]
    assert not list(tmp_path.glob(".*"))  # no temporary file left


def test_obj_reads_back_faces(tmp_path):
    """OBJ frames hold the positions (as text, to meshio's printed precision) and the quads."""
    m = benchmark_cloth(4)
    tr = _traj(m, 2)
    files = export_trajectory(m, tr, tmp_path, fmt="obj")
    for k, f in enumerate(files):
        mesh = meshio.read(f)
        np.testing.assert_allclose(mesh.points, tr.q[k], rtol=0, atol=1e-12)
        np.testing.assert_array_equal(_cells(mesh)["quad"], cloth_quads(m))


def test_xdmf_time_series_reads_back(cloth_and_weight, tmp_path):
    """One XDMF file: initial positions + per-frame displacement and velocity; the springs as lines (mixed scene)."""
    m, tr = cloth_and_weight
    [f] = export_trajectory(m, tr, tmp_path, fmt="xdmf", stem="c", every=2)
    assert f.name == "c.xdmf" and sorted(p.name for p in tmp_path.iterdir()) == ["c.xdmf"]
    with meshio.xdmf.TimeSeriesReader(f) as r:
        points, cells = r.read_points_cells()
        np.testing.assert_array_equal(points, tr.q[0])
        np.testing.assert_array_equal(_cells(meshio.Mesh(points, cells))["line"], m.spring_indices)
        assert r.num_steps == 2  # frames 0 and 2
        for step, k in enumerate((0, 2)):
            t, pd, _ = r.read_data(step)
            assert t == pytest.approx(tr.t[k], abs=0)
            np.testing.assert_allclose(points + pd["displacement"], tr.q[k], rtol=0, atol=1e-15)
            np.testing.assert_array_equal(pd["velocity"], tr.qd[k])


def test_xdmf_of_a_pure_cloth_holds_quads(tmp_path):
    m = benchmark_cloth(4)
    [f] = export_trajectory(m, _traj(m, 2), tmp_path, fmt="xdmf")
    with meshio.xdmf.TimeSeriesReader(f) as r:
        points, cells = r.read_points_cells()
    np.testing.assert_array_equal(_cells(meshio.Mesh(points, cells))["quad"], cloth_quads(m))


def test_every_keeps_the_last_frame(cloth_and_weight, tmp_path):
    m, tr = cloth_and_weight
    files = export_trajectory(m, tr, tmp_path, fmt="vtu", every=5)
    assert [f.name for f in files] == ["frame_0000.vtu", "frame_0002.vtu", "frame.vtu.series"]


def test_bad_requests_are_one_line_errors(cloth_and_weight, tmp_path):
    m, tr = cloth_and_weight
    with pytest.raises(SpringsimError, match="export.format: must be one of vtu, vtk, xdmf, ply, obj"):
        export_trajectory(m, tr, tmp_path, fmt="stl")
    with pytest.raises(SpringsimError, match="export.every"):
        export_trajectory(m, tr, tmp_path, every=0)
    b = ModelBuilder()
    b.add_particles(np.eye(3), None, 1.0)
    b.add_springs([[0, 1]], 10.0)
    chain = b.finalize()
    with pytest.raises(SpringsimError, match="OBJ holds faces only"):
        export_trajectory(chain, _traj(chain), tmp_path, fmt="obj")
    with pytest.raises(SpringsimError, match="trajectory has 3 particles"):
        export_trajectory(m, _traj(chain), tmp_path)


def test_without_meshio_the_error_names_the_extra(cloth_and_weight, tmp_path, monkeypatch):
    m, tr = cloth_and_weight
    monkeypatch.setitem(sys.modules, "meshio", None)
    with pytest.raises(SpringsimError, match=r"needs meshio: pip install 'springsim\[mesh\]'"):
        export_trajectory(m, tr, tmp_path)


def test_export_command_end_to_end(tmp_path, capsys):
    """run --out, then export: PLY frames of the spring scene read back; --help lists the formats and the default."""
    npz = tmp_path / "t.npz"
    spring = str(SCENES / "spring.yaml")
    assert cli.main(["run", spring, "--steps", "4", "--out", str(npz), "--quiet"]) == 0
    assert cli.main(["export", str(npz), spring, "--format", "ply", "--every", "2", "--out", str(tmp_path / "ply")]) == 0
    files = sorted((tmp_path / "ply").glob("*.ply"))
    assert [f.name for f in files] == ["spring_0000.ply", "spring_0002.ply", "spring_0004.ply"]
    np.testing.assert_array_equal(meshio.read(files[-1]).points, Trajectory.load(npz).q[-1])
    assert cli.main(["export", str(npz), spring, "--format", "stl", "--out", str(tmp_path)]) == 2
    capsys.readouterr()
    assert cli.main(["export", "--help"]) == 0
    assert "one of vtu, vtk, xdmf, ply, obj (default vtu)" in " ".join(capsys.readouterr().out.split())
