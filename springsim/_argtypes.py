"""argparse ``type=`` converters shared by the CLI modules (one-line messages, no tracebacks)."""

from __future__ import annotations

import argparse

__all__ = ["int_at_least"]


def int_at_least(lo: int):
    """A converter accepting integers ``>= lo``, e.g. ``type=int_at_least(1)``."""

    def convert(text: str) -> int:
        try:
            v = int(text)
        except ValueError:
            raise argparse.ArgumentTypeError(f"must be an integer, got {text!r}") from None
        if v < lo:
            raise argparse.ArgumentTypeError(f"must be >= {lo}, got {v}")
        return v

    convert.__name__ = f"integer >= {lo}"
    return convert
