"""`brl reproduce STUDY`: a study as a declared plan of brl's own commands, run in dependency order, resumable.

A plan is a list of `Step`s, each one brl command line (`brl train ...`, `brl bench ...`, ..., `brl report ...`) with
its output under the study's directory and the steps it needs. Running a plan runs each step that has not finished
(a step's finish is recorded in `steps/NAME.json`, written atomically after the command returns); a step whose output
exists but did not finish is run again with `--resume`, so a kill at any moment loses at most the work in flight of
one step. `study.json` records the study and the options that shape its results (seeds, `--quick`, `--set`); a second
run into the same directory must give the same ones. The commands themselves are run by the caller (the CLI passes
a function that runs brl's command line in this process), so this module never imports the CLI.

Studies:
- `paper`: the example report (docs/example-report): the default method and `--variant paper`, each trained on GT and
  on estimated labels, the four settings on the paper suite, a CoRL2017 subset for each GT set's best model on
  validation, the baselines (autopilot, MP on GT and estimated labels), a NoCrash subset, the report.
- `segnet`: the shipped segmentation net's recipe (models/README.md): six recordings, then `brl train-seg`.
- `navigation`: the navigation report (docs/navigation-report): the navigation preset's models (what models/brl_nav
  ships), the navigation DQN, CoRL2017 and NoCrash for them and for the autopilot, MP and IL, the report.
"""

from __future__ import annotations

import json
import shlex
import subprocess
import sys
import time
from collections.abc import Callable, Sequence
from dataclasses import dataclass, field, fields
from pathlib import Path
from typing import Any

from brlcli.errors import BrlInputError

STUDY_FILE = "study.json"
STEPS_DIR = "steps"
BEST = "{best:"
"""An argument `{best:RUNS}` names, at run time, the model set RUNS' best model on validation (its summary.json:
the highest validation Score, ties to the lowest seed), as the example report chose its CoRL2017 models."""


@dataclass(frozen=True)
class Step:
    """One brl command of a plan: its name, its arguments (the command first), its output and what it needs."""

    name: str
    argv: tuple[str, ...]
    out: str
    needs: tuple[str, ...] = ()
    resumable: bool = True
    takes_set: str | None = None  # the configuration `--set` goes to: "train" or "train-seg"


@dataclass(frozen=True)
class StudyOptions:
    """What shapes a study's results (recorded in study.json) and how it runs (not recorded)."""

    seeds: str | None = None  # None: the study's own (0-8; --quick: 0-1)
    quick: bool = False
    sets: tuple[str, ...] = ()
    workers: int = 1
    executor: str = "local"
    extra: dict[str, Any] = field(default_factory=dict)

    def record(self, study: str) -> dict[str, Any]:
        """The part of the options a finished study must be resumed with."""
        return {"study": study, "seeds": self.seeds_text, "quick": self.quick, "set": list(self.sets)}

    @property
    def seeds_text(self) -> str:
        """The seeds every training step trains."""
        return self.seeds or ("0-1" if self.quick else "0-8")


def _run_opts(opts: StudyOptions, executor: bool = True) -> list[str]:
    """--workers (and --executor) for commands that take them."""
    out = ["--workers", str(opts.workers)]
    return out + (["--executor", opts.executor] if executor and opts.executor != "local" else [])


def _sets(opts: StudyOptions) -> list[str]:
    return [a for s in opts.sets for a in ("--set", s)]


def _paper_plan(opts: StudyOptions) -> list[Step]:
    """The example report's plan (docs/example-report/README.md)."""
    q = opts.quick
    seeds = opts.seeds_text
    train_extra = ["--steps", "300", "--no-evaluate"] if q else []
    paper_n = ["--episodes", "3"] if q else []
    corl_n = ["--episodes", "3" if q else "0.05"]
    nocrash_n = ["--episodes", "3" if q else "0.1"]
    steps: list[Step] = []
    bench_dirs: list[str] = []
    for method, variant in (("default", []), ("paper", ["--variant", "paper"])):
        for inp in ("gt", "estimated"):
            tag = "te" if inp == "estimated" else "gt"
            out = f"train/{method}_{tag}"
            argv = ["train", *variant, *(["--input", "estimated"] if inp == "estimated" else []), "--seeds", seeds,
                    *train_extra, *_run_opts(opts), *_sets(opts), "--out", out]
            steps.append(Step(f"train_{method}_{tag}", tuple(argv), out, takes_set="train"))
        for setting, train, deploy in (("tgdg", "gt", "gt"), ("tgde", "gt", "estimated"), ("tede", "te", "estimated"),
                                       ("tedg", "te", "gt")):
            out = f"bench/{method}_paper_{setting}"
            steps.append(Step(f"bench_{method}_{setting}", ("bench", "--suite", "paper", "--models",
                                                            f"train/{method}_{train}", "--deploy", deploy, *paper_n,
                                                            *_run_opts(opts), "--out", out),
                              out, needs=(f"train_{method}_{train}",)))
            bench_dirs.append(out)
        out = f"bench/{method}_corl_tgdg"
        steps.append(Step(f"corl_{method}", ("bench", "--suite", "corl2017", "--model", f"{BEST}train/{method}_gt}}",
                                             *corl_n, *_run_opts(opts), "--out", out), out,
                          needs=(f"train_{method}_gt",)))
        bench_dirs.append(out)
    baselines = [("paper_autopilot", ("--agent", "autopilot", "--suite", "paper", *paper_n)),
                 ("paper_mp_gt", ("--agent", "mp", "--suite", "paper", *paper_n)),
                 ("paper_mp_est", ("--agent", "mp", "--suite", "paper", "--deploy", "estimated", *paper_n)),
                 ("corl_mp_est", ("--agent", "mp", "--suite", "corl2017", "--deploy", "estimated", *corl_n))]
    for agent in ("autopilot", "mp", "il", "dqn"):
        baselines.append((f"nocrash_{agent}", ("--agent", agent, "--suite", "nocrash", *nocrash_n)))
    for name, args in baselines:
        out = f"bench/{name}"
        steps.append(Step(name, ("bench", *args, *_run_opts(opts), "--out", out), out))
        bench_dirs.append(out)
    out = "bench/nocrash_brl"
    steps.append(Step("nocrash_brl", ("bench", "--suite", "nocrash", "--model", f"{BEST}train/default_gt}}",
                                      *nocrash_n, *_run_opts(opts), "--out", out), out, needs=("train_default_gt",)))
    bench_dirs.append(out)
    steps.append(_report_step(steps, bench_dirs, ["train/default_gt", "train/default_te"]))
    return steps


def _navigation_plan(opts: StudyOptions) -> list[Step]:
    """The navigation report's plan (docs/navigation-report): the preset's models, the DQN, CoRL2017 (the fixed 20 %
    subset) and NoCrash (the full suite for the BRL models, the 20 % subset for the others; issue 35)."""
    q = opts.quick
    seeds = opts.seeds_text
    train_extra = ["--set", "imitation_iterations=1", "--set", "imitation_episodes=3", "--no-evaluate"] if q else []
    corl_n = ["--episodes", "3" if q else "0.2"]
    nocrash_n = ["--episodes", "3" if q else "0.2"]
    steps = [Step("train_brl", ("train", "--task", "navigation", "--seeds", seeds, *train_extra,
                                       *_run_opts(opts), *_sets(opts), "--out", "train/nav"), "train/nav",
                  takes_set="train"),
             Step("train_dqn", ("train-rl", "--task", "navigation", "--steps", "2000" if q else "189000",
                                "--eval-every", "1000" if q else "27000", *(["--eval-suite", "none"] if q else []),
                                "--out", "train/dqn_nav"), "train/dqn_nav")]
    bench_dirs: list[str] = []
    for suite, n in (("corl2017", corl_n), ("nocrash", nocrash_n)):
        policies = [("brl", ("--models", "train/nav"), ("train_brl",)),
                    ("dqn", ("--agent", "dqn", "--model", "train/dqn_nav"), ("train_dqn",)),
                    ("il", ("--agent", "il"), ()), ("mp", ("--agent", "mp"), ()),
                    ("autopilot", ("--agent", "autopilot"), ())]
        for name, args, needs in policies:
            out = f"bench/{suite}_{name}"
            episodes = [] if suite == "nocrash" and name == "brl" and not q else n  # the BRL models: the full suite
            steps.append(Step(f"{suite}_{name}", ("bench", "--suite", suite, *args, *episodes, *_run_opts(opts),
                                                  "--out", out), out, needs=needs))
            bench_dirs.append(out)
    steps.append(_report_step(steps, bench_dirs, []))  # imitation runs have no TD learning curves (iterations.csv)
    return steps


SEGNET_RECORDINGS = (
    ("seg_t01_train", "town01", "1,3,6,8", 12, 250, "--traffic", 11),
    ("seg_t01_exc", "town01", "1,3,6,8", 12, 250, "--excursions=0.05", 31),
    ("seg_t01_val", "town01", "1,3,6,8", 4, 125, "--traffic", 12),
    ("seg_t01_val_exc", "town01", "1,3,6,8", 4, 125, "--excursions=0.05", 32),
    ("seg_t02_test", "town02", "4,14", 4, 125, "--traffic", 13),
    ("seg_t02_test_exc", "town02", "4,14", 4, 125, "--excursions=0.05", 33),
)
"""The shipped net's six recordings (models/README.md): name, town, weathers, episodes, frames per episode, kind,
seed; every third frame."""


def _segnet_plan(opts: StudyOptions) -> list[Step]:
    """The shipped segmentation net's recipe (models/README.md): six recordings, then train-seg (calibrated)."""
    q = opts.quick
    seed_list = parse_study_seeds(opts.seeds_text)
    if opts.seeds is not None and len(seed_list) != 1:
        raise BrlInputError("the segnet study trains one net: give one seed (--seeds 0)")
    steps = []
    for name, town, weathers, episodes, frames, kind, seed in SEGNET_RECORDINGS:
        out = f"data/{name}"
        steps.append(Step(f"collect_{name}", ("collect", "--town", town, "--weathers", weathers, "--episodes",
                                              str(1 if q else episodes), "--episode-frames", str(30 if q else frames),
                                              "--every", "3", kind, "--seed", str(seed), "--out", out), out))
    seg_seed = [] if opts.seeds is None else ["--seed", str(seed_list[0])]
    argv = ("train-seg", "--data", "data/seg_t01_train", "--data", "data/seg_t01_exc", "--val", "data/seg_t01_val*",
            "--val", "data/seg_t02_test", "--val", "data/seg_t02_test_exc",
            "--fine-channels", "16", *(["--epochs", "1", "--batch-size", "4"] if q else []), *seg_seed,
            "--workers", str(max(opts.workers, 1)), *_sets(opts), "--out", "train/segnet")
    steps.append(Step("train_segnet", argv, "train/segnet", needs=tuple(s.name for s in steps),
                      takes_set="train-seg"))
    return steps


def _report_step(steps: Sequence[Step], bench_dirs: list[str], runs: list[str]) -> Step:
    by_out = {s.out: s.name for s in steps}
    needs = tuple(by_out[d] for d in bench_dirs) + tuple(by_out[r] for r in runs if r in by_out)
    argv = ("report", *bench_dirs, *[a for r in runs for a in ("--runs", r)], "--out", "report")
    return Step("report", argv, "report", needs=needs, resumable=False)


STUDIES: dict[str, Callable[[StudyOptions], list[Step]]] = {
    "paper": _paper_plan, "segnet": _segnet_plan, "navigation": _navigation_plan}
"""The studies `brl reproduce` knows, each a function from the options to its plan."""


def parse_study_seeds(text: str) -> list[int]:
    """`0-8` or `0,2,5` -> the seeds (as `brl train --seeds`)."""
    from brlcli.train import parse_seeds

    return parse_seeds(text)


def build_plan(study: str, opts: StudyOptions) -> list[Step]:
    """The study's plan for these options; one-line errors for an unknown study or a `--set` no step takes."""
    if study not in STUDIES:
        raise BrlInputError(f"unknown study '{study}'; choose one of {', '.join(STUDIES)}")
    parse_study_seeds(opts.seeds_text)
    plan = STUDIES[study](opts)
    for item in opts.sets:
        key = item.partition("=")[0].strip()
        if "=" not in item or not key:
            raise BrlInputError(f"--set '{item}' is not KEY=VALUE")
        targets = {s.takes_set for s in plan if s.takes_set}
        if not any(_config_takes(t, key) for t in targets):
            raise BrlInputError(f"--set {key}: no step of the {study} study takes it (its steps configure "
                                f"{', '.join(sorted(targets)) or 'nothing'})")
    return plan


def _config_takes(target: str, key: str) -> bool:
    """Whether the configuration of `brl train` / `brl train-seg` has the (dotted) key's top level."""
    if target == "train":
        from brlcli.trainconfig import TrainConfig as cls
    else:
        from brlcli.segnet.train import SegTrainConfig as cls  # type: ignore[assignment]
    top = key.split(".")[0]
    return top in {f.name for f in fields(cls)}


def select_steps(plan: list[Step], only: str | None = None, start: str | None = None) -> list[Step]:
    """The steps to run: all, `--only STEP`, or `--from STEP` (that step and every step after it in the plan)."""
    names = [s.name for s in plan]
    for given, flag in ((only, "--only"), (start, "--from")):
        if given is not None and given not in names:
            raise BrlInputError(f"{flag} {given}: the plan has no such step; its steps: {', '.join(names)}")
    if only is not None and start is not None:
        raise BrlInputError("give --only or --from, not both")
    if only is not None:
        return [s for s in plan if s.name == only]
    if start is not None:
        return plan[names.index(start):]
    return list(plan)


def shell_line(step: Step, root: Path) -> str:
    """The step as the equivalent `brl ...` command line, its paths under `root` (for --dry-run)."""
    args = []
    for a in _with_root(step, root):
        if a.startswith(BEST):
            runs = a[len(BEST):-1]
            a = f"{runs}/seed_BEST"
        args.append(shlex.quote(a))
    return "brl " + " ".join(args)


def _with_root(step: Step, root: Path) -> list[str]:
    """The step's arguments with its study paths (train/, bench/, data/, report) made absolute under root."""
    prefixes = ("train/", "bench/", "data/", f"{BEST}train/")
    out = []
    for a in step.argv:
        if a == "report" and out and out[-1] == "--out":
            out.append(str(root / a))
        elif a.startswith(BEST):
            out.append(f"{BEST}{root / a[len(BEST):-1]}}}")
        elif a.startswith(prefixes):
            out.append(str(root / a))
        else:
            out.append(a)
    return out


def best_model(runs: Path) -> Path:
    """The model set's best model on validation: the highest Score in its seed_N/summary.json, ties to the lowest
    seed (as the example report chose its CoRL2017 models)."""
    scored = []
    for seed_dir in runs.glob("seed_*"):
        try:
            seed = int(seed_dir.name.removeprefix("seed_"))
            ev = json.loads((seed_dir / "summary.json").read_text())["summary"].get("eval") or {}
        except (OSError, ValueError, KeyError, TypeError):
            continue
        scored.append((-float(ev.get("score", 0.0)), seed, seed_dir))
    if not scored:
        raise BrlInputError(f"{runs} holds no finished seed_N/summary.json to choose the best model from")
    return min(scored)[2]


def check_study_dir(root: Path, study: str, opts: StudyOptions) -> None:
    """Refuse, before anything is written, a directory that holds another study or this study with other options."""
    path = root / STUDY_FILE
    if root.exists() and not root.is_dir():
        raise BrlInputError(f"--out {root} is a file; give a directory")
    if path.exists():
        try:
            saved = json.loads(path.read_text())["config"]["plan"]
        except (OSError, ValueError, KeyError, TypeError):
            raise BrlInputError(f"{path} is not a brl study record; choose another --out") from None
        wanted = opts.record(study)
        if saved != wanted:
            diff = ", ".join(f"{k} {saved.get(k)!r} (asked {wanted[k]!r})" for k in wanted if saved.get(k) != wanted[k])
            raise BrlInputError(f"--out {root} holds another plan: {diff}; resume it with the same options or choose "
                                f"another --out")
    elif root.is_dir() and any(root.iterdir()):
        raise BrlInputError(f"--out {root} holds files that are not a brl study; choose an empty or new directory")


def step_done(root: Path, step: Step) -> bool:
    """Whether the step finished (its record in steps/)."""
    return (root / STEPS_DIR / f"{step.name}.json").exists()


def check_needs(plan: list[Step], chosen: list[Step], root: Path) -> None:
    """Refuse, before anything is written, a chosen step whose inputs neither finished nor run before it."""
    by_name = {s.name: s for s in plan}
    will_run: set[str] = set()
    for step in chosen:
        missing = [n for n in step.needs if n not in will_run and not step_done(root, by_name[n])]
        if missing and not step_done(root, step):
            shown = ", ".join(missing[:4]) + (f" and {len(missing) - 4} more" if len(missing) > 4 else "")
            raise BrlInputError(f"step {step.name} needs {shown}, which did not finish; run them first (drop --only "
                                f"/ --from)")
        will_run.add(step.name)


class StepFailed(Exception):
    """A step's command ended with a non-zero exit code (parallel runs: its log names why)."""

    def __init__(self, step: str, code: int, log: Path | None = None) -> None:
        super().__init__(f"step {step} failed (exit {code})" + (f"; its output: {log}" if log else ""))
        self.code = code


def _step_argv(step: Step, root: Path) -> list[str]:
    """The step's command line as it runs now: paths under root, the best model chosen, --resume if it started."""
    argv = _with_root(step, root)
    argv = [str(best_model(Path(a[len(BEST):-1]))) if a.startswith(BEST) else a for a in argv]
    if step.resumable and (root / step.out).exists():
        argv.append("--resume")
    return argv


def _finish(root: Path, step: Step, argv: list[str], wall_s: float) -> None:
    from brlcli.provenance import atomic_write_json, provenance

    atomic_write_json(root / STEPS_DIR / f"{step.name}.json",
                      provenance({"argv": argv, "wall_s": round(wall_s, 1)}, kind="step"))


def spawn_brl(argv: list[str], log: Path) -> subprocess.Popen:
    """A step of a parallel run: `python -m brlcli.cli ARGV` in its own process, its output to `log`."""
    log.parent.mkdir(parents=True, exist_ok=True)
    with open(log, "ab") as fh:
        return subprocess.Popen([sys.executable, "-m", "brlcli.cli", *argv], stdout=fh, stderr=subprocess.STDOUT)


def run_plan(study: str, plan: list[Step], chosen: list[Step], root: Path, opts: StudyOptions,
             run_argv: Callable[[list[str]], None], note: Callable[[str], None] = print, jobs: int = 1,
             spawn: Callable[[list[str], Path], subprocess.Popen] = spawn_brl) -> dict[str, Any]:
    """Run the chosen steps of a plan, skipping finished ones: in order, each through `run_argv` (brl's command
    line, in this process), or with `jobs` > 1 up to `jobs` independent steps at a time, each a process of its own
    (`spawn`; its output in steps/NAME.log); steps/NAME.json after each; returns what ran and what was skipped."""
    from brlcli.provenance import atomic_write_json, provenance

    check_needs(plan, chosen, root)
    root.mkdir(parents=True, exist_ok=True)
    if not (root / STUDY_FILE).exists():
        atomic_write_json(root / STUDY_FILE, provenance({"plan": opts.record(study),
                                                         "steps": [s.name for s in plan]}, kind="reproduce"))
    skipped = [s.name for s in chosen if step_done(root, s)]
    todo = [s for s in chosen if not step_done(root, s)]
    if jobs > 1:
        ran = _run_parallel(plan, todo, root, jobs, spawn, note)
    else:
        ran = []
        for i, step in enumerate(todo, 1):
            argv = _step_argv(step, root)
            note(f"[{i}/{len(todo)}] {step.name}: brl {' '.join(shlex.quote(a) for a in argv)}")
            t0 = time.perf_counter()
            run_argv(argv)
            _finish(root, step, argv, time.perf_counter() - t0)
            ran.append(step.name)
    return {"ran": ran, "skipped": skipped, "result": str(root / plan[-1].out)}


def _run_parallel(plan: list[Step], todo: list[Step], root: Path, jobs: int,
                  spawn: Callable[[list[str], Path], subprocess.Popen], note: Callable[[str], None]) -> list[str]:
    """Up to `jobs` steps at a time, each started once every step it needs has finished; a failure or an
    interruption stops the others (each keeps what it finished, as its own command does on SIGTERM)."""
    by_name = {s.name: s for s in plan}
    pending, running, ran = list(todo), {}, []  # running: name -> (process, argv, start time)
    try:
        while pending or running:
            for step in list(pending):
                if len(running) >= jobs:
                    break
                if all(step_done(root, by_name[n]) for n in step.needs):
                    argv = _step_argv(step, root)
                    log = root / STEPS_DIR / f"{step.name}.log"
                    note(f"start {step.name} ({len(ran) + len(running) + 1}/{len(todo)}): brl "
                         f"{' '.join(shlex.quote(a) for a in argv)}  [output: {log}]")
                    running[step.name] = (spawn(argv, log), argv, time.perf_counter())
                    pending.remove(step)
            if not running:
                raise StepFailed(pending[0].name, 1)  # unreachable after check_needs; no step can start
            time.sleep(0.2)
            for name, (proc, argv, t0) in list(running.items()):
                code = proc.poll()
                if code is None:
                    continue
                del running[name]
                if code:
                    raise StepFailed(name, code, root / STEPS_DIR / f"{name}.log")
                _finish(root, by_name[name], argv, time.perf_counter() - t0)
                ran.append(name)
                note(f"done {name} ({time.perf_counter() - t0:.0f} s)")
    finally:
        for proc, _, _ in running.values():  # Ctrl-C, a kill or a failed step: the others stop and stay resumable
            proc.terminate()
        for proc, _, _ in running.values():
            proc.wait()
    return ran
