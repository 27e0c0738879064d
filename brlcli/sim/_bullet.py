"""pybullet behind one import, with its console chatter (a build banner at import and connect) silenced."""

from __future__ import annotations

import contextlib
import os
import sys
from collections.abc import Iterator


@contextlib.contextmanager
def quiet_console() -> Iterator[None]:
    """Send file-descriptor-level stdout and stderr (C printf included) to /dev/null inside the block."""
    fds = []
    for stream in (sys.stdout, sys.stderr):
        try:
            stream.flush()
            fds.append(stream.fileno())
        except (AttributeError, OSError, ValueError):  # stream replaced (pytest capture, notebooks)
            continue
    saved = [os.dup(fd) for fd in fds]
    devnull = os.open(os.devnull, os.O_WRONLY)
    try:
        for fd in fds:
            os.dup2(devnull, fd)
        yield
    finally:
        for fd, keep in zip(fds, saved, strict=True):
            os.dup2(keep, fd)
            os.close(keep)
        os.close(devnull)


with quiet_console():
    import pybullet


def connect_direct() -> int:
    """A new headless pybullet client id."""
    with quiet_console():
        return pybullet.connect(pybullet.DIRECT)
