"""Output files and interrupts of the command line: no lost frames, no half-written or wrongly replaced files, one
line for bad input, bounded work for hostile trajectory files (docs/robustness.md, "Guarantees").

Signals are real (``os.kill`` of the test process, or of a subprocess where the default action would end the test
run); full disks are injected ``OSError``s.
"""

from __future__ import annotations

import errno
import hashlib
import io
import os
import signal
import stat
import subprocess
import sys
import tempfile
import textwrap
import time
import zipfile
from pathlib import Path

import numpy as np
import pytest

from helpers import one_line_error, run_cli

import springsim
from springsim import cli
from springsim.errors import SpringsimError
from springsim.run.driver import Trajectory

ROOT = Path(__file__).resolve().parents[2]
SPRING = str(ROOT / "scenes" / "spring.yaml")
TWO = ("solver: {type: implicit_euler, timestep: 0.01, steps: 6}\n"
       "particles: [{pos: [0, 0, 1], mass: 1, fixed: true}, {pos: [0, 0, 0], mass: 1}]\n"
       "springs: [{particle_ids: [0, 1], stiffness: 100}]\n")


_main, _one_line_error = run_cli, one_line_error


@pytest.fixture
def scene(tmp_path):
    """A two-particle spring scene (6 steps) in a file of its own."""
    f = tmp_path / "scene.yaml"
    f.write_text(TWO)
    return f


@pytest.fixture
def no_run(monkeypatch):
    """Counts the runs started (a list that grows by one per call of ``simulate``)."""
    runs = []
    real = springsim.run.driver.simulate
    monkeypatch.setattr(springsim.run.driver, "simulate", lambda *a, **k: runs.append(1) or real(*a, **k))
    return runs


def _simulate_then(monkeypatch, action):
    """Make the run call ``action()`` after its last step (the scene file is gone, a signal arrives, ...)."""
    real = springsim.run.driver.simulate

    def simulate(*a, **k):
        traj = real(*a, **k)
        action()
        return traj

    monkeypatch.setattr(springsim.run.driver, "simulate", simulate)


def _savez_that(monkeypatch, action, times=1):
    """Make the first ``times`` calls of ``np.savez`` write part of the file, then call ``action()``."""
    real = np.savez
    calls = []

    def savez(fh, **arrays):
        calls.append(1)
        if len(calls) <= times:
            fh.write(b"PK\x03\x04 part of the file")
            action()
            fh.seek(0)
            fh.truncate()
        return real(fh, **arrays)

    monkeypatch.setattr(np, "savez", savez)
    return calls


def _hidden(d: Path) -> list[str]:
    return sorted(p.name for p in d.iterdir() if p.name.startswith("."))


def _script(code: str, tmp_path: Path) -> subprocess.CompletedProcess:
    """Run ``code`` in a fresh interpreter (for signals whose default action would end the test process)."""
    return subprocess.run([sys.executable, "-c", textwrap.dedent(code)], capture_output=True, text=True, timeout=300,
                          cwd=tmp_path, env={**os.environ, "PYTHONPATH": os.pathsep.join(sys.path)})


# -- item 2: hostile trajectory files ------------------------------------------------------------------------------
def _npy(descr: str, shape, data: bytes) -> bytes:
    buf = io.BytesIO()
    np.lib.format.write_array_header_1_0(buf, {"descr": descr, "fortran_order": False, "shape": shape})
    return buf.getvalue() + data


def test_lying_header_is_refused_from_the_header(tmp_path, capsys, monkeypatch):
    """An .npz whose q header claims (1, 3e10, 3) over a few bytes of data is refused at once, naming the file and
    the array (not "the scene is too large"), without reading or allocating the array."""
    f = tmp_path / "liar.npz"
    with zipfile.ZipFile(f, "w") as zf:
        zf.writestr("t.npy", _npy("<f8", (1,), np.zeros(1).tobytes()))
        zf.writestr("q.npy", _npy("<f8", (1, 30_000_000_000, 3), np.zeros(6).tobytes()))
    reads = []
    monkeypatch.setattr(np.lib.format, "read_array", lambda *a, **k: reads.append(1))
    t0 = time.perf_counter()
    line = _one_line_error(capsys, "export", f, SPRING, "--out", tmp_path / "out")
    assert str(f) in line and "array q" in line and "too large" not in line
    with pytest.raises(SpringsimError, match="array q"):
        Trajectory.load(f)
    assert reads == [] and time.perf_counter() - t0 < 10.0


def test_huge_announced_trajectory_is_refused_before_reading(tmp_path, capsys, monkeypatch):
    """render and export of a compressed file whose q announces far more particles than the scene refuse it from
    the header (one line naming the file and q, no array read); Trajectory.load refuses what does not fit in memory."""
    f = tmp_path / "big.npz"
    q = np.zeros((2, 200_000, 3))
    np.savez_compressed(f, t=np.zeros(2), q=q, qd=q)  # 9.6 MB of arrays in a few kB
    assert f.stat().st_size < 100_000
    reads = []
    real = np.lib.format.read_array
    monkeypatch.setattr(np.lib.format, "read_array", lambda *a, **k: reads.append(1) or real(*a, **k))
    for argv in (["render", f, "--scene", SPRING, "--out", tmp_path / "x.png"],
                 ["export", f, SPRING, "--out", tmp_path / "out"]):
        line = _one_line_error(capsys, *argv)
        assert str(f) in line and "200000 particles" in line and "array q" in line
    assert reads == []
    from springsim._runtime import memory

    monkeypatch.setattr(memory, "available_memory", lambda: 2**20)
    with pytest.raises(SpringsimError, match=r"array q \(2, 200000, 3\).*memory"):
        Trajectory.load(f)
    assert reads == []


def test_text_file_given_as_npz(tmp_path, capsys):
    """A text file given as a trajectory is "not an .npz", without numpy's advice to load it with allow_pickle."""
    f = tmp_path / "notes.npz"
    f.write_text("these are not frames\n" * 10)
    line = _one_line_error(capsys, "render", f, "--scene", SPRING, "--out", tmp_path / "x.png")
    assert str(f) in line and "not an .npz" in line and "pickle" not in line


# -- item 3: the scene file may change or vanish during the run -----------------------------------------------------
def test_scene_deleted_during_the_run_keeps_the_frames(scene, tmp_path, capsys, monkeypatch):
    """A scene file deleted during the run does not cost the frames: they are saved, with the SHA-256 of the bytes
    that were loaded."""
    digest = hashlib.sha256(scene.read_bytes()).hexdigest()
    _simulate_then(monkeypatch, scene.unlink)
    out = tmp_path / "out.npz"
    code, _, err = _main(capsys, "run", scene, "--out", out, "--quiet")
    assert code == 0, err
    traj = Trajectory.load(out)
    assert traj.frame_count == 7 and traj.meta["scene_sha256"] == digest


def test_scene_edited_during_the_run_records_what_was_run(scene, tmp_path, capsys, monkeypatch):
    """The provenance hash is the one of the scene that was run, not of the file as edited during the run."""
    digest = hashlib.sha256(scene.read_bytes()).hexdigest()
    _simulate_then(monkeypatch, lambda: scene.write_text(TWO.replace("100", "200")))
    out = tmp_path / "out.npz"
    assert _main(capsys, "run", scene, "--out", out, "--quiet")[0] == 0
    assert Trajectory.load(out).meta["scene_sha256"] == digest


def test_interrupt_after_the_scene_moved_keeps_the_frames(scene, tmp_path, capsys, monkeypatch):
    """Ctrl-C in a run whose scene file was moved away saves the frames so far and exits 130."""
    def progress_then_move(*a, **k):
        def progress(k_, n):
            if k_ == 3:
                scene.rename(tmp_path / "moved.yaml")
                raise KeyboardInterrupt
        return real(*a, **{**k, "progress": progress})

    real = springsim.run.driver.simulate
    monkeypatch.setattr(springsim.run.driver, "simulate", progress_then_move)
    out = tmp_path / "out.npz"
    code, _, err = _main(capsys, "run", scene, "--out", out)
    assert code == 130 and f"to {out}" in err and "Traceback" not in err
    assert Trajectory.load(out).frame_count == 4


# -- items 4, 7, 17: interrupts during the save, SIGTERM, rescue files ----------------------------------------------
def test_ctrl_c_during_the_final_save_keeps_the_frames(scene, tmp_path, capsys):
    """A real SIGINT arriving while --out is written lets the write finish: the frames are at --out, exit 130."""
    out = tmp_path / "out.npz"
    mp = pytest.MonkeyPatch()
    try:
        calls = _savez_that(mp, lambda: os.kill(os.getpid(), signal.SIGINT))
        code, _, err = _main(capsys, "run", scene, "--out", out, "--quiet")
    finally:
        mp.undo()
    assert calls and code == 130 and "interrupted" in err and f"saved to {out}" in err, err
    assert Trajectory.load(out).frame_count == 7 and _hidden(tmp_path) == []


def test_keyboard_interrupt_inside_the_save_goes_to_a_rescue_file(scene, tmp_path, capsys, monkeypatch):
    """A KeyboardInterrupt raised inside the write of --out sends the frames to a rescue file, named on stderr;
    an interrupted command exits 130 even when its frames were rescued."""
    def interrupt():
        raise KeyboardInterrupt

    monkeypatch.setattr(tempfile, "tempdir", str(tmp_path / "tmp"))
    (tmp_path / "tmp").mkdir()
    _savez_that(monkeypatch, interrupt)
    out = tmp_path / "out.npz"
    code, _, err = _main(capsys, "run", scene, "--out", out, "--quiet")
    assert code == 130 and "Traceback" not in err, err
    rescue = Path(err.split(" to ")[-1].split(" instead")[0])
    assert rescue.parent == tmp_path / "tmp" and Trajectory.load(rescue).frame_count == 7
    assert not out.exists() and _hidden(tmp_path) == []


def test_interrupted_run_with_a_full_disk_exits_130(scene, tmp_path, capsys, monkeypatch):
    """Ctrl-C in a run whose --out cannot be written: the frames go to a rescue file and the exit status is 130."""
    def progress_interrupt(*a, **k):
        def progress(k_, n):
            if k_ == 2:
                raise KeyboardInterrupt
        return real(*a, **{**k, "progress": progress})

    def full():
        raise OSError(errno.ENOSPC, "No space left on device")

    real = springsim.run.driver.simulate
    monkeypatch.setattr(springsim.run.driver, "simulate", progress_interrupt)
    monkeypatch.setattr(tempfile, "tempdir", str(tmp_path))
    _savez_that(monkeypatch, full)
    code, _, err = _main(capsys, "run", scene, "--out", tmp_path / "out.npz")
    assert code == 130 and "No space left on device" in err
    rescue = next(tmp_path.glob("springsim-rescue-*.npz"))
    assert Trajectory.load(rescue).frame_count == 3 and f"to {rescue}" in err


def test_rescue_that_cannot_be_written_leaves_no_empty_file(scene, tmp_path, capsys, monkeypatch):
    """With --out and the temporary directory both full, no empty rescue file is left and one line says the frames
    are lost (exit 1: the run itself succeeded, its output could not be written)."""
    def full():
        raise OSError(errno.ENOSPC, "No space left on device")

    tmp = tmp_path / "tmp"
    tmp.mkdir()
    monkeypatch.setattr(tempfile, "tempdir", str(tmp))
    _savez_that(monkeypatch, full, times=2)
    out = tmp_path / "out.npz"
    out.write_bytes(b"previous")
    line = _one_line_error(capsys, "run", scene, "--out", out, "--quiet", code=1)
    assert "No space left on device" in line and "the frames are lost" in line
    assert os.listdir(tmp) == [] and out.read_bytes() == b"previous" and _hidden(tmp_path) == []


def test_sigterm_during_the_run_saves_the_frames(tmp_path):
    """SIGTERM during a run is handled like Ctrl-C: the frames so far are saved to --out, no temporary file is left,
    exit 143 (128 + SIGTERM)."""
    (tmp_path / "scene.yaml").write_text(TWO.replace("steps: 6", "steps: 50"))
    r = _script("""
        import os, signal, sys
        import springsim.run.driver
        from springsim import cli
        real = springsim.run.driver.simulate
        def simulate(*a, **k):
            def progress(k_, n):
                if k_ == 5:
                    os.kill(os.getpid(), signal.SIGTERM)
            return real(*a, **{**k, "progress": progress})
        springsim.run.driver.simulate = simulate
        sys.exit(cli.main(["run", "scene.yaml", "--out", "out.npz"]))
    """, tmp_path)
    assert r.returncode == 143 and "terminated" in r.stderr and "Traceback" not in r.stderr, r.stderr
    assert 6 <= Trajectory.load(tmp_path / "out.npz").frame_count < 51 and _hidden(tmp_path) == []


def test_sigterm_during_the_save_keeps_the_frames_and_no_temporary_file(tmp_path):
    """SIGTERM while --out is written lets the write finish (no hidden temporary file is left), exit 143."""
    (tmp_path / "scene.yaml").write_text(TWO)
    r = _script("""
        import os, signal, sys
        import numpy as np
        from springsim import cli
        real = np.savez
        def savez(fh, **arrays):
            real(fh, **arrays)
            os.kill(os.getpid(), signal.SIGTERM)
        np.savez = savez
        sys.exit(cli.main(["run", "scene.yaml", "--out", "out.npz", "--quiet"]))
    """, tmp_path)
    assert r.returncode == 143 and "Traceback" not in r.stderr, r.stderr
    assert Trajectory.load(tmp_path / "out.npz").frame_count == 7 and _hidden(tmp_path) == []


def test_closed_stdout_is_quiet(tmp_path):
    """`springsim run ... | head` closing the pipe early: no "Broken pipe" message, exit 141 (128 + SIGPIPE)."""
    p = subprocess.Popen([sys.executable, "-m", "springsim", "run", SPRING, "--steps", "3"], stdout=subprocess.PIPE,
                         stderr=subprocess.PIPE, env={**os.environ, "PYTHONPATH": os.pathsep.join(sys.path)})
    p.stdout.close()  # the reader is gone before the summary is printed
    err = p.stderr.read().decode()
    assert p.wait(timeout=300) == 141 and err == "", err


# -- items 5, 16: pictures ----------------------------------------------------------------------------------------
@pytest.fixture
def frames(tmp_path):
    """A 12-frame trajectory of scenes/spring.yaml."""
    f = tmp_path / "traj.npz"
    assert cli.main(["run", SPRING, "--steps", "11", "--out", str(f), "--quiet"]) == 0
    return f


def test_interrupted_gif_keeps_the_previous_file(frames, tmp_path, capsys, monkeypatch):
    """Ctrl-C while a GIF is rendered leaves the previous GIF as it was (no shorter GIF), no temporary file."""
    pytest.importorskip("matplotlib")
    from matplotlib.animation import PillowWriter

    gif = tmp_path / "anim.gif"
    assert _main(capsys, "render", frames, "--scene", SPRING, "--every", "1", "--out", gif)[0] == 0
    before = gif.read_bytes()
    real = PillowWriter.grab_frame
    grabbed = []

    def grab(self, **kw):
        grabbed.append(1)
        if len(grabbed) == 4:
            raise KeyboardInterrupt
        return real(self, **kw)

    monkeypatch.setattr(PillowWriter, "grab_frame", grab)
    code, out, err = _main(capsys, "render", frames, "--scene", SPRING, "--every", "1", "--out", gif)
    assert code == 130 and "wrote" not in out and gif.read_bytes() == before and _hidden(tmp_path) == []


def test_picture_write_failure_leaves_no_partial_file(frames, tmp_path, capsys, monkeypatch):
    """A full disk while a PNG is written: one line, exit 2, no file at --out and no temporary file."""
    pytest.importorskip("matplotlib")
    from matplotlib.figure import Figure

    def savefig(self, fname, **kw):
        Path(fname).write_bytes(b"\x89PNG partial")
        raise OSError(errno.ENOSPC, "No space left on device")

    monkeypatch.setattr(Figure, "savefig", savefig)
    png = tmp_path / "x.png"
    assert "No space left" in _one_line_error(capsys, "render", frames, "--scene", SPRING, "--out", png)
    assert not png.exists() and _hidden(tmp_path) == []


@pytest.mark.parametrize("name, fragment", [
    ("{tmp}", "is a directory"),
    ("{tmp}/missing/x.png", "does not exist"),
    ("{tmp}/newdir/", "names a directory"),
    ("{tmp}/x", "unknown extension (none); give a file name ending in .png"),
    ("{tmp}/x.xyz", "unknown extension .xyz; give a file name ending in .png"),
    ("/dev/full", "not a regular file"),
    ("{scene}", "unknown extension .yaml"),
])
def test_render_out_follows_the_rules_of_run_out(scene, tmp_path, capsys, no_run, name, fragment):
    """render --out is checked like run --out, before the run: directories, missing parents, unknown extensions
    (listing the known one), devices; nothing is written and no "wrote" line is printed."""
    pytest.importorskip("matplotlib")
    before, beside_device = sorted(os.listdir(tmp_path)), Path("/dev/full.png").exists()
    out = name.format(tmp=tmp_path, scene=scene)
    assert fragment in _one_line_error(capsys, "render", scene, "--out", out)
    assert no_run == [] and sorted(os.listdir(tmp_path)) == before
    assert Path("/dev/full.png").exists() == beside_device  # was written as "--out /dev/full"


def test_render_gif_needs_gif_and_plot_needs_png(scene, tmp_path, capsys, no_run):
    """--every writes a GIF and plot a PNG: any other extension is refused before the run, listing the known one."""
    pytest.importorskip("matplotlib")
    assert "ending in .gif" in _one_line_error(capsys, "render", scene, "--every", "2", "--out", tmp_path / "a.png")
    assert "ending in .png" in _one_line_error(capsys, "plot", scene, "--out", tmp_path / "p.jpg")
    assert no_run == []


def test_empty_trajectory_and_unknown_picture_format(tmp_path, capsys):
    """A trajectory without frames is one line for export and render; a picture name matplotlib cannot write is one
    line too (render_frame through the API: a SpringsimError listing the formats)."""
    pytest.importorskip("matplotlib")
    pytest.importorskip("meshio")
    f = tmp_path / "empty.npz"
    Trajectory(np.zeros(0), np.zeros((0, 2, 3)), np.zeros((0, 2, 3))).save(f)
    assert "no frames" in _one_line_error(capsys, "export", f, SPRING, "--out", tmp_path / "out")
    assert "no frames" in _one_line_error(capsys, "render", f, "--scene", SPRING, "--out", tmp_path / "x.png")
    from springsim.io.viz import render_frame
    from springsim.scene import load_scene

    m = load_scene(SPRING).model
    with pytest.raises(SpringsimError, match=r"unknown picture extension \.xyz.*\.png"):
        render_frame(m, m.particle_q, tmp_path / "f.xyz")
    assert os.listdir(tmp_path) == ["empty.npz"]


def test_extreme_coordinates_are_one_line(tmp_path, capsys):
    """Finite positions near the largest double are refused by render in one line (no overflow warnings or
    matplotlib traceback)."""
    pytest.importorskip("matplotlib")
    q = np.zeros((2, 2, 3))
    q[:, 0], q[:, 1] = [1e308, -1e308, 1e308], [-1e308, 1e308, -1e308]
    f = tmp_path / "far.npz"
    Trajectory(np.array([0.0, 1.0]), q, np.zeros_like(q)).save(f)
    assert "positions reach 1e+308 m" in _one_line_error(capsys, "render", f, "--scene", SPRING, "--out",
                                                         tmp_path / "x.png")


def test_numpy_warnings_of_a_run_are_not_multi_line(tmp_path):
    """A run on extreme finite inputs reports the blow-up in its own lines: no numpy warning with a source path."""
    f = tmp_path / "far.yaml"
    f.write_text("solver: {type: explicit_euler, timestep: 0.01, steps: 3}\n"
                 "particles: [{pos: [1.0e200, 0, 0], mass: 1}, {pos: [-1.0e200, 0, 0], mass: 1}]\n"
                 "springs: [{particle_ids: [0, 1], stiffness: 1.0e300}]\n")
    r = subprocess.run([sys.executable, "-m", "springsim", "run", str(f), "--quiet"], capture_output=True, text=True,
                       timeout=300, env={**os.environ, "PYTHONPATH": os.pathsep.join(sys.path)})
    assert r.returncode == 1 and "RuntimeWarning" not in r.stderr and ".py:" not in r.stderr, r.stderr
    assert all(line.startswith("springsim: ") for line in r.stderr.strip().splitlines()), r.stderr


# -- items 6, 18: run --out names -----------------------------------------------------------------------------------
def test_out_must_not_be_the_scene(scene, tmp_path, capsys, no_run):
    """--out naming the scene file (also through a hard link) is refused before the run; the scene is untouched."""
    before = scene.read_bytes()
    assert "ending in .npz" in _one_line_error(capsys, "run", scene, "--out", scene)
    link = tmp_path / "scene.npz"
    os.link(scene, link)
    assert f"is the input file {link}" in _one_line_error(capsys, "run", link, "--out", link)
    assert f"is the input file {scene}" in _one_line_error(capsys, "run", scene, "--out", link)
    assert scene.read_bytes() == before and no_run == []


@pytest.mark.parametrize("name, fragment", [
    ("{tmp}/x.txt", "unknown extension .txt; give a file name ending in .npz"),
    ("{tmp}/newdir/", "names a directory"),
    ("{tmp}/" + "a" * 300 + ".npz", "the file name is 304 bytes long, more than"),
])
def test_out_names_are_checked_before_the_run(scene, tmp_path, capsys, no_run, name, fragment):
    """--out with another extension than .npz, ending in a slash or with a name longer than the directory allows is
    refused before the run, in one line; nothing is written."""
    before = sorted(os.listdir(tmp_path))
    assert fragment in _one_line_error(capsys, "run", scene, "--out", name.format(tmp=tmp_path))
    assert no_run == [] and sorted(os.listdir(tmp_path)) == before


def test_long_name_probe_uses_the_real_length(scene, tmp_path, capsys, monkeypatch, no_run):
    """Where PC_NAME_MAX is unknown, the probe file has the length of the real name, so a name the directory refuses
    fails before the run."""
    monkeypatch.setattr(os, "pathconf", lambda *a: (_ for _ in ()).throw(OSError(errno.EINVAL, "unknown")))
    line = _one_line_error(capsys, "run", scene, "--out", tmp_path / ("b" * 300 + ".npz"))
    assert "cannot write" in line and "File name too long" in line and no_run == []


# -- items 14, 17: solver nulls, option messages -------------------------------------------------------------------
@pytest.mark.parametrize("integrator", ["explicit_euler", "symplectic_euler", "midpoint", "linearized_implicit",
                                        "implicit_euler", "bdf2", "tr_bdf2", "energy_momentum"])
def test_null_timestep_is_refused_naming_the_field(tmp_path, capsys, integrator):
    """`timestep: null` has no default to fall back on: one line naming solver.timestep, exit 2, for every
    integrator."""
    f = tmp_path / "s.yaml"
    f.write_text(TWO.replace("timestep: 0.01", "timestep: null").replace("implicit_euler", integrator))
    line = _one_line_error(capsys, "run", f)
    assert "solver.timestep: is required and has no default; got null" in line


def test_null_solver_values_mean_the_default(tmp_path, capsys):
    """A null solver value takes the field's default: benchmark_cloth's 1/60 s step, gravity -9.81, steps 100;
    a null type is refused naming solver.type."""
    from springsim.scene import load_scene

    s = load_scene("solver: {type: implicit_euler, timestep: null, steps: 2}\nbenchmark_cloth: {n: 3}\n")
    assert s.config.dt == pytest.approx(1 / 60)
    s = load_scene("solver: {type: symplectic_euler, timestep: 0.01, gravity: null, steps: null, up_axis: null,"
                   " linear_solver: ~}\nparticles: [{pos: [0, 0, 0], mass: 1}]\n")
    assert s.config.steps is None and s.config.run_steps() == 100 and s.model.gravity == -9.81
    f = tmp_path / "b.yaml"
    f.write_text("solver: {type: implicit_euler, timestep: null, steps: 2}\nbenchmark_cloth: {n: 3}\n")
    code, out, err = _main(capsys, "run", f)
    assert code == 0 and "2 x dt = 0.0166667 s" in out, err
    f.write_text(TWO.replace("type: implicit_euler", "type: null"))
    assert "solver.type: is required" in _one_line_error(capsys, "run", f)


def test_small_max_step_names_the_option(scene, capsys):
    """--max-step below the adaptive driver's smallest step names --max-step (not the internal h_min)."""
    import inspect

    from springsim.run.adaptive import simulate_adaptive
    from springsim.run.options import ADAPTIVE_H_MIN

    assert inspect.signature(simulate_adaptive).parameters["h_min"].default == ADAPTIVE_H_MIN
    line = _one_line_error(capsys, "run", scene, "--integrator", "tr_bdf2", "--time-rtol", "1e-3",
                           "--max-step", "1e-8")
    assert "--max-step" in line and "h_min" not in line


def test_usage_errors_are_springsim_error_lines(scene, capsys):
    """argparse errors read `springsim: error: ...; see 'springsim run --help'`, one line, exit 2."""
    line = _one_line_error(capsys, "run", scene, "--steps", "x")
    assert line.startswith("springsim: error: argument --steps") and line.endswith("see 'springsim run --help'")


# -- item 15: trajectory meta ----------------------------------------------------------------------------------------
@pytest.mark.parametrize("meta, fragment", [
    ('{"format_version": "1"}', "meta.format_version must be an integer"),
    ('{"format_version": null}', "meta.format_version must be an integer"),
    ('{"format_version": true}', "meta.format_version must be an integer"),
    ('{"format": null}', "meta.format must be a string"),
    ('{"a": ' + "[" * 100_000 + "]" * 100_000 + "}", "nested too deeply"),
    ("[1, 2]", "meta must hold a JSON object"),
    ("{bad json", "meta is not JSON"),
])
def test_bad_meta_is_a_springsim_error(tmp_path, meta, fragment):
    """Trajectory.load with a meta of the wrong type or nesting raises SpringsimError naming the file and field."""
    f = tmp_path / "m.npz"
    np.savez(f, t=np.zeros(1), q=np.zeros((1, 2, 3)), meta=np.array(meta))
    with pytest.raises(SpringsimError, match=fragment) as e:
        Trajectory.load(f)
    assert str(f) in str(e.value) and "\n" not in str(e.value)


def test_meta_cannot_overwrite_the_format_keys(tmp_path):
    """Trajectory.save writes the format keys itself: a meta "format" or "format_version" entry gives a file that
    springsim still reads."""
    f = tmp_path / "t.npz"
    Trajectory(np.zeros(1), np.zeros((1, 2, 3)), np.zeros((1, 2, 3)),
               meta={"format": "mine", "format_version": 99, "note": "kept"}).save(f)
    meta = Trajectory.load(f).meta
    assert meta["format"] == "springsim-trajectory" and meta["format_version"] == 1 and meta["note"] == "kept"


# -- item 19: modes of exported files --------------------------------------------------------------------------------
def test_exported_files_get_the_npz_mode_rule(frames, tmp_path, capsys):
    """Exported mesh files get 0666 less the umask when new and keep their mode when replaced, like the .npz."""
    pytest.importorskip("meshio")
    old = os.umask(0o027)
    try:
        out = tmp_path / "mesh"
        assert _main(capsys, "export", frames, SPRING, "--out", out, "--every", "5")[0] == 0
        files = sorted(out.iterdir())
        assert files and all(stat.S_IMODE(p.stat().st_mode) == 0o640 for p in files)
        os.chmod(files[0], 0o604)
        assert _main(capsys, "export", frames, SPRING, "--out", out, "--every", "5")[0] == 0
        assert stat.S_IMODE(files[0].stat().st_mode) == 0o604 and _hidden(out) == []
    finally:
        os.umask(old)
