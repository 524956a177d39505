"""The head's pivot: the point the head turns about, in the head frame, and ``pivot.yaml``.

opentrack's point tracker sends the position of a model point that its
"calibrate" step moves to the head's pivot (``tracker-pt`` ``t_MH``, fitted by
``cv/translation-calibrator.cpp``), so that turning the head does not move x,
y and z. headplod's records carry P1, the bridge of the glasses; the UDP
output sends ``P1 + axes^T @ pivot_mm`` instead (:mod:`headplod.live.opentrack`).

The fit (:func:`fit_pivot`). A head turning about a fixed point has, in every
frame k, ``p_k + A_k^T c = q``: ``p_k`` P1 (world, mm), ``A_k`` the pose's
axes (rows Ξ, Ψ, V in the world), ``c`` the pivot in the head frame (x along
Ξ, the wearer's left; y along Ψ, up; z along V, forward; for the default
marker model the glasses frame G) and ``q`` the pivot in the world. That is
linear in ``(c, q)``: 3N equations, 6 unknowns, solved by least squares.
Eliminating ``q`` leaves ``M c = b`` with ``M = mean_k (A_k^T - Ā)^T (A_k^T - Ā)``;
for small turns ``A_k^T - Ā`` is about the rotation angle times a cross
product, so ``sqrt`` of M's smallest eigenvalue is the rms rotation, rad,
about the worst-excited direction. Turning left-right determines the lateral
and forward parts of ``c``, nodding the vertical and forward parts; a motion
about one axis only leaves the part along that axis undetermined. The fit is
refused when that spread is under ``PivotFitConfig.min_spread_deg``, when
there are too few poses, when the residual is large (the shoulders moved),
or when the pivot lies implausibly far from the bridge.

``pivot.yaml`` (OpenCV FileStorage YAML, written by ``headplod pivot``, read
by ``headplod track --udp``): ``pivot_mm`` (1x3, head frame, mm), and for
people ``rms_mm``, ``std_mm``, ``frames``, ``spread_deg``. It sits next to
``rig.yaml`` (the folder of ``--calib``, or the dataset folder): the
contract's ``markers.yaml`` admits no other key, and ``rig.yaml`` describes
the cameras, not the head.
"""
from __future__ import annotations

import math
from dataclasses import dataclass
from pathlib import Path

import cv2
import numpy as np

from .. import io
from .opentrack import check_pivot_mm

__all__ = ["PIVOT_FILE", "PivotFitConfig", "PivotFit", "fit_pivot", "read_pivot", "write_pivot", "find_pivot_file"]

#: The name of the pivot file next to ``rig.yaml``.
PIVOT_FILE = "pivot.yaml"


@dataclass(frozen=True)
class PivotFitConfig:
    """Settings of :func:`fit_pivot`.

    Attributes
    ----------
    min_frames : int
        Fewest tracked poses to fit (>= 3).
    min_spread_deg : float
        Least rms rotation about the worst-determined direction, deg: below
        it the pivot is refused (a motion about one axis only, or too small).
    max_rms_mm : float
        Largest rms distance of the per-frame pivot from its mean, mm, after
        dropping outliers: above it the head did not turn about one point
        (the shoulders or the chair moved).
    max_pivot_mm : float
        Farthest plausible pivot from the bridge, mm.
    outlier_factor : float
        Frames whose residual exceeds this many times the median (and 3 mm)
        are dropped once and the fit repeated.
    """

    min_frames: int = 20
    min_spread_deg: float = 5.0
    max_rms_mm: float = 12.0
    max_pivot_mm: float = 250.0
    outlier_factor: float = 3.0

    def __post_init__(self) -> None:
        if int(self.min_frames) < 3:
            raise ValueError(f"min_frames: expected >= 3, got {self.min_frames}")
        for name in ("min_spread_deg", "max_rms_mm", "max_pivot_mm", "outlier_factor"):
            value = getattr(self, name)
            if not (math.isfinite(value) and value > 0):
                raise ValueError(f"{name}: expected a positive number, got {value}")


@dataclass(frozen=True)
class PivotFit:
    """The result of :func:`fit_pivot`; falsy when refused.

    Attributes
    ----------
    ok : bool
        False when the fit was refused (``reason`` says why and what to do).
    pivot_mm : (3,) ndarray or None
        The pivot in the head frame (along Ξ, Ψ, V), mm.
    pivot_world_mm : (3,) ndarray or None
        The fixed point in the world frame, mm.
    std_mm : (3,) ndarray or None
        Standard deviation of ``pivot_mm`` (from the residual, assuming
        independent frames: optimistic for correlated errors), mm.
    rms_mm : float
        Rms distance of the per-frame pivot, ``p_k + A_k^T c``, from ``q``, mm.
    spread_deg : (3,) ndarray
        Rms rotation about the three principal directions, deg, ascending.
    condition : float
        Condition number of the reduced normal matrix M (largest over
        smallest eigenvalue).
    frames : int
        Poses used (after dropping outliers).
    dropped : int
        Poses dropped as outliers.
    reason : str or None
    """

    ok: bool
    pivot_mm: np.ndarray | None
    pivot_world_mm: np.ndarray | None
    std_mm: np.ndarray | None
    rms_mm: float
    spread_deg: np.ndarray
    condition: float
    frames: int
    dropped: int
    reason: str | None = None

    def __bool__(self) -> bool:
        return self.ok

    def describe(self) -> str:
        """One line for people."""
        spread = "/".join(f"{s:.1f}" for s in self.spread_deg)
        if not self.ok and not np.all(np.isfinite(self.spread_deg)):
            return f"no pivot: {self.reason}"          # refused before any spread was measured (too few poses)
        if not self.ok:
            return f"no pivot: {self.reason} (rotation spread {spread}°, {self.frames} poses)"
        c, s = self.pivot_mm, self.std_mm
        return (f"pivot ({c[0]:.1f}, {c[1]:.1f}, {c[2]:.1f}) mm ±({s[0]:.1f}, {s[1]:.1f}, {s[2]:.1f}) in the head "
                f"frame (x left, y up, z forward from the bridge); residual {self.rms_mm:.1f} mm rms over "
                f"{self.frames} poses ({self.dropped} dropped); rotation spread {spread}°")


def _solve(p: np.ndarray, At: np.ndarray):
    """Least squares of ``p_k + At_k c = q``; (c, q, per-frame residual norms, M eigenvalues, eigenvectors, M)."""
    At_mean = At.mean(axis=0)
    p_mean = p.mean(axis=0)
    D = At - At_mean                                       # (N, 3, 3)
    e = p - p_mean                                         # (N, 3)
    M = np.einsum("kij,kil->jl", D, D) / len(p)            # mean D_k^T D_k
    b = -np.einsum("kij,ki->j", D, e) / len(p)             # -mean D_k^T e_k
    w, U = np.linalg.eigh(M)
    c = np.linalg.lstsq(M, b, rcond=None)[0]
    q = p_mean + At_mean @ c
    r = p + At @ c - q
    return c, q, np.linalg.norm(r, axis=1), w, U, M


def fit_pivot(positions_mm, axes, config: PivotFitConfig = PivotFitConfig()) -> PivotFit:
    """The fixed point of a head's motion, in the head frame.

    Parameters
    ----------
    positions_mm : (N, 3) array_like of float
        P1 per pose, world frame, mm.
    axes : (N, 3, 3) array_like of float
        Rows Ξ, Ψ, V per pose, world frame.
    config : PivotFitConfig

    Returns
    -------
    PivotFit
        Falsy, with a reason, when the motion does not determine the pivot.

    Raises
    ------
    ValueError
        On mismatched shapes or non-finite values.
    """
    p = np.asarray(positions_mm, dtype=float)
    A = np.asarray(axes, dtype=float)
    if p.ndim != 2 or p.shape[1] != 3:
        raise ValueError(f"positions_mm: expected shape (N, 3), got {p.shape}")
    if A.shape != (len(p), 3, 3):
        raise ValueError(f"axes: expected shape ({len(p)}, 3, 3), got {A.shape}")
    if not (np.all(np.isfinite(p)) and np.all(np.isfinite(A))):
        raise ValueError("positions_mm and axes must be finite")
    nothing = np.full(3, np.nan)

    def refuse(reason, frames=len(p), spread=nothing, condition=math.inf, rms=math.nan, dropped=0):
        return PivotFit(False, None, None, None, rms, spread, condition, frames, dropped, reason)

    if len(p) < config.min_frames:
        return refuse(f"{len(p)} tracked poses, {config.min_frames} needed, over which the head turns at least "
                      f"{config.min_spread_deg:g}° rms about each axis (left-right about ±30°, up-down about ±15°); "
                      "turn the head for longer")
    At = np.transpose(A, (0, 2, 1))                        # head -> world per frame
    keep = np.ones(len(p), bool)
    c, q, r, w, U, M = _solve(p, At)
    limit = max(config.outlier_factor * float(np.median(r)), 3.0)
    if np.any(r > limit) and np.count_nonzero(r <= limit) >= config.min_frames:
        keep = r <= limit
        c, q, r, w, U, M = _solve(p[keep], At[keep])
    n = int(keep.sum())
    dropped = len(p) - n
    spread = np.degrees(np.sqrt(np.clip(w, 0.0, None)))
    condition = float(w[-1] / w[0]) if w[0] > 0 else math.inf
    rms = float(np.sqrt(np.mean(r ** 2)))
    if spread[0] < config.min_spread_deg:
        weak = U[:, 0]                                     # least-determined direction, head frame
        axis = int(np.argmax(np.abs(weak)))
        advice = {0: "turn the head left and right more (about ±30°)",
                  1: "nod up and down more (about ±15°)",
                  2: "turn left-right and nod up-down, both"}[axis]
        return refuse(f"the motion does not determine the pivot (rms rotation {spread[0]:.1f}° about the weakest "
                      f"direction, {config.min_spread_deg:g}° needed); {advice}",
                      n, spread, condition, rms, dropped)
    if rms > config.max_rms_mm:
        return refuse(f"the head did not turn about one point (residual {rms:.1f} mm rms, at most "
                      f"{config.max_rms_mm:g} mm); keep the shoulders and the chair still and turn the head only",
                      n, spread, condition, rms, dropped)
    if np.linalg.norm(c) > config.max_pivot_mm:
        return refuse(f"the fitted pivot {np.round(c, 1).tolist()} mm lies {np.linalg.norm(c):.0f} mm from the "
                      f"bridge, more than {config.max_pivot_mm:g} mm; keep the shoulders still and turn the head only",
                      n, spread, condition, rms, dropped)
    dof = max(3 * n - 6, 1)
    sigma2 = float(np.sum(r ** 2)) / dof
    cov = sigma2 * np.linalg.inv(M) / n
    std = np.sqrt(np.clip(np.diag(cov), 0.0, None))
    return PivotFit(True, c, q, std, rms, spread, condition, n, dropped)


def write_pivot(path, fit: PivotFit) -> Path:
    """Write ``pivot.yaml`` atomically (whole or untouched); returns its path.

    Raises
    ------
    ValueError
        For a refused fit.
    OSError
        When the file cannot be written.
    """
    if not fit:
        raise ValueError(f"no pivot to write: {fit.reason}")

    def write(name: str) -> None:
        with io.writing_storage(name) as fs:            # through memory: OpenCV never sees the path
            fs.writeComment("head pivot from the bridge of the glasses (P1), head frame: x along Xi "
                            "(wearer's left), y along Psi (up), z along V (forward), mm; headplod pivot")
            fs.write("pivot_mm", np.asarray(fit.pivot_mm, dtype=np.float64).reshape(1, 3))
            fs.write("std_mm", np.asarray(fit.std_mm, dtype=np.float64).reshape(1, 3))
            fs.write("rms_mm", float(fit.rms_mm))
            fs.write("spread_deg", np.asarray(fit.spread_deg, dtype=np.float64).reshape(1, 3))
            fs.write("frames", int(fit.frames))

    return io.write_atomically(path, write, suffix=".yaml")


def read_pivot(path) -> np.ndarray:
    """Read ``pivot.yaml``: the pivot, (3,) mm, head frame.

    Raises
    ------
    ContractError
        On a missing or unreadable file, a missing ``pivot_mm`` or a value
        :func:`~headplod.live.opentrack.check_pivot_mm` refuses.
    """
    path = Path(path).expanduser()
    if not path.is_file():
        raise io.ContractError(f"{path}: no such file (the head pivot; 'headplod pivot' writes it)")
    try:
        fs = io.read_storage(path)                      # through memory: OpenCV never sees the path
    except OSError as exc:
        raise io.ContractError(f"{path}: cannot be read ({exc.strerror or exc})") from None
    except (cv2.error, SystemError) as exc:
        raise io.ContractError(f"{path}: not an OpenCV YAML file ({str(exc).strip().splitlines()[-1]})") from None
    try:
        node = fs.getNode("pivot_mm")
        value = None if node.empty() else node.mat()
    finally:
        fs.release()
    if value is None:
        raise io.ContractError(f"{path}: no key 'pivot_mm' (1x3, mm, head frame); 'headplod pivot' writes it")
    try:
        return check_pivot_mm(np.asarray(value, dtype=float).reshape(-1))
    except ValueError as exc:
        raise io.ContractError(f"{path}: {exc}") from None


def find_pivot_file(*folders) -> Path | None:
    """The first ``pivot.yaml`` in the given folders (None entries skipped), or None."""
    for folder in folders:
        if folder is None:
            continue
        candidate = Path(folder).expanduser() / PIVOT_FILE
        if candidate.is_file():
            return candidate
    return None
