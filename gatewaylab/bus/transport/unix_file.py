"""The socket files of a rig's Unix endpoints: bound only where nothing else is, removed only while they
are still the socket that was bound, so an endpoint never deletes a file of the user's."""

from __future__ import annotations

import contextlib
import errno
import os
import stat
from pathlib import Path
from typing import TYPE_CHECKING

if TYPE_CHECKING:
    import socket

__all__ = ["UNIX_PATH_MAX", "Identity", "bind_unix", "remove_unix"]

#: The longest path a Unix socket may have (AF_UNIX's sun_path is 108 bytes with the terminating NUL).
UNIX_PATH_MAX = 107

#: What :func:`bind_unix` returns: the bound file's (device, inode), for :func:`remove_unix`.
Identity = tuple[int, int]


def bind_unix(sock: socket.socket, path: Path) -> Identity:
    """Bind ``sock`` at ``path``. A socket file already there (left by a rig killed with SIGKILL) is
    replaced; any other file is left alone (FileExistsError), as is a path longer than AF_UNIX allows
    (OSError ENAMETOOLONG, naming the path and its length)."""
    size = len(os.fsencode(path))
    if size > UNIX_PATH_MAX:
        raise OSError(errno.ENAMETOOLONG, f"the socket path is {size} bytes, longer than a Unix socket's "
                                          f"{UNIX_PATH_MAX}", str(path))
    try:
        found = os.lstat(path)
    except FileNotFoundError:
        pass
    else:
        if not stat.S_ISSOCK(found.st_mode):
            raise FileExistsError(errno.EEXIST, "a file that is not a socket is there (left untouched)", str(path))
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
