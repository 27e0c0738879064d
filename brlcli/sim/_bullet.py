"""Import pybullet without its build-time banner on stdout (it would pollute piped output)."""

from __future__ import annotations

import os
import sys


def _quiet_import():
    sys.stdout.flush()
    try:
        fd = sys.stdout.fileno()
    except (AttributeError, OSError, ValueError):  # stdout replaced (pytest capture, notebooks)
        import pybullet

        return pybullet
    saved = os.dup(fd)
    devnull = os.open(os.devnull, os.O_WRONLY)
    try:
        os.dup2(devnull, fd)
        import pybullet
    finally:
        sys.stdout.flush()
        os.dup2(saved, fd)
        os.close(devnull)
        os.close(saved)
    return pybullet


pybullet = _quiet_import()
