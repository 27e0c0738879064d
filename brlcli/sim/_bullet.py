"""pybullet behind one import, with its console chatter at import and connect kept off stdout."""

from __future__ import annotations

import contextlib
import ctypes
import os
import sys
from collections.abc import Iterator


def _flush_c_stdout() -> None:
    try:
        libc = ctypes.CDLL("libc.so.6")
        libc.fflush(ctypes.c_void_p.in_dll(libc, "stdout"))
    except (OSError, AttributeError, ValueError):
        pass


@contextlib.contextmanager
def quiet_stdout() -> Iterator[None]:
    """Send file-descriptor-level stdout (C printf included) to /dev/null inside the block."""
    try:
        sys.stdout.flush()
        fd = sys.stdout.fileno()
    except (AttributeError, OSError, ValueError):  # stdout replaced (pytest capture, notebooks)
        yield
        return
    saved = os.dup(fd)
    devnull = os.open(os.devnull, os.O_WRONLY)
    try:
        os.dup2(devnull, fd)
        yield
        _flush_c_stdout()
    finally:
        os.dup2(saved, fd)
        os.close(devnull)
        os.close(saved)


with quiet_stdout():
    import pybullet


def connect_direct() -> int:
    """A new headless pybullet client id."""
    with quiet_stdout():
        return pybullet.connect(pybullet.DIRECT)

