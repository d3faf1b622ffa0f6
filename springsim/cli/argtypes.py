"""argparse ``type=`` converters shared by the CLI modules (one-line messages, no tracebacks)."""

from __future__ import annotations

import argparse
import math

__all__ = ["int_at_least", "positive_float"]


def int_at_least(lo: int, hi: int | None = None):
    """A converter accepting integers ``>= lo`` (and ``<= hi`` when given), e.g. ``type=int_at_least(1)``.

    Parameters
    ----------
    lo : int
        Smallest value accepted.
    hi : int, optional
        Largest value accepted.

    Returns
    -------
    callable
        ``convert(text) -> int``, raising ``argparse.ArgumentTypeError`` with a one-line message (also for texts
        longer than 40 characters, which never reach Python's integer conversion).
    """

    def convert(text: str) -> int:
        if len(text) > 40:  # also keeps Python's integer conversion away from huge digit strings
            raise argparse.ArgumentTypeError(f"must be an integer >= {lo}{'' if hi is None else f' and <= {hi}'}, "
                                             f"got a {len(text)}-character value")
        try:
            v = int(text)
        except ValueError:
            raise argparse.ArgumentTypeError(f"must be an integer, got {text!r}") from None
        if v < lo:
            raise argparse.ArgumentTypeError(f"must be >= {lo}, got {v}")
        if hi is not None and v > hi:
            raise argparse.ArgumentTypeError(f"must be <= {hi}, got {v}")
        return v

    convert.__name__ = f"integer >= {lo}"
    return convert


def positive_float(text: str) -> float:
    """A converter accepting finite numbers ``> 0`` (``type=positive_float``).

    Parameters
    ----------
    text : str
        The command-line value.

    Returns
    -------
    float
        The number.

    Raises
    ------
    argparse.ArgumentTypeError
        For a value that is not a finite number > 0.
    """
    try:
        v = float(text)
    except ValueError:
        raise argparse.ArgumentTypeError(f"must be a number, got {text[:40]!r}") from None
    if not (math.isfinite(v) and v > 0):
        raise argparse.ArgumentTypeError(f"must be finite and > 0, got {text}")
    return v
