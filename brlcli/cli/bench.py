"""`brl bench`, `brl report`: running the suites and reporting their results."""

from __future__ import annotations

import time
from pathlib import Path
from typing import Annotated

import typer

from brlcli.cli.common import (
    ExecutorKind,
    LazyProgress,
    RayAddress,
    app,
    make_executor,
    out_option,
    run_command,
    segnet_notice,
    stderr_console,
)


@app.command()
def bench(
    suite: Annotated[str, typer.Option(help="paper (lane-keeping table), validation (the paper suite on the towns' "
                                            "validation routes), corl2017, nocrash, nav_validation or "
                                            "nav_validation_traffic.")] = "paper",
    agent: Annotated[str, typer.Option(help="brl (trained models), autopilot (privileged expert), oracle (the "
                                            "expert restricted to the BRL agent's actions), mp (modular pipeline), "
                                            "il (imitation learning), dqn (deep RL).")] = "brl",
    model: Annotated[list[str] | None, typer.Option(help="A trained model: BRL model.npz or run dir (repeatable); il: "
                                                         "il.pt or its dir; dqn: drl.pt or its dir (default: the "
                                                         "shipped one).")] = None,
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
    executor: ExecutorKind = "local",
    ray_address: RayAddress = None,
    shard: Annotated[str | None, typer.Option(help="Run slice K of N (K/N), e.g. one Docker job per shard.")] = None,
    seed: Annotated[int, typer.Option(min=0, help="Bench seed (traffic and weather noise per episode).")] = 0,
    out: Annotated[str | None, out_option("bench", "bench.json, results.jsonl, frames/")] = None,
    resume: Annotated[bool, typer.Option("--resume", help="Skip episodes already in --out.")] = False,
) -> None:
    """Run the paper's test suite or the CoRL2017 benchmark for BRL models or a baseline (setting from the inputs)."""
    from rich.progress import BarColumn, MofNCompleteColumn, TextColumn, TimeElapsedColumn
    from rich.table import Table

    from brlcli.bench.plan import plan_bench, summary_rows
    from brlcli.bench.runner import prepare, run_bench

    ex = make_executor(executor, workers, ray_address)
    plan = plan_bench(suite, agent, model, models, deploy, segnet, conditions, tasks, weathers, episodes, shard, seed)
    if deploy == "estimated" and agent in ("brl", "mp", "dqn"):
        segnet_notice(segnet)
    console = stderr_console()
    bars = LazyProgress(console, TextColumn(f"bench {suite}"), BarColumn(), MofNCompleteColumn(),
                        TextColumn("{task.fields[rate]:6.1f} episodes/min  success {task.fields[succ]:3.0f}%  "
                                   "({task.fields[where]})"), TimeElapsedColumn())
    with run_command("bench", out, resume, executor=ex, console=console, kept="finished episodes are saved") \
            as out_dir, bars:
        done = prepare(out_dir, plan.config, resume)
        task = bars.bar.add_task("", total=plan.total, completed=min(len(done), plan.total), rate=0.0, succ=0.0,
                                 where=ex.describe())
        stats, t0 = {"n": 0, "ok": 0}, time.perf_counter()

        def report(r: dict) -> None:
            stats["n"] += 1
            stats["ok"] += int(r["success"])
            bars.bar.update(task, advance=1, rate=60.0 * stats["n"] / (time.perf_counter() - t0),
                            succ=100.0 * stats["ok"] / stats["n"])

        results = run_bench(plan.specs, plan.policies, out_dir, plan.config, resume=True, progress=report,
                            executor=ex)
    table = Table(title=f"{suite}: {len(results)} episodes in {out_dir}")
    for col in ("policy", "setting", "episodes", "success", "collision-free", "either", "km"):
        table.add_column(col, justify="right", overflow="fold")  # names wrap, never cut to an ellipsis
    for row in summary_rows(plan, results):
        table.add_row(row["policy"], row["setting"], str(row["episodes"]), f"{row['success']:.0%}",
                      f"{row['collision_free']:.0%}", _share(row["either"]), f"{row['km']:.2f}")
    stderr_console(wide=True).print(table)  # a batch job's log gets the whole table, not rich's 80 columns
    typer.echo(str(out_dir))


def _share(value: float) -> str:
    return "–" if value != value else f"{value:.1%}"


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
    from rich.table import Table

    from brlcli.report import build_report

    console = stderr_console(wide=True)
    with run_command("report", out, False, overwrite=True, console=console, kept=None) as out_dir, \
            console.status("building the report"):
        rep = build_report(results or [], runs or [], out_dir, formats, curve_dirs=curves or [])
    table = Table(title=f"brl report: {rep['episodes']} episodes -> {out_dir}")
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
    typer.echo(str(out_dir / ("report.md" if "report.md" in rep["files"] else "report.json")))
