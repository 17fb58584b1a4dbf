"""The socket files of a rig's Unix endpoints: bound only where nothing else is, removed only while they
are still the socket that was bound, so an endpoint never deletes a file of the user's."""

from __future__ import annotations

import contextlib
import os
import stat
from pathlib import Path
from typing import TYPE_CHECKING

from gatewaylab.common.errors import LocalError

if TYPE_CHECKING:
    import socket

__all__ = ["UNIX_PATH_MAX", "Identity", "SocketPathError", "bind_unix", "remove_unix"]

#: The longest path a Unix socket may have (AF_UNIX's sun_path is 108 bytes with the terminating NUL).
UNIX_PATH_MAX = 107

#: What :func:`bind_unix` returns: the bound file's (device, inode), for :func:`remove_unix`.
Identity = tuple[int, int]


class SocketPathError(LocalError, OSError):
    """A path :func:`bind_unix` will not bind: too long for AF_UNIX (``too_long``), or a file that is not
    a socket is there (left untouched)."""

    def __init__(self, message: str, path: Path, too_long: bool = False) -> None:
        super().__init__(message)
        self.path = path
        self.too_long = too_long


def bind_unix(sock: socket.socket, path: Path) -> Identity:
    """Bind ``sock`` at ``path``. A socket file already there (left by a rig killed with SIGKILL) is
    replaced; any other file is left alone, as is a path longer than AF_UNIX allows (SocketPathError)."""
    size = len(os.fsencode(path))
    if size > UNIX_PATH_MAX:
        raise SocketPathError(f"{path}: the socket path is {size} bytes, longer than a Unix socket's "
                              f"{UNIX_PATH_MAX}", path, too_long=True)
    try:
        found = os.lstat(path)
    except FileNotFoundError:
        pass
    else:
        if not stat.S_ISSOCK(found.st_mode):
            raise SocketPathError(f"{path}: a file that is not a socket is there (left untouched)", path)
        os.unlink(path)
    sock.bind(str(path))
    bound = os.lstat(path)
    return bound.st_dev, bound.st_ino


def remove_unix(path: Path, identity: Identity) -> None:
    """Remove the socket file :func:`bind_unix` made, unless something else has taken its place."""
    try:
        found = os.lstat(path)
    except OSError:
        return
    if stat.S_ISSOCK(found.st_mode) and (found.st_dev, found.st_ino) == identity:
        with contextlib.suppress(FileNotFoundError):
            os.unlink(path)
