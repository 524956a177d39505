"""The speed baseline of the tracking benchmarks: one ``cv2.threshold`` pass over both images.

Shared by :mod:`headplod.bench.track` and :mod:`headplod.bench.rig`, which
report the tracker's time per pair as a multiple of it.
"""
from __future__ import annotations

import time

import cv2
import numpy as np

__all__ = ["threshold_baseline_s"]


def threshold_baseline_s(left: np.ndarray, right: np.ndarray, repeats: int = 15) -> float:
    """Median time of one cv2.threshold pass over both images, s."""
    out_l, out_r = np.empty_like(left), np.empty_like(right)
    times = []
    for _ in range(repeats):
        t0 = time.perf_counter()
        cv2.threshold(left, 100, 255, cv2.THRESH_BINARY, dst=out_l)
        cv2.threshold(right, 100, 255, cv2.THRESH_BINARY, dst=out_r)
        times.append(time.perf_counter() - t0)
    return float(np.median(times))
