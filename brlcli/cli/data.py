"""`brl collect`, `brl preview`: recording frames with the privileged expert, and pictures of the towns."""

from __future__ import annotations

from typing import Annotated, Any

import typer

from brlcli.cli.common import LazyProgress, app, out_option, run_command, stderr_console


@app.command()
def collect(
    town: Annotated[str, typer.Option(help="Town to drive in.")] = "town01",
    weathers: Annotated[str, typer.Option(help="Comma-separated weather ids or names, cycled per episode.")]
    = "1,3,6,8",
    episodes: Annotated[int | None, typer.Option(help="Number of episodes (one bag each) [default: 10].")] = None,
    frames: Annotated[int | None, typer.Option(help="Total recorded frames (alternative to --episodes).")] = None,
    episode_frames: Annotated[int, typer.Option(help="Recorded frames per episode.")] = 300,
    every: Annotated[int, typer.Option(help="Record every N-th simulated frame (10 fps / N).")] = 1,
    seed: Annotated[int, typer.Option(min=0, help="Seed of routes, noise and traffic.")] = 0,
    out: Annotated[str | None, out_option("collect", "episode_NNNNN/ bags, collect.json")] = None,
    storage: Annotated[str, typer.Option(help="Bag storage: mcap (zstd chunks) or sqlite3.")] = "mcap",
    traffic: Annotated[bool, typer.Option("--traffic", help="CoRL2017 traffic (town01 20+50, town02 15+50).")]
    = False,
    noise: Annotated[bool, typer.Option(help="Inject steering noise (the expert recovers; off-centre views).")]
    = True,
    excursions: Annotated[float, typer.Option(help="Lateral excursions per second: for 3-8 s the car drives on a "
                                                   "sidewalk or in the opposite lane, views a failing agent sees "
                                                   "(perception data; outside CIL). 0: none.")] = 0.0,
    depth: Annotated[bool, typer.Option(help="Record the depth image too.")] = True,
    width: Annotated[int, typer.Option(help="Camera width, px.")] = 200,
    height: Annotated[int, typer.Option(help="Camera height, px.")] = 88,
    resume: Annotated[bool, typer.Option("--resume", help="Skip episodes already recorded in --out.")] = False,
) -> None:
    """Drive with the privileged autopilot and record RGB, labels, depth, measurements to ROS 2 bags."""
    from rich.progress import BarColumn, MofNCompleteColumn, TextColumn, TimeElapsedColumn

    from brlcli.collect import CollectConfig, check_output
    from brlcli.collect import collect as run_collect

    cfg = CollectConfig.from_options(town, weathers, episodes, frames, episode_frames, every, seed, storage, traffic,
                                     noise, excursions, depth, width, height)
    total = cfg.episodes * cfg.episode_frames
    console = stderr_console()
    bars = LazyProgress(console, TextColumn("recording"), BarColumn(), MofNCompleteColumn(),
                        TextColumn("{task.fields[fps]:6.0f} frames/s"), TimeElapsedColumn())
    ids: list[Any] = []

    def report(_episode: int, recorded: int, fps: float) -> None:
        if not ids:
            ids.append(bars.bar.add_task("", total=total, fps=0.0))
        bars.bar.update(ids[0], completed=recorded, fps=fps)

    with run_command("collect", out, resume, console=console, kept="finished episodes are kept") as out_dir, bars:
        check_output(cfg, out_dir, resume)
        result = run_collect(cfg, out_dir, resume=resume, progress=report)
    console.print(f"{result['frames']} frames in {len(result['bags'])} bags, {result['frames_per_s']:.0f} frames/s")
    typer.echo(str(out_dir))


@app.command()
def preview(
    towns: Annotated[list[str] | None, typer.Argument(help="Towns to draw (default: town01 town02).")] = None,
    out: Annotated[str, typer.Option("--out", help="Output directory for the PNGs (rewritten in place).")]
    = "out/preview",
    weathers: Annotated[str, typer.Option(help="Comma-separated weather ids or names.")] = "1,6,8,14",
    seed: Annotated[int, typer.Option(min=0, help="Seed for traffic and rain.")] = 0,
) -> None:
    """Draw each town from above with its routes, and camera frames (RGB beside labels) in several weathers."""
    from brlcli.viz.preview import check_previews, write_previews

    names, weather_list = check_previews(towns or ["town01", "town02"], weathers, seed)
    console = stderr_console()
    with run_command("preview", out, False, overwrite=True, console=console, kept=None) as out_dir, \
            console.status("rendering previews"):
        paths = write_previews(names, out_dir, weather_list, seed=seed)
    for p in paths:
        typer.echo(str(p))
