"""Issue 35: one line per bench directory: successes (crashes) per traffic level and the opposite-lane share.

    python scripts/nvt_summary.py runs/s38/nvt_fine_ghost [more bench directories]
    python scripts/nvt_summary.py --seeds runs/s43/nvt_rule9_s*    # and mean, std, best and worst over them
    python scripts/nvt_summary.py --seeds --conditions runs/s44/nocrash20_unsel_s*   # and NoCrash per condition
    B=docs/navigation-report/bench    # the archived report inputs
    python scripts/nvt_summary.py --seeds --episodes-of $B/nocrash20_mp $B/nocrash_full_s?   # on another's episodes

Reads each directory's results (nav_validation_traffic or NoCrash; a `brl bench` output or its archive,
`scripts/archive_bench.py`): per task (empty, regular, dense) the
episodes reaching the goal, those ended by a crash in brackets, and the share of all frames partly in the opposite
lane. With `--seeds`, the directories are one model per seed: a last line gives each level's mean and standard
deviation (population, over the seeds) of the goals and crashes, and the best and worst seed by total goals (then
fewest crashes). With `--conditions` (NoCrash, CoRL2017), the goals per task and condition pooled over the
directories, and each task's success over all of them. `--episodes-of DIR` keeps, in every directory, only the
episodes that DIR holds too (matched by episode identifier: the fixed NoCrash subset inside full runs). Bad input
is one line, exit 2. Outside the paper.
"""

from __future__ import annotations

import argparse
import functools
import sys
from pathlib import Path

import numpy as np

from brlcli.errors import BrlInputError
from brlcli.report.load import load_results

TASK_ORDER = ("empty", "regular", "dense")
"""Traffic levels in the order the tables give them; other tasks (CoRL2017's) follow in the order met."""


@functools.cache
def _episodes(bench_dir: Path) -> tuple[dict, ...]:
    return tuple(load_results([bench_dir]).episodes)  # read once per directory, however many summaries use it


def episode_ids(bench_dir: Path) -> set[str]:
    """The identifiers of the episodes a bench directory holds."""
    return {r["id"] for r in _episodes(bench_dir)}


def _tasks(rows: list[dict]) -> list[str]:
    met = list(dict.fromkeys(r["task"] for r in rows))
    return [t for t in TASK_ORDER if t in met] + [t for t in met if t not in TASK_ORDER]


def _rows(bench_dir: Path, keep: set[str] | None = None) -> list[dict]:
    rows = list(_episodes(bench_dir))
    if keep is not None:
        rows = [r for r in rows if r["id"] in keep]
        if not rows:
            raise BrlInputError(f"{bench_dir} holds none of the episodes of --episodes-of")
    return rows


def counts(bench_dir: Path, keep: set[str] | None = None) -> dict[str, tuple[int, int, int]]:
    """Per task: (goals, crashes, episodes)."""
    rows = _rows(bench_dir, keep)
    out = {}
    for task in _tasks(rows):
        sel = [r for r in rows if r["task"] == task]
        out[task] = (sum(r["success"] for r in sel), sum(bool(r.get("crashed", r["collided"])) for r in sel), len(sel))
    return out


def seed_summary(bench_dirs: list[Path], keep: set[str] | None = None) -> str:
    """Mean +- std of goals (crashes) per task over one bench directory per seed, and the best and worst seed."""
    per = [counts(d, keep) for d in bench_dirs]
    if any(c.keys() != per[0].keys() or any(c[t][2] != per[0][t][2] for t in c) for c in per):
        raise BrlInputError("--seeds needs the same episodes in every directory (one of them is partial)")
    parts = []
    for task in per[0]:
        goals = np.array([c[task][0] for c in per], float)
        crashes = np.array([c[task][1] for c in per], float)
        parts.append(f"{task} {goals.mean():.1f} +- {goals.std():.1f} ({crashes.mean():.1f} +- {crashes.std():.1f}) "
                     f"of {per[0][task][2]}")
    key = [(sum(v[0] for v in c.values()), -sum(v[1] for v in c.values())) for c in per]
    best, worst = max(range(len(per)), key=key.__getitem__), min(range(len(per)), key=key.__getitem__)
    return (f"{len(per)} seeds: " + " | ".join(parts) + f" | best {bench_dirs[best]}, worst {bench_dirs[worst]}")


def summary(bench_dir: Path, keep: set[str] | None = None) -> str:
    """'Empty g/n (c) | Regular ... | opposite lane x %' for one bench directory."""
    rows = _rows(bench_dir, keep)
    parts = [f"{task} {goals}/{n} ({crashes})" for task, (goals, crashes, n) in counts(bench_dir, keep).items()]
    otherlane = sum(r.get("otherlane_steps", 0) for r in rows) / max(sum(r["steps"] for r in rows), 1)
    return f"{bench_dir}: " + " | ".join(parts) + f" | opposite lane {100 * otherlane:.1f} % of frames"


CONDITIONS = ("training", "new_weather", "new_town", "new_town_weather")


def condition_summary(bench_dirs: list[Path], keep: set[str] | None = None) -> str:
    """Per task: goals / episodes per condition pooled over the directories, and the task's success share."""
    rows = [r for d in bench_dirs for r in _rows(d, keep)]
    lines = []
    for task in _tasks(rows):
        sel = [r for r in rows if r["task"] == task]
        parts = []
        for cond in CONDITIONS:
            c = [r for r in sel if r["condition"] == cond]
            if c:
                parts.append(f"{cond} {sum(r['success'] for r in c)}/{len(c)}")
        goals = sum(r["success"] for r in sel)
        lines.append(f"{task}: {' | '.join(parts)} | all {goals}/{len(sel)} = {100 * goals / len(sel):.1f} %")
    return "\n".join(lines)


def main(argv: list[str]) -> int:
    """The command line: one line per directory, then the optional summaries; 2 on bad input."""
    parser = argparse.ArgumentParser(prog="nvt_summary", description=__doc__.split("\n\n")[0])
    parser.add_argument("dirs", nargs="+", type=Path, help="brl bench results directories (or their archives)")
    parser.add_argument("--seeds", action="store_true", help="mean, std, best and worst over the directories")
    parser.add_argument("--conditions", action="store_true", help="goals per task and condition, pooled")
    parser.add_argument("--episodes-of", type=Path, metavar="DIR", help="only the episodes DIR holds too")
    args = parser.parse_args(argv)
    try:
        keep = episode_ids(args.episodes_of) if args.episodes_of else None
        for d in args.dirs:
            print(summary(d, keep))
        if args.seeds:
            print(seed_summary(args.dirs, keep))
        if args.conditions:
            print(condition_summary(args.dirs, keep))
    except BrlInputError as exc:
        print(f"nvt_summary: error: {exc}", file=sys.stderr)
        return 2
    return 0


if __name__ == "__main__":
    sys.exit(main(sys.argv[1:]))
