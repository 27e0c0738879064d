"""The `brl` command line: a thin Typer shell over library functions (heavy imports inside commands)."""

from __future__ import annotations

import sys
from pathlib import Path
from typing import Annotated

import typer

app = typer.Typer(
    name="brl",
    help="Bayesian RL of vision-based vehicular control (Gharaee et al., ICPR 2020) on a CPU town simulator.",
    no_args_is_help=True,
    add_completion=False,
    pretty_exceptions_enable=False,
)


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
    """brl: collect, train-seg, train, bench, report — and preview the simulator's towns."""


@app.command()
def preview(
    towns: Annotated[list[str] | None, typer.Argument(help="Towns to draw (default: town01 town02).")] = None,
    out: Annotated[Path, typer.Option("--out", help="Output directory for the PNGs.")] = Path("out/preview"),
    weathers: Annotated[str, typer.Option(help="Comma-separated weather ids or names.")] = "1,6,8,14",
    seed: Annotated[int, typer.Option(help="Seed for traffic and rain.")] = 0,
) -> None:
    """Draw each town from above with its routes, and camera frames (RGB beside labels) in several weathers."""
    from rich.console import Console

    from brlcli.sim.town import load_town
    from brlcli.sim.weather import get_weather
    from brlcli.viz.preview import write_previews

    names = towns or ["town01", "town02"]
    for n in names:
        load_town(n)  # fail early, before anything is written
    wl = [w.strip() for w in weathers.split(",") if w.strip()]
    for w in wl:
        get_weather(w)
    console = Console(stderr=True)
    with console.status("rendering previews"):
        paths = write_previews(names, out, wl, seed=seed)
    for p in paths:
        typer.echo(str(p))


def main() -> None:
    """Entry point: run the app; bad input prints one line and exits with code 2."""
    from brlcli.errors import BrlInputError

    try:
        app()
    except BrlInputError as exc:
        typer.echo(f"brl: error: {exc}", err=True)
        sys.exit(2)
    except KeyboardInterrupt:
        typer.echo("brl: interrupted", err=True)
        sys.exit(130)


if __name__ == "__main__":
    main()
