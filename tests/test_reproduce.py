"""`brl reproduce` (issue 37): plans, dry runs, bad input, resume, and the quick paper study end to end."""

import json
from pathlib import Path

import pytest

from brlcli.errors import BrlInputError
from brlcli.reproduce import STUDIES, StudyOptions, best_model, build_plan, run_plan, select_steps


def _main(args: list[str], capsys) -> tuple[int, str, str]:
    from brlcli.cli import main

    with pytest.raises(SystemExit) as exit_info:
        main(args)
    captured = capsys.readouterr()
    return int(exit_info.value.code or 0), captured.out, captured.err


@pytest.mark.parametrize("study", list(STUDIES))
@pytest.mark.parametrize("quick", [False, True])
def test_every_step_is_a_valid_brl_command_after_what_it_needs(study: str, quick: bool, tmp_path: Path) -> None:
    from brlcli.cli import brl_command

    group = brl_command()
    plan = build_plan(study, StudyOptions(quick=quick))
    seen: set[str] = set()
    for step in plan:
        assert set(step.needs) <= seen, step.name
        seen.add(step.name)
        command = group.commands[step.argv[0]]
        with command.make_context(step.argv[0], [a.replace("{best:", "").rstrip("}") for a in step.argv[1:]],
                                  resilient_parsing=True):
            pass  # every option exists and takes its value
    assert len({s.out for s in plan}) == len(plan)  # no two steps write one directory


def test_the_dry_run_prints_every_command_and_writes_nothing(tmp_path: Path, capsys) -> None:
    code, out, _ = _main(["reproduce", "paper", "--out", str(tmp_path / "s"), "--dry-run", "--workers", "2"], capsys)
    lines = [line for line in out.splitlines() if line.startswith("brl ")]
    assert code == 0 and len(lines) == len(build_plan("paper", StudyOptions()))
    assert any(line.startswith("brl train --variant paper --input estimated --seeds 0-8") for line in lines)
    assert lines[-1].startswith("brl report ") and "seed_BEST" in out and "--workers 2" in lines[0]
    assert not (tmp_path / "s").exists()


@pytest.mark.parametrize("args, message", [
    (["reproduce", "papr"], "unknown study 'papr'"),
    (["reproduce", "paper", "--only", "nope"], "--only nope: the plan has no such step"),
    (["reproduce", "paper", "--set", "no_such_key=1"], "no step of the paper study takes it"),
    (["reproduce", "paper", "--only", "report"], "step report needs"),
    (["reproduce", "segnet", "--seeds", "0-1"], "trains one net"),
])
def test_bad_input_is_one_line_and_writes_nothing(args: list[str], message: str, tmp_path: Path,
                                                  capsys) -> None:
    code, _, err = _main([*args, "--out", str(tmp_path / "s")], capsys)
    assert code == 2 and message in err and err.strip().count("\n") == 0
    assert not (tmp_path / "s").exists()


def test_a_killed_study_resumes_without_redoing_finished_steps(tmp_path: Path, capsys) -> None:
    opts = StudyOptions(quick=True)
    plan = build_plan("navigation", opts)
    calls: list[list[str]] = []

    def killed_at_third(argv: list[str]) -> None:
        calls.append(argv)
        out = Path(argv[argv.index("--out") + 1])
        out.mkdir(parents=True, exist_ok=True)
        if len(calls) == 3:
            raise KeyboardInterrupt

    root = tmp_path / "s"
    with pytest.raises(KeyboardInterrupt):
        run_plan("navigation", plan, plan, root, opts, killed_at_third, note=lambda m: None)
    assert [p.stem for p in (root / "steps").iterdir()] and len(list((root / "steps").iterdir())) == 2
    calls.clear()
    result = run_plan("navigation", plan, plan, root, opts, lambda a: calls.append(a), note=lambda m: None)
    assert result["skipped"] == [s.name for s in plan[:2]] and len(calls) == len(plan) - 2
    assert calls[0][-1] == "--resume"  # the step in flight continues from what it wrote
    assert all("--resume" not in c for c in calls[1:-1])
    record = json.loads((root / "study.json").read_text())["config"]
    assert record["plan"] == opts.record("navigation")
    code, _, err = _main(["reproduce", "navigation", "--out", str(root)], capsys)  # not --quick: another plan
    assert code == 2 and "holds another plan: seeds '0-1' (asked '0-8'), quick True (asked False)" in err


def test_the_navigation_plan_benches_the_brl_models_on_the_full_nocrash_suite() -> None:
    steps = {s.name: s.argv for s in build_plan("navigation", StudyOptions())}
    assert "--episodes" not in steps["nocrash_brl"]
    for name in ("nocrash_il", "nocrash_mp", "nocrash_autopilot", "nocrash_dqn", "corl2017_brl", "corl2017_il",
                 "corl2017_autopilot"):
        assert steps[name][steps[name].index("--episodes") + 1] == "0.2", name
    quick = {s.name: s.argv for s in build_plan("navigation", StudyOptions(quick=True))}
    assert quick["nocrash_brl"][quick["nocrash_brl"].index("--episodes") + 1] == "3"


def test_only_and_from_pick_steps_in_plan_order() -> None:
    plan = build_plan("paper", StudyOptions())
    assert [s.name for s in select_steps(plan, only="corl_paper")] == ["corl_paper"]
    assert [s.name for s in select_steps(plan, start="nocrash_brl")] == ["nocrash_brl", "report"]
    with pytest.raises(BrlInputError, match="not both"):
        select_steps(plan, only="report", start="report")


def test_the_quick_paper_study_ends_with_every_table_and_resumes_for_free(tmp_path: Path, capsys) -> None:
    root = tmp_path / "paper"  # one seed, 60 learning steps instead of --quick's 300: the same 24 steps and tables,
    # faster; two steps at a time, each a process of its own
    argv = ["reproduce", "paper", "--quick", "--seeds", "0", "--set", "steps=60", "--jobs", "2", "--out", str(root)]
    code, out, err = _main(argv, capsys)
    assert code == 0, err
    assert out.strip().splitlines()[-1] == str(root.resolve() / "report")
    tables = {p.name for p in (root / "report" / "tables").glob("*.csv")}
    assert {"paper_test_table.csv", "paper_posteriors.csv", "corl_success.csv", "nocrash_success.csv",
            "training_runs.csv"} <= tables
    assert len(list((root / "steps").glob("*.json"))) == len(build_plan("paper", StudyOptions(quick=True)))
    code, _, err = _main(argv, capsys)
    assert code == 0 and "0 steps run, 24 already finished" in err


def test_the_best_model_has_the_highest_validation_score_and_ties_go_to_the_lowest_seed(tmp_path: Path) -> None:
    def seed(n: int, score: float | None) -> None:
        (tmp_path / f"seed_{n}").mkdir()
        if score is not None:
            summary = {"summary": {"eval": {"score": score}}}
            (tmp_path / f"seed_{n}" / "summary.json").write_text(json.dumps(summary))

    with pytest.raises(BrlInputError, match="no finished seed_N"):
        best_model(tmp_path)
    seed(0, 0.5)
    seed(1, 0.9)
    seed(2, None)  # unfinished: not a candidate
    seed(10, 0.9)
    assert best_model(tmp_path) == tmp_path / "seed_1"


def test_parallel_steps_start_when_their_inputs_finished_and_a_failure_stops_the_run(tmp_path: Path) -> None:
    import subprocess
    import sys

    opts = StudyOptions(quick=True)
    plan = build_plan("navigation", opts)
    started: list[str] = []

    def spawn(argv: list[str], log: Path) -> subprocess.Popen:
        out = argv[argv.index("--out") + 1]
        started.append(out)
        return subprocess.Popen([sys.executable, "-c", f"import os, time; time.sleep(0.1); os.makedirs({out!r})"])

    root = tmp_path / "s"
    result = run_plan("navigation", plan, plan, root, opts, lambda a: None, note=lambda m: None, jobs=3, spawn=spawn)
    assert sorted(result["ran"]) == sorted(s.name for s in plan) and result["ran"][-1] == "report"
    order = {Path(o).relative_to(root).as_posix(): i for i, o in enumerate(started)}
    for step in plan:  # a step starts after everything it needs has started (and finished)
        assert all(order[next(s.out for s in plan if s.name == n)] < order[step.out] for n in step.needs)

    from brlcli.reproduce import StepFailed

    def failing(argv: list[str], log: Path) -> subprocess.Popen:
        return subprocess.Popen([sys.executable, "-c", "raise SystemExit(3)"])

    with pytest.raises(StepFailed, match=r"failed \(exit 3\)"):
        run_plan("navigation", plan, plan, tmp_path / "f", opts, lambda a: None, note=lambda m: None, jobs=2,
                 spawn=failing)
