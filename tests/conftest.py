"""Shared pytest fixtures; puts ``tests/`` on ``sys.path`` so tests can ``import helpers``."""

from __future__ import annotations

import os
import sys

import numpy as np
import pytest

sys.path.insert(0, os.path.dirname(__file__))

from helpers import random_scene  # noqa: E402


@pytest.fixture
def rng():
    """A seeded generator (seed 2024) for tests that need one."""
    return np.random.default_rng(2024)


@pytest.fixture
def scene(rng):
    """A small random scene with every force term and fixed particles."""
    return random_scene(rng)
