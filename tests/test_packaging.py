"""The package stands on its own: the tests import the installed springsim, the wheel ships the scenes and the
licence and runs outside the checkout, and numba's cache stays out of the source tree."""

from __future__ import annotations

import importlib.metadata
import json
import os
import re
import shutil
import site
import subprocess
import sys
import zipfile
from pathlib import Path

import pytest

import springsim

ROOT = Path(__file__).resolve().parents[1]
SCENES = sorted(p.name for p in (ROOT / "scenes").glob("*.yaml"))


def _clean_env(**extra) -> dict:
    """The environment without anything that would make a child import the checkout's springsim."""
    env = {k: v for k, v in os.environ.items() if k not in ("PYTHONPATH", "PYTHONHOME", "PYTHONSTARTUP")}
    env.update(OMP_NUM_THREADS="1", OPENBLAS_NUM_THREADS="1", **extra)
    return env


def _this_springsim_env(**extra) -> dict:
    """The environment for a child that imports the springsim these tests import (installed or a source tree)."""
    return _clean_env(PYTHONPATH=str(Path(springsim.__file__).resolve().parents[1]), **extra)


def test_springsim_is_imported_from_where_it_is_installed():
    """With a non-editable install the tests import the installed package, not the checkout's ``springsim/``."""
    import site

    pkg = Path(springsim.__file__).resolve().parent
    # the installation's metadata, from the environment's site directories only (a build's springsim.egg-info in the
    # checkout, on sys.path under ``python -m pytest``, is not an installation)
    sites = [*site.getsitepackages(), site.getusersitepackages()]
    dist = next(iter(importlib.metadata.distributions(name="springsim", path=sites)), None)
    if dist is None:  # not installed: a source tree on PYTHONPATH
        assert (pkg.parent / "pyproject.toml").is_file(), pkg
        return
    direct_url = dist.read_text("direct_url.json")
    editable = bool(direct_url and json.loads(direct_url).get("dir_info", {}).get("editable"))
    if editable:  # imports a source tree (this checkout, or another one put first on PYTHONPATH)
        assert (pkg.parent / "pyproject.toml").is_file(), pkg
    else:
        installed = Path(dist.locate_file("springsim/__init__.py")).resolve().parent
        assert pkg == installed, f"springsim imported from {pkg}, installed in {installed}"
        assert pkg != (ROOT / "springsim").resolve(), "the tests import the checkout, not the installed package"


def test_numba_cache_goes_to_a_user_directory(tmp_path):
    """Importing springsim points numba's cache at a per-user directory (not __pycache__ in the source tree)."""
    code = ("import numpy as np, springsim\n"
            "from numba.core import config\n"
            "from springsim.forces._numba_kernels import spring_forces\n"
            "q = np.array([[0.0, 0, 0], [1.5, 0, 0]]); out = np.zeros((2, 3))\n"
            "spring_forces(q, np.zeros((2, 3)), np.array([[0, 1]]), np.ones(1), np.zeros(1), np.ones(1), 1e-9, out)\n"
            "print(config.CACHE_DIR)\n")
    env = _this_springsim_env(XDG_CACHE_HOME=str(tmp_path / "cache"))
    env.pop("NUMBA_CACHE_DIR", None)
    out = subprocess.run([sys.executable, "-c", code], env=env, cwd=tmp_path, capture_output=True, text=True,
                         timeout=300)
    assert out.returncode == 0, out.stderr
    expected = tmp_path / "cache" / "springsim" / "numba"
    assert out.stdout.strip() == str(expected)
    assert list(expected.rglob("*spring_forces*.nbi")), "no cache index written to the user directory"


def test_numba_cache_dir_set_by_the_user_is_kept(tmp_path):
    """A NUMBA_CACHE_DIR the user set is left as it is."""
    env = _this_springsim_env(NUMBA_CACHE_DIR=str(tmp_path / "mine"))
    out = subprocess.run([sys.executable, "-c", "import os, springsim; print(os.environ['NUMBA_CACHE_DIR'])"],
                         env=env, cwd=tmp_path, capture_output=True, text=True, timeout=120)
    assert out.returncode == 0 and out.stdout.strip() == str(tmp_path / "mine"), out.stderr


def _build_wheel(tmp_path: Path) -> Path:
    """Build springsim's wheel from a copy of the files the build reads (the checkout is left untouched)."""
    src = tmp_path / "src"
    ignore = shutil.ignore_patterns("__pycache__", "*.pyc", "*.nbi", "*.nbc")
    for d in ("springsim", "scenes"):
        shutil.copytree(ROOT / d, src / d, ignore=ignore)
    for f in ("pyproject.toml", "setup.py", "README.md", "LICENSE"):
        shutil.copy2(ROOT / f, src / f)
    cmd = [sys.executable, "-m", "pip", "wheel", "--no-deps", "--quiet", "-w", str(tmp_path / "dist"), str(src)]
    try:  # offline with the test extra's setuptools; else pip fetches the build backend as for any install
        modern = int(importlib.metadata.version("setuptools").split(".")[0]) >= 77
    except importlib.metadata.PackageNotFoundError:
        modern = False
    if modern:
        cmd[4:4] = ["--no-build-isolation", "--no-index"]
    out = subprocess.run(cmd, env=_clean_env(), cwd=tmp_path, capture_output=True, text=True, timeout=300)
    assert out.returncode == 0, out.stderr
    (wheel,) = (tmp_path / "dist").glob("springsim-*.whl")
    return wheel


@pytest.mark.slow
def test_wheel_ships_scenes_and_licence_and_runs_outside_the_checkout(tmp_path):
    """The wheel holds every shipped scene and LICENSE; installed in a fresh venv, `springsim run cloth_16` works."""
    wheel = _build_wheel(tmp_path)
    names = zipfile.ZipFile(wheel).namelist()
    for scene in SCENES:
        assert f"springsim/scene/data/{scene}" in names, scene
    assert any(n.endswith(".dist-info/licenses/LICENSE") for n in names)
    metadata = zipfile.ZipFile(wheel).read(next(n for n in names if n.endswith(".dist-info/METADATA"))).decode()
    assert "License-Expression: MIT" in metadata and "Author: the springsim developers" in metadata

    # A fresh venv with the wheel installed; its dependencies come from this test environment's site-packages,
    # which come after the venv's own on sys.path (so the wheel's springsim is the one imported).
    venv = tmp_path / "venv"
    subprocess.run([sys.executable, "-m", "venv", "--without-pip", str(venv)], check=True, timeout=120)
    bindir = venv / ("Scripts" if os.name == "nt" else "bin")
    python = bindir / ("python.exe" if os.name == "nt" else "python")
    purelib = subprocess.run([str(python), "-c", "import sysconfig; print(sysconfig.get_paths()['purelib'])"],
                             capture_output=True, text=True, check=True, timeout=60).stdout.strip()
    env = _clean_env()
    out = subprocess.run([sys.executable, "-m", "pip", "--python", str(python), "install", "--no-deps", "--no-index",
                          "--quiet", str(wheel)], env=env, cwd=tmp_path, capture_output=True, text=True, timeout=300)
    assert out.returncode == 0, out.stderr
    ours = [p for p in site.getsitepackages() + [site.getusersitepackages()] if os.path.isdir(p)]
    Path(purelib, "springsim-test-deps.pth").write_text("\n".join(ours) + "\n")  # after the install: pip
    # would otherwise see this environment's springsim as installed already

    where = subprocess.run([str(python), "-c", "import springsim; print(springsim.__file__)"], env=env,
                           cwd=tmp_path, capture_output=True, text=True, timeout=120)
    assert Path(where.stdout.strip()).resolve().is_relative_to(Path(purelib).resolve()), where
    springsim_exe = bindir / ("springsim.exe" if os.name == "nt" else "springsim")
    listing = subprocess.run([str(springsim_exe), "scenes"], env=env, cwd=tmp_path, capture_output=True, text=True,
                             timeout=300)
    assert listing.returncode == 0, listing.stderr
    natural = lambda name: [int(t) if t.isdigit() else t for t in re.split(r"(\d+)", name)]  # noqa: E731
    assert [line.split()[0] for line in listing.stdout.splitlines()[1:]] == \
        sorted((Path(s).stem for s in SCENES), key=natural)
    run = subprocess.run([str(springsim_exe), "run", "cloth_16", "--steps", "2"], env=env, cwd=tmp_path,
                         capture_output=True, text=True, timeout=300)
    assert run.returncode == 0, run.stderr
    assert "springsim/scene/data/cloth_16.yaml (cloth_16)" in run.stdout.replace(os.sep, "/")
    assert "steps:" in run.stdout and "2 x dt" in run.stdout
