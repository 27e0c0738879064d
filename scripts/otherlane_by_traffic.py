"""Issue 35: how often a training run's car is partly in the opposite lane, per traffic level, from its log.csv.

    python scripts/otherlane_by_traffic.py runs/s38/fine_ghost/seed_0 [--part 3]

For each member run under the directory (member_<k>/log.csv, or the directory's own log.csv) and each traffic level
of its episodes, the share of the learning steps in the last 1/PART of the run whose car is partly in the opposite
lane (intersection_otherlane > 0), the crashes per 1,000 steps and the mean reward per step. A driver
that weaves only when road users are in view shows a higher share in regular and dense than in empty. Outside the
paper.
"""

from __future__ import annotations

import argparse
import csv
from pathlib import Path


def level_shares(log_csv: Path, part: int) -> dict[str, dict[str, float]]:
    """Per traffic level of the last 1/part of a log: steps, opposite-lane share, crash share, mean reward."""
    with open(log_csv, newline="") as fh:
        rows = list(csv.DictReader(fh))
    last = rows[len(rows) - len(rows) // part:]
    out: dict[str, dict[str, float]] = {}
    for level in dict.fromkeys(r.get("traffic", "") for r in last):
        sel = [r for r in last if r.get("traffic", "") == level]
        out[level or "(no traffic)"] = {
            "steps": len(sel),
            "otherlane": sum(float(r["intersection_otherlane"]) > 0 for r in sel) / len(sel),
            "crashes_per_1000": 1000 * sum(int(r.get("crashed", 0) or 0) for r in sel) / len(sel),
            "mean_reward": sum(float(r["reward"]) for r in sel) / len(sel),
        }
    return out


def main() -> None:
    """Print one line per member and traffic level."""
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("run", type=Path, help="a seed directory (member_<k>/log.csv) or a run with its own log.csv")
    ap.add_argument("--part", type=int, default=3, help="look at the last 1/PART of each run (default 3)")
    args = ap.parse_args()
    logs = sorted(args.run.glob("member_*/log.csv")) or [args.run / "log.csv"]
    print(f"{'run':<12} {'traffic':<10} {'steps':>6} {'opposite lane':>14} {'crashes/1000':>13} {'reward':>8}")
    for log in logs:
        for level, f in level_shares(log, args.part).items():
            print(f"{log.parent.name:<12} {level:<10} {f['steps']:>6} {100 * f['otherlane']:>13.1f}% "
                  f"{f['crashes_per_1000']:>13.1f} {f['mean_reward']:>8.2f}")


if __name__ == "__main__":
    main()
