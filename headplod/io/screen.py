"""The display: ``screen.yaml``.

:class:`Screen` (pixel size and three corners in the world frame, mm, with
the pixel/world mapping, the ray intersection and the side of its plane a view
is drawn from), :func:`read_screen` and :func:`write_screen`;
:class:`ViewError`, an eye no view can be drawn from.
"""

from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np

from ._storage import (
    _Ctx,
    _check_vec3,
    _frozen,
    _fs_write,
    _open_storage,
    _positive_int,
    _read_numeric,
    writing_storage,
)
from ..tol import tol

# --------------------------------------------------------------------------
# constants
# --------------------------------------------------------------------------

_SCREEN_KEYS = ("size_px", "top_left", "top_right", "bottom_left")


_SCREEN_HINT = (
    "screen.yaml holds size_px (width, height) and the corners top_left, "
    "top_right, bottom_left of the visible image in the world frame, mm"
)


def _validate_screen(ctx: _Ctx, size_px, tl, tr, bl) -> dict:
    try:
        size = np.array(size_px, dtype=np.float64).reshape(-1)
    except (TypeError, ValueError):
        raise ctx.error(f"{ctx.name('size_px')} is {size_px!r}, expected (width, height) in px",
                        _SCREEN_HINT) from None
    if size.size != 2:
        raise ctx.error(f"{ctx.name('size_px')} has {size.size} values, expected 2 (width, height)",
                        _SCREEN_HINT)
    w = _positive_int(ctx, "size_px[0] (width)", size[0], _SCREEN_HINT)
    h = _positive_int(ctx, "size_px[1] (height)", size[1], _SCREEN_HINT)
    corners = {}
    for key, v in (("top_left", tl), ("top_right", tr), ("bottom_left", bl)):
        try:
            a = np.array(v, dtype=np.float64)
        except (TypeError, ValueError):
            raise ctx.error(f"{ctx.name(key)} is not numeric", _SCREEN_HINT) from None
        corners[key] = _check_vec3(ctx, key, a, _SCREEN_HINT)
    a = corners["top_right"] - corners["top_left"]
    b = corners["bottom_left"] - corners["top_left"]
    na, nb = np.linalg.norm(a), np.linalg.norm(b)
    if na < tol.small or nb < tol.small or np.linalg.norm(np.cross(a, b)) <= tol.small * na * nb:
        raise ctx.error(
            "the corners do not span a plane: top_right − top_left = "
            f"{a.tolist()} mm and bottom_left − top_left = {b.tolist()} mm are zero or parallel",
            _SCREEN_HINT,
        )
    return {"size_px": (w, h), **{k: _frozen(v) for k, v in corners.items()}}


class ViewError(ValueError):
    """An eye no view of the screen can be drawn from: on or behind its plane, or not 3 finite numbers (mm).

    A head-coupled view looks through the screen as through a window, so the eye must be on the side the
    screen is seen from (:meth:`Screen.check_eye`); a command reports it as bad usage.
    """


@dataclass(frozen=True, eq=False)
class Screen:
    """The display: its pixel size and three corners in the world frame.

    Screen pixel (x, y) is at
    ``top_left + (x / w) (top_right − top_left) + (y / h) (bottom_left − top_left)``
    (mm, world frame), with ``(w, h) = size_px``.

    Parameters
    ----------
    size_px : tuple of int
        ``(width, height)`` of the visible image, px.
    top_left, top_right, bottom_left : ndarray, shape (3,)
        Corners of the visible image area in the world frame, mm.
    """

    size_px: tuple[int, int]
    top_left: np.ndarray
    top_right: np.ndarray
    bottom_left: np.ndarray

    def __post_init__(self) -> None:
        v = _validate_screen(_Ctx.obj("Screen"), self.size_px, self.top_left, self.top_right,
                             self.bottom_left)
        for k, x in v.items():
            object.__setattr__(self, k, x)

    @property
    def normal(self) -> np.ndarray:
        """Unit normal of the screen plane, (top_right − top_left) × (bottom_left − top_left)."""
        n = np.cross(self.top_right - self.top_left, self.bottom_left - self.top_left)
        return n / np.linalg.norm(n)

    def eye_distance_mm(self, eye_mm: Any) -> float:
        """Signed distance of an eye from the screen plane, mm: positive on the side the screen is seen from
        (opposite to :attr:`normal`), zero on the plane, negative behind it.

        ``eye_mm``: (3,) world frame, mm.
        """
        eye = np.asarray(eye_mm, dtype=np.float64).reshape(-1)
        return float(np.dot(self.normal, self.top_left - eye))

    def check_eye(self, eye_mm: Any, far_mm: float | None = None) -> float:
        """The :meth:`eye_distance_mm` of an eye a view can be drawn from; raises :class:`ViewError` otherwise.

        The eye ((3,) world frame, mm) must be 3 finite numbers on the side the screen is seen from, farther
        from the plane than ``tol.small`` of the screen's longer side (on the plane, the window has no depth:
        every point behind it projects to its edge), and with ``far_mm`` (the far clip plane's distance from
        the eye, parallel to the screen, mm) nearer than that: from farther, everything behind the screen is
        clipped.
        """
        eye = np.asarray(eye_mm, dtype=np.float64).reshape(-1)
        if eye.shape != (3,) or not np.isfinite(eye).all():
            raise ViewError(f"the eye must be 3 finite numbers (mm), got {np.asarray(eye_mm).tolist()!r}")
        d = self.eye_distance_mm(eye)
        size = max(np.linalg.norm(self.top_right - self.top_left), np.linalg.norm(self.bottom_left - self.top_left))
        if not d > tol.small * size:
            where = ("on the screen plane" if abs(d) <= tol.small * size
                     else f"behind the screen plane, {-d:.4g} mm behind it")
            raise ViewError(f"the eye {np.round(eye, 3).tolist()} mm is {where}; it must be in front of the screen, "
                            "on the viewer's side")
        if far_mm is not None and not d < far_mm:
            raise ViewError(f"the eye {np.round(eye, 3).tolist()} mm is {d:.4g} mm in front of the screen plane, "
                            f"beyond the far clip plane ({far_mm:g} mm from the eye): everything behind the screen "
                            "would be clipped")
        return d

    def pixel_to_world(self, xy_px: Any) -> np.ndarray:
        """World position (mm) of screen pixels.

        Parameters
        ----------
        xy_px : array_like, shape (..., 2)
            Screen pixel coordinates (x, y), px.

        Returns
        -------
        ndarray, shape (..., 3)
            Points in the world frame, mm.
        """
        xy = np.asarray(xy_px, dtype=np.float64)
        if xy.shape[-1:] != (2,):
            raise ValueError(f"pixel_to_world needs shape (..., 2), got {xy.shape}")
        w, h = self.size_px
        a = (self.top_right - self.top_left) / w
        b = (self.bottom_left - self.top_left) / h
        return self.top_left + xy[..., :1] * a + xy[..., 1:2] * b

    def intersect_ray(self, origin_mm: Any, direction: Any) -> np.ndarray | None:
        """Screen pixel where a ray meets the screen plane.

        Parameters
        ----------
        origin_mm : array_like, shape (3,)
            Ray origin in the world frame, mm (e.g. the head position).
        direction : array_like, shape (3,)
            Ray direction in the world frame (e.g. V); need not be unit.

        Returns
        -------
        ndarray, shape (2,) or None
            Screen pixel (x, y), px, of the intersection with the (infinite)
            screen plane; it may lie outside ``[0, w] x [0, h]``. ``None``
            when the ray is parallel to the plane or the plane is behind the
            origin.
        """
        o = np.asarray(origin_mm, dtype=np.float64).reshape(-1)
        d = np.asarray(direction, dtype=np.float64).reshape(-1)
        if o.shape != (3,) or d.shape != (3,):
            raise ValueError(f"intersect_ray needs two 3-vectors, got {o.shape} and {d.shape}")
        if not (np.isfinite(o).all() and np.isfinite(d).all()):
            raise ValueError("intersect_ray: origin and direction must be finite")
        nd = np.linalg.norm(d)
        if nd == 0:
            raise ValueError("intersect_ray: direction is the zero vector")
        n = self.normal
        denom = float(np.dot(n, d)) / nd
        if abs(denom) < tol.zero:
            return None
        s = float(np.dot(n, self.top_left - o)) / float(np.dot(n, d))
        if not s > 0:
            return None
        w, h = self.size_px
        M = np.column_stack([(self.top_right - self.top_left) / w,
                             (self.bottom_left - self.top_left) / h])
        p = o + s * d - self.top_left
        xy, *_ = np.linalg.lstsq(M, p, rcond=None)
        return xy

    def __eq__(self, other: object) -> bool:
        if not isinstance(other, Screen):
            return NotImplemented
        return self.size_px == other.size_px and all(
            np.array_equal(getattr(self, k), getattr(other, k))
            for k in ("top_left", "top_right", "bottom_left")
        )

    __hash__ = None  # type: ignore[assignment]


def read_screen(path: str | Path) -> Screen:
    """Read and validate ``screen.yaml``.

    Parameters
    ----------
    path : str or Path
        OpenCV FileStorage YAML with ``size_px`` (width, height; a sequence
        or a 1x2/2x1 matrix of positive integers, px) and ``top_left``,
        ``top_right``, ``bottom_left`` (3-vectors, world frame, mm). Other
        keys are ignored.

    Returns
    -------
    Screen

    Raises
    ------
    ContractError
        On a missing or malformed file, a missing key, wrong shapes,
        non-finite or non-integer values, or corners that do not span a
        plane.
    """
    fs, ctx = _open_storage(path, "the screen (screen.yaml)")
    try:
        raw = {k: _read_numeric(fs, ctx, k, _SCREEN_HINT) for k in _SCREEN_KEYS}
        v = _validate_screen(ctx, raw["size_px"], raw["top_left"], raw["top_right"], raw["bottom_left"])
    finally:
        fs.release()
    return Screen(**v)


def write_screen(path: str | Path, screen: Screen) -> None:
    """Write ``screen.yaml``: ``size_px`` as ``[w, h]``, corners as 3x1 float64 (mm)."""
    if not isinstance(screen, Screen):
        raise TypeError(f"write_screen needs a Screen, got {type(screen).__name__}")
    with writing_storage(path) as fs:
        _fs_write(fs, "size_px", [int(screen.size_px[0]), int(screen.size_px[1])])
        for k in ("top_left", "top_right", "bottom_left"):
            fs.write(k, np.ascontiguousarray(getattr(screen, k), dtype=np.float64).reshape(3, 1))
