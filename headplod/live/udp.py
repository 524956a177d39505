"""The opentrack sender: :class:`OpentrackSender` sends each pose record as one UDP datagram
(:mod:`headplod.live.opentrack`: the pivot's position in cm, yaw, pitch, roll in degrees, in the frame
chosen, ``"tracker-pt"`` by default) to opentrack's "UDP over network" input, and keeps count of what
the system refused.

A record with ``ok`` false sends nothing: opentrack keeps the last pose it
received (it also ignores datagrams holding NaN), which is the right
behaviour for a frame without a trustworthy pose. A datagram the system
refuses to send (a broadcast address without permission, an unreachable
network) is counted in :attr:`OpentrackSender.failed`, its first and last
errors kept; the socket is connected, so that opentrack not listening (an
ICMP "port unreachable") shows as "opentrack not listening on HOST:PORT".
:class:`~headplod.live.status.StatusLine` shows them, ``headplod track`` prints a line as sending
fails or recovers (:meth:`OpentrackSender.news`) and a summary at the end.

Recentring: :meth:`OpentrackSender.request_recentre` (safe from a signal
handler or another thread: it only counts the request) asks that the next
pose sent become the zero of what opentrack receives; :meth:`OpentrackSender.send`
applies it before it computes that pose's datagram, so a request takes effect
between frames, never within one. Asked while tracking is lost, it waits for
the next tracked frame (nothing is sent meanwhile: opentrack holds the last
pose it received). The math is :func:`~headplod.live.opentrack.opentrack_values`'
``centre``; the records written are not affected.
"""
from __future__ import annotations

import socket
from typing import Mapping

import numpy as np

from .opentrack import (DEFAULT_PIVOT_MM, OPENTRACK_FRAMES, OPENTRACK_PORT, check_pivot_mm, encode_opentrack,
                        opentrack_values)


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
    centre : (position_mm, axes) or None
        The pose that is the zero of what is sent (:meth:`request_recentre`),
        None before the first recentring.
    recentred : int
        How many times a request was applied; ``recentred_frame`` is the
        frame of the last.

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
        # As the user writes it: an IPv6 address in brackets ([::1]:4242).
        self.where = f"[{host}]:{self.port}" if ":" in host else f"{host}:{self.port}"
        self._sock = socket.socket(family, type_, proto)
        if family == socket.AF_INET:
            # A broadcast address (255.255.255.255, a subnet's .255) reaches opentrack on any machine of
            # the network; without this option the kernel refuses every datagram to it (EACCES).
            self._sock.setsockopt(socket.SOL_SOCKET, socket.SO_BROADCAST, 1)
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
        self.centre: tuple[np.ndarray, np.ndarray] | None = None
        self.recentred = 0
        self.recentred_frame: int | None = None
        self._requests = 0                                     # recentring asked (a counter: signal-safe)
        self._applied = 0                                      # ... and applied
        self._request_how: str | None = None
        self._recentre_said = 0
        self._pending_said = 0
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
        self.last_error = f"{self.where}: {e}"
        if self.first_error is None:
            self.first_error = self.last_error

    @property
    def listening(self) -> bool:
        """False while opentrack's port answers "unreachable" (a refusal within the last 3 sends)."""
        return self._attempts - self._last_refused > 3

    def state(self) -> str | None:
        """What is wrong with sending now, in a few words, or None when the last sends went through."""
        if not self.listening:
            return f"opentrack not listening on {self.where}"
        if self._attempts - self._last_failed <= 3:
            return f"sending to {self.where} fails: {self.last_error.split(': ', 1)[-1]}"
        return None

    def request_recentre(self, how: str | None = None) -> None:
        """Ask that the next pose sent become the zero (0 translation, 0 rotation) of what opentrack receives.

        Only counts the request (safe in a signal handler or another thread); :meth:`send` applies it to
        the next record with a pose. ``how`` (e.g. ``"key c"``, ``"SIGUSR1"``) is said in :meth:`news`.
        """
        self._request_how = how
        self._requests += 1

    @property
    def recentre_pending(self) -> bool:
        """True while a recentring was asked and not yet applied (no pose sent since)."""
        return self._requests != self._applied

    def news(self) -> str | None:
        """A line when sending went wrong, or right again, or the pose sent was recentred, since the last call
        (None when nothing changed; two lines, joined by a newline, when both happened)."""
        lines = []
        if self.recentred != self._recentre_said:
            self._recentre_said = self.recentred
            how = f" ({self._request_how})" if self._request_how else ""
            lines.append(f"udp: recentred{how}: the pose of frame {self.recentred_frame} is now opentrack's zero")
        elif self.recentre_pending and self._pending_said != self._requests:
            self._pending_said = self._requests
            how = f" ({self._request_how})" if self._request_how else ""
            lines.append(f"udp: recentre asked{how} while no pose is tracked: the next tracked pose becomes "
                         "opentrack's zero")
        now = self.state()
        if now != self._said:
            self._said = now
            if now is not None:
                lines.append(f"udp: {now}; poses are not received (the run goes on)")
            else:
                lines.append(f"udp: {self.where} receives the poses again ({self.failed} not sent before)")
        return "\n".join(lines) or None

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
        requests = self._requests                       # read once: a request arriving now is the next frame's
        centre = self.centre
        if requests != self._applied:
            centre = (np.array(record["position"], float), np.array(record["axes"], float))
        try:
            packet = encode_opentrack(opentrack_values(record["position"], record["axes"], self.pivot_mm,
                                                       self.frame, centre=centre))
        except ValueError:
            self.skipped += 1                           # a non-finite pose: not a centre either
            return False
        if centre is not self.centre:                   # the whole datagram was made with the new centre
            self.centre, self._applied = centre, requests
            self.recentred += 1
            self.recentred_frame = record.get("frame")
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
            line += f"; {self.refused} refused: opentrack was not listening on {self.where}"
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
