"""opentrack's UDP protocol: the six values of a head pose (the pivot's position in cm, tracker-pt
or OpenCV axes; yaw, pitch, roll in degrees), their 48-byte datagram, and ``HOST:PORT`` parsing.

Pure functions, no socket: :mod:`headplod.live.udp` sends the datagrams.

opentrack ("UDP over network" input)
-------------------------------------
opentrack's UDP input (``tracker-udp/ftnoir_tracker_udp.cpp`` in the
opentrack/opentrack repository, listening on port 4242 by default, see
``tracker-udp/ftnoir_tracker_udp.h``) reads datagrams of six ``double`` in the
order of ``enum Axis`` in ``api/plugin-api.hpp``: ``TX, TY, TZ, Yaw, Pitch,
Roll``; a datagram holding a NaN is ignored. The maintainer states that the
doubles are little-endian, positions in centimetres and rotations in degrees
(opentrack issue #881). A datagram here is therefore ``struct.pack('<6d', x_cm,
y_cm, z_cm, yaw_deg, pitch_deg, roll_deg)``: 48 bytes.

What is sent is what opentrack's point tracker (``tracker-pt``) sends, so that
a user switching from it changes nothing in opentrack: no axis to invert, no
offset to enter. The sources read (opentrack master, commit f009bb52, July
2026):

- ``tracker-pt/pt-api.cpp`` lines 46-50, ``to_screen_pos``: a blob at pixel
  (px, py) of a w x h image becomes ``((px - w/2)/w, -(py - h/2)/w)``: x to
  the image's right, y UP (the pixel row is negated).
- ``tracker-pt/point_tracker.cpp`` lines 304-307 (POSIT's translation
  ``order[0] * Z0/focal_length``, ``Z0``) and 354-357 (``project``: ``f *
  v_C[0]/v_C[2]``, ``f * v_C[1]/v_C[2]``): the camera frame C of ``X_CM`` is
  x to the camera's right, y up, z away from the camera (depth > 0).
- ``tracker-pt/ftnoir_tracker_pt.cpp`` lines 153-195, ``Tracker_PT::data``:
  ``X_GH = X_CM * X_MH`` with ``X_MH`` a pure translation by the model offset
  ``t_MH`` (``pt-settings.hpp`` lines 47-49, "model-centroid-x/y/z", mm,
  default 0, which the dialog's "calibrate" button estimates from head
  turns: ``ftnoir_tracker_pt_dialog.cpp`` lines 174-197 and 275-285,
  ``cv/translation-calibrator.cpp``); ``TX, TY, TZ = X_GH.t / 10``. So the
  position is that of the model point ``t_MH`` (the head's pivot, once
  calibrated), in C, in cm. The angles are the z-y-x decomposition of
  ``R_EG X_GH.R R_EG^T`` with ``R_EG = [[0,0,-1],[-1,0,0],[0,1,0]]``, yaw =
  alpha, pitch = -beta, roll = gamma (lines 167-189).

Working the last step through for the three elementary head motions (a
head facing the camera, the image not mirrored) gives tracker-pt's signs:

- x (TX) positive: the head is to the camera's right (the wearer's left);
- y (TY) positive: the head is UP;
- z (TZ) positive: farther from the camera;
- yaw positive: the wearer turns to their RIGHT;
- pitch positive: the wearer looks UP;
- roll positive: the head tilts to the wearer's LEFT (left ear toward the
  left shoulder).

Position. The default frame here, ``"tracker-pt"``, is that: headplod's world
frame (the left camera's OpenCV frame: x right, y DOWN, z forward) with y
negated, in cm. ``"opencv"`` (``headplod track --udp-axes opencv``) keeps y
down, which is what opentrack's ArUco tracker sends
(``tracker-aruco/ftnoir_tracker_aruco.cpp``: ``tvec * .1`` of
``cv::solvePnP``) and what headplod sent before. The JSON pose records are not
affected: they keep the contract's frame (``docs/contract.md``, y down)
and P1.

The point sent is the head's pivot, not P1: ``P1 + axes^T @ pivot_mm`` with
``pivot_mm`` in the head frame (x along Ξ toward P0, the wearer's left; y
along Ψ, up; z along V, forward; for the default marker model this is the
glasses frame G of the contract). That plays the part of tracker-pt's
``t_MH``: a head turning about its neck then leaves x, y and z still instead
of swinging them round the neck. :data:`DEFAULT_PIVOT_MM` is a typical head;
``headplod pivot`` measures it (:mod:`headplod.live.pivot`).

Angles. A head facing the cameras (V along the world's -z, Ψ up = world -y,
Ξ the wearer's left = world +x) has yaw = pitch = roll = 0. The angles are
intrinsic Tait-Bryan angles in the order yaw, then pitch, then roll (the
"aerospace" z-y'-x'' sequence), with the signs above:

- yaw: rotation about the head's up axis; positive when the wearer turns to
  their RIGHT (V moves toward the world's -x, the cameras' left);
- pitch: about the yawed lateral axis; positive when the wearer looks UP
  (V moves toward the world's -y);
- roll: about the yawed and pitched forward axis V; positive when the head
  tilts to the wearer's LEFT (left ear toward the left shoulder, the top of
  the head toward the world's +x; clockwise as the cameras see it).

Written as a matrix: with the user frame F = (forward, left, up) =
(-z, +x, -y) of the world, the head axes expressed in F, columns (V, Ξ, Ψ),
are ``Rz(-yaw) @ Ry(-pitch) @ Rx(-roll)`` (right-handed elementary
rotations). This is the decomposition of opentrack's ``compat/euler.cpp``
(``euler_to_rmat`` negates all three angles and builds Rz Ry Rx;
``rmat_to_euler`` is the inverse used here), and it gives the three signs
tracker-pt gives (above); ``tracker-steamvr/steamvr.cpp`` and
``tracker-aruco/ftnoir_tracker_aruco.cpp`` agree on them. The angles do not
depend on the position frame chosen. Ranges: yaw and roll in (-180, 180],
pitch in [-90, 90]; at pitch ±90° roll is reported as 0.

Recentring (``centre=`` of :func:`opentrack_values`; ``headplod track
--udp``: the key ``c``, ``kill -USR1 PID``, ``--recentre-at-start``). A
reference pose A becomes the zero of what is sent: A itself gives six zeros,
and a later pose B gives

- position: B's point sent minus A's, in the position frame chosen
  (``tracker-pt`` or ``opencv``, cm): the difference in opentrack's axes, as
  opentrack's own centring subtracts the centre's TX, TY, TZ
  (``logic/pipeline.cpp``, ``pipeline::apply_center``);
- angles: the yaw, pitch and roll (as above) of B's head axes expressed in
  A's head frame, ``M_A^T M_B``: the turn from A, about A's own axes. This is
  opentrack's "VR 360" centring (the centre's quaternion inverted and
  composed); for a turn about one axis it is the difference of the angles
  (opentrack's "point" centring), and unlike that difference it stays a pure
  yaw when A looks down at a laptop and the head then turns left or right.

The JSON pose records are not recentred: they keep the contract's frames.
"""
from __future__ import annotations

import ipaddress
import math
import re
import struct
from typing import Sequence

import numpy as np
from ..tol import tol

OPENTRACK_PORT = 4242
"""opentrack's default UDP input port (``tracker-udp/ftnoir_tracker_udp.h``)."""

#: Position frames of the UDP output: ``"tracker-pt"`` (x right, y UP, z away from the camera, as opentrack's
#: point tracker; the default) and ``"opencv"`` (the contract's world frame, y DOWN, as opentrack's ArUco tracker).
OPENTRACK_FRAMES = ("tracker-pt", "opencv")

#: The head's pivot (the neck) from the bridge of the glasses, in the head frame (x along Ξ, the wearer's left;
#: y along Ψ, up; z along V, forward), mm. No lateral offset; 80 mm down and 90 mm back: the head's yaw axis
#: (the atlanto-axial joint, C1-C2) runs about 80-100 mm behind the eyes, and its pitch axis (the
#: atlanto-occipital joints, just below and in front of the ear canal) some 60-90 mm below the eyes' level,
#: the bridge of glasses sitting a few mm in front of and above the eyes; one point stands for both axes.
#: The synthetic renderer's heads turn about the same point (``synthetic/scenes.py`` ``NECK_PIVOT_HEAD_MM``).
#: Heads differ by a couple of centimetres: ``headplod pivot`` measures the wearer's.
DEFAULT_PIVOT_MM = (0.0, -80.0, -90.0)

_PACKET = struct.Struct("<6d")
OPENTRACK_PACKET_BYTES = _PACKET.size  # 48

# Columns: the user frame F = (forward, left, up) in world coordinates.
_F_IN_WORLD = np.array([[0.0, 1.0, 0.0],
                        [0.0, 0.0, -1.0],
                        [-1.0, 0.0, 0.0]])


def _check_pose(position_mm, axes) -> tuple[np.ndarray, np.ndarray]:
    p = np.asarray(position_mm, dtype=float)
    a = np.asarray(axes, dtype=float)
    if p.shape != (3,):
        raise ValueError(f"position_mm: expected shape (3,), got {p.shape}")
    if a.shape != (3, 3):
        raise ValueError(f"axes: expected shape (3, 3) (rows Ξ, Ψ, V), got {a.shape}")
    return p, a


def check_pivot_mm(pivot_mm) -> np.ndarray:
    """A pivot as a (3,) float array, checked: finite, within 300 mm of the bridge.

    Raises
    ------
    ValueError
        On a wrong shape, a non-finite value or a pivot farther than 300 mm
        (a head is not that big: metres or a typo).
    """
    c = np.asarray(pivot_mm, dtype=float)
    if c.shape != (3,):
        raise ValueError(f"pivot: expected 3 values X,Y,Z in mm, got shape {c.shape}")
    if not np.all(np.isfinite(c)):
        raise ValueError(f"pivot: expected finite values in mm, got {c.tolist()}")
    if np.linalg.norm(c) > 300.0:
        raise ValueError(f"pivot: {c.tolist()} mm is {np.linalg.norm(c):.0f} mm from the bridge, expected "
                         "within 300 mm (a head's neck lies ~120 mm from it; mm, not cm or m?)")
    return c


def pivot_position_mm(position_mm, axes, pivot_mm) -> np.ndarray:
    """The pivot's position in the world frame: ``P1 + axes^T @ pivot_mm``.

    Parameters
    ----------
    position_mm : (3,) array_like of float
        P1, world frame, mm.
    axes : (3, 3) array_like of float
        Rows Ξ, Ψ, V in the world frame.
    pivot_mm : (3,) array_like of float
        The pivot in the head frame (coordinates along Ξ, Ψ, V), mm.

    Returns
    -------
    (3,) ndarray of float
        World frame, mm.
    """
    p, a = _check_pose(position_mm, axes)
    return p + a.T @ np.asarray(pivot_mm, dtype=float)


def _attitude(axes: np.ndarray) -> np.ndarray:
    """The head axes (forward V, left Ξ, up Ψ) expressed in the user frame F: ``M = F^T [V Ξ Ψ]``."""
    xi, psi, v = axes
    return _F_IN_WORLD.T @ np.column_stack([v, xi, psi])


def _angles_deg(M: np.ndarray) -> tuple[float, float, float]:
    """Yaw, pitch, roll (degrees, the module's convention) of an attitude ``M`` (:func:`_attitude`)."""
    cos_pitch = math.hypot(M[0, 0], M[1, 0])
    if cos_pitch > tol.small:
        yaw = -math.atan2(M[1, 0], M[0, 0])
        pitch = math.atan2(M[2, 0], cos_pitch)
        roll = -math.atan2(M[2, 1], M[2, 2])
    else:  # looking straight up or down: yaw and roll share an axis; put it all in yaw
        pitch = math.atan2(M[2, 0], cos_pitch)
        yaw = -math.atan2(-M[0, 1], M[1, 1])
        roll = 0.0
    return math.degrees(yaw), math.degrees(pitch), math.degrees(roll)


def _point_sent_mm(p: np.ndarray, a: np.ndarray, pivot_mm, frame: str) -> np.ndarray:
    """The pivot's position in the position frame ``frame``, mm."""
    q = pivot_position_mm(p, a, pivot_mm)
    return q * np.array([1.0, -1.0, 1.0]) if frame == "tracker-pt" else q


def opentrack_values(position_mm, axes, pivot_mm=(0.0, 0.0, 0.0), frame: str = "tracker-pt",
                     centre=None) -> tuple[float, float, float, float, float, float]:
    """The six values opentrack expects for a head pose.

    Parameters
    ----------
    position_mm : (3,) array_like of float
        Head position (P1), world frame (left camera, OpenCV: x right, y down,
        z forward), mm.
    axes : (3, 3) array_like of float
        Rows Ξ, Ψ, V: unit vectors in the world frame (the contract's pose
        axes; a proper rotation).
    pivot_mm : (3,) array_like of float
        The point whose position is sent, in the head frame (along Ξ, Ψ, V),
        mm; (0, 0, 0) sends P1. :data:`DEFAULT_PIVOT_MM` is a head's neck.
    frame : {"tracker-pt", "opencv"}
        The position's axes: ``"tracker-pt"`` (x right, y up, z away from
        the camera: opentrack's point tracker) or ``"opencv"`` (y down).
    centre : (position_mm, axes), optional
        A reference pose (P1 and axes, as the first two parameters) that is
        the zero: the values are then this pose relative to it (module
        docstring, "Recentring"); ``opentrack_values(*centre, centre=centre)``
        is six zeros. Default: none, the values are the pose's own.

    Returns
    -------
    x_cm, y_cm, z_cm : float
        The pivot's position, cm, in ``frame`` (relative to the centre's).
    yaw_deg, pitch_deg, roll_deg : float
        Intrinsic yaw-pitch-roll in degrees, zero facing the cameras (or at
        the centre's attitude); yaw positive turning to the wearer's right,
        pitch positive looking up, roll positive tilting to the wearer's
        left. See the module docstring for the definition and its sources.

    Raises
    ------
    ValueError
        On a wrong shape or an unknown frame.
    """
    if frame not in OPENTRACK_FRAMES:
        raise ValueError(f"frame: expected one of {', '.join(OPENTRACK_FRAMES)}, got {frame!r}")
    p, a = _check_pose(position_mm, axes)
    M = _attitude(a)
    q = _point_sent_mm(p, a, pivot_mm, frame)
    if centre is not None:
        cp, ca = _check_pose(*centre)
        M = _attitude(ca).T @ M                      # B's head axes in A's head frame
        q = q - _point_sent_mm(cp, ca, pivot_mm, frame)
    x_cm, y_cm, z_cm = (float(c) / 10.0 for c in q)
    return (x_cm, y_cm, z_cm) + _angles_deg(M)


def axes_from_opentrack(yaw_deg: float, pitch_deg: float, roll_deg: float) -> np.ndarray:
    """Head axes for opentrack angles; the inverse of :func:`opentrack_values`.

    Parameters
    ----------
    yaw_deg, pitch_deg, roll_deg : float
        Angles in degrees, in :func:`opentrack_values`'s convention.

    Returns
    -------
    axes : (3, 3) ndarray of float
        Rows Ξ, Ψ, V in the world frame; a proper rotation.
    """
    a, b, c = (-math.radians(yaw_deg), -math.radians(pitch_deg), -math.radians(roll_deg))
    ca, sa, cb, sb, cc, sc = math.cos(a), math.sin(a), math.cos(b), math.sin(b), math.cos(c), math.sin(c)
    Rz = np.array([[ca, -sa, 0.0], [sa, ca, 0.0], [0.0, 0.0, 1.0]])
    Ry = np.array([[cb, 0.0, sb], [0.0, 1.0, 0.0], [-sb, 0.0, cb]])
    Rx = np.array([[1.0, 0.0, 0.0], [0.0, cc, -sc], [0.0, sc, cc]])
    v, xi, psi = (_F_IN_WORLD @ (Rz @ Ry @ Rx)).T
    return np.array([xi, psi, v])


def encode_opentrack(values: Sequence[float]) -> bytes:
    """Pack six values into an opentrack UDP datagram.

    Parameters
    ----------
    values : sequence of 6 float
        ``x_cm, y_cm, z_cm, yaw_deg, pitch_deg, roll_deg`` (as returned by
        :func:`opentrack_values`).

    Returns
    -------
    bytes
        48 bytes: six little-endian IEEE-754 doubles (``struct`` format ``'<6d'``).

    Raises
    ------
    ValueError
        When there are not six values or one is not finite (opentrack would
        drop the datagram anyway).
    """
    vals = [float(x) for x in values]
    if len(vals) != 6:
        raise ValueError(f"expected 6 values (x, y, z cm, yaw, pitch, roll deg), got {len(vals)}")
    if not all(math.isfinite(x) for x in vals):
        raise ValueError(f"values must be finite, got {vals}")
    return _PACKET.pack(*vals)


def decode_opentrack(data: bytes) -> tuple[float, float, float, float, float, float]:
    """Unpack an opentrack UDP datagram made by :func:`encode_opentrack`.

    Parameters
    ----------
    data : bytes
        Exactly 48 bytes.

    Returns
    -------
    x_cm, y_cm, z_cm, yaw_deg, pitch_deg, roll_deg : float

    Raises
    ------
    ValueError
        When ``data`` is not 48 bytes long.
    """
    if len(data) != _PACKET.size:
        raise ValueError(f"an opentrack datagram is {_PACKET.size} bytes, got {len(data)}")
    return _PACKET.unpack(data)


#: Where ``--udp PORT`` sends: this machine (opentrack running beside the tracker).
LOCAL_HOST = "127.0.0.1"

#: The forms ``--udp`` takes, for the message that refuses another.
ADDRESS_FORMS = "HOST:PORT, [IPv6]:PORT or PORT (e.g. 127.0.0.1:4242, gamepc:4242, [::1]:4242, 4242)"

#: A host name: dot-separated labels of letters, digits and inner hyphens (RFC 1123), at most 253 characters.
_HOST_NAME = re.compile(r"^(?=.{1,253}\.?$)[A-Za-z0-9]([A-Za-z0-9-]{0,61}[A-Za-z0-9])?"
                        r"(\.[A-Za-z0-9]([A-Za-z0-9-]{0,61}[A-Za-z0-9])?)*\.?$")


def parse_host_port(text: str, default_port: int = OPENTRACK_PORT) -> tuple[str, int]:
    """Split ``"HOST:PORT"``, ``"HOST"`` or ``"PORT"`` into ``(host, port)``.

    A number alone is a port on this machine (``"4242"`` -> ``("127.0.0.1", 4242)``). IPv6 addresses are
    written ``[::1]:4242``; a bare address with several colons (``::1``) is taken as a host without a port.
    The host must be a host name (letters, digits, hyphens and dots), an IPv4 address or an IPv6 address.

    Parameters
    ----------
    text : str
        The address as given on a command line.
    default_port : int
        The port when ``text`` has none (opentrack's 4242).

    Returns
    -------
    host : str
    port : int
        In 1..65535.

    Raises
    ------
    ValueError
        On an empty or malformed host (naming :data:`ADDRESS_FORMS`), a port that is not an integer or is out
        of range, or an unclosed ``[``.
    """
    s = str(text).strip()
    port_text = None
    if s.isdigit():                                     # "4242": a port, on this machine
        host, port_text = LOCAL_HOST, s
    elif s.startswith("["):
        end = s.find("]")
        if end < 0:
            raise ValueError(f"bad address {text!r}: '[' without ']'; expected {ADDRESS_FORMS}")
        host, rest = s[1:end], s[end + 1:]
        if rest:
            if not rest.startswith(":"):
                raise ValueError(f"bad address {text!r}: expected ':PORT' after ']', got {rest!r}")
            port_text = rest[1:]
        _check_ipv6(host, text, "an IPv6 address")
    elif s.count(":") == 1:
        host, port_text = s.split(":")
    else:
        host = s
    host = host.strip()
    if not host:
        raise ValueError(f"bad address {text!r}: empty host; expected {ADDRESS_FORMS}")
    if ":" in host:                                     # several colons, no brackets: an IPv6 address or nothing
        _check_ipv6(host, text, "a host name or an IP address")
    elif not _HOST_NAME.match(host) or (host.replace(".", "").isdigit() and not _is_ipv4(host)):
        raise ValueError(f"bad address {text!r}: {host!r} is not a host name or an IP address; "
                         f"expected {ADDRESS_FORMS}")
    if port_text is None:
        return host, int(default_port)
    try:
        port = int(port_text.strip())
    except ValueError:
        raise ValueError(f"bad port in {text!r}: expected an integer 1..65535, got {port_text!r}") from None
    if not 1 <= port <= 65535:
        raise ValueError(f"bad port in {text!r}: expected 1..65535, got {port}")
    return host, port


def _is_ipv4(host: str) -> bool:
    try:
        ipaddress.IPv4Address(host)
    except ValueError:
        return False
    return True


def _check_ipv6(host: str, text: str, expected: str) -> None:
    try:
        ipaddress.IPv6Address(host)
    except ValueError:
        raise ValueError(f"bad address {text!r}: {host!r} is not {expected}; expected {ADDRESS_FORMS}") from None
