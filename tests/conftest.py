"""Shared test fixtures."""

from __future__ import annotations

import contextlib
import io
import signal
import subprocess
from collections.abc import Callable

import pytest


def run_brl_in_process(*args: str) -> subprocess.CompletedProcess:
    """`brl ARGS` run by the console script's own entry point in this process: its exit code, stdout and stderr.
    Bad-input checks use it to spare a new interpreter (and torch's import) per case; an exception that main()
    does not turn into an exit code escapes and fails the test, as a traceback would."""
    from brlcli.cli import main

    out, err = io.StringIO(), io.StringIO()
    sigterm = signal.getsignal(signal.SIGTERM)
    code = 0
    try:
        with contextlib.redirect_stdout(out), contextlib.redirect_stderr(err):
            main(list(args))
    except SystemExit as exc:
        code = exc.code if isinstance(exc.code, int) else int(exc.code is not None)
    finally:
        signal.signal(signal.SIGTERM, sigterm)  # main() installs brl's SIGTERM handler
    return subprocess.CompletedProcess(["brl", *args], code, out.getvalue(), err.getvalue())


@pytest.fixture
def brl_in_process() -> Callable[..., subprocess.CompletedProcess]:
    """run_brl_in_process, as a fixture."""
    return run_brl_in_process
