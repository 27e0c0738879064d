"""What produced an output: brl version, git commit, resolved configuration; atomic file writes."""

from __future__ import annotations

import json
import os
import platform
import subprocess
import tempfile
from pathlib import Path
from typing import Any

from brlcli import __version__
from brlcli.errors import BrlWriteError


def git_commit() -> str:
    """The git commit of the brl source tree (env `BRL_GIT_COMMIT` overrides; 'unknown' outside a checkout)."""
    env = os.environ.get("BRL_GIT_COMMIT")
    if env:
        return env
    try:
        out = subprocess.run(["git", "rev-parse", "HEAD"], cwd=Path(__file__).resolve().parent, capture_output=True,
                             text=True, timeout=5, check=False)
    except (OSError, subprocess.SubprocessError):
        return "unknown"
    return out.stdout.strip() if out.returncode == 0 and out.stdout.strip() else "unknown"


def provenance(config: dict[str, Any], kind: str | None = None) -> dict[str, Any]:
    """The record stored beside every output: version, commit, python, the resolved configuration and, for the
    marker file of a command's output directory, the command's `kind` (see `brlcli.outdir`)."""
    record = {"brl_version": __version__, "git_commit": git_commit(), "python": platform.python_version(),
              "config": config}
    return record if kind is None else {"kind": kind, **record}


def atomic_write_bytes(path: Path, data: bytes) -> None:
    """Write `data` to `path` through a temporary file in the same directory and a rename; a failed write (disk
    full, permissions) raises `BrlWriteError` and leaves the old file, if any, in place."""
    path = Path(path)
    try:
        path.parent.mkdir(parents=True, exist_ok=True)
        fd, tmp = tempfile.mkstemp(prefix=f".{path.name}.", suffix=".tmp", dir=path.parent)
    except OSError as exc:
        raise BrlWriteError(f"cannot write {path}: {exc.strerror or exc}") from None
    try:
        with os.fdopen(fd, "wb") as fh:
            fh.write(data)
            fh.flush()
            os.fsync(fh.fileno())
        os.chmod(tmp, 0o644)
        os.replace(tmp, path)
    except BaseException as exc:
        Path(tmp).unlink(missing_ok=True)
        if isinstance(exc, OSError):
            raise BrlWriteError(f"cannot write {path}: {exc.strerror or exc}") from None
        raise


def atomic_write_json(path: Path, obj: Any) -> None:
    """Write JSON atomically (sorted keys, indented)."""
    atomic_write_bytes(path, (json.dumps(obj, indent=2, sort_keys=True) + "\n").encode())
