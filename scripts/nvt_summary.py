"""Issue 35: one line per bench directory: successes (crashes) per traffic level and the opposite-lane share.

    python scripts/nvt_summary.py runs/s38/nvt_fine_ghost [more bench directories]
    python scripts/nvt_summary.py --seeds runs/s43/nvt_rule9_s*    # and mean, std, best and worst over them
    python scripts/nvt_summary.py --seeds --conditions runs/s44/nocrash20_unsel_s*   # and NoCrash per condition

Reads each directory's results.jsonl (nav_validation_traffic or NoCrash): per task (empty, regular, dense) the
episodes reaching the goal, those ended by a crash in brackets, and the share of all frames partly in the opposite
lane. With `--seeds`, the directories are one model per seed: a last line gives each level's mean and standard
deviation (population, over the seeds) of the goals and crashes, and the best and worst seed by total goals (then
fewest crashes). With `--conditions` (NoCrash, CoRL2017), the goals per task and condition pooled over the
directories, and each task's success over all of them. Outside the paper.
"""

from __future__ import annotations

import json
import sys
from pathlib import Path

import numpy as np


def _rows(bench_dir: Path) -> list[dict]:
    return [json.loads(line) for line in (bench_dir / "results.jsonl").read_text().splitlines() if line.strip()]


def counts(bench_dir: Path) -> dict[str, tuple[int, int, int]]:
    """Per task: (goals, crashes, episodes)."""
    rows = _rows(bench_dir)
    out = {}
    for task in dict.fromkeys(r["task"] for r in rows):
        sel = [r for r in rows if r["task"] == task]
        out[task] = (sum(r["success"] for r in sel), sum(bool(r.get("crashed", r["collided"])) for r in sel), len(sel))
    return out


def seed_summary(bench_dirs: list[Path]) -> str:
    """Mean +- std of goals (crashes) per task over one bench directory per seed, and the best and worst seed."""
    per = [counts(d) for d in bench_dirs]
    parts = []
    for task in per[0]:
        goals = np.array([c[task][0] for c in per], float)
        crashes = np.array([c[task][1] for c in per], float)
        parts.append(f"{task} {goals.mean():.1f} +- {goals.std():.1f} ({crashes.mean():.1f} +- {crashes.std():.1f}) "
                     f"of {per[0][task][2]}")
    key = [(sum(v[0] for v in c.values()), -sum(v[1] for v in c.values())) for c in per]
    best, worst = max(range(len(per)), key=key.__getitem__), min(range(len(per)), key=key.__getitem__)
    return (f"{len(per)} seeds: " + " | ".join(parts) + f" | best {bench_dirs[best]}, worst {bench_dirs[worst]}")


def summary(bench_dir: Path) -> str:
    """'Empty g/n (c) | Regular ... | opposite lane x %' for one bench directory."""
    rows = _rows(bench_dir)
    parts = []
    for task in dict.fromkeys(r["task"] for r in rows):
        sel = [r for r in rows if r["task"] == task]
        goals = sum(r["success"] for r in sel)
        crashes = sum(bool(r.get("crashed", r["collided"])) for r in sel)
        parts.append(f"{task} {goals}/{len(sel)} ({crashes})")
    otherlane = sum(r["otherlane_steps"] for r in rows) / max(sum(r["steps"] for r in rows), 1)
    return f"{bench_dir}: " + " | ".join(parts) + f" | opposite lane {100 * otherlane:.1f} % of frames"


CONDITIONS = ("training", "new_weather", "new_town", "new_town_weather")


def condition_summary(bench_dirs: list[Path]) -> str:
    """Per task: goals / episodes per condition pooled over the directories, and the task's success share."""
    rows = [r for d in bench_dirs for r in _rows(d)]
    lines = []
    for task in dict.fromkeys(r["task"] for r in rows):
        sel = [r for r in rows if r["task"] == task]
        parts = []
        for cond in CONDITIONS:
            c = [r for r in sel if r["condition"] == cond]
            if c:
                parts.append(f"{cond} {sum(r['success'] for r in c)}/{len(c)}")
        goals = sum(r["success"] for r in sel)
        lines.append(f"{task}: {' | '.join(parts)} | all {goals}/{len(sel)} = {100 * goals / len(sel):.1f} %")
    return "\n".join(lines)


if __name__ == "__main__":
    args = sys.argv[1:]
    seeds, conditions = "--seeds" in args, "--conditions" in args
    dirs = [Path(a) for a in args if a not in ("--seeds", "--conditions")]
    for d in dirs:
        print(summary(d))
    if seeds and dirs:
        print(seed_summary(dirs))
    if conditions and dirs:
        print(condition_summary(dirs))
