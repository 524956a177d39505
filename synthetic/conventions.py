"""Contract conventions, re-implemented independently of ``headplod``.

This module encodes what ``docs/contract.md`` says about the
glasses model, the head axes (Ξ, Ψ, V) and the contract files, with its own
code, so that the synthetic data generator never imports the tracker.

Frames
------
- Camera frame: OpenCV (x right, y down, z forward), pixel (0, 0) is the centre
  of the top-left pixel.
- World frame W: the left camera's frame.  A point X_left maps to the right
  camera as ``R @ X_left + T`` (mm).
- Glasses frame G: origin at P1 (the bridge), x toward P0, z forward (out of the
  wearer's face, toward the display), y = z × x (up).  P0 is therefore on the
  wearer's left.

All lengths are mm, all angles in public signatures are degrees.
"""
from __future__ import annotations

from pathlib import Path
from typing import Mapping, Optional, Sequence, Union

import cv2
import numpy as np

__all__ = [
    "DEFAULT_MARKERS_MM",
    "DEFAULT_DIAMETER_MM",
    "TRIANGLES",
    "triangle_normals",
    "model_view_direction",
    "model_axes",
    "fit_rotation",
    "viewing_axes",
    "rot_x",
    "rot_y",
    "rot_z",
    "facing_rotation",
    "head_rotation",
    "write_rig",
    "write_markers",
    "write_screen",
    "write_image",
    "read_matrix_yaml",
]

#: Default marker model, rows P0..P4 in the glasses frame G, mm, shape (5, 3).
DEFAULT_MARKERS_MM = np.array(
    [
        [65.0, 0.0, 0.0],
        [0.0, 0.0, 0.0],
        [-65.0, 0.0, 0.0],
        [40.0, -30.0, 0.0],
        [-40.0, -30.0, 0.0],
    ],
    dtype=np.float64,
)
DEFAULT_MARKERS_MM.setflags(write=False)

#: Default marker (retro-reflective disk) diameter, mm.
DEFAULT_DIAMETER_MM = 6.0

#: Marker index triples of the three triangles that define V.
TRIANGLES = ((0, 1, 3), (1, 2, 4), (1, 3, 4))

PathLike = Union[str, Path]


def cross3(a, b) -> np.ndarray:
    """Cross product of two 3-vectors (faster than ``np.cross`` for one pair)."""
    a0, a1, a2 = float(a[0]), float(a[1]), float(a[2])
    b0, b1, b2 = float(b[0]), float(b[1]), float(b[2])
    return np.array([a1 * b2 - a2 * b1, a2 * b0 - a0 * b2, a0 * b1 - a1 * b0])


def _unit(v: np.ndarray, axis: int = -1) -> np.ndarray:
    n = np.linalg.norm(v, axis=axis, keepdims=True)
    return v / n


def triangle_normals(points: np.ndarray) -> np.ndarray:
    """Unnormalized-orientation unit normals of the three V triangles.

    Parameters
    ----------
    points : (5, 3) array
        Marker positions P0..P4 in any frame, mm.

    Returns
    -------
    (3, 3) array
        Rows: unit normals ``(B - A) × (C - A)`` of triangles (P0, P1, P3),
        (P1, P2, P4), (P1, P3, P4), in the same frame, with the sign given by
        the vertex order (not yet oriented).
    """
    p = np.asarray(points, dtype=np.float64).reshape(5, 3)
    out = []
    for a, b, c in TRIANGLES:
        out.append(np.cross(p[b] - p[a], p[c] - p[a]))
    return _unit(np.array(out))


def model_view_direction(model_points_mm: np.ndarray = DEFAULT_MARKERS_MM) -> np.ndarray:
    """V of a marker model expressed in its own glasses frame G.

    The normalized mean of the unit normals of triangles (P0, P1, P3),
    (P1, P2, P4), (P1, P3, P4), each turned to G's +z side.

    Parameters
    ----------
    model_points_mm : (5, 3) array
        P0..P4 in G, mm.

    Returns
    -------
    (3,) array
        Unit vector in G.  ``[0, 0, 1]`` for the default (flat) model.
    """
    n = triangle_normals(model_points_mm)
    n = n * np.where(n[:, 2] < 0.0, -1.0, 1.0)[:, None]
    return _unit(n.mean(axis=0))


def model_axes(model_points_mm: np.ndarray = DEFAULT_MARKERS_MM) -> np.ndarray:
    """Head axes of a model in its own frame G (the pose ``R = I, p = 0``).

    Returns
    -------
    (3, 3) array
        Rows Ξ_G, Ψ_G, V_G (unit vectors in G).  This is a proper rotation
        taking G coordinates to head-axes coordinates; identity for the
        default model.
    """
    m = np.asarray(model_points_mm, dtype=np.float64).reshape(5, 3)
    return _axes_from(m, model_view_direction(m))


def _axes_from(points: np.ndarray, v: np.ndarray) -> np.ndarray:
    xi = points[0] - points[1]
    xi = xi - np.dot(xi, v) * v
    xi = xi / np.linalg.norm(xi)
    psi = cross3(v, xi)
    return np.vstack([xi, psi, v])


def fit_rotation(model_points_mm: np.ndarray, points_world: np.ndarray) -> np.ndarray:
    """Least-squares rotation R with ``points_world ≈ R @ model + p`` (Kabsch).

    Parameters
    ----------
    model_points_mm, points_world : (N, 3) arrays, mm.

    Returns
    -------
    (3, 3) array, proper rotation (det +1), world from G.
    """
    a = np.asarray(model_points_mm, dtype=np.float64)
    b = np.asarray(points_world, dtype=np.float64)
    a0 = a - a.mean(axis=0)
    b0 = b - b.mean(axis=0)
    u, _, vt = np.linalg.svd(b0.T @ a0)
    d = np.sign(np.linalg.det(u @ vt))
    return u @ np.diag([1.0, 1.0, d]) @ vt


def viewing_axes(
    points_world: np.ndarray,
    model_points_mm: Optional[np.ndarray] = None,
    R_world_from_G: Optional[np.ndarray] = None,
) -> np.ndarray:
    """Head axes (rows Ξ, Ψ, V) from the five world marker positions.

    Implements docs/contract.md exactly: V is the normalized mean of the unit
    normals of the triangles (P0, P1, P3), (P1, P2, P4), (P1, P3, P4), each
    turned to the side of G's +z; Ξ is P0 − P1 with its V component removed,
    normalized; Ψ = V × Ξ.

    The side of G's +z is taken from the pose rotation: the model's own V in
    G (normals oriented to G's +z) transported to the world,
    ``R_world_from_G @ V_G``; each world normal is flipped to have a positive
    dot product with it.  ``R_world_from_G`` is fitted from the model when not
    given (exact for noise-free positions).

    Parameters
    ----------
    points_world : (5, 3) array
        P0..P4 in the world (left camera) frame, mm.
    model_points_mm : (5, 3) array, optional
        The marker model in G (default model when None).  Only used to find
        the +z side of G when ``R_world_from_G`` is not given.
    R_world_from_G : (3, 3) array, optional
        The pose rotation, G to world.

    Returns
    -------
    (3, 3) array
        Rows Ξ, Ψ, V, unit vectors in the world frame (right-handed,
        orthonormal).  For the default model equal to ``R_world_from_G.T``
        (the rotation from world to G).
    """
    p = np.asarray(points_world, dtype=np.float64).reshape(5, 3)
    model = DEFAULT_MARKERS_MM if model_points_mm is None else np.asarray(model_points_mm, np.float64)
    if R_world_from_G is None:
        R_world_from_G = fit_rotation(model, p)
    ref = np.asarray(R_world_from_G, np.float64) @ model_view_direction(model)
    n = triangle_normals(p)
    n = n * np.where(n @ ref < 0.0, -1.0, 1.0)[:, None]
    v = _unit(n.mean(axis=0))
    return _axes_from(p, v)


# ----------------------------------------------------------------------------
# rotations
# ----------------------------------------------------------------------------

def rot_x(deg: float) -> np.ndarray:
    """Right-handed rotation by ``deg`` degrees about +x, (3, 3)."""
    a = np.deg2rad(deg)
    c, s = np.cos(a), np.sin(a)
    return np.array([[1, 0, 0], [0, c, -s], [0, s, c]], dtype=np.float64)


def rot_y(deg: float) -> np.ndarray:
    """Right-handed rotation by ``deg`` degrees about +y, (3, 3)."""
    a = np.deg2rad(deg)
    c, s = np.cos(a), np.sin(a)
    return np.array([[c, 0, s], [0, 1, 0], [-s, 0, c]], dtype=np.float64)


def rot_z(deg: float) -> np.ndarray:
    """Right-handed rotation by ``deg`` degrees about +z, (3, 3)."""
    a = np.deg2rad(deg)
    c, s = np.cos(a), np.sin(a)
    return np.array([[c, -s, 0], [s, c, 0], [0, 0, 1]], dtype=np.float64)


def facing_rotation(forward: Sequence[float], up: Sequence[float] = (0.0, -1.0, 0.0)) -> np.ndarray:
    """Rotation (world from head) of a level head looking along ``forward``.

    Parameters
    ----------
    forward : (3,) world direction the head's +z (V) points to.
    up : (3,) world direction the head's +y should lean to (default world −y,
        i.e. image-up for a level camera).  Must not be parallel to forward.

    Returns
    -------
    (3, 3) array, columns: head x (= y × z, the wearer's left), head y (up,
    the component of ``up`` orthogonal to ``forward``), head z (= forward).
    """
    z = _unit(np.asarray(forward, np.float64))
    u = np.asarray(up, np.float64)
    y = u - np.dot(u, z) * z
    y = y / np.linalg.norm(y)
    x = cross3(y, z)
    return np.column_stack([x, y, z])


def head_rotation(
    yaw_deg: float,
    pitch_deg: float,
    roll_deg: float,
    facing: Union[None, Sequence[float], np.ndarray] = None,
    up: Sequence[float] = (0.0, -1.0, 0.0),
) -> np.ndarray:
    """Rotation (world from head) of a head facing the cameras, then turned.

    Convention: ``R = R0 @ rot_y(yaw) @ rot_x(pitch) @ rot_z(roll)`` where the
    rotations are intrinsic, right-handed, about the head's own axes
    (x = toward P0 = wearer's left, y = up, z = view direction):

    - yaw about the head's up axis: positive yaw turns the face toward the
      wearer's left (toward P0),
    - pitch about the head's x axis: positive pitch tips the face down (chin
      down),
    - roll about the view axis: positive roll lifts the wearer's left side
      (P0 goes up), i.e. the head tilts toward the wearer's right shoulder.

    The base orientation R0 (yaw = pitch = roll = 0):

    - ``facing=None``: the head looks along world −z (straight into the left
      camera, world = left camera frame) with its up along world −y, so
      ``R0 = diag(1, -1, -1)``;
    - ``facing`` a (3,) vector: the head looks along that world direction,
      up leaning to ``up`` (see :func:`facing_rotation`);
    - ``facing`` a (3, 3) matrix: used as R0 directly.

    For the default (flat) marker model the head frame is G, so this is
    ``R_world_from_G``.  For a curved model it is the frame of the head axes
    (Ξ, Ψ, V); use ``R_world_from_head @ model_axes(model)`` to get
    ``R_world_from_G``.

    Returns
    -------
    (3, 3) array, proper rotation, world from head.
    """
    if facing is None:
        r0 = np.diag([1.0, -1.0, -1.0])
    else:
        f = np.asarray(facing, np.float64)
        r0 = f if f.shape == (3, 3) else facing_rotation(f, up)
    return r0 @ rot_y(yaw_deg) @ rot_x(pitch_deg) @ rot_z(roll_deg)


# ----------------------------------------------------------------------------
# contract file writers (OpenCV FileStorage YAML)
# ----------------------------------------------------------------------------

# OpenCV's Python binding is never handed a path: it turns a str into UTF-8 and crashes the process on a
# name that is not UTF-8 text (b'caf\xe9'). Python reads and writes the files; OpenCV only encodes bytes.


def write_image(path: PathLike, img: np.ndarray) -> None:
    """Write ``img`` (gray or BGR uint8) as the image file ``path`` (format from its ending), as
    ``cv2.imwrite`` would; OSError when it cannot be encoded or written."""
    path = Path(path)
    ok, data = cv2.imencode(path.suffix, img) if path.suffix.isascii() else (False, None)
    if not ok:
        raise OSError(f"could not encode {path}")
    path.write_bytes(data.tobytes())


def _storage() -> cv2.FileStorage:
    """A FileStorage writing YAML into memory (:func:`_save`)."""
    return cv2.FileStorage(".yaml", cv2.FILE_STORAGE_WRITE | cv2.FILE_STORAGE_MEMORY | cv2.FILE_STORAGE_FORMAT_YAML)


def _save(fs: cv2.FileStorage, path: Path) -> None:
    """Release ``fs`` and write its YAML to ``path`` (the bytes OpenCV would write there)."""
    path.write_text(fs.releaseAndGetString(), encoding="utf-8")

def _fs_write_value(fs: cv2.FileStorage, key: str, value) -> None:
    if isinstance(value, (bool, np.bool_)):
        fs.write(key, int(value))
    elif isinstance(value, (int, np.integer)):
        fs.write(key, int(value))
    elif isinstance(value, (float, np.floating)):
        fs.write(key, float(value))
    elif isinstance(value, str):
        fs.write(key, value)
    else:
        arr = np.asarray(value, dtype=np.float64)
        if arr.ndim == 1:
            arr = arr.reshape(1, -1)
        fs.write(key, arr)


def write_rig(
    path: PathLike,
    image_size: Sequence[int],
    K1: np.ndarray,
    D1: np.ndarray,
    K2: np.ndarray,
    D2: np.ndarray,
    R: np.ndarray,
    T: np.ndarray,
    extra: Optional[Mapping[str, object]] = None,
) -> Path:
    """Write a contract ``rig.yaml``.

    Keys, in the order of the sample datasets: ``image_width``,
    ``image_height`` (ints), ``K1`` (3x3), ``D1`` (1xN), ``K2``, ``D2``, ``R``
    (3x3), ``T`` (3x1, mm), all float64, followed by ``extra`` keys (ints,
    floats, strings or matrices).

    Parameters
    ----------
    path : output file.
    image_size : (width, height) in px.
    K1, K2 : (3, 3) camera matrices, px.
    D1, D2 : (N,) OpenCV distortion coefficients k1 k2 p1 p2 k3 ...
    R, T : right camera extrinsics, ``X_right = R @ X_left + T``, T in mm.
    """
    path = Path(path)
    path.parent.mkdir(parents=True, exist_ok=True)
    fs = _storage()
    fs.write("image_width", int(image_size[0]))
    fs.write("image_height", int(image_size[1]))
    fs.write("K1", np.asarray(K1, np.float64).reshape(3, 3))
    fs.write("D1", np.asarray(D1, np.float64).reshape(1, -1))
    fs.write("K2", np.asarray(K2, np.float64).reshape(3, 3))
    fs.write("D2", np.asarray(D2, np.float64).reshape(1, -1))
    fs.write("R", np.asarray(R, np.float64).reshape(3, 3))
    fs.write("T", np.asarray(T, np.float64).reshape(3, 1))
    for k, v in (extra or {}).items():
        _fs_write_value(fs, k, v)
    _save(fs, path)
    return path


def write_markers(path: PathLike, points_mm: np.ndarray, diameter_mm: float = DEFAULT_DIAMETER_MM) -> Path:
    """Write a contract ``markers.yaml``: ``markers`` (5x3 float64, rows P0..P4
    in G, mm) and ``diameter`` (mm)."""
    pts = np.asarray(points_mm, np.float64).reshape(5, 3)
    path = Path(path)
    path.parent.mkdir(parents=True, exist_ok=True)
    fs = _storage()
    fs.write("markers", pts)
    fs.write("diameter", float(diameter_mm))
    _save(fs, path)
    return path


def write_screen(
    path: PathLike,
    size_px: Sequence[int],
    top_left: Sequence[float],
    top_right: Sequence[float],
    bottom_left: Sequence[float],
) -> Path:
    """Write a contract ``screen.yaml``.

    Keys: ``size_px`` (1x2 int matrix: width, height) and the corners
    ``top_left``, ``top_right``, ``bottom_left`` (3x1 float64, world frame,
    mm) of the visible image area.
    """
    path = Path(path)
    path.parent.mkdir(parents=True, exist_ok=True)
    fs = _storage()
    fs.write("size_px", np.array([[int(size_px[0]), int(size_px[1])]], dtype=np.int32))
    fs.write("top_left", np.asarray(top_left, np.float64).reshape(3, 1))
    fs.write("top_right", np.asarray(top_right, np.float64).reshape(3, 1))
    fs.write("bottom_left", np.asarray(bottom_left, np.float64).reshape(3, 1))
    _save(fs, path)
    return path


def read_matrix_yaml(path: PathLike) -> dict:
    """Read every top-level key of an OpenCV FileStorage file.

    Matrices come back as float64 numpy arrays, integers as int, reals as
    float, strings as str.  (Used by tests and by ``render`` when given a
    rig path; it is not the project's reader, see ``headplod.io``.)
    """
    text = Path(path).read_bytes().decode("utf-8", errors="replace")    # FileNotFoundError when missing
    fs = cv2.FileStorage(text, cv2.FILE_STORAGE_READ | cv2.FILE_STORAGE_MEMORY)
    if not fs.isOpened():
        raise FileNotFoundError(path)
    out = {}
    try:
        root = fs.root()
        for key in root.keys():
            node = fs.getNode(key)
            if node.isString():
                out[key] = node.string()
            elif node.isInt():
                out[key] = int(node.real())
            elif node.isReal():
                out[key] = float(node.real())
            else:
                m = node.mat()
                out[key] = None if m is None else np.asarray(m, dtype=np.float64)
    finally:
        fs.release()
    return out
