"""Modules that moved into subpackages: their former import paths, and files written before the move.

``springsim._compat.MOVED`` maps every former public module name (``springsim.driver``, ...) to the module now
(``springsim.run.driver``). Importing a former name gives the module itself with a DeprecationWarning that names
the importing line. Files written by the former layout (``tests/data/flat_layout.*``, see its README) load: the
trajectory ``.npz`` holds no class paths, the pickle names ``springsim.model._rebuild`` and
``springsim.driver.Trajectory``.
"""

from __future__ import annotations

import importlib
import importlib.util
import os
import pickle
import subprocess
import sys
import warnings
from pathlib import Path

import numpy as np
import pytest

import springsim
from springsim import ModelBuilder, Trajectory
from springsim._compat import MOVED

DATA = Path(__file__).resolve().parents[1] / "data"
PACKAGE = Path(springsim.__file__).resolve().parent


def _forget(monkeypatch, old: str) -> None:
    """Make ``old`` un-imported for this test (restored afterwards): the next import goes through the finder."""
    monkeypatch.delitem(sys.modules, old, raising=False)
    monkeypatch.delitem(vars(springsim), old.rpartition(".")[2], raising=False)  # not hasattr: that imports it


def test_the_table_names_public_modules_that_exist_and_no_file_at_the_former_paths():
    """Every target is a module of the package; no module stands at a former path; private modules need no alias."""
    assert len(MOVED) == 9
    for old, new in MOVED.items():
        name = old.removeprefix("springsim.")
        assert "." not in name and not name.startswith("_"), old
        assert new.startswith("springsim.") and importlib.util.find_spec(new) is not None, new
        assert not (PACKAGE / f"{name}.py").exists() and not (PACKAGE / name).exists(), old


@pytest.mark.parametrize("old", sorted(MOVED))
def test_a_former_path_imports_the_module_itself_with_a_deprecation_warning(monkeypatch, old):
    """``import springsim.<old>`` warns once, naming the new path and the importing line, and is the same module."""
    new = MOVED[old]
    _forget(monkeypatch, old)
    with pytest.warns(DeprecationWarning, match=f"{old} is deprecated: the module moved to {new}") as record:
        module = importlib.import_module(old)
    assert module is importlib.import_module(new) is sys.modules[old] is sys.modules[new]
    assert module.__name__ == new and module.__spec__.name == new  # the module keeps its own spec
    ours = [w for w in record if "is deprecated: the module moved" in str(w.message)]
    assert [Path(w.filename).resolve() for w in ours] == [Path(__file__).resolve()]
    with warnings.catch_warnings():
        warnings.simplefilter("error")
        assert importlib.import_module(old) is module  # once: the former name is now in sys.modules


def test_from_imports_through_a_former_path(monkeypatch):
    """``from springsim.builder import ModelBuilder`` and ``from springsim import driver`` keep working."""
    for old in ("springsim.builder", "springsim.driver", "springsim.reference"):
        _forget(monkeypatch, old)
    with pytest.warns(DeprecationWarning, match="springsim.builder is deprecated"):
        from springsim.builder import ModelBuilder as FormerBuilder
    assert FormerBuilder is ModelBuilder
    with pytest.warns(DeprecationWarning, match="springsim.driver is deprecated"):
        from springsim import driver
    assert driver is importlib.import_module("springsim.run.driver") and driver.Trajectory is Trajectory
    with pytest.warns(DeprecationWarning, match="springsim.reference is deprecated"):
        reference = springsim.reference  # as an attribute of the package, not imported before
    assert reference is importlib.import_module("springsim.analysis.reference")
    with pytest.raises(AttributeError):
        springsim.no_such_module  # noqa: B018


def test_the_packages_keep_their_names():
    """``springsim.model`` and ``springsim.analysis`` became packages that export what the modules did."""
    from springsim.analysis import explicit_substeps, max_frequency, stiffness_matrix  # noqa: F401
    from springsim.model import AXES, FINGERPRINT_V1, ClothGrid, Model, State  # noqa: F401

    assert Model is springsim.Model and State is springsim.State


def test_a_script_sees_the_warning_by_default(tmp_path):
    """Python shows a DeprecationWarning attributed to ``__main__`` by default: the warning names the script."""
    script = tmp_path / "old_script.py"
    script.write_text("import springsim.options\nfrom springsim.viz import plot_dof\n")
    env = {k: v for k, v in os.environ.items() if k not in ("PYTHONWARNINGS", "PYTHONPATH")}
    env["PYTHONPATH"] = str(PACKAGE.parent)
    out = subprocess.run([sys.executable, str(script)], env=env, cwd=tmp_path, capture_output=True, text=True,
                         timeout=120)
    assert out.returncode == 0, out.stderr
    lines = [line for line in out.stderr.splitlines() if "DeprecationWarning" in line]
    assert len(lines) == 2, out.stderr
    assert lines[0].startswith(f"{script}:1: DeprecationWarning: springsim.options is deprecated"), out.stderr
    assert lines[1].startswith(f"{script}:2: DeprecationWarning: springsim.viz is deprecated"), out.stderr


#: The default softening the files of the former layout hold: ``np.cbrt``'s (numpy 2.4), one unit in the last place
#: from today's machine-independent cube root (springsim.forces.gravitational.portable_cbrt); given explicitly, the
#: scene built today is the files' model to the last bit.
_FLAT_LAYOUT_SOFTENING = float.fromhex("0x1.26b8f710478bep-12")


def _flat_layout_scene():
    """The scene of ``tests/data/flat_layout.*``, built today."""
    b = ModelBuilder(gravity=-9.81, up_axis="z")
    top = b.add_particle((0, 0, 1), mass=0.1, fixed=True)
    bob = b.add_particle((0, 0, 0), mass=0.1, drag=0.01)
    b.add_spring(top, bob, stiffness=100.0, damping=0.5)
    b.add_gravitational(top, bob, G=1e-3, softening=_FLAT_LAYOUT_SOFTENING)
    b.add_cloth_grid(3, 3, origin=(2, 0, 1), size=(1, 1), total_mass=1.0, pin=["top-left"])
    return b.finalize()


def test_a_trajectory_saved_by_the_flat_layout_loads():
    """The ``.npz`` of the former layout loads; it records the fingerprint of the same scene built today."""
    model = _flat_layout_scene()
    traj = Trajectory.load(DATA / "flat_layout.npz")
    assert traj.q.shape == (4, model.particle_count, 3) and traj.qd.shape == traj.q.shape
    np.testing.assert_array_equal(traj.t, [0.0, 0.01, 0.02, 0.03])
    assert traj.meta["model_fingerprint"] == model.fingerprint()
    np.testing.assert_array_equal(traj.q[0], model.particle_q)


@pytest.mark.skipif(int(np.__version__.split(".")[0]) < 2, reason="the pickle was written with numpy 2")
def test_objects_pickled_by_the_flat_layout_load(monkeypatch):
    """A model pickled as ``springsim.model._rebuild(springsim.model.Model, ...)`` and a trajectory pickled as
    ``springsim.driver.Trajectory`` unpickle to the same model (fingerprint, immutable arrays, cloth grids) and
    trajectory (the one the ``.npz`` holds); the trajectory's class comes through its former path."""
    _forget(monkeypatch, "springsim.driver")
    with pytest.warns(DeprecationWarning, match="springsim.driver is deprecated"):
        saved = pickle.loads((DATA / "flat_layout.pkl").read_bytes())
    model, traj = saved["model"], saved["trajectory"]
    today = _flat_layout_scene()
    assert type(model) is type(today) and model.fingerprint() == today.fingerprint()
    assert model.cloth_grids == today.cloth_grids and type(model.cloth_grids[0]) is type(today.cloth_grids[0])
    assert not model.particle_q.flags.writeable and not model.spring_stiffness.flags.writeable
    assert type(traj) is Trajectory
    from_file = Trajectory.load(DATA / "flat_layout.npz")
    for name in ("t", "q", "qd"):
        np.testing.assert_array_equal(getattr(traj, name), getattr(from_file, name))
    assert traj.meta["model_fingerprint"] == today.fingerprint()
