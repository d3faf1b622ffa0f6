"""Pictures: plot_dof, render_frame, render_gif and the plot/render CLI commands write readable files."""

from __future__ import annotations

import argparse
import sys
from pathlib import Path

import numpy as np
import pytest

from springsim.errors import SpringsimError
from springsim.integrators import make_integrator
from springsim.io.viz import plot_dof, render_frame, render_gif, require_matplotlib
from springsim.model.builder import ModelBuilder
from springsim.run.driver import Trajectory, simulate
from springsim.scene import benchmark_cloth

PNG = b"\x89PNG\r\n\x1a\n"
SCENES = Path(__file__).resolve().parents[2] / "scenes"


@pytest.fixture(scope="module")
def cloth_run():
    """A 5x5 benchmark cloth falling for 6 implicit Euler steps."""
    m = benchmark_cloth(5)
    return m, simulate(m, make_integrator("implicit_euler", m), 1 / 60, 6)


def _chain():
    b = ModelBuilder()
    b.add_particles(np.array([[0.0, 0, 0], [0.5, 0, 0], [1.0, 0, 0]]), None, 1.0, fixed=[True, False, False])
    b.add_springs(np.array([[0, 1], [1, 2]]), 100.0)
    return b.finalize()


def test_plot_dof_writes_png(cloth_run, tmp_path):
    """plot_dof writes a PNG for a coordinate given by name or index."""
    _, tr = cloth_run
    for dof in ("z", 2):
        out = plot_dof(tr, 24, dof, (-1.0, 0.1), tmp_path / f"d{dof}.png")
        assert out.read_bytes()[:8] == PNG


def test_plot_dof_rejects_bad_input(cloth_run, tmp_path):
    """A particle out of range or an unknown coordinate is a SpringsimError naming the plot field."""
    _, tr = cloth_run
    with pytest.raises(SpringsimError, match="plot.particle"):
        plot_dof(tr, 25, 0, None, tmp_path / "x.png")
    with pytest.raises(SpringsimError, match="plot.dof"):
        plot_dof(tr, 0, "w", None, tmp_path / "x.png")


def test_render_frame_cloth_and_springs(cloth_run, tmp_path):
    """render_frame draws a cloth surface and a plain spring chain to PNG files."""
    m, tr = cloth_run
    assert render_frame(m, tr.q[-1], tmp_path / "cloth.png", title="cloth").read_bytes()[:8] == PNG
    c = _chain()
    assert render_frame(c, c.particle_q, tmp_path / "chain.png").read_bytes()[:8] == PNG
    with pytest.raises(SpringsimError, match="shape"):
        render_frame(c, np.zeros((2, 3)), tmp_path / "bad.png")


def test_render_gif(cloth_run, tmp_path):
    """render_gif writes an animated GIF with one image per selected frame."""
    from PIL import Image

    m, tr = cloth_run
    out = render_gif(m, tr, tmp_path / "a.gif", every=3)
    assert out.read_bytes()[:6] in (b"GIF89a", b"GIF87a")
    with Image.open(out) as im:
        assert im.n_frames == 3  # frames 0, 3, 6
        assert min(im.size) >= 480  # large enough to read the titles


def test_run_title_names_integrator_and_step(cloth_run):
    """Titles come from the trajectory's metadata: integrator and h, or the adaptive tolerance."""
    from springsim.io.viz import run_title

    m, tr = cloth_run
    assert run_title(tr) == "benchmark_cloth_5: implicit_euler, h = 0.01667 s"
    assert run_title(tr, "mine") == "mine: implicit_euler, h = 0.01667 s"
    ad = Trajectory(tr.t, tr.q, tr.qd, meta={"integrator": "tr_bdf2", "time_rtol": 1e-3})
    assert run_title(ad) == "tr_bdf2, adaptive, rtol = 0.001"
    assert run_title(Trajectory(tr.t, tr.q, tr.qd)) == ""


def test_missing_matplotlib_is_a_clear_error(monkeypatch):
    """Without matplotlib the viz functions raise SpringsimError with the install hint."""
    monkeypatch.setitem(sys.modules, "matplotlib", None)
    with pytest.raises(SpringsimError, match=r"springsim\[plot\]"):
        require_matplotlib()


def _run(cmd, argv):
    p = argparse.ArgumentParser()
    cmd.add_arguments(p)
    return cmd.run(p.parse_args(argv))


def test_plot_and_render_commands(tmp_path):
    """The plot and render commands write a PNG from a scene, a GIF, and a PNG from a trajectory .npz."""
    from springsim.cli.pictures import plot_command, render_command

    spring = str(SCENES / "spring.yaml")
    assert _run(plot_command, [spring, "--out", str(tmp_path / "p.png"), "--steps", "20"]) == 0
    assert (tmp_path / "p.png").read_bytes()[:8] == PNG
    assert _run(render_command, [spring, "--every", "5", "--steps", "10", "--out", str(tmp_path / "s.gif")]) == 0
    assert (tmp_path / "s.gif").read_bytes()[:3] == b"GIF"
    q = np.zeros((2, 2, 3))
    q[:, 0, 2] = 1.0
    Trajectory(np.array([0.0, 0.01]), q, np.zeros_like(q)).save(tmp_path / "t.npz")
    argv = [str(tmp_path / "t.npz"), "--scene", spring, "--frame", "1", "--out", str(tmp_path / "t.png")]
    assert _run(render_command, argv) == 0
    assert (tmp_path / "t.png").read_bytes()[:8] == PNG
    with pytest.raises(SpringsimError, match="--scene"):
        _run(render_command, [str(tmp_path / "t.npz"), "--out", str(tmp_path / "u.png")])


def test_cli_registers_plot_render_export(tmp_path, capsys):
    """springsim plot/render/export go through the CLI registry; a scene without plot: is exit status 2."""
    from springsim.cli import main

    spring = str(SCENES / "spring.yaml")
    assert main(["plot", spring, "--steps", "10", "--out", str(tmp_path / "p.png")]) == 0
    assert (tmp_path / "p.png").read_bytes()[:8] == PNG
    assert main(["render", spring, "--steps", "4", "--every", "2", "--out", str(tmp_path / "x.png")]) == 2
    assert main(["plot", str(SCENES / "stiff_chain.yaml"), "--out", str(tmp_path / "c.png")]) == 2
    assert "no plot: block" in capsys.readouterr().err


def test_render_checks_the_trajectory_against_its_scene(tmp_path, capsys):
    """render of an .npz names a particle-count mismatch (exit 2) and warns when the file was made from another model
    (by the model fingerprint, or without one by the scene file's SHA-256)."""
    from springsim.cli import main

    spring, damped = str(SCENES / "spring.yaml"), str(SCENES / "damped_spring.yaml")
    npz = str(tmp_path / "s.npz")
    assert main(["run", spring, "--steps", "3", "--out", npz, "--quiet"]) == 0
    assert main(["render", npz, "--scene", spring, "--out", str(tmp_path / "a.png")]) == 0
    assert "warning" not in capsys.readouterr().err
    assert main(["render", npz, "--scene", damped, "--out", str(tmp_path / "b.png")]) == 0
    assert "computed from another model" in capsys.readouterr().err
    assert main(["render", npz, "--scene", str(SCENES / "three_body.yaml"), "--out", str(tmp_path / "c.png")]) == 2
    assert "has 2 particles" in capsys.readouterr().err
    # without a model fingerprint (a distributed run of a generated scene), the scene files' hashes decide
    from springsim.run.driver import Trajectory

    t = Trajectory.load(npz)
    t.meta["model_fingerprint"] = None
    t.save(npz)
    assert main(["render", npz, "--scene", spring, "--out", str(tmp_path / "d.png")]) == 0
    assert "warning" not in capsys.readouterr().err
    assert main(["render", npz, "--scene", damped, "--out", str(tmp_path / "e.png")]) == 0
    assert "computed from another scene file" in capsys.readouterr().err


def test_render_keeps_a_scenes_own_springs_beside_a_cloth(tmp_path):
    """A weight hung from a cloth corner is drawn on its spring: the cloth is a surface, every other spring a line."""
    from mpl_toolkits.mplot3d.art3d import Line3DCollection

    from springsim.io.viz import _axes, _draw, springs_outside_grids

    b = ModelBuilder()
    grid = b.add_cloth_grid(4, 4, pin="top")
    weight = b.add_particle((0.0, 0.0, -0.5), mass=0.5)
    hook = b.add_spring(grid[0], weight, stiffness=100.0)
    m = b.finalize()
    np.testing.assert_array_equal(springs_outside_grids(m), [hook])
    fig, ax = _axes(require_matplotlib(), -np.ones(3), np.ones(3), (3, 3))
    lines = [a for a in _draw(ax, m, m.particle_q, show_springs=True, show_particles=True, surface=True)
             if isinstance(a, Line3DCollection)]
    assert len(lines) == 1  # the hook (the cloth's own springs are the surface)
    assert render_frame(m, m.particle_q, tmp_path / "w.png").read_bytes()[:8] == PNG
