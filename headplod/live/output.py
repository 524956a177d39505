"""Outputs to other programs: opentrack's UDP protocol, and a live status line.

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
affected: they keep the contract's frame (``spec/conventions.md``, y down)
and P1.

The point sent is the head's pivot, not P1: ``P1 + axes^T @ pivot_mm`` with
``pivot_mm`` in the head frame (x along Ξ toward P0, the wearer's left; y
along Ψ, up; z along V, forward; for the default marker model this is the
glasses frame G of the contract). That plays the part of tracker-pt's
``t_MH``: a head turning about its neck then leaves x, y and z still instead
of swinging them by ~10 cm. :data:`DEFAULT_PIVOT_MM` is a typical head;
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

A record with ``ok`` false sends nothing: opentrack keeps the last pose it
received (it also ignores datagrams holding NaN), which is the right
behaviour for a frame without a trustworthy pose. A datagram the system
refuses to send (a broadcast address without permission, an unreachable
network) is counted in :attr:`OpentrackSender.failed`, its first and last
errors kept; the socket is connected, so that opentrack not listening (an
ICMP "port unreachable") shows as "opentrack not listening on HOST:PORT".
:class:`StatusLine` shows them, ``headplod track`` prints a line as sending
fails or recovers (:meth:`OpentrackSender.news`) and a summary at the end.
"""
from __future__ import annotations

import math
import re
import socket
import struct
import sys
import time
from collections import deque
from typing import Mapping, Sequence, TextIO

import numpy as np

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


def opentrack_values(position_mm, axes, pivot_mm=(0.0, 0.0, 0.0),
                     frame: str = "tracker-pt") -> tuple[float, float, float, float, float, float]:
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

    Returns
    -------
    x_cm, y_cm, z_cm : float
        The pivot's position, cm, in ``frame``.
    yaw_deg, pitch_deg, roll_deg : float
        Intrinsic yaw-pitch-roll in degrees, zero facing the cameras; yaw
        positive turning to the wearer's right, pitch positive looking up,
        roll positive tilting to the wearer's left. See the module docstring
        for the definition and its sources.

    Raises
    ------
    ValueError
        On a wrong shape or an unknown frame.
    """
    if frame not in OPENTRACK_FRAMES:
        raise ValueError(f"frame: expected one of {', '.join(OPENTRACK_FRAMES)}, got {frame!r}")
    p, a = _check_pose(position_mm, axes)
    xi, psi, v = a
    # Head axes (forward V, left Ξ, up Ψ) expressed in F: M = F^T [V Ξ Ψ].
    M = _F_IN_WORLD.T @ np.column_stack([v, xi, psi])
    cos_pitch = math.hypot(M[0, 0], M[1, 0])
    if cos_pitch > 1e-9:
        yaw = -math.atan2(M[1, 0], M[0, 0])
        pitch = math.atan2(M[2, 0], cos_pitch)
        roll = -math.atan2(M[2, 1], M[2, 2])
    else:  # looking straight up or down: yaw and roll share an axis; put it all in yaw
        pitch = math.atan2(M[2, 0], cos_pitch)
        yaw = -math.atan2(-M[0, 1], M[1, 1])
        roll = 0.0
    q = pivot_position_mm(p, a, pivot_mm)
    if frame == "tracker-pt":
        q = q * np.array([1.0, -1.0, 1.0])
    x_cm, y_cm, z_cm = (float(c) / 10.0 for c in q)
    return (x_cm, y_cm, z_cm, math.degrees(yaw), math.degrees(pitch), math.degrees(roll))


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


def parse_host_port(text: str, default_port: int = OPENTRACK_PORT) -> tuple[str, int]:
    """Split ``"HOST:PORT"`` or ``"HOST"`` into ``(host, port)``.

    IPv6 addresses are written ``[::1]:4242``; a bare address with several
    colons (``::1``) is taken as a host without a port.

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
        On an empty host, a port that is not an integer or is out of range,
        or an unclosed ``[``.
    """
    s = str(text).strip()
    port_text = None
    if s.startswith("["):
        end = s.find("]")
        if end < 0:
            raise ValueError(f"bad address {text!r}: '[' without ']' (write IPv6 as [::1]:4242)")
        host, rest = s[1:end], s[end + 1:]
        if rest:
            if not rest.startswith(":"):
                raise ValueError(f"bad address {text!r}: expected ':PORT' after ']', got {rest!r}")
            port_text = rest[1:]
    elif s.count(":") == 1:
        host, port_text = s.split(":")
    else:
        host = s
    host = host.strip()
    if not host:
        raise ValueError(f"bad address {text!r}: empty host (expected HOST or HOST:PORT, e.g. 127.0.0.1:4242)")
    if port_text is None:
        return host, int(default_port)
    try:
        port = int(port_text.strip())
    except ValueError:
        raise ValueError(f"bad port in {text!r}: expected an integer 1..65535, got {port_text!r}") from None
    if not 1 <= port <= 65535:
        raise ValueError(f"bad port in {text!r}: expected 1..65535, got {port}")
    return host, port


class OpentrackSender:
    """Send pose records to opentrack's "UDP over network" input.

    Parameters
    ----------
    host : str
        Host name or address of the machine running opentrack. It is
        resolved once, here.
    port : int
        opentrack's UDP port (default 4242).
    pivot_mm : (3,) array_like of float
        The point sent, in the head frame (along Ξ, Ψ, V), mm (default
        :data:`DEFAULT_PIVOT_MM`, a head's neck; (0, 0, 0) sends P1).
    frame : {"tracker-pt", "opencv"}
        The position's axes (default ``"tracker-pt"``: y up).

    Attributes
    ----------
    sent : int
        Datagrams sent.
    skipped : int
        Records not sent (``ok`` false, or a non-finite pose).
    failed : int
        Datagrams the socket refused (a send that failed returns False; the
        caller keeps running).
    refused : int
        Of those, how many for an ICMP "port unreachable": nothing listens
        on the port (opentrack not running, or its input not started).
    first_error, last_error : str or None
        The first and the last socket error, ``"HOST:PORT: message"``.

    Notes
    -----
    The socket is connected to opentrack's address, so that the system
    reports an ICMP "port unreachable" for a datagram as
    ``ConnectionRefusedError`` on the next send: :attr:`listening` is then
    False, and :meth:`news` says so as it happens. An address that cannot
    be reached yet (a network not up) is retried at each send.

    Examples
    --------
    >>> with OpentrackSender("127.0.0.1") as out:     # doctest: +SKIP
    ...     for record in records:
    ...         out.send(record)
    """

    def __init__(self, host: str, port: int = OPENTRACK_PORT, *, pivot_mm=DEFAULT_PIVOT_MM,
                 frame: str = "tracker-pt"):
        if frame not in OPENTRACK_FRAMES:
            raise ValueError(f"OpentrackSender: frame must be one of {', '.join(OPENTRACK_FRAMES)}, got {frame!r}")
        self.pivot_mm = check_pivot_mm(pivot_mm)
        self.frame = frame
        if not host:
            raise ValueError("OpentrackSender: empty host")
        if not 1 <= int(port) <= 65535:
            raise ValueError(f"OpentrackSender: port must be 1..65535, got {port}")
        try:
            infos = socket.getaddrinfo(host, int(port), type=socket.SOCK_DGRAM)
        except socket.gaierror as e:
            raise ValueError(f"OpentrackSender: cannot resolve host {host!r}: {e}") from None
        family, type_, proto, _, self.address = infos[0]
        self.host, self.port = host, int(port)
        self._sock = socket.socket(family, type_, proto)
        self.sent = 0
        self.skipped = 0
        self.failed = 0
        self.refused = 0
        self.first_error: str | None = None
        self.last_error: str | None = None
        self._attempts = 0
        self._last_refused = self._last_failed = -10 ** 9     # attempt numbers
        self._said: str | None = None                          # the state :meth:`news` last reported
        self._connected = False
        try:
            self._sock.connect(self.address)        # a UDP connect sends nothing; an error is met again at send
            self._connected = True
        except OSError:
            pass

    def _connect(self) -> bool:
        """Connect the socket to opentrack's address; False on an error (a datagram not sent, kept)."""
        try:
            self._sock.connect(self.address)
        except OSError as e:
            self._fail(e)
            return False
        self._connected = True
        return True

    def _fail(self, e: OSError) -> None:
        self.failed += 1
        self._last_failed = self._attempts
        if isinstance(e, ConnectionRefusedError):
            self.refused += 1
            self._last_refused = self._attempts
        self.last_error = f"{self.host}:{self.port}: {e}"
        if self.first_error is None:
            self.first_error = self.last_error

    @property
    def listening(self) -> bool:
        """False while opentrack's port answers "unreachable" (a refusal within the last 3 sends)."""
        return self._attempts - self._last_refused > 3

    def state(self) -> str | None:
        """What is wrong with sending now, in a few words, or None when the last sends went through."""
        if not self.listening:
            return f"opentrack not listening on {self.host}:{self.port}"
        if self._attempts - self._last_failed <= 3:
            return f"sending to {self.host}:{self.port} fails: {self.last_error.split(': ', 1)[-1]}"
        return None

    def news(self) -> str | None:
        """A line when sending went wrong, or right again, since the last call (None when nothing changed)."""
        now = self.state()
        if now == self._said:
            return None
        before, self._said = self._said, now
        if now is not None:
            return f"udp: {now}; poses are not received (the run goes on)"
        return f"udp: {self.host}:{self.port} receives the poses again ({self.failed} not sent before)"

    def send(self, record: Mapping) -> bool:
        """Send one pose record.

        Parameters
        ----------
        record : mapping
            A pose record as the tracker writes it: keys ``ok``, ``position``
            ((3,) mm, world frame) and ``axes`` ((3, 3), rows Ξ, Ψ, V).

        Returns
        -------
        bool
            True when a datagram was sent. False, and nothing sent, for a
            record with ``ok`` false or a missing or non-finite pose, or when
            the socket reports an error (kept in ``last_error``).
        """
        if self._sock is None:
            raise ValueError("OpentrackSender: send() after close()")
        if not record.get("ok") or record.get("position") is None or record.get("axes") is None:
            self.skipped += 1
            return False
        try:
            packet = encode_opentrack(opentrack_values(record["position"], record["axes"], self.pivot_mm,
                                                       self.frame))
        except ValueError:
            self.skipped += 1
            return False
        self._attempts += 1
        if not self._connected and not self._connect():
            return False
        try:
            self._sock.send(packet)
        except OSError as e:
            self._fail(e)
            return False
        self.sent += 1
        return True

    def failure_summary(self) -> str | None:
        """One line on the sends that failed, or None when none did.

        Examples
        --------
        ``"udp: 120 of 120 datagrams not sent; first: 255.255.255.255:4242: [Errno 13] Permission denied"``
        """
        if not self.failed:
            return None
        line = f"udp: {self.failed} of {self.failed + self.sent} datagrams not sent; first: {self.first_error}"
        if self.refused:
            line += f"; {self.refused} refused: opentrack was not listening on {self.host}:{self.port}"
        if self.last_error != self.first_error:
            line += f"; last: {self.last_error}"
        return line

    def close(self) -> None:
        """Close the socket (idempotent)."""
        if self._sock is not None:
            self._sock.close()
            self._sock = None

    def __enter__(self) -> "OpentrackSender":
        return self

    def __exit__(self, *exc) -> None:
        self.close()


def short_rig_message(message: str, width: int = 90) -> str:
    """A tracker's ``rig_message`` shortened for a status line.

    Drops the leading ``"rig.yaml: "``, long parenthesized explanations and
    the ± of the time offset. When that is still longer than ``width`` and
    the message recommends recalibrating, the recommendation is what is
    kept; then trailing "; " clauses are dropped until it fits (a single
    clause too long is cut at a word, ending in "…"). The full
    text is in the records (``rig_message``) and printed at the end of
    ``headplod track``.

    Examples
    --------
    >>> short_rig_message("rig.yaml: right camera turned ~0.42°, baseline x1.021, "
    ...                   "time offset 7.9 ms ±0.5; refining")
    'right camera turned ~0.42°, baseline x1.021, time offset 7.9 ms; refining'
    """
    text = re.sub(r"^rig\.yaml:\s*", "", str(message).strip())
    text = re.sub(r"\s*\([^()]{13,}\)", "", text)
    text = re.sub(r"\s*±\s*[0-9.]+", "", text)
    text = re.sub(r"\s+", " ", text).strip()
    if len(text) > width and "recalibrate:" in text:
        text = text[text.index("recalibrate:"):]
    parts = text.split("; ")
    while len(parts) > 1 and len("; ".join(parts)) > width:
        parts.pop()                                   # the least important clause is the last
    text = "; ".join(parts)
    if len(text) > width:
        cut = text[:max(width - 1, 1)]
        text = (cut.rsplit(" ", 1)[0] if " " in cut else cut).rstrip(" ,;") + "…"
    return text


class StatusLine:
    """A one-line live summary of tracking, for a terminal.

    Call :meth:`update` once per frame. At most every ``every_s`` seconds the
    line is written: on a terminal it overwrites itself (``'\\r'``), otherwise
    (a pipe, a log file) each rendering is its own line. Example::

        59.8 Hz | latency 14.2/19.0 ms (med/p95) | skew 0.3/1.1 ms (med/max) | dropped 2 | ok 97.5% | last failure: ...
          | rig: right camera turned ~0.42°, baseline x1.021; refining

    Parameters
    ----------
    stream : text stream
        Where to write (default standard error).
    every_s : float
        Minimum interval between two renderings, s (> 0).
    window_s : float
        Length of the sliding window for the rate, latency and skew, s.
    sender : OpentrackSender, optional
        When given, sends that failed are shown: ``udp: N not sent (first:
        ...)``.

    Notes
    -----
    Rate: (frames in the window - 1) / (time between the first and the last),
    Hz. Latency (capture time to pose, ms; a live camera's capture time is the
    driver's buffer timestamp or the grab time, see
    :data:`headplod.live.loop.LATENCY_FROM`): median and 95th percentile over
    the window. Skew (left/right capture-time difference, ms): median and
    maximum of its absolute value over the window. Dropped frames, frames
    dropped for a zero or non-increasing time (``bad time N (first: ...)``,
    shown once there is one), % ok and the last failure reason are over the
    whole run. The rig part is the last record's
    ``rig_message`` (the tracker's online refinement of ``rig.yaml``),
    shortened by :func:`short_rig_message`.
    """

    def __init__(self, stream: TextIO | None = None, every_s: float = 1.0, window_s: float = 5.0,
                 sender: OpentrackSender | None = None):
        if not every_s > 0:
            raise ValueError(f"every_s must be > 0, got {every_s}")
        if not window_s > 0:
            raise ValueError(f"window_s must be > 0, got {window_s}")
        self.stream = sys.stderr if stream is None else stream
        self.every_s = float(every_s)
        self.window_s = float(window_s)
        self.sender = sender
        try:
            self._tty = bool(self.stream.isatty())
        except (AttributeError, ValueError):
            self._tty = False
        self._times: deque[float] = deque()
        self._latency: deque[tuple[float, float]] = deque()
        self._skew: deque[tuple[float, float]] = deque()
        self.frames = 0
        self.ok = 0
        self.failed = 0
        self.dropped = 0
        self.time_dropped = 0
        self.time_dropped_first: str | None = None
        self.last_failure: str | None = None
        self.internal_errors = 0
        self.rig_message: str | None = None
        self._last_render: float | None = None
        self._last_len = 0
        self._rendered = False
        self._closed = False

    def update(self, record: Mapping, latency_ms: float | None = None, skew_ms: float | None = None,
               dropped: int = 0, now: float | None = None, time_dropped: int | None = None,
               time_dropped_first: str | None = None) -> str | None:
        """Account for one frame, and write the line when it is due.

        Parameters
        ----------
        record : mapping
            The frame's pose record (``ok``, ``reason``, optional
            ``rig_message``: kept until a later record brings another).
        latency_ms : float, optional
            Capture time (a live camera's: the driver's buffer timestamp or
            the grab time, not mid-exposure) to pose, ms.
        skew_ms : float, optional
            Left minus right capture time, ms (its absolute value is used).
        dropped : int
            Frames dropped since the previous update.
        time_dropped : int, optional
            Frames dropped so far for a zero or non-increasing time (a
            running count, not an increment); shown with the first one.
        time_dropped_first : str, optional
            The first of them.
        now : float, optional
            The current time, s, on any monotonic clock (default
            ``time.monotonic()``).

        Returns
        -------
        str or None
            The line when it was written, else None.
        """
        now = time.monotonic() if now is None else float(now)
        self.frames += 1
        self.dropped += int(dropped)
        if time_dropped is not None:
            self.time_dropped = int(time_dropped)
            self.time_dropped_first = time_dropped_first
        if record.get("ok"):
            self.ok += 1
        else:
            self.failed += 1
            self.last_failure = record.get("reason") or "no reason given"
            self.internal_errors += self.last_failure.startswith("internal error")
        if record.get("rig_message"):
            self.rig_message = str(record["rig_message"])
        self._times.append(now)
        if latency_ms is not None and math.isfinite(latency_ms):
            self._latency.append((now, float(latency_ms)))
        if skew_ms is not None and math.isfinite(skew_ms):
            self._skew.append((now, abs(float(skew_ms))))
        self._expire(now)
        if self._last_render is None:
            self._last_render = now
            return None
        if now - self._last_render < self.every_s:
            return None
        self._last_render = now
        line = self.render()
        self._write(line)
        return line

    def _expire(self, now: float) -> None:
        start = now - self.window_s
        while self._times and self._times[0] < start:
            self._times.popleft()
        for q in (self._latency, self._skew):
            while q and q[0][0] < start:
                q.popleft()

    def rate_hz(self) -> float | None:
        """Frame rate over the sliding window, Hz; None with fewer than two frames."""
        if len(self._times) < 2 or self._times[-1] <= self._times[0]:
            return None
        return (len(self._times) - 1) / (self._times[-1] - self._times[0])

    def summary(self) -> dict:
        """The current statistics.

        Returns
        -------
        dict
            ``frames``, ``ok``, ``failed``, ``dropped`` (counts over the run),
            ``time_dropped`` and ``time_dropped_first`` (frames dropped for
            a zero or non-increasing time, and the first),
            ``ok_percent``, ``rate_hz``, ``latency_ms_median``,
            ``latency_ms_p95``, ``skew_ms_median``, ``skew_ms_max`` (over the
            window; None when there is no data), ``last_failure`` and
            ``rig_message`` (the last record's, in full), ``udp_failed``
            (datagrams not sent; None without a sender),
            ``udp_first_error``, ``udp_state`` (what is wrong with sending
            now, e.g. "opentrack not listening on HOST:PORT"; None when the
            last sends went through) and ``internal_errors`` (frames whose
            reason is an internal error).
        """
        lat = np.array([v for _, v in self._latency])
        skew = np.array([v for _, v in self._skew])
        return {
            "frames": self.frames,
            "ok": self.ok,
            "failed": self.failed,
            "dropped": self.dropped,
            "time_dropped": self.time_dropped,
            "time_dropped_first": self.time_dropped_first,
            "ok_percent": 100.0 * self.ok / self.frames if self.frames else None,
            "rate_hz": self.rate_hz(),
            "latency_ms_median": float(np.median(lat)) if lat.size else None,
            "latency_ms_p95": float(np.percentile(lat, 95)) if lat.size else None,
            "skew_ms_median": float(np.median(skew)) if skew.size else None,
            "skew_ms_max": float(skew.max()) if skew.size else None,
            "last_failure": self.last_failure,
            "rig_message": self.rig_message,
            "udp_failed": None if self.sender is None else self.sender.failed,
            "udp_first_error": None if self.sender is None else self.sender.first_error,
            "udp_state": None if self.sender is None else self.sender.state(),
            "internal_errors": self.internal_errors,
        }

    def render(self) -> str:
        """The status line for the current statistics (no newline, no ``'\\r'``)."""
        s = self.summary()

        def num(x, fmt="{:.1f}"):
            return "--" if x is None else fmt.format(x)

        parts = [f"{num(s['rate_hz'])} Hz",
                 f"latency {num(s['latency_ms_median'])}/{num(s['latency_ms_p95'])} ms (med/p95)",
                 f"skew {num(s['skew_ms_median'])}/{num(s['skew_ms_max'])} ms (med/max)",
                 f"dropped {s['dropped']}",
                 *([f"bad time {s['time_dropped']} (first: {s['time_dropped_first']})"]
                   if s["time_dropped"] else []),
                 f"ok {num(s['ok_percent'])}%",
                 *([f"internal errors {s['internal_errors']}"] if s["internal_errors"] else [])]
        if s["udp_state"]:
            parts.append(f"udp: {s['udp_state']} ({s['udp_failed']} not sent)")
        elif s["udp_failed"]:
            parts.append(f"udp: {s['udp_failed']} not sent (first: {s['udp_first_error']})")
        if s["last_failure"]:
            parts.append(f"last failure: {s['last_failure']}")
        if s["rig_message"]:
            parts.append("rig: " + short_rig_message(s["rig_message"]))
        return " | ".join(parts)

    def _write(self, line: str) -> None:
        if self._tty:
            pad = max(0, self._last_len - len(line))
            self.stream.write("\r" + line + " " * pad)
            self._last_len = len(line)
        else:
            self.stream.write(line + "\n")
        self.stream.flush()
        self._rendered = True

    def close(self) -> None:
        """End the line on a terminal (a final newline); idempotent."""
        if self._closed:
            return
        self._closed = True
        if self._tty and self._rendered:
            self.stream.write("\n")
            self.stream.flush()

    def __enter__(self) -> "StatusLine":
        return self

    def __exit__(self, *exc) -> None:
        self.close()


class ForgivingStream:
    """A text stream whose writes never raise: a terminal that closed (EIO) or a pipe whose reader left
    (EPIPE) ends the messages, not the run. Wraps ``stream``; ``broken`` tells whether a write failed."""

    def __init__(self, stream: TextIO):
        self.stream = stream
        self.broken = False

    def write(self, text: str) -> int:
        if not self.broken:
            try:
                return self.stream.write(text)
            except (OSError, ValueError):          # ValueError: the stream was closed
                self.broken = True
        return len(text)

    def flush(self) -> None:
        if not self.broken:
            try:
                self.stream.flush()
            except (OSError, ValueError):
                self.broken = True

    def isatty(self) -> bool:
        try:
            return not self.broken and self.stream.isatty()
        except (OSError, ValueError, AttributeError):
            return False

    def __getattr__(self, name):
        return getattr(self.stream, name)
