"""The README's Python examples run as written, converge, and warn about nothing."""

import re
import warnings
from pathlib import Path

import pytest

README = Path(__file__).resolve().parents[1] / "README.md"


def _python_blocks():
    return re.findall(r"```python\n(.*?)```", README.read_text(encoding="utf-8"), flags=re.S)


def test_readme_has_python_examples():
    """The README shows Python usage."""
    assert len(_python_blocks()) >= 2


@pytest.mark.slow
def test_readme_python_examples_run_cleanly(capsys):
    """Every Python block of the README runs in order, in one namespace, without any warning; the first example's
    printed line matches its comment (every step met its criteria)."""
    namespace: dict = {}
    with warnings.catch_warnings():
        warnings.simplefilter("error")
        for block in _python_blocks():
            exec(compile(block, str(README), "exec"), namespace)  # noqa: S102 - our own documentation
    out = capsys.readouterr().out
    assert "(31, 576, 3) 0" in out
