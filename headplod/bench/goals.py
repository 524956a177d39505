"""How many frames per set a benchmark goal needs before a run can judge it, and the goal's verdict.

A quick run (``bench track --quick``) has short sets: a goal whose statistic those sets cannot resolve (the 99th
percentile of 20 frames is their slowest frame; 99 % of 60 frames cannot be told from 98.3 %) is reported as
not judged, never as met or missed.
"""
from __future__ import annotations

import math

__all__ = ["NOT_JUDGED", "frames_for_quantile", "frames_for_fraction", "frames_for_mean", "short_sets",
           "not_judged", "verdict"]

NOT_JUDGED = "not judged in a quick run"


def frames_for_quantile(q: float) -> int:
    """Frames a set needs for its ``q`` quantile (0..1) to have at least one frame beyond it: 1 / (1 - q)."""
    return max(1, math.ceil(round(1.0 / (1.0 - q), 9)))


def frames_for_fraction(fraction: float) -> int:
    """Frames a set needs to tell a share of ``fraction`` (0..1) from the next lower one: one frame is 1 - fraction."""
    return frames_for_quantile(fraction)


def frames_for_mean(sd_per_frame: float, within: float) -> int:
    """Frames a mean needs to be known within ``within`` (one standard error) from values of ``sd_per_frame``."""
    return math.ceil(round((sd_per_frame / within) ** 2, 9))


def short_sets(frames_by_set: dict, needs: int) -> dict:
    """The sets of ``frames_by_set`` ({name: frames}) with fewer than ``needs`` frames: {name: frames}."""
    return {name: n for name, n in frames_by_set.items() if n < needs}


def not_judged(goal: dict, needs: int, short: dict) -> dict:
    """``goal`` (a benchmark's goal dict) marked as not judged in a quick run: ``met`` None, ``judged`` False,
    ``needs_frames`` and ``why`` (one phrase naming how short its sets are)."""
    fewest = min(short.values())
    why = (f"needs ≥ {needs} frames per set; {len(short)} of its sets have fewer (the fewest {fewest}); "
           "run without --quick to judge it")
    return {**goal, "met": None, "judged": False, "needs_frames": needs, "why": why}


def verdict(goal: dict) -> str:
    """The bracketed word of a goal's line: ``met``, ``NOT MET`` or :data:`NOT_JUDGED`."""
    if goal.get("judged", True) is False:
        return NOT_JUDGED
    return "met" if goal["met"] else "NOT MET"
