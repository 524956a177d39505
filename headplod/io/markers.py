"""The glasses' marker model: ``markers.yaml``.

:class:`MarkerModel` (P0..P4 in the glasses frame G, mm), the contract's
default model, :func:`read_markers` and :func:`write_markers`, and the
triangles whose normals define the viewing direction V.
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np

from ._storage import (
    _Ctx,
    _check_finite,
    _fmt,
    _frozen,
    _open_storage,
    _read_numeric,
    _shape_str,
    writing_storage,
)
from ..tol import tol

# --------------------------------------------------------------------------
# tolerances and constants
# --------------------------------------------------------------------------

#: Tolerance on the marker model's P1 = origin and P0, P2 on the x axis (mm).
MARKER_TOL_MM = 1e-6
#: A model smaller than this across (mm) is in other units: glasses are ~100 mm wide, so 0.13 is metres.
MIN_MODEL_SPAN_MM = 5.0
_MARKER_KEYS = ("markers", "diameter")


_MARKER_HINT = (
    "markers is a 5x3 matrix of P0..P4 in the glasses frame G (mm) with P1 at "
    "the origin and P0 (x > 0), P2 (x < 0) on G's x axis; see docs/contract.md"
)
#: Triangles whose normals define V (indices into P0..P4).
VIEW_TRIANGLES = ((0, 1, 3), (1, 2, 4), (1, 3, 4))

_DEFAULT_MARKERS_MM = np.array(
    [[65.0, 0.0, 0.0], [0.0, 0.0, 0.0], [-65.0, 0.0, 0.0], [40.0, -30.0, 0.0], [-40.0, -30.0, 0.0]]
)


def _oriented_normals(P: np.ndarray) -> list[np.ndarray]:
    normals = []
    for a, b, c in VIEW_TRIANGLES:
        n = np.cross(P[b] - P[a], P[c] - P[a])
        n = n / np.linalg.norm(n)
        normals.append(-n if n[2] < 0 else n)
    return normals


def _validate_markers(ctx: _Ctx, points: Any, diameter: Any) -> tuple[np.ndarray, float]:
    try:
        P = np.array(points, dtype=np.float64)
    except (TypeError, ValueError) as exc:
        raise ctx.error(f"{ctx.name('markers')} is not numeric ({exc})", _MARKER_HINT) from None
    if P.shape != (5, 3):
        hint = _MARKER_HINT + ("; this looks transposed" if P.shape == (3, 5) else "")
        raise ctx.error(f"{ctx.name('markers')} has shape {_shape_str(P)}, expected 5x3", hint)
    _check_finite(ctx, "markers", P)
    span_mm = float(np.ptp(P, axis=0).max())
    if span_mm < MIN_MODEL_SPAN_MM:
        metres = 0 < span_mm and np.abs(P).max() < 1.0        # (all five at one point: a file left blank)
        raise ctx.error(
            f"the markers span {_fmt(span_mm)} mm, expected the glasses' size in mm "
            f"(the default model spans {_fmt(float(np.ptp(_DEFAULT_MARKERS_MM, axis=0).max()))} mm)",
            ("this looks like metres; markers.yaml is in mm: multiply every coordinate by 1000"
             if metres else "the five markers are at one point: fill in the glasses' coordinates"
             if span_mm == 0 else "markers.yaml is in mm (docs/contract.md)"),
        )
    axis_tol_mm = MARKER_TOL_MM
    if np.abs(P[1]).max() > axis_tol_mm:
        raise ctx.error(
            f"P1 (the bridge) is at {P[1].tolist()} mm, expected the origin [0, 0, 0] "
            f"(tolerance {axis_tol_mm:g} mm)",
            "subtract P1 from every marker so that G's origin is at P1",
        )
    for i in (0, 2):
        if max(abs(P[i, 1]), abs(P[i, 2])) > axis_tol_mm:
            raise ctx.error(
                f"P{i} is at {P[i].tolist()} mm, expected on G's x axis (y = z = 0, "
                f"tolerance {axis_tol_mm:g} mm)",
                "rotate the model so that P0 - P1 lies along +x; P0, P1, P2 are collinear",
            )
    if not P[0, 0] > 0:
        raise ctx.error(f"P0 has x = {_fmt(P[0, 0])} mm, expected x > 0 (G's x points toward P0)",
                        _MARKER_HINT)
    if not P[2, 0] < 0:
        raise ctx.error(f"P2 has x = {_fmt(P[2, 0])} mm, expected x < 0 (P1 lies between P0 and P2)",
                        _MARKER_HINT)
    for i in (3, 4):
        if math.hypot(P[i, 1], P[i, 2]) <= axis_tol_mm:
            raise ctx.error(
                f"P{i} is at {P[i].tolist()} mm, on G's x axis, expected off the line P0-P1-P2",
                "P3 and P4 sit below the bridge line (default y = -30 mm)",
            )
    for tri in VIEW_TRIANGLES:
        a, b, c = (P[i] for i in tri)
        n = np.cross(b - a, c - a)
        scale = np.linalg.norm(b - a) * np.linalg.norm(c - a)
        name = "(" + ", ".join(f"P{i}" for i in tri) + ")"
        if np.linalg.norm(n) <= tol.small * scale:
            raise ctx.error(f"triangle {name} is degenerate (its markers are collinear)",
                            "the viewing direction V needs three non-collinear markers per triangle")
        if abs(n[2]) <= tol.text * np.linalg.norm(n):
            raise ctx.error(
                f"triangle {name} is perpendicular to G's x-y plane (its normal has z = 0), "
                "so its normal cannot be turned to G's +z",
                "move P3/P4 so that each triangle faces forward",
            )
    V = np.mean(_oriented_normals(P), axis=0)
    if np.linalg.norm(V) < tol.text:
        raise ctx.error("the mean of the triangle normals is zero, so V is undefined", _MARKER_HINT)
    try:
        d = float(diameter)
    except (TypeError, ValueError):
        raise ctx.error(f"{ctx.name('diameter')} is {diameter!r}, expected a positive number (mm)") from None
    if not (math.isfinite(d) and d > 0):
        raise ctx.error(f"{ctx.name('diameter')} is {_fmt(d)}, expected a positive marker diameter in mm")
    return P, d


@dataclass(frozen=True, eq=False)
class MarkerModel:
    """The glasses' five markers in the glasses frame G.

    Parameters
    ----------
    points_mm : ndarray, shape (5, 3)
        P0..P4 in G, mm: P1 at the origin, P0 (x > 0) and P2 (x < 0) on G's
        x axis, P3 and P4 off that axis (may lie off z = 0 for a curved frame).
    diameter_mm : float
        Marker disk diameter, mm.

    Notes
    -----
    The constructor validates like :func:`read_markers`. Equality compares
    values.
    """

    points_mm: np.ndarray
    diameter_mm: float = 6.0

    def __post_init__(self) -> None:
        P, d = _validate_markers(_Ctx.obj("MarkerModel"), self.points_mm, self.diameter_mm)
        object.__setattr__(self, "points_mm", _frozen(P))
        object.__setattr__(self, "diameter_mm", d)

    @property
    def view_dir_G(self) -> np.ndarray:
        """The viewing direction V in G (unit, shape (3,)).

        The normalized mean of the unit normals of the triangles
        (P0, P1, P3), (P1, P2, P4) and (P1, P3, P4), each turned to G's +z
        side. ``(0, 0, 1)`` for the default model.
        """
        V = np.mean(_oriented_normals(self.points_mm), axis=0)
        return V / np.linalg.norm(V)

    @property
    def axes_G(self) -> np.ndarray:
        """The head axes in G: rows Ξ, Ψ, V (shape (3, 3)).

        Ξ is P0 − P1 with its component along V removed, normalized;
        Ψ = V × Ξ. For any rotation ``R_wg`` (G to world), the contract's
        ``axes`` are ``axes_G @ R_wg.T``. The identity for the default model.
        """
        V = self.view_dir_G
        x = self.points_mm[0] - self.points_mm[1]
        xi = x - np.dot(x, V) * V
        xi = xi / np.linalg.norm(xi)
        return np.array([xi, np.cross(V, xi), V])

    def __eq__(self, other: object) -> bool:
        if not isinstance(other, MarkerModel):
            return NotImplemented
        return np.array_equal(self.points_mm, other.points_mm) and self.diameter_mm == other.diameter_mm

    __hash__ = None  # type: ignore[assignment]


def default_marker_model() -> MarkerModel:
    """The contract's default model (P0..P4 of ``docs/contract.md``, 6 mm disks)."""
    return MarkerModel(_DEFAULT_MARKERS_MM.copy(), 6.0)


def read_markers(path: str | Path) -> MarkerModel:
    """Read and validate ``markers.yaml``.

    Parameters
    ----------
    path : str or Path
        OpenCV FileStorage YAML with key ``markers`` (5x3, rows P0..P4 in G,
        mm) and optional ``diameter`` (mm, default 6).

    Returns
    -------
    MarkerModel

    Raises
    ------
    ContractError
        On a missing or malformed file, a wrong shape, non-finite values,
        P1 not at the origin or P0/P2 off G's x axis (tolerance
        ``MARKER_TOL_MM``), a model that spans less than
        ``MIN_MODEL_SPAN_MM`` (metres, say), P0.x <= 0 or P2.x >= 0, P3/P4 on the x axis,
        a triangle whose normal cannot be oriented, a non-positive
        diameter, or an unknown key (so that a misspelt ``diameter`` is not
        silently replaced by the default).
    """
    fs, ctx = _open_storage(path, "the marker model (markers.yaml)")
    try:
        unknown = [k for k in fs.root().keys() if k not in _MARKER_KEYS]
        if unknown:
            raise ctx.error(
                f"unknown key(s) {unknown}, expected only 'markers' and optional 'diameter'",
                "fix the spelling or remove the key",
            )
        P = _read_numeric(fs, ctx, "markers", _MARKER_HINT)
        node = fs.getNode("diameter")
        if node.empty() or node.isNone():
            d: Any = 6.0
        else:
            darr = _read_numeric(fs, ctx, "diameter", "diameter is the marker disk diameter in mm")
            if darr.size != 1:
                raise ctx.error(f"key 'diameter' has shape {_shape_str(darr)}, expected one number (mm)")
            d = float(darr.reshape(-1)[0])
        P, d = _validate_markers(ctx, P, d)
    finally:
        fs.release()
    return MarkerModel(P, d)


def write_markers(path: str | Path, model: MarkerModel) -> None:
    """Write a marker model as ``markers.yaml`` (5x3 float64 ``markers``, ``diameter`` mm)."""
    if not isinstance(model, MarkerModel):
        raise TypeError(f"write_markers needs a MarkerModel, got {type(model).__name__}")
    with writing_storage(path) as fs:
        fs.write("markers", np.ascontiguousarray(model.points_mm, dtype=np.float64))
        fs.write("diameter", float(model.diameter_mm))
