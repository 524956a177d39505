"""The user's ways to recentre what ``headplod track --udp`` sends to opentrack: SIGUSR1 and the key ``c``.

:class:`RecentreControls` (a ``with`` block around the tracking loop):

- SIGUSR1 (``kill -USR1 PID``; the PID is in the start note,
  :meth:`RecentreControls.note`) asks for a recentring;
- when standard input is a terminal and the run is in its foreground, the
  terminal is put in cbreak mode (keys come one by one, not echoed; Ctrl-C
  still is SIGINT) and a reader thread waits for keys: ``c`` (or ``C``) asks
  for a recentring; other keys are ignored.

Both only ask (:meth:`OpentrackSender.request_recentre
<headplod.live.udp.OpentrackSender.request_recentre>` counts the request);
the loop applies it when it sends the next pose, between frames, so a pose
is never sent half recentred. On leaving the block, the reader stops, the
terminal's mode is put back as it was (also after Ctrl-C, SIGTERM, SIGHUP or
an exception; not after SIGKILL: ``stty sane`` then) and the SIGUSR1 handler
in place before is restored.

Without a sender (no ``--udp``) the block still handles SIGUSR1 (a stray
signal must not kill the run with its outputs half made): it is counted in
:attr:`RecentreControls.ignored`, and nothing else happens.
"""
from __future__ import annotations

import os
import select
import signal
import sys
import threading

__all__ = ["RecentreControls", "RECENTRE_KEYS", "RECENTRE_SIGNAL"]

#: The keys that recentre (in the terminal the run was started from).
RECENTRE_KEYS = b"cC"

#: The signal that recentres.
RECENTRE_SIGNAL = signal.SIGUSR1


def _main_thread() -> bool:
    return threading.current_thread() is threading.main_thread()


class RecentreControls:
    """SIGUSR1 and the key ``c`` ask ``sender`` to recentre, for the duration of a ``with`` block.

    Parameters
    ----------
    sender : OpentrackSender or None
        What is asked (:meth:`~headplod.live.udp.OpentrackSender.request_recentre`).
    stdin : file or int, optional
        Where keys are read (default ``sys.stdin``); only a terminal whose
        foreground the run is, and only with a sender.
    keys : bool
        Read keys at all (default True).
    termios_module : module, optional
        ``termios`` (tests pass a stand-in); None where the platform has none.

    Attributes
    ----------
    reading_keys : bool
        Whether keys are read (the terminal is in cbreak mode) inside the block.
    ignored : int
        SIGUSR1 received without a sender.
    """

    def __init__(self, sender, stdin=None, keys: bool = True, termios_module=None):
        self.sender = sender
        self._stdin = sys.stdin if stdin is None else stdin
        self._keys = keys and sender is not None
        if termios_module is None:
            try:
                import termios as termios_module
            except ImportError:                         # not a POSIX system: SIGUSR1 does not exist either
                termios_module = None
        self._termios = termios_module
        self.reading_keys = False
        self.ignored = 0
        self._fd: int | None = None
        self._saved = None                              # the terminal's attributes before cbreak
        self._previous_handler = None
        self._handler_set = False
        self._done = threading.Event()
        self._thread: threading.Thread | None = None

    # -- the signal -------------------------------------------------------------------------------------

    def _on_signal(self, signum, frame) -> None:
        self.ask("SIGUSR1")

    def ask(self, how: str) -> None:
        """Ask for a recentring (what the signal and the key do)."""
        if self.sender is None:
            self.ignored += 1
        else:
            self.sender.request_recentre(how)

    # -- the terminal -----------------------------------------------------------------------------------

    def _terminal_fd(self) -> int | None:
        """The file descriptor of standard input when it is a terminal this process has the foreground of."""
        try:
            fd = self._stdin if isinstance(self._stdin, int) else self._stdin.fileno()
            if not os.isatty(fd):
                return None
            if os.tcgetpgrp(fd) != os.getpgrp():    # in the background: touching the terminal would stop us
                return None
        except (AttributeError, ValueError, OSError):  # closed, not a real file (a test's capture), no terminal
            return None
        return fd

    def _set_attributes(self, attributes) -> None:
        """Set the terminal's attributes, never stopped by SIGTTOU (a run put in the background meanwhile)."""
        previous = None
        if _main_thread() and hasattr(signal, "SIGTTOU"):
            previous = signal.signal(signal.SIGTTOU, signal.SIG_IGN)
        try:
            self._termios.tcsetattr(self._fd, self._termios.TCSADRAIN, attributes)
        finally:
            if previous is not None:
                signal.signal(signal.SIGTTOU, previous)

    def _start_keys(self) -> None:
        if not self._keys or self._termios is None:
            return
        fd = self._terminal_fd()
        if fd is None:
            return
        t = self._termios
        try:
            self._saved = t.tcgetattr(fd)
            cbreak = [list(a) if isinstance(a, list) else a for a in self._saved]
            cbreak[3] &= ~(t.ECHO | t.ICANON)           # lflags: keys one by one, not echoed; ISIG kept (Ctrl-C)
            cbreak[6][t.VMIN], cbreak[6][t.VTIME] = 1, 0
            self._fd = fd
            self._set_attributes(cbreak)
        except (OSError, t.error):
            self._fd, self._saved = None, None
            return
        self.reading_keys = True
        self._done.clear()
        self._thread = threading.Thread(target=self._read_keys, name="headplod recentre keys", daemon=True)
        self._thread.start()

    def _read_keys(self) -> None:
        """The reader thread: wait for keys (polling ``_done`` every 0.1 s), ask on ``c``."""
        while not self._done.is_set():
            try:
                ready, _, _ = select.select([self._fd], [], [], 0.1)
                if not ready:
                    continue
                data = os.read(self._fd, 64)
            except (OSError, ValueError):               # the terminal is gone (SIGHUP): nothing more to read
                return
            if not data:                                # end of input
                return
            if any(k in data for k in RECENTRE_KEYS):
                self.ask("key c")

    def _stop_keys(self) -> None:
        self._done.set()
        if self._thread is not None:
            self._thread.join(timeout=1.0)
            self._thread = None
        if self._saved is not None:
            try:
                self._set_attributes(self._saved)
            except (OSError, self._termios.error):     # the terminal closed (SIGHUP): no mode to put back
                pass
            self._saved = None
        self._fd = None
        self.reading_keys = False

    # -- the block ------------------------------------------------------------------------------------

    def __enter__(self) -> "RecentreControls":
        if _main_thread() and RECENTRE_SIGNAL is not None:
            self._previous_handler = signal.signal(RECENTRE_SIGNAL, self._on_signal)
            self._handler_set = True
        try:
            self._start_keys()
        except BaseException:
            self.__exit__()
            raise
        return self

    def __exit__(self, *exc) -> None:
        try:
            self._stop_keys()
        finally:
            if self._handler_set:
                previous = self._previous_handler
                signal.signal(RECENTRE_SIGNAL, previous if previous is not None else signal.SIG_DFL)
                self._handler_set = False

    def note(self, pid: int | None = None) -> str:
        """The start note: how to recentre this run (its PID), and what it changes."""
        pid = os.getpid() if pid is None else pid
        key = "press c here or run " if self.reading_keys else "run "
        return (f"recentre: {key}'kill -USR1 {pid}' to make the current pose opentrack's zero "
                "(what is sent only; the records keep the camera frame)")
