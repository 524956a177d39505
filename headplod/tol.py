"""Numerical tolerances, named once (after trimesh's ``tol``).

Domain tolerances with a unit and a reason of their own (a rotation's
orthonormality in rig.yaml, a level's slack, a marker model's axes) are named
in their modules beside what they check; these are the generic ones, where
the only reason is float64 arithmetic or the precision of a text file:

    from headplod.tol import tol
    contrast = (hi - lo) / np.maximum(hi + lo, tol.zero)
"""
from __future__ import annotations

from dataclasses import dataclass

__all__ = ["NumericalTolerances", "tol"]


@dataclass(frozen=True)
class NumericalTolerances:
    """Generic tolerances of float64 arithmetic (dimensionless unless stated)."""

    zero: float = 1e-12
    """A sum, norm or eigenvalue (relative to the largest) at or below which it is taken as zero: the floor of a
    denominator that must stay positive, the rank cut of a covariance. Some 1e4 above float64's epsilon."""
    small: float = 1e-9
    """A quantity in its own unit (mm, deg, px, s) too small to be one, and the relative agreement of two float64
    values computed two ways (a matrix's symmetry, a fixed entry of K): far above rounding, far below any
    measurement."""
    floor: float = 1e-6
    """The floor of a measured quantity that divides another (a blob's peak in DN, an RMS in px, a span in
    deg or ms): far below any measurement's resolution, so it only keeps a division finite."""
    text: float = 1e-6
    """The agreement of values written to a text file with 6 decimals and read back, or of a value the user
    typed with one the hardware reports."""


tol = NumericalTolerances()
