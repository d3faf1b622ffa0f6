"""Every script in examples/ runs at its tiny size and writes the pictures its docstring names."""

import importlib.util
import re
import warnings
from pathlib import Path

import pytest

EXAMPLES = Path(__file__).resolve().parents[1] / "examples"
SCRIPTS = sorted(EXAMPLES.glob("*.py"))


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
