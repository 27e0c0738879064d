"""`brl train`, `brl sweep`, `brl train-rl`, `brl train-il`: the commands that train policies."""

from __future__ import annotations

from pathlib import Path
from typing import Annotated, Any

import typer

from brlcli.cli.common import (
    ConfigFile,
    Device,
    ExecutorKind,
    LazyProgress,
    PrintConfig,
    RayAddress,
    Resume,
    Sets,
    Workers,
    app,
    given,
    make_executor,
    out_option,
    print_config,
    raise_input,
    run_command,
    segnet_notice,
    stderr_console,
)

VARIANT_HELP = ("Method: action-averaging-committee (recommended, outside the paper: five agents trained apart that "
                "vote, each with its action values the averages of their TD targets and a restart when trapped), "
                "action-averaging-restart (one such agent), paper (eqs. 1-11, Algorithm 1, Table I as written), "
                "averaging-restart (per-component averaging), reference-code (the authors' code's agent).")


@app.command()
def train(
    ctx: typer.Context,
    task: Annotated[str, typer.Option(help="lane-keeping (the paper's) or navigation (route commands at junctions; "
                                           "outside the paper).")] = "lane-keeping",
    town: Annotated[str, typer.Option(help="Town to train in.")] = "town01",
    weather: Annotated[str, typer.Option(help="Weather id or name (the paper trains in 1, ClearNoon).")] = "1",
    input: Annotated[str, typer.Option("--input", help="State source: gt (simulator labels) or estimated.")] = "gt",
    steps: Annotated[int, typer.Option(help="Learning steps per model (paper: t_max = 4500; --task navigation's "
                                            "preset: 27000).")] = 4500,
    seed: Annotated[int, typer.Option(min=0, help="Seed of a single model.")] = 0,
    seeds: Annotated[str | None, typer.Option(help="Train a model set, e.g. 0-8 (overrides --seed).")] = None,
    workers: Workers = 1,
    executor: ExecutorKind = "local",
    ray_address: RayAddress = None,
    out: Annotated[str | None, out_option("train", "one seed_N/ per model")] = None,
    resume: Resume = False,
    variant: Annotated[str, typer.Option(help=VARIANT_HELP)] = "action-averaging-committee",
    target_speed_kmh: Annotated[float, typer.Option(help="Reward's target speed v_t, km/h.")] = 20.0,
    evaluate: Annotated[bool, typer.Option(help="Greedy evaluation on the task's validation routes at the end.")]
    = True,
    segnet: Annotated[str | None, typer.Option(help="Segmentation net for --input estimated (default: shipped).")]
    = None,
    curve_every: Annotated[int, typer.Option(help="Evaluate greedily on the task's evaluation suite every N steps "
                                                  "and write learning_curve.csv (0: never).")] = 0,
    config: ConfigFile = None,
    set_: Sets = None,
    print_config_: PrintConfig = False,
) -> None:
    """Online Bayesian RL training of the driving agent (paper Sec. III-IV)."""
    from brlcli.config import command_layers
    from brlcli.sim.weather import get_weather
    from brlcli.train import parse_seeds, train_many
    from brlcli.trainconfig import resolve_train_config

    options = {"task": ("task", task), "town": ("town", town), "weather": ("weather", get_weather(weather).id),
               "input": ("input", input), "steps": ("steps", steps), "variant": ("variant", variant),
               "target_speed_kmh": ("target_speed_kmh", target_speed_kmh), "evaluate": ("evaluate", evaluate),
               "segnet": ("segnet", segnet), "curve_every": ("curve_every", curve_every)}
    seed_list = parse_seeds(seeds) if seeds is not None else [seed]
    cfg = resolve_train_config(command_layers(config, given(ctx, options), set_)).for_seed(seed_list[0])
    if print_config_:
        print_config(cfg)
        return
    ex = make_executor(executor, workers, ray_address)
    if cfg.input == "estimated":
        segnet_notice(cfg.segnet)
    console = stderr_console()
    bars = TrainingBars(console, cfg.committee)
    with run_command("train", out, resume, overwrite=True, executor=ex, console=console,
                     kept="finished episodes are checkpointed") as out_dir, bars:
        results = train_many(cfg, seed_list, out_dir, workers=workers, resume=resume, progress=bars.report,
                             executor=ex)
    for r in results:
        console.print(train_summary_line(r["summary"]), soft_wrap=True)
    typer.echo(str(out_dir))


class TrainingBars(LazyProgress):
    """One bar per trained model (per committee member): steps, mean reward, TD error, components."""

    def __init__(self, console: Any, committee: int) -> None:
        from rich.progress import BarColumn, MofNCompleteColumn, TextColumn, TimeElapsedColumn

        super().__init__(console, TextColumn("seed {task.fields[seed]}"), BarColumn(), MofNCompleteColumn(),
                         TextColumn("reward {task.fields[reward]:7.2f}  TD {task.fields[td]:8.2f}  "
                                    "comps {task.fields[comps]}"), TimeElapsedColumn())
        self.committee = committee
        self.tasks: dict[tuple[int, int], Any] = {}

    def report(self, p: Any) -> None:  # p: brlcli.train.Progress
        """Show a progress report."""
        key = (p.seed, p.member)
        if key not in self.tasks:
            label = (f"{p.seed} gate" if p.member < 0 else p.seed if self.committee == 1
                     else f"{p.seed} member {p.member}")
            self.tasks[key] = self.bar.add_task("", total=p.steps, seed=label, reward=0.0, td=0.0, comps=1)
        self.bar.update(self.tasks[key], completed=p.step, total=p.steps, reward=p.mean_reward, td=p.td_error,
                        comps=p.components)


def train_summary_line(s: dict) -> str:
    """One trained model's end-of-run line: totals, and the greedy evaluation's success beside Either and Score."""
    line = (f"seed {s['seed']}: {s['steps']} steps, {s['episodes']} episodes, {s['components']} components, "
            f"{s['steps_per_s']:.0f} steps/s")
    if s.get("gate"):
        driver = s["driver"]
        line += (f" (a brake gate of {s['gate']['steps']} steps in traffic over "
                 + (f"a committee of {driver['committee']}" if driver.get("committee") else "one driver")
                 + (" that imitates the expert" if driver.get("learning") == "imitation" else "") + ")")
    if s.get("imitation"):
        im = s["imitation"]
        line += (f" (imitation of the expert: {im['iterations']} DAgger iterations of {im['episodes_per_iteration']} "
                 f"episodes" + (f", agreement {im['last_agreement']:.0%} on its own states" if im["last_agreement"]
                                is not None else "") + ")")
    if s.get("committee"):
        restarted = sum(1 for m in s.get("members", []) if m.get("restarts"))
        line += (f" (a committee of {s['committee']} members, majority vote"
                 + (f"; {restarted} member{'s' if restarted > 1 else ''} restarted when trapped" if restarted else "")
                 + ")")
    if s.get("restarts"):
        why = "; ".join(f"{r['mean_reward']:.1f} per step over the window at step {r['step']:,}"
                        for r in s["restarts"])
        line += f" ({len(s['restarts'])} restart{'s' if len(s['restarts']) > 1 else ''}, trapped: {why})"
    ev = s.get("eval")
    if ev:
        task = "navigation" if str(ev.get("suite", "")).startswith("nav_validation") else "lane-keeping"
        where = f"{ev['suite']} suite" if "suite" in ev else f"{ev['town']} {ev.get('routes', 'lane_keeping')} routes"
        line += (f", {task} success {ev['success_rate']:.0%}  Either {ev['either_share']:.1%}  "
                 f"Score {ev['score']:.2f} ({where})")
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
    workers: Workers = 1,
    executor: ExecutorKind = "local",
    ray_address: RayAddress = None,
    out: Annotated[str | None, out_option("sweep", "VARIANT/seed_N/ runs, sweep.md/csv/png/json")] = None,
    resume: Annotated[bool, typer.Option("--resume", help="Continue a sweep in --out: finished runs are skipped, "
                                                          "unfinished ones resume from their checkpoint.")] = False,
    report_only: Annotated[Path | None, typer.Option("--report-only", help="Rebuild the tables and plot of the sweep "
                                                                           "in this directory from its finished runs."
                                                     )] = None,
) -> None:
    """Train every variant of a grid for several seeds, evaluate every model on a route set, compare the variants."""
    from brlcli.sweep import plan_sweep, prepare_sweep, run_sweep, write_tables
    from brlcli.train import parse_seeds

    console = stderr_console(wide=True)
    if report_only is not None:
        if grid is not None:
            raise_input("give a grid file or --report-only DIR, not both")
        result = write_tables(report_only)
        _sweep_table(console, result)
        typer.echo(str(Path(report_only) / "sweep.md"))
        return
    if grid is None:
        raise_input("give a sweep grid file (TOML or JSON), or --report-only DIR")
    ex = make_executor(executor, workers, ray_address)
    only = [v.strip() for v in variants.split(",") if v.strip()] if variants is not None else None
    plan = plan_sweep(grid, parse_seeds(seeds), routes=routes, episodes=episodes, variants=only)
    bars = SweepBars(console, len(plan.runs()))
    with run_command("sweep", out, resume, executor=ex, console=console,
                     kept="finished runs, episodes and checkpoints are kept") as out_dir, bars:
        prepare_sweep(plan, out_dir, resume, write=False)  # refuse a used --out before the progress bars start
        result = run_sweep(plan, out_dir, workers=workers, resume=resume, progress=bars.report, executor=ex)
    _sweep_table(console, result)
    typer.echo(str(out_dir / "sweep.md"))


class SweepBars(LazyProgress):
    """Two bars: runs trained, runs evaluated (with the run in progress)."""

    def __init__(self, console: Any, runs: int) -> None:
        from rich.progress import BarColumn, MofNCompleteColumn, TextColumn, TimeElapsedColumn

        super().__init__(console, TextColumn("{task.description:9}"), BarColumn(), MofNCompleteColumn(),
                         TextColumn("{task.fields[now]}"), TimeElapsedColumn())
        self.runs = runs
        self.ids: dict[str, Any] = {}
        self.seen: dict[tuple[str, int], int] = {}

    def _task(self, name: str) -> Any:
        if not self.ids:
            self.ids = {n: self.bar.add_task(n, total=self.runs, now="") for n in ("training", "evaluating")}
        return self.ids[name]

    def report(self, msg: dict) -> None:  # see brlcli.sweep.run_sweep
        """Show a progress message of the sweep."""
        kind, run = msg["kind"], f"{msg['variant']} seed {msg['seed']}"
        if kind == "trained":
            self.bar.advance(self._task("training"))
        elif kind == "evaluated":
            self.bar.advance(self._task("evaluating"))
        elif kind == "episode":
            key = (msg["variant"], msg["seed"])
            self.seen[key] = self.seen.get(key, 0) + 1
            self.bar.update(self._task("evaluating"), now=f"{run}: {self.seen[key]} episodes")
        elif kind == "step":
            self.bar.update(self._task("training"), now=f"{run}: step {msg['step']}/{msg['steps']}, "
                                                       f"{msg['components']} components")


def _sweep_table(console: Any, result: dict) -> None:
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


@app.command("train-rl")
def train_rl(
    ctx: typer.Context,
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
                                                 "navigation task's), nav_validation_traffic or none; auto: "
                                                 "the task's (with traffic: nav_validation_traffic).")] = "auto",
    seed: Annotated[int, typer.Option(min=0, help="Seed of the network, exploration and routes.")] = 0,
    device: Device = "cpu",
    out: Annotated[str | None, out_option("train-rl", "drl.pt, learning_curve.csv, checkpoint/")] = None,
    resume: Resume = False,
    segnet: Annotated[str | None, typer.Option(help="Segmentation net for --input estimated (default: shipped).")]
    = None,
    config: ConfigFile = None,
    set_: Sets = None,
    print_config_: PrintConfig = False,
) -> None:
    """Train the deep RL baseline (SB3 DQN) on the BRL agent's env, state, reward and actions."""
    from rich.progress import BarColumn, MofNCompleteColumn, TextColumn, TimeElapsedColumn

    from brlcli.baselines.deeprl import resolve_deep_rl_config, train_deep_rl
    from brlcli.bench.runner import suite_evaluator
    from brlcli.config import command_layers
    from brlcli.sim.weather import get_weather

    options = {"algo": ("algo", algo), "task": ("task", task), "town": ("town", town),
               "weather": ("weather", get_weather(weather).id), "input": ("input", input), "steps": ("steps", steps),
               "eval_every": ("eval_every", eval_every), "eval_suite": ("eval_suite", eval_suite),
               "seed": ("seed", seed), "segnet": ("segnet", segnet), "device": ("device", device)}
    cfg = resolve_deep_rl_config(command_layers(config, given(ctx, options), set_))
    if print_config_:
        print_config(cfg)
        return
    if cfg.input == "estimated":
        segnet_notice(cfg.segnet)
    suite = cfg.evaluation_suite
    console = stderr_console()
    bars = LazyProgress(console, TextColumn(f"{cfg.algo}"), BarColumn(), MofNCompleteColumn(),
                        TextColumn("episodes {task.fields[eps]}  epsilon {task.fields[expl]:.2f}  "
                                   + (f"{suite} success {{task.fields[succ]}}" if suite != "none" else
                                      "no evaluation")), TimeElapsedColumn())
    ids: list[Any] = []

    def report(p: Any) -> None:  # p: brlcli.baselines.deeprl.DeepRLProgress
        if not ids:
            ids.append(bars.bar.add_task("", total=cfg.steps, eps=0, expl=1.0, succ="-"))
        fields = {"completed": p.env_steps, "eps": p.episodes, "expl": p.exploration}
        if p.success is not None:
            fields["succ"] = f"{p.success:.0%} at {p.env_steps}"
        bars.bar.update(ids[0], **fields)

    with run_command("train-rl", out, resume, console=console, kept="finished chunks are checkpointed") as run_dir, \
            bars:
        result = train_deep_rl(cfg, run_dir, resume=resume, progress=report, evaluator=suite_evaluator(suite))
    s = result["summary"]
    line = f"{s['env_steps']} env steps, {s['episodes']} episodes, {s['steps_per_s']:.0f} steps/s"
    if s.get("final_eval"):
        line += f", {suite} success {s['final_eval']['success']:.0%}"
    console.print(line)
    typer.echo(str(run_dir / "drl.pt"))


@app.command("train-il")
def train_il(
    ctx: typer.Context,
    data: Annotated[list[str], typer.Option(help="Demonstration bags from brl collect (--every 1 pairs each image "
                                                 "with its own expert control): bags, directories, globs.")],
    val: Annotated[list[str] | None, typer.Option(help="Validation bags (default: hold out whole bags of --data).")]
    = None,
    val_fraction: Annotated[float, typer.Option(help="Share of --data bags held out when no --val.")] = 0.1,
    epochs: Annotated[int, typer.Option(help="Training epochs.")] = 5,
    batch_size: Annotated[int, typer.Option(help="Batch size (>= 4).")] = 64,
    seed: Annotated[int, typer.Option(min=0, help="Seed of initialisation, order, split and augmentation.")] = 0,
    workers: Annotated[int, typer.Option(help="CPU threads for torch.")] = 2,
    device: Device = "cpu",
    out: Annotated[str | None, out_option("train-il", "il.pt = best, last.pt, metrics.jsonl")] = None,
    resume: Resume = False,
    config: ConfigFile = None,
    set_: Sets = None,
    print_config_: PrintConfig = False,
) -> None:
    """Train the conditional imitation-learning baseline (CIL-style branched CNN) on autopilot demonstrations."""
    from brlcli.baselines.il import ILTrainConfig
    from brlcli.baselines.il import train_il as run_train_il
    from brlcli.config import command_layers, resolve

    options = {"val_fraction": ("val_fraction", val_fraction), "epochs": ("epochs", epochs),
               "batch_size": ("batch_size", batch_size), "seed": ("seed", seed), "workers": ("threads", workers),
               "device": ("device", device)}
    cfg = resolve(ILTrainConfig, command_layers(config, given(ctx, options), set_), "imitation-learning")
    if print_config_:
        print_config(cfg)
        return
    console = stderr_console()

    def report(r: dict) -> None:
        v = r.get("val", {})
        val_text = f"  val loss {v['loss']:.4f}  steer MAE {v['mae_steer']:.4f}" if v else ""
        console.print(f"epoch {r['epoch']:3d}/{cfg.epochs}  train loss {r['train_loss']:.4f}{val_text}  "
                      f"({r['wall_s']:.0f} s)")

    with run_command("train-il", out, resume, console=console, kept="finished epochs are saved") as run_dir, \
            console.status("reading bags and training"):
        result = run_train_il(cfg, list(data), run_dir, val=list(val) if val else None, resume=resume,
                              progress=report)
    console.print(f"{result['train_frames']} training frames, {result['val_frames']} validation frames; best "
                  f"validation loss {result['best_val_loss']:.4f}")
    typer.echo(result["model"])
