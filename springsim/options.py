"""Limits shared by every entry point (Python API, YAML, command line)."""

from __future__ import annotations

__all__ = ["MAX_STEPS", "describe_int"]

#: Largest number of steps a run may ask for (a guard against overflowing step counts).
MAX_STEPS = 10**12


def describe_int(value: int) -> str:
    """``str(value)``, or its digit count when it is too long to show (Python refuses to print > 4300 digits)."""
    if abs(value) < 10**30:
        return str(value)
    return f"an integer of about {int(abs(value).bit_length() * 0.30103) + 1} digits"
