"""Every script in examples/ runs at its tiny size and writes the pictures its docstring names."""

import importlib.util
import re
import warnings
from pathlib import Path

import numpy as np
import pytest

EXAMPLES = Path(__file__).resolve().parents[1] / "examples"
SCRIPTS = sorted(EXAMPLES.glob("*.py"))
#: Out-of-plane RMS [m] above which the hanging cloth counts as folded (a flat-hanging sheet: about 0.01 m;
#: the pleated cloth of the example: about 0.08 m).
FOLDED_RMS = 0.04


def _load(path):
    spec = importlib.util.spec_from_file_location(f"example_{path.stem}", path)
    module = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(module)
    return module


def test_examples_exist_and_are_linked_from_the_readme():
    readme = (EXAMPLES.parent / "README.md").read_text()
    assert len(SCRIPTS) >= 5
    for path in SCRIPTS:
        assert f"examples/{path.name}" in readme


@pytest.mark.parametrize("path", SCRIPTS, ids=[p.stem for p in SCRIPTS])
def test_example_runs_tiny(path, tmp_path, capsys):
    module = _load(path)
    doc = module.__doc__
    assert "--tiny" in doc and "python examples/" + path.name in doc
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")  # an example may show a method's known failure (three_body)
        module.main(["--tiny", "--out-dir", str(tmp_path)])
    out = capsys.readouterr().out
    for name in re.findall(r"``(\w+\.(?:png|gif))``", doc):
        f = tmp_path / name
        assert f.exists() and "wrote" in out, name
        magic = f.read_bytes()[:4]
        assert magic == (b"GIF8" if name.endswith(".gif") else b"\x89PNG")


def _stated_seconds(text: str) -> int:
    """The ``~N s`` time figure in ``text`` (one per script line or table row)."""
    (seconds,) = re.findall(r"~(\d+) s\b", text)
    return int(seconds)


@pytest.mark.parametrize("path", SCRIPTS, ids=[p.stem for p in SCRIPTS])
def test_stated_times_agree(path):
    """Each example states one measured time (``~N s on 1 core``) in its docstring, and the README's table the same."""
    doc_line = next(line for line in _load(path).__doc__.splitlines()
                    if f"python examples/{path.name}" in line and "--tiny" not in line)
    assert "on 1 core" in doc_line
    readme_row = next(line for line in (EXAMPLES.parent / "README.md").read_text().splitlines()
                      if line.startswith(f"| [`examples/{path.name}`]"))
    assert _stated_seconds(doc_line) == _stated_seconds(readme_row.rsplit("|", 2)[1])


def _out_of_plane_rms(q):
    """RMS distance [m] of the points ``q`` (N, 3) from their best-fitting plane: 0 for a flat sheet."""
    return float(np.linalg.svd(q - q.mean(axis=0), compute_uv=False)[-1] / np.sqrt(len(q)))


@pytest.mark.slow
def test_hanging_cloth_hangs_in_folds_and_its_gif_is_small(tmp_path):
    """At full size the hanging cloth's last frame is far from a flat sheet, and its GIF stays under 500 kB."""
    model, traj = _load(EXAMPLES / "hanging_cloth.py").main(["--out-dir", str(tmp_path)])
    assert traj.summary()["failed_steps"] == 0
    assert _out_of_plane_rms(traj.q[-1]) > FOLDED_RMS
    assert (tmp_path / "hanging_cloth.gif").stat().st_size < 500_000


@pytest.mark.slow
def test_three_body_converges_on_every_step(tmp_path, capsys):
    """The full three-body run meets its criteria on every step: no ConvergenceWarning in its results table."""
    from springsim import SpringsimWarning

    with warnings.catch_warnings():
        warnings.simplefilter("error", SpringsimWarning)
        _load(EXAMPLES / "three_body.py").main(["--out-dir", str(tmp_path)])
    out, err = capsys.readouterr()
    assert "Warning" not in out + err and out.splitlines()[0].startswith("integrator")
