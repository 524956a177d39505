"""Landscapes unlike the built-in one, made from a seed, for judging the criteria where they were not fitted.

Each is an (n, n) grid of heights, metres, row 0 north, meant for a sample spacing of :data:`SPACING_M`
(``Terrain(heights, SPACING_M, SPACING_M, detail=False)``; ``tools/make_dem.py --ridges SEED`` writes the
``ridges`` one as .npy for ``--terrain``). All are spectral fields: a normal random spectrum shaped by a power
law f^-β (the slope of real relief: β about 2 in amplitude for eroded ground, less for rough), then bent:

- ``ridges``: sharp crests, the folded mid-level of a smooth field (the ridged-multifractal idea), over rolling
  ground, with fine relief (∝ f^-1.3) up to 40 m: relief finer than the mesh's levels can follow;
- ``hills``: rolling hills (β 2.2) over rough ground (β 1.4, up to 30 m): no crests, detail everywhere;
- ``mesas``: flat tables and terraces bounded by steep scarps (a smooth field pushed through a soft staircase):
  long silhouettes and flat tops, where geometric and shading error part ways.

Pure numpy; deterministic for a seed.
"""
from __future__ import annotations

import numpy as np

__all__ = ["KINDS", "SAMPLES", "SPACING_M", "heights", "terrain", "parse_name"]

#: Samples per side of every landscape (the default mesh's 32 x 2^5 + 1).
SAMPLES = 1025
#: The spacing the landscapes are meant for, m.
SPACING_M = 25.0


def _field(rng, n: int, beta: float) -> np.ndarray:
    """(n, n) a spectral field with amplitude ∝ f^-beta, scaled to 0..1."""
    fy, fx = np.fft.fftfreq(n)[:, None], np.fft.rfftfreq(n)[None, :]
    f = np.hypot(fy, fx)
    f[0, 0] = 1.0
    spectrum = (rng.normal(size=f.shape) + 1j * rng.normal(size=f.shape)) / f ** beta
    spectrum[0, 0] = 0.0
    h = np.fft.irfft2(spectrum, s=(n, n))
    return (h - h.min()) / np.ptp(h)


def _ridges(rng, n):
    base, detail = _field(rng, n, 1.8), _field(rng, n, 1.3)
    ridged = 1.0 - np.abs(2.0 * base - 1.0)
    return 900.0 * (0.7 * ridged ** 3 + 0.25 * base) + 40.0 * detail


def _hills(rng, n):
    base, detail = _field(rng, n, 2.2), _field(rng, n, 1.4)
    return 700.0 * base + 30.0 * detail


def _mesas(rng, n):
    base, detail = _field(rng, n, 2.0), _field(rng, n, 1.5)
    steps = 6.0 * base
    # A soft staircase: flat treads, scarps a few samples wide.
    terraced = np.floor(steps) + 0.5 * (1.0 + np.tanh(12.0 * (steps - np.floor(steps) - 0.5)))
    return 110.0 * terraced + 15.0 * detail


KINDS = {"ridges": _ridges, "hills": _hills, "mesas": _mesas}
"""The landscapes by name (module notes)."""


def heights(kind: str, seed: int, n: int = SAMPLES) -> np.ndarray:
    """(n, n) float32 heights, m, of landscape ``kind`` (one of :data:`KINDS`) for ``seed``; row 0 north."""
    if kind not in KINDS:
        raise ValueError(f"unknown landscape {kind!r}; expected one of {tuple(KINDS)}")
    return KINDS[kind](np.random.default_rng(int(seed)), int(n)).astype(np.float32)


def parse_name(name: str) -> tuple[str, int]:
    """``"ridges:24"`` → (``"ridges"``, 24); ValueError naming the form for anything else."""
    kind, _, seed = str(name).partition(":")
    if kind not in KINDS or not seed.isdigit():
        raise ValueError(f"a landscape is KIND:SEED with KIND one of {tuple(KINDS)} and SEED a whole number, "
                         f"got {name!r}")
    return kind, int(seed)


def terrain(name: str):
    """The :class:`headplod.plod.terrain.Terrain` of landscape ``name`` (``KIND:SEED``), no synthetic detail: the
    same ground as its ``.npy`` (``tools/make_dem.py --ridges``) read with ``--terrain``, whose row 0 is north
    (a :class:`Terrain`'s row 0 is south)."""
    from ..plod.terrain import Terrain

    kind, seed = parse_name(name)
    return Terrain(heights(kind, seed)[::-1], SPACING_M, SPACING_M, detail=False)
