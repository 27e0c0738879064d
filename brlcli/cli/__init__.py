"""The `brl` command line: a thin Typer shell; each command declares its options and calls the library.

Commands live in `brlcli.cli.data` (collect, preview), `brlcli.cli.seg` (train-seg, eval-seg, calibrate-seg),
`brlcli.cli.train` (train, sweep, train-rl, train-il) and `brlcli.cli.bench` (bench, report); `brlcli.cli.common`
holds what they share.
Heavy imports happen inside the commands, so `brl --help` starts fast.
"""

from __future__ import annotations

import errno
import signal
import sys
import threading
from typing import Annotated, Any

import typer

# isort: off
from brlcli.cli import data, seg, train, bench, study  # noqa: F401  (registers the commands, in the order `brl --help` lists)
# isort: on
from brlcli.cli.common import app
from brlcli.cli.train import train_summary_line

__all__ = ["app", "main", "train_summary_line"]


def _version(value: bool) -> None:
    if value:
        from brlcli import __version__

        typer.echo(f"brl {__version__}")
        raise typer.Exit()


@app.callback()
def _root(
    version: Annotated[bool, typer.Option("--version", callback=_version, is_eager=True, help="Print the version.")]
    = False,
) -> None:
    """brl: collect, train-seg, train, sweep, bench, report, reproduce; baselines train-il, train-rl; preview."""


WRITE_ERRNOS = frozenset({errno.ENOSPC, errno.EDQUOT, errno.EROFS, errno.EACCES, errno.EPERM, errno.EIO, errno.EFBIG})
"""OSErrors that mean the output could not be written (disk full, permissions changed, read-only filesystem)."""


def _stop_on_sigterm(signum: int, frame: Any) -> None:
    """SIGTERM (`kill`, `docker stop`) ends a run as Ctrl-C does: finished work is saved, worker processes are
    stopped, one line is printed and the exit code is 130 (the run can be resumed)."""
    raise KeyboardInterrupt


def main(argv: list[str] | None = None) -> None:
    """Entry point: run the app. Bad input (ours or a usage error) prints one line and exits with 2; an output
    that cannot be written at run time prints one line and exits with 1 (the directory stays resumable)."""
    from brlcli.errors import BrlInputError, BrlWriteError

    if threading.current_thread() is threading.main_thread():
        signal.signal(signal.SIGTERM, _stop_on_sigterm)
    args = sys.argv[1:] if argv is None else list(argv)
    if not args:
        args = ["--help"]  # brl alone: the help, exit 0
    try:
        code = brl_command().main(args, prog_name="brl", standalone_mode=False)
    except BrlInputError as exc:
        _fail(str(exc), 2)
    except typer.TyperException as exc:  # click's usage errors: bad values, unknown options, missing options
        _fail(exc.format_message(), getattr(exc, "exit_code", 2) or 2)
    except BrlWriteError as exc:
        _fail(str(exc), 1)
    except OSError as exc:
        if exc.errno not in WRITE_ERRNOS:
            raise
        where = f" {exc.filename}" if exc.filename else ""
        _fail(f"cannot write{where}: {exc.strerror}", 1)
    except (KeyboardInterrupt, typer.Abort):
        typer.echo("brl: interrupted", err=True)
        sys.exit(130)
    sys.exit(code if isinstance(code, int) else 0)


def brl_command() -> Any:  # -> click.Group
    """The click command of the app, every option's value named after the option in the help (`--model MODEL`, as
    argparse does) instead of Typer's Python type names (`<list[str]>`)."""
    group = typer.main.get_command(app)
    for command in group.commands.values():  # type: ignore[attr-defined]
        for param in command.params:  # Typer's own click: options are told by their param_type_name
            if getattr(param, "param_type_name", "") == "option" and not getattr(param, "is_flag", False) \
                    and not getattr(param, "count", False) and param.metavar is None and param.name:
                param.metavar = param.name.rstrip("_").upper()
    return group


def _fail(message: str, code: int) -> None:
    """Print `brl: error: MESSAGE` on one line and exit with `code`."""
    line = " ".join(str(message).split())
    typer.echo(f"brl: error: {line}", err=True)
    sys.exit(code)
