"""The command line's allocator policy (springsim._runtime.alloc): applied in a fresh process, switchable off."""

from __future__ import annotations

import os
import platform
import subprocess
import sys

import pytest

GLIBC = sys.platform.startswith("linux") and platform.libc_ver()[0] == "glibc"
CODE = "from springsim._runtime.alloc import retain_freed_memory as r; import numpy as np; print(r(), r()); " \
       "a = np.ones(50_000_000); del a; b = np.ones(50_000_000); print(float(b.sum()))"


def _run(env_value):
    env = dict(os.environ)
    env.pop("SPRINGSIM_RETAIN_MEMORY", None)
    if env_value is not None:
        env["SPRINGSIM_RETAIN_MEMORY"] = env_value
    out = subprocess.run([sys.executable, "-c", CODE], env=env, capture_output=True, text=True, timeout=120, check=True)
    return out.stdout.split("\n")


@pytest.mark.parametrize("env_value", [None, "0"])
def test_policy_applies_on_glibc_and_turns_off(env_value):
    """In force on glibc Linux (idempotent), never elsewhere or with SPRINGSIM_RETAIN_MEMORY=0; large
    blocks allocated after it work as before."""
    first, total = _run(env_value)[:2]
    expected = GLIBC and env_value is None
    assert first == f"{expected} {expected}"
    assert float(total) == 50_000_000.0
