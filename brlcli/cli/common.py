"""What every `brl` command shares: the Typer app, the options several commands take, the layered configuration
options, the run preamble (output directory, resume, executor, Ctrl-C and SIGTERM), lazy progress bars, one-line
errors. Library code never imports this package."""

from __future__ import annotations

import json
import sys
from collections.abc import Iterator
from contextlib import contextmanager
from pathlib import Path
from typing import TYPE_CHECKING, Annotated, Any, NoReturn

import typer

if TYPE_CHECKING:
    from rich.console import Console
    from rich.progress import Progress

    from brlcli.executor import Executor

app = typer.Typer(
    name="brl",
    help="Bayesian RL of vision-based vehicular control (Gharaee et al., ICPR 2020) on a CPU town simulator.",
    no_args_is_help=True,
    add_completion=True,
    pretty_exceptions_enable=False,
    rich_markup_mode=None,  # help texts are plain text: [brackets] stay as written
    context_settings={"help_option_names": ["-h", "--help"]},
)

FRESH_OUT = "a new runs/{command}/YYYYmmdd-HHMMSS"

Workers = Annotated[int, typer.Option(help="Parallel processes (a local Ray instance's CPUs).")]
ExecutorKind = Annotated[str, typer.Option("--executor", help="Where tasks run: local (processes on this machine) or "
                                                              "ray (a Ray cluster; pip install 'brl[ray]').")]
RayAddress = Annotated[str | None, typer.Option(help="--executor ray: HOST:PORT of a cluster's head, auto (a running "
                                                     "cluster) or local (a new local instance). Default: a running "
                                                     "cluster if there is one, else a local instance.")]
Device = Annotated[str, typer.Option("--device", help="Where torch runs: cpu (the default; bit-identical results), "
                                                    "cuda, cuda:N, or auto (cuda when torch sees a GPU).")]
Resume = Annotated[bool, typer.Option("--resume", help="Continue an interrupted run in --out (finished work is kept).")]
ConfigFile = Annotated[str | None, typer.Option("--config", help="TOML (or .json) file of configuration overrides "
                                                                 "(the keys --print-config shows), under the options.")]
Sets = Annotated[list[str] | None, typer.Option("--set", help="KEY=VALUE override of any configuration key, dotted "
                                                              "for tables (params.gamma=0.8); repeatable; applied "
                                                              "last.")]
PrintConfig = Annotated[bool, typer.Option("--print-config", help="Print the resolved configuration (JSON) and "
                                                                  "exit.")]


def out_option(command: str, holds: str) -> Any:
    """The --out option of a command: what the directory holds; without it, a fresh runs/COMMAND/STAMP."""
    return typer.Option("--out", help=f"Output directory ({holds}; default: {FRESH_OUT.format(command=command)}).")


def raise_input(message: str) -> NoReturn:
    """Raise the one-line input error the entry point turns into exit code 2."""
    from brlcli.errors import BrlInputError

    raise BrlInputError(message)


def given(ctx: typer.Context, options: dict[str, tuple[str, Any]]) -> dict[str, Any]:
    """The configuration layer of the options given on the command line: Typer parameter name -> (dotted
    configuration key, value); options left at their default are not in it, so presets and --config apply."""
    layer: dict[str, Any] = {}
    for param, (key, value) in options.items():
        source = getattr(ctx.get_parameter_source(param), "name", None)  # typer may vendor click: compare by name
        if source in ("COMMANDLINE", "ENVIRONMENT"):
            *tables, last = key.split(".")
            table = layer
            for t in tables:
                table = table.setdefault(t, {})
            table[last] = value
    return layer


def print_config(cfg: Any) -> None:
    """--print-config: the resolved configuration as JSON on stdout."""
    typer.echo(json.dumps(cfg.to_dict(), indent=2, sort_keys=True))


def make_executor(kind: str, workers: int, ray_address: str | None) -> Executor:
    """Validate --executor, --workers and --ray-address (Ray itself is imported only when tasks run on it)."""
    from brlcli.executor import Executor

    return Executor(kind, workers, ray_address)


def stderr_console(wide: bool = False) -> Console:
    """The console for progress and summaries (stderr; 160 columns when not a terminal and `wide`)."""
    from rich.console import Console

    return Console(stderr=True, width=None if (sys.stderr.isatty() or not wide) else 160)


def table_console() -> Console:
    """A stdout console wide enough for tables, also when piped (rich's default is then 80 columns)."""
    from rich.console import Console

    console = Console()
    return console if console.is_terminal else Console(width=160)


@contextmanager
def run_command(command: str, out: str | None, resume: bool, kind: str | None = None, overwrite: bool = False,
                executor: Executor | None = None, kept: str | None = "finished work is saved",
                console: Console | None = None) -> Iterator[Path]:
    """The preamble every command that writes a run shares: --resume needs --out; the output directory (given, or a
    fresh runs/COMMAND/STAMP) is checked before anything is written (`kind`: the marker it must hold); the executor
    is connected (Ray: 'connecting to Ray'); an interruption (Ctrl-C, SIGTERM) of a resumable run (`kept`: what it
    keeps; None: not resumable) prints one line saying what is kept and how to continue; every interruption exits
    with 130. The executor is closed at the end."""
    from brlcli.outdir import check_out_dir, default_out, parse_out

    if resume and out is None:
        raise_input(f"--resume continues a run: give its --out (brl {command} --resume --out DIR)")
    out_dir = default_out(command) if out is None else parse_out(out)
    check_out_dir(out_dir, kind or command, resume=resume, overwrite=overwrite)
    console = console or stderr_console()
    try:
        if executor is not None and executor.kind == "ray":
            with console.status("connecting to Ray"):
                executor.connect()  # before anything is written: an unreachable cluster is a one-line error
            console.print(f"{command} on {executor.describe()}")
        yield out_dir
    except KeyboardInterrupt:
        if kept is None:
            raise
        console.print(f"interrupted: {kept}; continue with --resume --out {out_dir}")
        raise typer.Exit(130) from None
    finally:
        if executor is not None:
            executor.close()


class LazyProgress:
    """Rich progress bars that appear with the first report, so a run refused before it starts shows none."""

    def __init__(self, console: Console, *columns: Any) -> None:
        self.console = console
        self.columns = columns
        self._bar: Progress | None = None

    @property
    def bar(self) -> Progress:
        """The bars, started on first use."""
        if self._bar is None:
            from rich.progress import Progress

            self._bar = Progress(*self.columns, console=self.console)
            self._bar.start()
        return self._bar

    def __enter__(self) -> LazyProgress:
        return self

    def __exit__(self, *exc: object) -> None:
        if self._bar is not None:
            self._bar.stop()


def segnet_notice(segnet: str | None) -> None:
    """Say on one line (stderr) when the estimated input comes from an uncalibrated (brl 0.1) net file."""
    from brlcli.segnet.infer import uncalibrated_notice

    message = uncalibrated_notice(segnet)
    if message:
        typer.echo(f"brl: notice: {message}", err=True)
