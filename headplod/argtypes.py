"""Value types of the command line's options, shared by the commands (argparse ``type=``)."""
from __future__ import annotations

import argparse
import math

__all__ = ["floats", "frame_count", "non_negative"]


def floats(n: int):
    """An argparse type: ``n`` comma-separated finite numbers, as a tuple of floats."""
    def parse(text: str):
        try:
            values = [float(v) for v in text.split(",")]
        except ValueError:
            raise argparse.ArgumentTypeError(f"expected {n} comma-separated numbers, got {text!r}")
        if len(values) != n or not all(math.isfinite(v) for v in values):
            raise argparse.ArgumentTypeError(f"expected {n} comma-separated finite numbers, got {text!r}")
        return tuple(values)
    return parse


def frame_count(text: str) -> int:
    """An argparse type: a number of frames, a whole number of at least 1 (0 or -1 would run nothing)."""
    try:
        value = int(text)
    except ValueError:
        raise argparse.ArgumentTypeError(f"expected a whole number of frames, got {text!r}") from None
    if value < 1:
        raise argparse.ArgumentTypeError(f"must be at least 1 frame, got {value}")
    return value


def non_negative(text: str) -> float:
    """An argparse type: a finite number of at least 0."""
    try:
        value = float(text)
    except ValueError:
        raise argparse.ArgumentTypeError(f"expected a number, got {text!r}") from None
    if not (value >= 0 and math.isfinite(value)):
        raise argparse.ArgumentTypeError(f"expected a finite number >= 0, got {text!r}")
    return value
