"""The `brl` command line: a thin Typer shell over library functions (heavy imports inside commands)."""

from __future__ import annotations

import errno
import signal
import sys
import threading
from pathlib import Path
from typing import TYPE_CHECKING, Annotated, Any

import typer

if TYPE_CHECKING:
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
VARIANT_HELP = ("Method: action-averaging-restart (recommended, outside the paper: each action value the average "
                "of its TD targets, and a restart when training is trapped), paper (eqs. 1-11, Algorithm 1, Table I "
                "as written), averaging-restart (the previous recommendation: per-component averaging), "
                "reference-code (the authors' code's agent) [default: action-averaging-restart].")


def _out(value: str | None, command: str) -> Path:
    """The --out directory: as given (an empty string is refused), or a fresh one per invocation if not given."""
    from brlcli.outdir import default_out, parse_out

    return default_out(command) if value is None else parse_out(value)


def _check_out(out: Path, kind: str, resume: bool = False, overwrite: bool = False) -> None:
    from brlcli.outdir import check_out_dir

    check_out_dir(out, kind, resume=resume, overwrite=overwrite)


EXECUTOR_HELP = "Where tasks run: local (processes on this machine) or ray (a Ray cluster; pip install 'brl[ray]')."
RAY_ADDRESS_HELP = ("--executor ray: HOST:PORT of a cluster's head, auto (a running cluster) or local (a new local "
                    "instance). Default: a running cluster if there is one, else a local instance.")


def _executor(kind: str, workers: int, ray_address: str | None) -> Executor:
    """Validate --executor, --workers and --ray-address (Ray itself is imported only when tasks run on it)."""
    from brlcli.executor import Executor

    return Executor(kind, workers, ray_address)


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
    """brl: collect, train-seg, train, sweep, bench, report; baselines train-il, train-rl; preview the towns."""


@app.command()
def preview(
    towns: Annotated[list[str] | None, typer.Argument(help="Towns to draw (default: town01 town02).")] = None,
    out: Annotated[str, typer.Option("--out", help="Output directory for the PNGs (rewritten in place).")]
    = "out/preview",
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
    out_dir = _out(out, "preview")
    _check_out(out_dir, "preview", overwrite=True)
    console = Console(stderr=True)
    with console.status("rendering previews"):
        paths = write_previews(names, out_dir, wl, seed=seed)
    for p in paths:
        typer.echo(str(p))


def _with_segnet(cfg: Any) -> Any:
    """A training config (TrainConfig, DeepRLConfig) with the shipped net filled in for estimated input; --segnet
    without estimated input is refused."""
    if cfg.segnet is not None and cfg.input != "estimated":
        raise_input("--segnet is only used with --input estimated")
    if cfg.input == "estimated" and cfg.segnet is None:
        from brlcli.models import default_segnet_path

        return type(cfg).from_dict({**cfg.to_dict(), "segnet": str(default_segnet_path())})
    return cfg


@app.command()
def train(
    task: Annotated[str | None, typer.Option(help="lane-keeping (the paper's) or navigation (route commands at "
                                                  "junctions; outside the paper) [default: lane-keeping].")] = None,
    town: Annotated[str | None, typer.Option(help="Town to train in [default: town01].")] = None,
    weather: Annotated[str | None, typer.Option(help="Weather id or name (the paper trains in 1, ClearNoon) "
                                                     "[default: 1].")] = None,
    input: Annotated[str | None, typer.Option("--input", help="State source: gt (simulator labels) or estimated "
                                                              "[default: gt].")] = None,
    steps: Annotated[int | None, typer.Option(help="Learning steps per model (paper: t_max = 4500) "
                                                   "[default: 4500].")] = None,
    seed: Annotated[int, typer.Option(help="Seed of a single model.")] = 0,
    seeds: Annotated[str | None, typer.Option(help="Train a model set, e.g. 0-8 (overrides --seed).")] = None,
    workers: Annotated[int, typer.Option(help="Parallel processes for a model set (a local Ray instance's CPUs).")]
    = 1,
    executor: Annotated[str, typer.Option(help=EXECUTOR_HELP)] = "local",
    ray_address: Annotated[str | None, typer.Option(help=RAY_ADDRESS_HELP)] = None,
    out: Annotated[str | None, typer.Option("--out", help="Output directory (one seed_N/ per model; default: "
                                                          f"{FRESH_OUT.format(command='train')}).")] = None,
    resume: Annotated[bool, typer.Option("--resume", help="Continue interrupted runs in --out.")] = False,
    variant: Annotated[str | None, typer.Option(help=VARIANT_HELP)] = None,
    target_speed_kmh: Annotated[float | None, typer.Option(help="Reward's target speed v_t, km/h [default: 20].")]
    = None,
    evaluate: Annotated[bool | None, typer.Option(help="Greedy evaluation on the town's validation routes at the end "
                                                       "[default: evaluate].")] = None,
    segnet: Annotated[str | None, typer.Option(help="Segmentation net for --input estimated (default: shipped).")]
    = None,
    curve_every: Annotated[int | None, typer.Option(help="Evaluate greedily on the paper suite every N steps and "
                                                         "write learning_curve.csv (0: never) [default: 0].")] = None,
    config: Annotated[str | None, typer.Option("--config", help="TOML file of training-config overrides (the schema "
                                                                "of one brl sweep variant), under the options.")]
    = None,
    set_: Annotated[list[str] | None, typer.Option("--set", help="KEY=VALUE override of any training-config key, "
                                                                 "dotted for tables (params.gamma=0.8); repeatable; "
                                                                 "applied last.")] = None,
    print_config: Annotated[bool, typer.Option("--print-config", help="Print the resolved configuration (JSON) "
                                                                      "and exit.")] = False,
) -> None:
    """Online Bayesian RL training of the driving agent (paper Sec. III-IV)."""
    import json

    from rich.console import Console
    from rich.progress import BarColumn, MofNCompleteColumn, Progress, TextColumn, TimeElapsedColumn

    from brlcli.sim.weather import get_weather
    from brlcli.train import DEFAULT_VARIANT, check_inputs, check_run_dirs, parse_seeds, train_many
    from brlcli.trainconfig import parse_sets, read_config_file, resolve_config

    ex = _executor(executor, workers, ray_address)
    seed_list = parse_seeds(seeds) if seeds is not None else [seed]
    if resume and out is None:
        raise_input("--resume continues a run: give its --out")
    options = {"task": task, "town": town, "weather": None if weather is None else get_weather(weather).id,
               "input": input, "steps": steps, "variant": variant, "target_speed_kmh": target_speed_kmh,
               "evaluate": evaluate, "segnet": segnet, "curve_every": curve_every}
    layers = [read_config_file(config) if config is not None else {},
              {k: v for k, v in options.items() if v is not None}, parse_sets(set_ or [])]
    for layer, where in zip(layers, ("--config", "options", "--set"), strict=True):
        if "seed" in layer:
            raise_input(f"{where} cannot set seed: seeds come from --seed or --seeds")
    cfg = resolve_config([*layers, {"seed": seed_list[0]}], default_variant=DEFAULT_VARIANT)
    cfg = _with_segnet(cfg)
    if print_config:
        typer.echo(json.dumps(cfg.to_dict(), indent=2, sort_keys=True))
        return
    from brlcli.sim.town import load_town

    steps = cfg.steps
    load_town(cfg.town)
    check_inputs(cfg)
    if cfg.input == "estimated":
        _segnet_notice(cfg.segnet)
    out_dir = _out(out, "train")
    check_run_dirs(cfg, seed_list, out_dir, resume)
    _check_out(out_dir, "train", resume, overwrite=True)  # a model set may grow by seeds; each seed is checked above
    console = Console(stderr=True)
    if executor == "ray":
        with console.status("connecting to Ray"):
            ex.connect()
        console.print(f"training {len(seed_list)} seeds on {ex.describe()}")
    columns = (TextColumn("seed {task.fields[seed]}"), BarColumn(), MofNCompleteColumn(),
               TextColumn("reward {task.fields[reward]:7.2f}  TD {task.fields[td]:8.2f}  comps {task.fields[comps]}"),
               TimeElapsedColumn())
    with Progress(*columns, console=console, transient=False) as bar:
        tasks = {(s, k): bar.add_task("", total=steps, seed=s if cfg.committee == 1 else f"{s} member {k}",
                                      reward=0.0, td=0.0, comps=1)
                 for s in seed_list for k in range(cfg.committee)}

        def report(p) -> None:  # p: brlcli.train.Progress
            bar.update(tasks[(p.seed, p.member)], completed=p.step, total=p.steps, reward=p.mean_reward, td=p.td_error,
                       comps=p.components)

        try:
            results = train_many(cfg, seed_list, out_dir, workers=workers, resume=resume, progress=report,
                                 executor=ex)
        except KeyboardInterrupt:
            console.print(f"interrupted: finished episodes are checkpointed; continue with --resume --out {out_dir}")
            raise typer.Exit(130) from None
        finally:
            ex.close()
    for r in results:
        console.print(train_summary_line(r["summary"]), soft_wrap=True)
    typer.echo(str(out_dir))


def train_summary_line(s: dict) -> str:
    """One trained model's end-of-run line: totals, and the greedy evaluation's success beside Either and Score."""
    line = (f"seed {s['seed']}: {s['steps']} steps, {s['episodes']} episodes, {s['components']} components, "
            f"{s['steps_per_s']:.0f} steps/s")
    if s.get("committee"):
        line += f" (a committee of {s['committee']} members, majority vote)"
    if s.get("restarts"):
        line += f" ({len(s['restarts'])} restart{'s' if len(s['restarts']) > 1 else ''})"
    ev = s.get("eval")
    if ev and ev.get("suite") == "nav_validation":
        line += (f", navigation success {ev['success_rate']:.0%}  Either {ev['either_share']:.1%}  "
                 f"Score {ev['score']:.2f} (nav_validation suite)")
    elif ev:
        line += (f", lane-keeping success {ev['success_rate']:.0%}  Either {ev['either_share']:.1%}  "
                 f"Score {ev['score']:.2f} ({ev['town']} {ev.get('routes', 'lane_keeping')} routes)")
    return line


@app.command()
def sweep(
    grid: Annotated[Path | None, typer.Argument(help="Grid file (TOML or JSON): [base] and [variants.NAME] tables of "
                                                     "training-config overrides (params.* for the agent).")] = None,
    seeds: Annotated[str, typer.Option(help="Seeds of every variant, e.g. 0-8 or 0,2,5.")] = "0-8",
    routes: Annotated[str, typer.Option(help="Route set of the greedy evaluation: validation (model selection) or "
                                             "paper (the test routes, for reporting).")] = "validation",
    variants: Annotated[str | None, typer.Option(help="Comma-separated subset of the grid's variants.")] = None,
    episodes: Annotated[str | None, typer.Option(help="Evaluate on a deterministic subset: a count (20) or a "
                                                      "fraction (0.25) of the route set's episodes.")] = None,
    workers: Annotated[int, typer.Option(help="Parallel processes (a local Ray instance's CPUs).")] = 1,
    executor: Annotated[str, typer.Option(help=EXECUTOR_HELP)] = "local",
    ray_address: Annotated[str | None, typer.Option(help=RAY_ADDRESS_HELP)] = None,
    out: Annotated[str | None, typer.Option("--out", help="Sweep directory (VARIANT/seed_N/ runs, sweep.md/csv/png/"
                                                          f"json; default: {FRESH_OUT.format(command='sweep')}).")]
    = None,
    resume: Annotated[bool, typer.Option("--resume", help="Continue a sweep in --out: finished runs are skipped, "
                                                          "unfinished ones resume from their checkpoint.")] = False,
    report_only: Annotated[Path | None, typer.Option("--report-only", help="Rebuild the tables and plot of the sweep "
                                                                           "in this directory from its finished runs."
                                                     )] = None,
) -> None:
    """Train every variant of a grid for several seeds, evaluate every model on a route set, compare the variants."""
    from rich.console import Console
    from rich.progress import BarColumn, MofNCompleteColumn, Progress, TextColumn, TimeElapsedColumn

    from brlcli.sweep import plan_sweep, prepare_sweep, run_sweep, write_tables
    from brlcli.train import parse_seeds

    console = Console(stderr=True, width=None if sys.stderr.isatty() else 120)
    if report_only is not None:
        if grid is not None:
            raise_input("give a grid file or --report-only DIR, not both")
        result = write_tables(report_only)
        _sweep_table(console, result)
        typer.echo(str(Path(report_only) / "sweep.md"))
        return
    if grid is None:
        raise_input("give a sweep grid file (TOML or JSON), or --report-only DIR")
    ex = _executor(executor, workers, ray_address)
    only = [v.strip() for v in variants.split(",") if v.strip()] if variants is not None else None
    plan = plan_sweep(grid, parse_seeds(seeds), routes=routes, episodes=episodes, variants=only)
    if resume and out is None:
        raise_input("--resume continues a sweep: give its --out")
    out = _out(out, "sweep")
    _check_out(out, "sweep", resume)
    prepare_sweep(plan, out, resume, write=False)  # refuse a used --out before the progress bars start
    if executor == "ray":
        with console.status("connecting to Ray"):
            ex.connect()
        console.print(f"sweep of {len(plan.runs())} runs on {ex.describe()}")
    n = len(plan.runs())
    columns = (TextColumn("{task.description:9}"), BarColumn(), MofNCompleteColumn(), TextColumn("{task.fields[now]}"),
               TimeElapsedColumn())
    with Progress(*columns, console=console) as bar:
        trained = bar.add_task("training", total=n, now="")
        evaluated = bar.add_task("evaluating", total=n, now="")
        seen: dict[tuple[str, int], int] = {}

        def report(msg: dict) -> None:  # see brlcli.sweep.run_sweep
            kind, run = msg["kind"], f"{msg['variant']} seed {msg['seed']}"
            if kind == "trained":
                bar.advance(trained)
            elif kind == "evaluated":
                bar.advance(evaluated)
            elif kind == "episode":
                key = (msg["variant"], msg["seed"])
                seen[key] = seen.get(key, 0) + 1
                bar.update(evaluated, now=f"{run}: {seen[key]} episodes")
            elif kind == "step":
                bar.update(trained, now=f"{run}: step {msg['step']}/{msg['steps']}, {msg['components']} components")

        try:
            result = run_sweep(plan, out, workers=workers, resume=resume, progress=report, executor=ex)
        except KeyboardInterrupt:
            console.print(f"interrupted: finished runs, episodes and checkpoints are kept; continue with --resume "
                          f"--out {out}")
            raise typer.Exit(130) from None
        finally:
            ex.close()
    _sweep_table(console, result)
    typer.echo(str(out / "sweep.md"))


def _sweep_table(console, result: dict) -> None:
    from rich.table import Table

    table = Table(title=f"brl sweep: {result['runs']}/{result['total']} runs finished in {result['out']}")
    for col in ("variant", "seeds", "success", "either", "score", "best", "success posterior"):
        table.add_column(col, justify="left" if col in ("variant", "best") else "right")
    for r in result["rows"]:
        if not r["seeds"]:
            table.add_row(r["variant"], "0", *(["–"] * 5))
            continue
        table.add_row(r["variant"], str(r["seeds"]), f"{r['success_mean']:.1%} ± {r['success_std']:.1%}",
                      f"{r['either_mean']:.1%} ± {r['either_std']:.1%}",
                      f"{r['score_mean']:.3f} ± {r['score_std']:.3f}", f"seed_{r['best_seed']} ({r['best_score']:.3f})",
                      f"{r['success_posterior_mean']:.1%} [{r['success_posterior_lo']:.1%}, "
                      f"{r['success_posterior_hi']:.1%}]")
    console.print(table)
    for note in result["notes"]:
        console.print(f"note: {note}")


CORL_TRAFFIC = {"town01": (20, 50), "town02": (15, 50)}


@app.command()
def collect(
    town: Annotated[str, typer.Option(help="Town to drive in.")] = "town01",
    weathers: Annotated[str, typer.Option(help="Comma-separated weather ids or names, cycled per episode.")]
    = "1,3,6,8",
    episodes: Annotated[int | None, typer.Option(help="Number of episodes (one bag each).")] = None,
    frames: Annotated[int | None, typer.Option(help="Total recorded frames (alternative to --episodes).")] = None,
    episode_frames: Annotated[int, typer.Option(help="Recorded frames per episode.")] = 300,
    every: Annotated[int, typer.Option(help="Record every N-th simulated frame (10 fps / N).")] = 1,
    seed: Annotated[int, typer.Option(help="Seed of routes, noise and traffic.")] = 0,
    out: Annotated[str | None, typer.Option("--out", help="Output directory (episode_NNNNN/ bags; default: "
                                                          f"{FRESH_OUT.format(command='collect')}).")] = None,
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
    import math
    from dataclasses import asdict

    from rich.console import Console
    from rich.progress import BarColumn, MofNCompleteColumn, Progress, TextColumn, TimeElapsedColumn

    from brlcli.collect import CollectConfig, check_output
    from brlcli.collect import collect as run_collect
    from brlcli.sim.camera import CameraConfig
    from brlcli.sim.town import load_town
    from brlcli.sim.weather import get_weather

    name = load_town(town).name
    wl = tuple(get_weather(w.strip()).id for w in weathers.split(",") if w.strip())
    if episodes is not None and frames is not None:
        raise_input("give --episodes or --frames, not both")
    if frames is not None:
        if frames < 1:
            raise_input("--frames must be at least 1")
        episodes = math.ceil(frames / episode_frames)
    try:
        camera = asdict(CameraConfig(width=width, height=height))
    except ValueError as exc:
        raise_input(str(exc))
    vehicles, pedestrians = CORL_TRAFFIC.get(name, (15, 50)) if traffic else (0, 0)
    cfg = CollectConfig(town=town, weathers=wl, episodes=10 if episodes is None else episodes,
                        episode_frames=episode_frames, every=every,
                        seed=seed, storage=storage, vehicles=vehicles, pedestrians=pedestrians, noise=noise,
                        excursions=excursions, depth=depth, camera=camera)
    if resume and out is None:
        raise_input("--resume continues a recording: give its --out")
    out = _out(out, "collect")
    check_output(cfg, out, resume)
    _check_out(out, "collect", resume)
    console = Console(stderr=True)
    total = cfg.episodes * cfg.episode_frames
    columns = (TextColumn("recording"), BarColumn(), MofNCompleteColumn(),
               TextColumn("{task.fields[fps]:6.0f} frames/s"), TimeElapsedColumn())
    with Progress(*columns, console=console) as bar:
        task = bar.add_task("", total=total, fps=0.0)

        def report(_episode: int, recorded: int, fps: float) -> None:
            bar.update(task, completed=recorded, fps=fps)

        try:
            result = run_collect(cfg, out, resume=resume, progress=report)
        except KeyboardInterrupt:
            console.print(f"interrupted: finished episodes are kept; continue with --resume --out {out}")
            raise typer.Exit(130) from None
        bar.update(task, completed=total)
    console.print(f"{result['frames']} frames in {len(result['bags'])} bags, {result['frames_per_s']:.0f} frames/s")
    typer.echo(str(out))


@app.command()
def bench(
    suite: Annotated[str, typer.Option(help="paper (lane-keeping table), validation (the paper suite on the towns' "
                                            "validation routes), corl2017 or nocrash.")] = "paper",
    agent: Annotated[str, typer.Option(help="brl (trained models), autopilot (privileged expert), oracle (the "
                                            "expert restricted to the BRL agent's actions), mp (modular pipeline), "
                                            "il (imitation learning), dqn (deep RL).")] = "brl",
    model: Annotated[str | None, typer.Option(help="A trained model: BRL model.npz or run dir; il: il.pt or its dir; "
                                                   "dqn: drl.pt or its dir (default: the shipped one).")] = None,
    models: Annotated[list[str] | None, typer.Option(help="A model set: a directory of seed_N/ runs, or a glob "
                                                          "(default: the shipped GT set models/brl_gt).")] = None,
    deploy: Annotated[str, typer.Option(help="Deployment input: gt or estimated.")] = "gt",
    segnet: Annotated[str | None, typer.Option(help="Segmentation net for --deploy estimated (default: shipped).")]
    = None,
    conditions: Annotated[str | None, typer.Option(help="corl2017, nocrash: training,new_weather,new_town,"
                                                        "new_town_weather; paper, validation: unseen_town,"
                                                        "training_town.")] = None,
    tasks: Annotated[str | None, typer.Option(help="Comma-separated tasks (corl2017: straight,one_curve,navigation,"
                                                   "navigation_dynamic; nocrash: empty,regular,dense).")] = None,
    weathers: Annotated[str | None, typer.Option(help="Comma-separated weather ids or names.")] = None,
    episodes: Annotated[str | None, typer.Option(help="Deterministic subset: a count (40) or a fraction (0.1).")]
    = None,
    workers: Annotated[int, typer.Option(help="Local worker processes (a local Ray instance's CPUs).")] = 1,
    executor: Annotated[str, typer.Option(help=EXECUTOR_HELP)] = "local",
    ray_address: Annotated[str | None, typer.Option(help=RAY_ADDRESS_HELP)] = None,
    shard: Annotated[str | None, typer.Option(help="Run slice K of N (K/N), e.g. one Docker job per shard.")] = None,
    seed: Annotated[int, typer.Option(help="Bench seed (traffic and weather noise per episode).")] = 0,
    out: Annotated[str | None, typer.Option("--out", help="Results directory (default: "
                                                          f"{FRESH_OUT.format(command='bench')}).")] = None,
    resume: Annotated[bool, typer.Option("--resume", help="Skip episodes already in --out.")] = False,
) -> None:
    """Run the paper's test suite or the CoRL2017 benchmark for BRL models or a baseline (setting from the inputs)."""
    from rich.console import Console
    from rich.progress import BarColumn, MofNCompleteColumn, Progress, TextColumn, TimeElapsedColumn
    from rich.table import Table

    from brlcli.bench.registry import baseline_specs, build_policy, check_suite_task, find_models
    from brlcli.bench.runner import prepare, run_bench, suite_version, town_versions
    from brlcli.bench.suites import build_suite, parse_shard, subset
    from brlcli.bench.suites import shard as take_shard
    from brlcli.policy import PolicySpec, model_variant

    ex = _executor(executor, workers, ray_address)
    k, n = parse_shard(shard)
    specs = take_shard(subset(build_suite(suite, conditions, tasks, weathers), episodes), k, n)
    if deploy not in ("gt", "estimated"):
        raise_input(f"--deploy must be gt or estimated, not '{deploy}'")
    if agent == "brl":
        pols = [PolicySpec("brl", name, {"model": path, "deploy": deploy, "segnet": segnet})
                for name, path in find_models(model, models)]
    else:
        if models:
            raise_input(f"--models is for brl model sets; give --agent {agent} one --model")
        pols = [PolicySpec(agent, name, opts) for name, opts in baseline_specs(agent, model, deploy, segnet)]
    for p in pols:  # load every model once here: a bad file fails before anything is written
        check_suite_task(suite, build_policy(p.kind, p.name, p.options))
    if deploy == "estimated" and agent in ("brl", "mp", "dqn"):
        _segnet_notice(segnet)
    variants = {p.name: model_variant(Path(p.options["model"])) for p in pols if p.kind == "brl"}
    config = {"suite": suite, "suite_version": suite_version(suite), "town_versions": town_versions(specs),
              "policies": [{"kind": p.kind, "name": p.name, **p.options,
                            **({"variant": variants[p.name]} if p.name in variants else {})} for p in pols],
              "deploy": deploy,
              "seed": seed, "selection": {"conditions": conditions, "tasks": tasks, "weathers": weathers,
                                          "episodes": episodes}, "shard": [k, n]}
    if resume and out is None:
        raise_input("--resume continues a bench: give its --out")
    out = _out(out, "bench")
    _check_out(out, "bench", resume)
    console = Console(stderr=True)
    if executor == "ray":
        with console.status("connecting to Ray"):
            ex.connect()  # before anything is written: an unreachable cluster is a one-line error
    try:
        done = prepare(out, config, resume)
    except BaseException:
        ex.close()
        raise
    total = len(specs) * len(pols)
    columns = (TextColumn("bench {task.fields[suite]}"), BarColumn(), MofNCompleteColumn(),
               TextColumn("{task.fields[rate]:6.1f} episodes/min  success {task.fields[succ]:3.0f}%  "
                          "({task.fields[where]})"), TimeElapsedColumn())
    import time

    t0 = time.perf_counter()
    with Progress(*columns, console=console) as bar:
        task = bar.add_task("", total=total, completed=min(len(done), total), suite=suite, rate=0.0, succ=0.0,
                            where=ex.describe())
        stats = {"n": 0, "ok": 0}

        def report(r: dict) -> None:
            stats["n"] += 1
            stats["ok"] += int(r["success"])
            bar.update(task, advance=1, rate=60.0 * stats["n"] / (time.perf_counter() - t0),
                       succ=100.0 * stats["ok"] / stats["n"])

        try:
            results = run_bench(specs, pols, out, config, resume=True, progress=report, executor=ex)
        except KeyboardInterrupt:
            console.print(f"interrupted: finished episodes are saved; continue with --resume --out {out}")
            raise typer.Exit(130) from None
        finally:
            ex.close()
    table = Table(title=f"{suite}: {len(results)} episodes in {out}")
    for col in ("policy", "setting", "episodes", "success", "collision-free", "either", "km"):
        table.add_column(col, justify="right")
    for p in pols:
        rows = [r for r in results if r["policy"] == p.name]
        if not rows:
            continue
        steps = sum(r["steps"] for r in rows)
        table.add_row(p.name, rows[0]["setting"], str(len(rows)),
                      f"{100 * sum(r['success'] for r in rows) / len(rows):.0f}%",
                      f"{100 * sum(not r['collided'] for r in rows) / len(rows):.0f}%",
                      f"{100 * sum(r['either_steps'] for r in rows) / max(steps, 1):.1f}%",
                      f"{sum(r['km'] for r in rows):.2f}")
    console.print(table)
    typer.echo(str(out))


@app.command()
def report(
    results: Annotated[list[Path] | None, typer.Argument(help="`brl bench` results directories (shards, settings, "
                                                              "agents) to merge.")] = None,
    runs: Annotated[list[Path] | None, typer.Option("--runs", help="Training runs for the convergence plots: a run "
                                                                   "directory or a directory of seed_N/ runs "
                                                                   "(repeatable).")] = None,
    curves: Annotated[list[Path] | None, typer.Option("--curves", help="Runs with learning_curve.csv (brl train "
                                                                       "--curve-every, brl train-rl) for the sample-"
                                                                       "efficiency table and plot (repeatable).")]
    = None,
    out: Annotated[str, typer.Option("--out", help="Report directory (rebuilt in place).")] = "runs/report",
    formats: Annotated[str, typer.Option("--format", help="Comma-separated outputs: md, tex, csv, html.")]
    = "md,tex,csv,html",
) -> None:
    """Tables (the paper's test table, CoRL2017), Beta posteriors and plots beside the published figures."""
    from rich.console import Console
    from rich.table import Table

    from brlcli.report import build_report

    console = Console(stderr=True, width=None if sys.stderr.isatty() else 120)
    out = _out(out, "report")
    _check_out(out, "report", overwrite=True)
    with console.status("building the report"):
        rep = build_report(results or [], runs or [], out, formats, curve_dirs=curves or [])
    table = Table(title=f"brl report: {rep['episodes']} episodes -> {out}")
    for col in ("suite", "setting", "agent", "episodes", "success", "collision-free", "either", "score", "km"):
        table.add_column(col, justify="left" if col in ("suite", "setting", "agent") else "right")

    def cell(row: dict, key: str, fmt: str) -> str:
        value = row.get(key)
        return "–" if value is None or value != value else format(value, fmt)

    for row in rep["summary"]:
        table.add_row(row["suite"], row["setting"], row["agent"], str(row["episodes"]),
                      cell(row, "success", ".1%"), cell(row, "collision_free", ".1%"), cell(row, "either", ".1%"),
                      cell(row, "score", ".2f"), cell(row, "km", ".2f"))
    console.print(table)
    for note in rep["notes"]:
        console.print(f"note: {note}")
    typer.echo(str(Path(out) / ("report.md" if "report.md" in rep["files"] else "report.json")))


@app.command("train-seg")
def train_seg(
    data: Annotated[list[str], typer.Option(help="Training bags: bag directories, directories of bags, globs.")],
    val: Annotated[list[str] | None, typer.Option(help="A validation set (repeatable; the first picks the best "
                                                       "epoch and calibrates it). None: hold out episodes of --data.")]
    = None,
    val_fraction: Annotated[float, typer.Option(help="Share of --data episodes held out when no --val.")] = 0.1,
    epochs: Annotated[int, typer.Option(help="Training epochs.")] = 14,
    batch_size: Annotated[int, typer.Option(help="Batch size (>= 4).")] = 16,
    class_weights: Annotated[str, typer.Option(help="Cross-entropy class weights: enet (1 / ln(1.02 + p_c)) or "
                                                    "none.")] = "enet",
    fine_channels: Annotated[int, typer.Option(help="Channels of the output-stride-2 refinement (0: none, the "
                                                    "brl 0.1 net).")] = 0,
    select: Annotated[str, typer.Option(help="Best epoch by the first validation set's miou (category mean IoU) "
                                             "or state (mean state L1).")] = "miou",
    seed: Annotated[int, typer.Option(help="Seed of initialisation, order and augmentation.")] = 0,
    workers: Annotated[int, typer.Option(help="CPU threads for torch.")] = 2,
    out: Annotated[str | None, typer.Option("--out", help="Output directory (segnet.pt = best epoch, calibrated; "
                                                          "best.pt, last.pt, metrics.jsonl, calibration.json; default: "
                                                          f"{FRESH_OUT.format(command='train-seg')}).")] = None,
    resume: Annotated[bool, typer.Option("--resume", help="Continue from the last finished epoch in --out.")] = False,
) -> None:
    """Train the EncNet-style segmentation net on frames recorded by brl collect, then calibrate it for the state."""
    import json

    from rich.console import Console

    from brlcli.provenance import atomic_write_json, provenance
    from brlcli.segdata import load_frames, resolve_data
    from brlcli.segnet.model import SegNetConfig
    from brlcli.segnet.train import SegTrainConfig, train_segnet

    if fine_channels < 0:
        raise_input("--fine-channels must be >= 0")
    cfg = SegTrainConfig(epochs=epochs, batch_size=batch_size, seed=seed, threads=workers,
                         class_weighting=class_weights, select=select,
                         net=SegNetConfig(fine=fine_channels).to_dict())
    train_bags, val_bags = resolve_data(data, val, val_fraction, seed)
    record = provenance({**cfg.to_dict(), "data": [str(b) for b in train_bags],
                         "val": {k: [str(b) for b in v] for k, v in val_bags.items()}}, kind="train-seg")
    if resume and out is None:
        raise_input("--resume continues a run: give its --out")
    out = _out(out, "train-seg")
    _check_out(out, "train-seg", resume)
    cfg_path = out / "config.json"
    if cfg_path.exists():
        if not resume:
            raise_input(f"{out} already holds a segmentation run; pass --resume or choose another --out")
        if json.loads(cfg_path.read_text())["config"] != record["config"]:
            raise_input(f"{out} holds a run with other options or data; resume with the same options")
    console = Console(stderr=True)
    with console.status("reading bags"):
        train_frames = load_frames(train_bags)
        val_frames = {k: load_frames(v) for k, v in val_bags.items()}
    console.print(f"{len(train_frames)} training frames; validation: "
                  + ", ".join(f"{k} {len(v)}" for k, v in val_frames.items()))
    atomic_write_json(cfg_path, record)

    def report(r: dict) -> None:
        if "calibration" in r:
            console.print(f"calibration on {next(iter(val_frames))}: {r['calibration']}")
            return
        vals = "  ".join(f"{k}: mIoU cat {r[k]['miou_categories']:.3f} state L1 {r[k]['state_l1']:.3f}"
                         for k in val_frames)
        console.print(f"epoch {r['epoch']:3d}/{epochs}  loss {r['loss']:.4f}  {vals}  ({r['wall_s']:.0f} s)")

    try:
        result = train_segnet(train_frames, val_frames, cfg, out, progress=report, resume=resume)
    except KeyboardInterrupt:
        console.print(f"interrupted: finished epochs are saved; continue with --resume --out {out}")
        raise typer.Exit(130) from None
    console.print(f"best epoch by {select} on {next(iter(val_frames))}: {result['best']:.3f}; calibrated:")
    calibrated = {name: sets["calibrated"] for name, sets in result["calibration"]["sets"].items()}
    _table_console().print(_seg_table(calibrated, "segmentation net (calibrated)"))
    typer.echo(str(out / "segnet.pt"))


def _table_console():  # -> rich.console.Console
    """A stdout console wide enough for the segmentation tables, also when piped (rich's default is then 80)."""
    from rich.console import Console

    console = Console()
    return console if console.is_terminal else Console(width=160)


def _seg_table(results: dict, title: str):  # -> rich.table.Table
    """IoU and state error per set of frames (what `brl eval-seg` and `brl train-seg` print)."""
    from rich.table import Table

    table = Table(title=title)
    for col in ("set", "frames", "mIoU 5 cat", "road", "line", "off-road", "dynamic", "static", "state L1",
                "line bias", "road bias", "line area", "road area"):
        table.add_column(col, justify="left" if col == "set" else "right")

    def num(value: float | None, fmt: str) -> str:
        return "–" if value is None else format(value, fmt)

    for name, r in results.items():
        iou = r["iou_categories"]
        table.add_row(name, str(r["frames"]), f"{r['miou_categories']:.3f}",
                      *(num(iou[k], ".3f") for k in ("road", "road_line", "off_road", "dynamic", "static")),
                      f"{r['state_l1']:.3f}", num(r["state_bias"]["road_line"], "+.3f"),
                      num(r["state_bias"]["road"], "+.3f"), num(r["area_ratio"]["road_line"], ".2f") + "x",
                      num(r["area_ratio"]["road"], ".2f") + "x")
    return table


@app.command("eval-seg")
def eval_seg(
    data: Annotated[list[str], typer.Option(help="Recorded bags to evaluate on (repeatable: one set each).")],
    segnet: Annotated[str | None, typer.Option(help="Segmentation-net file (default: the shipped one).")] = None,
    uncalibrated: Annotated[bool, typer.Option("--uncalibrated", help="Ignore the file's calibration (logit "
                                                                     "offsets).")] = False,
    out: Annotated[Path | None, typer.Option("--out", help="Also write the figures to this JSON file.")] = None,
) -> None:
    """IoU and the state error (L1 between GT and estimated states, bias, area ratios) of a net on bags."""
    from rich.console import Console

    from brlcli.bags import find_bags
    from brlcli.models import default_segnet_path
    from brlcli.provenance import atomic_write_json, provenance
    from brlcli.segdata import load_frames
    from brlcli.segnet.filetools import evaluate_file
    from brlcli.segnet.io import load_segnet

    path = Path(segnet) if segnet else default_segnet_path()
    load_segnet(path)  # a bad file fails before the bags are read
    sets = {_set_name(d): find_bags([d]) for d in data}
    if out is not None and out.is_dir():
        raise_input(f"--out {out} is a directory; give a JSON file name")
    console = Console(stderr=True)
    with console.status("reading bags"):
        frames = {name: load_frames(bags) for name, bags in sets.items()}
    with console.status("segmenting"):
        result = evaluate_file(path, frames, calibrated=not uncalibrated)
    if result["calibration"] == "none in file":
        console.print(f"note: {path} carries no calibration (format {result['format_version']})")
    _table_console().print(_seg_table(result["sets"], f"{path} ({result['calibration']} calibration)"))
    if out is not None:
        atomic_write_json(out, provenance({"segnet": str(path), "data": {k: [str(b) for b in v]
                                                                          for k, v in sets.items()},
                                           "uncalibrated": uncalibrated}) | {"results": result})
        typer.echo(str(out))


def _set_name(data: str) -> str:
    """A data set's name in tables: its directory name."""
    return Path(data).name or str(data)


@app.command("calibrate-seg")
def calibrate_seg(
    data: Annotated[list[str], typer.Option(help="Held-out recorded bags to fit the calibration on (not the "
                                                 "net's training bags, not the ones you report on).")],
    out: Annotated[Path, typer.Option("--out", help="The calibrated net's file (must not exist).")],
    segnet: Annotated[str | None, typer.Option(help="Segmentation-net file (default: the shipped one).")] = None,
) -> None:
    """Fit a net's per-class logit offsets so that its labels give the states of the ground truth."""
    from rich.console import Console

    from brlcli.bags import find_bags
    from brlcli.models import default_segnet_path
    from brlcli.segdata import load_frames
    from brlcli.segnet.filetools import calibrate_file
    from brlcli.segnet.io import load_segnet

    path = Path(segnet) if segnet else default_segnet_path()
    load_segnet(path, deployable=False)
    bags = find_bags(list(data))
    if out.exists():
        raise_input(f"{out} already exists; choose another --out")
    console = Console(stderr=True)
    with console.status("reading bags"):
        frames = load_frames(bags)
    name = ",".join(_set_name(d) for d in data)
    with console.status("calibrating") as status:
        record = calibrate_file(path, frames, out, name, progress=lambda m: status.update(f"calibrating: {m}"))
    _table_console().print(_seg_table({f"{name} before": record["sets"][name]["uncalibrated"],
                                f"{name} after": record["sets"][name]["calibrated"]}, f"{out}"))
    typer.echo(str(out))


@app.command("train-il")
def train_il(
    data: Annotated[list[str], typer.Option(help="Demonstration bags from brl collect (--every 1 pairs each image "
                                                 "with its own expert control): bags, directories, globs.")],
    val: Annotated[list[str] | None, typer.Option(help="Validation bags (default: hold out whole bags of --data).")]
    = None,
    val_fraction: Annotated[float, typer.Option(help="Share of --data bags held out when no --val.")] = 0.1,
    epochs: Annotated[int, typer.Option(help="Training epochs.")] = 5,
    batch_size: Annotated[int, typer.Option(help="Batch size (>= 4).")] = 64,
    seed: Annotated[int, typer.Option(help="Seed of initialisation, order, split and augmentation.")] = 0,
    workers: Annotated[int, typer.Option(help="CPU threads for torch.")] = 2,
    out: Annotated[str | None, typer.Option("--out", help="Run directory (il.pt = best, last.pt, metrics.jsonl; "
                                                          f"default: {FRESH_OUT.format(command='train-il')}).")]
    = None,
    resume: Annotated[bool, typer.Option("--resume", help="Continue from the last finished epoch in --out.")] = False,
) -> None:
    """Train the conditional imitation-learning baseline (CIL-style branched CNN) on autopilot demonstrations."""
    from rich.console import Console

    from brlcli.bags import find_bags
    from brlcli.baselines.il import ILTrainConfig
    from brlcli.baselines.il import train_il as run_train_il

    cfg = ILTrainConfig(epochs=epochs, batch_size=batch_size, seed=seed, threads=workers, val_fraction=val_fraction)
    find_bags(list(data))  # fail early on missing bags
    if val:
        find_bags(list(val))
    if resume and out is None:
        raise_input("--resume continues a run: give its --out")
    out = _out(out, "train-il")
    if (out / "config.json").exists() and not resume:
        raise_input(f"{out} already holds an imitation-learning run; pass --resume or choose another --out")
    _check_out(out, "train-il", resume)
    console = Console(stderr=True)

    def report(r: dict) -> None:
        v = r.get("val", {})
        val_text = f"  val loss {v['loss']:.4f}  steer MAE {v['mae_steer']:.4f}" if v else ""
        console.print(f"epoch {r['epoch']:3d}/{epochs}  train loss {r['train_loss']:.4f}{val_text}  "
                      f"({r['wall_s']:.0f} s)")

    try:
        with console.status("reading bags and training"):
            result = run_train_il(cfg, list(data), out, val=list(val) if val else None, resume=resume,
                                  progress=report)
    except KeyboardInterrupt:
        console.print(f"interrupted: finished epochs are saved; continue with --resume --out {out}")
        raise typer.Exit(130) from None
    console.print(f"{result['train_frames']} training frames, {result['val_frames']} validation frames; best "
                  f"validation loss {result['best_val_loss']:.4f}")
    typer.echo(result["model"])


@app.command("train-rl")
def train_rl(
    algo: Annotated[str, typer.Option(help="Deep RL algorithm (Stable-Baselines3): dqn.")] = "dqn",
    task: Annotated[str, typer.Option(help="lane-keeping or navigation (brl train's tasks; navigation adds the "
                                           "one-hot route command to the state).")] = "lane-keeping",
    town: Annotated[str, typer.Option(help="Town to train in (the BRL agent's: town01).")] = "town01",
    weather: Annotated[str, typer.Option(help="Weather id or name.")] = "1",
    input: Annotated[str, typer.Option("--input", help="State source: gt or estimated.")] = "gt",
    steps: Annotated[int, typer.Option(help="Budget in environment steps (decisions).")] = 100_000,
    eval_every: Annotated[int, typer.Option(help="Evaluate on --eval-suite every N env steps (learning curve).")]
    = 5_000,
    eval_suite: Annotated[str, typer.Option(help="paper (the lane-keeping test suite), nav_validation (the "
                                                 "navigation task's) or none; auto: the task's.")] = "auto",
    seed: Annotated[int, typer.Option(help="Seed of the network, exploration and routes.")] = 0,
    out: Annotated[str | None, typer.Option("--out", help="Run directory (drl.pt, learning_curve.csv, checkpoint/; "
                                                          f"default: {FRESH_OUT.format(command='train-rl')}).")]
    = None,
    resume: Annotated[bool, typer.Option("--resume", help="Continue from the last finished chunk in --out.")] = False,
    segnet: Annotated[str | None, typer.Option(help="Segmentation net for --input estimated (default: shipped).")]
    = None,
    config: Annotated[str | None, typer.Option("--config", help="TOML file of deep RL config overrides (keys of its "
                                                                "config.json), under the options.")] = None,
    set_: Annotated[list[str] | None, typer.Option("--set", help="KEY=VALUE override of any deep RL config key, "
                                                                 "e.g. the reward and episode options of brl train "
                                                                 "(target_speed_kmh, road_view, offroad_end, "
                                                                 "otherlane_end, start_offset_m, start_yaw_deg, "
                                                                 "camera_pitch_deg); repeatable; applied last.")]
    = None,
    print_config: Annotated[bool, typer.Option("--print-config", help="Print the resolved configuration (JSON) "
                                                                      "and exit.")] = False,
    ctx: typer.Context = None,  # type: ignore[assignment]
) -> None:
    """Train the deep RL baseline (SB3 DQN) on the BRL agent's env, state, reward and actions."""
    import json

    from rich.console import Console
    from rich.progress import BarColumn, MofNCompleteColumn, Progress, TextColumn, TimeElapsedColumn

    from brlcli.baselines.deeprl import DeepRLConfig, check_run_dir, train_deep_rl
    from brlcli.bench.runner import suite_evaluator
    from brlcli.sim.town import load_town
    from brlcli.sim.weather import get_weather
    from brlcli.trainconfig import resolve_plain_config

    options = {"algo": algo, "task": task, "town": town, "weather": get_weather(weather).id, "input": input,
               "steps": steps,
               "eval_every": eval_every, "eval_suite": eval_suite, "seed": seed, "segnet": segnet}
    given = {k: v for k, v in options.items()  # typer may vendor click: compare the source by name
             if getattr(ctx.get_parameter_source(k), "name", None) == "COMMANDLINE"}
    cfg = resolve_plain_config(DeepRLConfig, [config, given, set_ or []], what="deep RL")
    cfg = _with_segnet(cfg)
    if print_config:
        typer.echo(json.dumps(cfg.to_dict(), indent=2, sort_keys=True))
        return
    load_town(cfg.town)
    algo, steps = cfg.algo, cfg.steps
    if cfg.input == "estimated":
        from brlcli.segnet import labeler_for

        labeler_for(cfg.input, cfg.segnet, "--input")
        _segnet_notice(cfg.segnet)
    if resume and out is None:
        raise_input("--resume continues a run: give its --out")
    out = _out(out, "train-rl")
    check_run_dir(cfg, out, resume)
    _check_out(out, "train-rl", resume)
    console = Console(stderr=True)
    suite = cfg.evaluation_suite
    columns = (TextColumn(f"{algo}"), BarColumn(), MofNCompleteColumn(),
               TextColumn("episodes {task.fields[eps]}  epsilon {task.fields[expl]:.2f}  "
                          + (f"{suite} success {{task.fields[succ]}}" if suite != "none" else "no evaluation")),
               TimeElapsedColumn())
    with Progress(*columns, console=console) as bar:
        task = bar.add_task("", total=steps, eps=0, expl=1.0, succ="-")

        def report(p) -> None:  # p: brlcli.baselines.deeprl.DeepRLProgress
            fields = {"completed": p.env_steps, "eps": p.episodes, "expl": p.exploration}
            if p.success is not None:
                fields["succ"] = f"{p.success:.0%} at {p.env_steps}"
            bar.update(task, **fields)

        try:
            result = train_deep_rl(cfg, out, resume=resume, progress=report, evaluator=suite_evaluator(suite))
        except KeyboardInterrupt:
            console.print(f"interrupted: finished chunks are checkpointed; continue with --resume --out {out}")
            raise typer.Exit(130) from None
    s = result["summary"]
    line = f"{s['env_steps']} env steps, {s['episodes']} episodes, {s['steps_per_s']:.0f} steps/s"
    if s.get("final_eval"):
        line += f", {suite} success {s['final_eval']['success']:.0%}"
    console.print(line)
    typer.echo(str(out / "drl.pt"))


def _segnet_notice(segnet: str | None) -> None:
    """Say on one line (stderr) when the estimated input comes from an uncalibrated (brl 0.1) net file."""
    from brlcli.segnet.infer import uncalibrated_notice

    message = uncalibrated_notice(segnet)
    if message:
        typer.echo(f"brl: notice: {message}", err=True)


def raise_input(message: str) -> None:
    """Raise the one-line input error the entry point turns into exit code 2."""
    from brlcli.errors import BrlInputError

    raise BrlInputError(message)


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
        code = typer.main.get_command(app).main(args, prog_name="brl", standalone_mode=False)
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


def _fail(message: str, code: int) -> None:
    """Print `brl: error: MESSAGE` on one line and exit with `code`."""
    line = " ".join(str(message).split())
    typer.echo(f"brl: error: {line}", err=True)
    sys.exit(code)


if __name__ == "__main__":
    main()
