"""Shipped scenes by name: ``springsim run cloth_16`` anywhere, ``springsim scenes``, :mod:`springsim.scene.shipped`."""

from pathlib import Path

import pytest

from springsim import SceneError, cli
from springsim.scene import load_scene
from springsim.scene.shipped import resolve_scene, shipped_scene, shipped_scenes

ROOT = Path(__file__).resolve().parents[2]
NAMES = sorted(p.stem for p in (ROOT / "scenes").glob("*.yaml"))


def test_every_scene_of_the_repository_is_shipped():
    """The shipped scenes are the repository's scenes/*.yaml, same names and same content."""
    shipped = shipped_scenes()
    assert sorted(shipped) == NAMES
    for name, path in shipped.items():
        assert path.read_bytes() == (ROOT / "scenes" / f"{name}.yaml").read_bytes()


def test_scenes_command_lists_name_particles_springs_description(capsys):
    """`springsim scenes` prints one row per shipped scene with its particle and spring counts and description."""
    assert cli.main(["scenes"]) == 0
    out, err = capsys.readouterr()
    lines = out.splitlines()
    assert lines[0].split() == ["name", "particles", "springs", "description"] and err == ""
    rows = {line.split()[0]: line.split(maxsplit=3) for line in lines[1:]}
    assert sorted(rows) == NAMES
    for name in ("cloth_16", "three_body"):
        model = load_scene(ROOT / "scenes" / f"{name}.yaml").model
        assert rows[name][1:3] == [str(model.particle_count), str(model.spring_count)]
    assert rows["cloth_16"][3] == "A hanging 16 x 16 cloth (1 m square, 1 kg), one edge pinned"
    assert [line.split()[0] for line in lines[1:]][:3] == ["cloth_16", "cloth_64", "cloth_256"]  # natural order
    assert cli.main(["scenes", "--paths"]) == 0
    assert f"({shipped_scene('spring')})" in capsys.readouterr().out


def test_run_takes_the_bare_name_of_a_shipped_scene(capsys, tmp_path, monkeypatch):
    """`springsim run cloth_16` (no such file in the working directory) runs the shipped scene."""
    monkeypatch.chdir(tmp_path)
    assert cli.main(["run", "cloth_16", "--steps", "2"]) == 0
    out = capsys.readouterr().out
    assert f"{shipped_scene('cloth_16')} (cloth_16)" in out and "2 x dt" in out


def test_a_file_of_that_name_wins_and_paths_are_never_looked_up(tmp_path, monkeypatch, capsys):
    """An existing file named like a shipped scene is run; a path with a directory, or an unknown name, is an error."""
    monkeypatch.chdir(tmp_path)
    (tmp_path / "cloth_16").write_text("solver: {type: implicit_euler, timestep: 0.01}\n"
                                       "particles: [{pos: [0, 0, 0], mass: 1}]\n")
    assert resolve_scene("cloth_16") == Path("cloth_16")
    assert resolve_scene("cloth_16.yaml") == shipped_scene("cloth_16")
    with pytest.raises(SceneError, match="no such file, nor the name of a shipped scene"):
        resolve_scene("no_such_scene")
    assert cli.main(["run", "elsewhere/cloth_64.yaml"]) == 2
    assert "elsewhere/cloth_64.yaml: no such file" in capsys.readouterr().err
    with pytest.raises(SceneError, match="shipped: cloth_16, cloth_64"):
        shipped_scene("nothing")
