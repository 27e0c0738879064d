"""`brl reproduce`: a study of the paper (or the seg net, or navigation) as one resumable plan of brl commands."""

from __future__ import annotations

from pathlib import Path
from typing import Annotated

import typer

from brlcli.cli.common import ExecutorKind, Sets, app, stderr_console


@app.command()
def reproduce(
    study: Annotated[str, typer.Argument(help="paper (the example report: four settings for the default method and "
                                              "--variant paper, CoRL2017 and NoCrash subsets, baselines), segnet "
                                              "(frames to the calibrated net) or navigation (committees, DQN, "
                                              "CoRL2017 and NoCrash subsets).")],
    out: Annotated[Path, typer.Option("--out", help="The study's directory (train/, bench/, data/, report/, "
                                                    "study.json, steps/); run again to resume.")],
    dry_run: Annotated[bool, typer.Option("--dry-run", help="Print the plan as brl commands and exit.")] = False,
    quick: Annotated[bool, typer.Option("--quick", help="A smoke size: two seeds, short training, a few episodes "
                                                        "per suite; every table of the full report.")] = False,
    seeds: Annotated[str | None, typer.Option(help="Seeds of every training step (default 0-8; --quick 0-1).")]
    = None,
    workers: Annotated[int, typer.Option(min=1, help="Worker processes of every step that takes them.")] = 1,
    executor: ExecutorKind = "local",
    jobs: Annotated[int, typer.Option(min=1, help="Independent steps run at the same time, each a process of its own "
                                                  "(its output in steps/NAME.log); 1: one after another.")] = 1,
    set_: Sets = None,
    only: Annotated[str | None, typer.Option(help="Run only this step (its inputs must have finished).")] = None,
    from_: Annotated[str | None, typer.Option("--from", help="Run this step and the steps after it.")] = None,
) -> None:
    """Run a whole study as a declared plan of brl commands in dependency order; finished steps are kept."""
    from brlcli.reproduce import (
        StepFailed,
        StudyOptions,
        build_plan,
        check_study_dir,
        run_plan,
        select_steps,
        shell_line,
    )

    if executor not in ("local", "ray"):
        raise typer.BadParameter(f"must be local or ray, not '{executor}'", param_hint="--executor")
    opts = StudyOptions(seeds=seeds, quick=quick, sets=tuple(set_ or ()), workers=workers, executor=executor)
    plan = build_plan(study, opts)
    chosen = select_steps(plan, only, from_)
    root = out.resolve()
    if dry_run:
        typer.echo(f"# brl reproduce {study}: {len(chosen)} of {len(plan)} steps, in order; outputs under {root}")
        for step in chosen:
            needs = f"  # after {', '.join(step.needs)}" if step.needs else ""
            typer.echo(f"{shell_line(step, root)}{needs}")
        if any("seed_BEST" in shell_line(s, root) for s in chosen):
            typer.echo("# seed_BEST: the set's best model on validation (highest Score in seed_N/summary.json, ties "
                       "to the lowest seed), chosen when the step runs")
        return
    check_study_dir(root, study, opts)
    console = stderr_console()

    def run_argv(argv: list[str]) -> None:
        from brlcli.cli import brl_command

        code = brl_command().main(argv, prog_name="brl", standalone_mode=False)
        if isinstance(code, int) and code:
            raise typer.Exit(code)

    try:
        result = run_plan(study, plan, chosen, root, opts, run_argv, note=lambda m: console.print(m, highlight=False),
                          jobs=jobs)
    except StepFailed as exc:
        typer.echo(f"brl: error: {exc}; finished steps are kept: run the same command again to resume", err=True)
        raise typer.Exit(exc.code) from None
    console.print(f"{study}: {len(result['ran'])} steps run, {len(result['skipped'])} already finished")
    typer.echo(result["result"])  # the report (paper, navigation) or the calibrated net's run (segnet)
