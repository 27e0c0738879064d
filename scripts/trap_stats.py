"""Read brl training runs for the trap of docs/lane-keeping-study.md (issue 18): per-window training statistics and
the chattering of the mixture's components.

    python scripts/trap_stats.py runs/study/grid8/step-visits/seed_*

Per run: for each window of 750 learning steps, mean reward / share of `backward` / share of steps partly off the road
/ share more than 20 % in the opposite lane / mean speed (km/h); then, over the last 1,500 steps, the share of steps
in "chattering" components (four action values within 0.3 of each other in the final model) and, per component with
at least 50 of those steps, the share taken by its most frequent action (c: chattering, d: distinct values).
"""

from __future__ import annotations

import argparse
import csv
from collections import Counter
from pathlib import Path

import numpy as np

from brlcli.agent import BayesianAgent

WINDOW = 750
TAIL = 1500
CHATTER_SPREAD = 0.3


def main() -> None:
    """Print the statistics of each run directory given."""
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("runs", nargs="+", help="brl train run directories (log.csv, model.npz)")
    args = ap.parse_args()
    for run in map(Path, args.runs):
        rows = list(csv.DictReader(open(run / "log.csv", newline="")))
        reward = np.array([float(r["reward"]) for r in rows])
        backward = np.array([r["action"] == "backward" for r in rows])
        off = np.array([float(r["intersection_offroad"]) > 0 for r in rows])
        other = np.array([float(r["intersection_otherlane"]) > 0.2 for r in rows])
        speed = np.array([float(r["forward_speed_kmh"]) for r in rows])
        windows = [f"{reward[i:i + WINDOW].mean():6.1f}/{backward[i:i + WINDOW].mean():.2f}/"
                   f"{off[i:i + WINDOW].mean():.2f}/{other[i:i + WINDOW].mean():.2f}/{speed[i:i + WINDOW].mean():4.1f}"
                   for i in range(0, len(rows), WINDOW)]
        print(f"{run}: reward/backward/off/otherlane/kmh per {WINDOW} steps: {' | '.join(windows)}")
        agent = BayesianAgent.load(run / "model.npz")
        spread = agent.Q.max(axis=0) - agent.Q.min(axis=0)
        tail = rows[-TAIL:]
        chatter = np.mean([spread[int(r["component"])] < CHATTER_SPREAD for r in tail])
        tops = []
        for m, n in Counter(r["component"] for r in tail).most_common():
            if n < 50:
                continue
            actions = Counter(r["action"] for r in tail if r["component"] == m)
            kind = "c" if spread[int(m)] < CHATTER_SPREAD else "d"
            tops.append(f"m{m} {kind} {n} steps top {actions.most_common(1)[0][1] / n:.2f}")
        print(f"    last {TAIL} steps: {chatter:.2f} in chattering components; {', '.join(tops)}")


if __name__ == "__main__":
    main()
