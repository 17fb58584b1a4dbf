"""The ``q`` key of the live views (``gatewaylab monitor``, ``dump``): the terminal in cbreak mode.

While a live view runs with a terminal on stdin, the terminal delivers each key as it is typed
(cbreak: no line editing, no echo; Ctrl-C still sends SIGINT) and ``q`` ends the view as Ctrl-C
does. The terminal's settings are put back on every way out: the end of the ``with`` block
(normal end, an exception, SIGINT/SIGTERM raised in it), interpreter exit, and after Ctrl-Z the
view sets cbreak again when it is continued in the foreground. Without a terminal on stdin (a
pipe, a file, ``</dev/null``), or when started in the background (``&``), nothing is touched.
"""

from __future__ import annotations

import atexit
import os
import select
import signal
import sys
import termios
from types import FrameType
from typing import Any, TextIO

__all__ = ["QUIT_KEYS", "QuitKey"]

#: The keys that leave a live view.
QUIT_KEYS = b"qQ"


def _tty_fd(stream: TextIO | None) -> int | None:
    """The file descriptor of ``stream`` when it is a terminal."""
    try:
        fd = stream.fileno() if stream is not None else -1
    except (AttributeError, OSError, ValueError):    # closed, or not a file (pytest's capture)
        return None
    return fd if fd >= 0 and os.isatty(fd) else None


def _foreground(fd: int) -> bool:
    """True unless the terminal belongs to another process group (we run in the background, where
    reading it or changing its mode would stop us with SIGTTIN/SIGTTOU)."""
    try:
        return os.tcgetpgrp(fd) == os.getpgrp()
    except OSError:        # not our controlling terminal: no job control applies to it
        return True


class QuitKey:
    """``with QuitKey() as keys:`` puts the terminal on stdin in cbreak mode; ``keys.poll()`` tells
    (without waiting) whether ``q`` was typed. ``active`` is False where there is no terminal to read
    (or ``enabled`` is False: a replay, which ends by itself)."""

    def __init__(self, stream: TextIO | None = None, enabled: bool = True) -> None:
        self._stream = stream
        self._enabled = enabled
        self._fd: int | None = None
        self._saved: list[Any] | None = None
        self._previous_cont: Any = None
        self.pressed = False

    @property
    def active(self) -> bool:
        """Whether keys are read (stdin is a terminal and the view started in the foreground)."""
        return self._fd is not None

    def __enter__(self) -> QuitKey:
        fd = _tty_fd(self._stream if self._stream is not None else sys.stdin) if self._enabled else None
        if fd is None or not _foreground(fd):
            return self
        blocked = _block_stop_signals()
        try:
            self._saved = termios.tcgetattr(fd)
            self._fd = fd
            self._cbreak()
            atexit.register(self._restore)
            try:
                self._previous_cont = signal.signal(signal.SIGCONT, self._on_continue)
            except ValueError:     # not the main thread: no re-arming after Ctrl-Z
                self._previous_cont = None
        except termios.error:
            self._fd = self._saved = None
        finally:
            _unblock(blocked)
        return self

    def __exit__(self, *exc: object) -> None:
        blocked = _block_stop_signals()     # a signal now must not leave the terminal in cbreak mode
        try:
            self._restore()
            atexit.unregister(self._restore)
            if self._previous_cont is not None:
                signal.signal(signal.SIGCONT, self._previous_cont)
                self._previous_cont = None
        finally:
            _unblock(blocked)

    def _cbreak(self) -> None:
        """Keys one by one, not echoed; signals (Ctrl-C, Ctrl-Z) and output processing unchanged."""
        fd = self._fd
        if fd is None or self._saved is None:
            return
        mode = termios.tcgetattr(fd)
        mode[3] &= ~(termios.ECHO | termios.ICANON)
        mode[6][termios.VMIN] = 1
        mode[6][termios.VTIME] = 0
        termios.tcsetattr(fd, termios.TCSANOW, mode)

    def _restore(self) -> None:
        fd, saved = self._fd, self._saved
        self._fd = self._saved = None
        if fd is not None and saved is not None and _foreground(fd):
            try:
                termios.tcsetattr(fd, termios.TCSANOW, saved)
            except termios.error:        # the terminal went away (hung up)
                pass

    def _on_continue(self, signum: int, frame: FrameType | None) -> None:
        """Continued after Ctrl-Z: the shell put its own mode back; in the foreground, take cbreak again."""
        if self._fd is not None and _foreground(self._fd):
            try:
                self._cbreak()
            except termios.error:
                pass

    def poll(self) -> bool:
        """True once ``q`` was typed; reads what waits on the terminal, never blocks."""
        fd = self._fd
        if self.pressed or fd is None or not _foreground(fd):
            return self.pressed
        try:
            ready, _, _ = select.select([fd], [], [], 0)
            data = os.read(fd, 256) if ready else b""
        except (OSError, ValueError):
            return self.pressed
        if ready and not data:          # end of input (the terminal hung up): nothing more to read
            self._fd = None
        self.pressed = any(key in QUIT_KEYS for key in data)
        return self.pressed


def _block_stop_signals() -> set[int | signal.Signals] | None:
    try:
        return signal.pthread_sigmask(signal.SIG_BLOCK, {signal.SIGINT, signal.SIGTERM})
    except (AttributeError, OSError, ValueError):
        return None


def _unblock(previous: set[int | signal.Signals] | None) -> None:
    if previous is not None:
        signal.pthread_sigmask(signal.SIG_SETMASK, previous)
