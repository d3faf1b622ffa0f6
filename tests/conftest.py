"""Shared pytest fixtures; puts ``tests/`` on ``sys.path`` so tests can ``import helpers``.

The tests import the installed springsim (pytest's configuration does not put the repository on
``sys.path``). The repository's ``benchmarks`` package, which is not installed, is registered here by
its path, so that its smoke tests can import it without the checkout's ``springsim/`` shadowing the
installed one.
"""

from __future__ import annotations

import importlib.util
import os
import sys

import numpy as np
import pytest

sys.path.insert(0, os.path.dirname(__file__))


def _register_benchmarks() -> None:
    """``import benchmarks`` (and its submodules) from the repository, without the repository on ``sys.path``."""
    if "benchmarks" in sys.modules:
        return
    root = os.path.join(os.path.dirname(os.path.dirname(os.path.abspath(__file__))), "benchmarks")
    spec = importlib.util.spec_from_file_location("benchmarks", os.path.join(root, "__init__.py"),
                                                  submodule_search_locations=[root])
    module = importlib.util.module_from_spec(spec)
    sys.modules["benchmarks"] = module
    spec.loader.exec_module(module)


_register_benchmarks()

from helpers import random_scene  # noqa: E402


@pytest.fixture
def rng():
    """A seeded generator (seed 2024) for tests that need one."""
    return np.random.default_rng(2024)


@pytest.fixture
def scene(rng):
    """A small random scene with every force term and fixed particles."""
    return random_scene(rng)
