"""Issue 35's crash anatomy: what a navigation model's collisions in traffic are.

    python scripts/crash_anatomy.py --model models/brl_nav_empty/seed_0 --traffic dense --episodes 40 \
        [--workers 2] [--json runs/s36/anatomy_dense.json]

The model (a navigation model.npz, brake-gated too, or a seed directory of committee members member_<k>/model.npz,
which vote; its action set is the one with as many primitives as the model has actions)
drives greedily in the training environment of `brl train --task navigation` (town01, training weather, the
navigation routes, NoCrash traffic of one level; a collision with a road user ends the episode), episode e seeded
with e. For every crash the script records who was hit (vehicle or pedestrian), the other road user's heading
relative to the ego car's (oncoming above 120 degrees, crossing 60-120, same direction below 60), the ego car's share
in the opposite lane at the crash, and whether a road user was on its route corridor (the hazard reward's free
distance below 15 m) the decision before. It also prints the share of decisions with part of the car in the
opposite lane. Outside the paper; every figure from the episode seeds.
"""

from __future__ import annotations

import argparse
import json
import math
import os
from concurrent.futures import ProcessPoolExecutor
from pathlib import Path

os.environ.setdefault("OMP_NUM_THREADS", "1")

import numpy as np

from brlcli.agent.command import load_navigation_agent
from brlcli.policy import model_state_option
from brlcli.provenance import atomic_write_json
from brlcli.sim.gym_env import ACTION_SETS
from brlcli.train import make_env
from brlcli.trainconfig import TrainConfig

NEAR_M = 15.0


def _episodes(job: tuple[str, str, list[int]]) -> list[dict]:
    model_path, level, seeds = job
    agent = load_navigation_agent(model_path)
    actions = next(name for name, primitives in ACTION_SETS.items() if len(primitives) == agent.n_actions)
    state = model_state_option(Path(model_path))  # the state option the model was trained with
    env = make_env(TrainConfig(task="navigation", traffic=[level], r_hazard=20.0, actions=actions,
                               state=state))  # the hazard reward only records the gap
    rng = np.random.default_rng(0)  # greedy acting draws nothing
    out = []
    for seed in seeds:
        obs, info = env.reset(seed=seed)
        done, gaps, otherlane = False, [math.inf], []
        while not done:
            obs, _, term, trunc, info = env.step(agent.act(obs, info["command"], rng, greedy=True))
            done = term or trunc
            m = info["measurements"]
            otherlane.append(m["intersection_otherlane"])
            gaps.append(info["hazard_gap_m"])
        row = {"seed": seed, "route": env.spec_route.name, "goal": bool(term), "crashed": bool(info["crashed"]),
               "decisions": len(otherlane), "otherlane_decisions": int(np.count_nonzero(np.array(otherlane) > 0))}
        if info["crashed"]:
            traffic = env.world.traffic
            boxes = traffic.boxes()
            d = np.hypot(boxes[:, 1] - m["x"], boxes[:, 2] - m["y"])
            i = int(np.argmin(d))
            rel_deg = abs((math.degrees(boxes[i, 7]) - m["yaw_deg"] + 180.0) % 360.0 - 180.0)
            row.update(hit="vehicle" if i < traffic.n_vehicles else "pedestrian",
                       heading="oncoming" if rel_deg > 120 else "crossing" if rel_deg > 60 else "same direction",
                       otherlane_at_crash=round(float(m["intersection_otherlane"]), 3),
                       hazard_before=bool(gaps[-2] < NEAR_M))
        out.append(row)
    return out


def main() -> None:
    """Drive the episodes and print the anatomy of the crashes."""
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--model", type=Path, required=True)
    ap.add_argument("--traffic", choices=("regular", "dense"), default="dense")
    ap.add_argument("--episodes", type=int, default=40)
    ap.add_argument("--workers", type=int, default=1)
    ap.add_argument("--json", type=Path, default=None)
    args = ap.parse_args()
    seeds = list(range(args.episodes))
    jobs = [(str(args.model), args.traffic, seeds[w::args.workers]) for w in range(args.workers)]
    with ProcessPoolExecutor(args.workers) as pool:
        rows = sorted((r for part in pool.map(_episodes, jobs) for r in part), key=lambda r: r["seed"])
    crashes = [r for r in rows if r["crashed"]]
    decisions = sum(r["decisions"] for r in rows)
    summary = {
        "model": str(args.model), "traffic": args.traffic, "episodes": len(rows),
        "goal": sum(r["goal"] for r in rows), "crashes": len(crashes),
        "crashes_by_kind": {f"{h} {k}": sum(r["hit"] == h and r["heading"] == k for r in crashes)
                            for h in ("vehicle", "pedestrian") for k in ("oncoming", "crossing", "same direction")},
        "crashes_in_opposite_lane": sum(r["otherlane_at_crash"] > 0 for r in crashes),
        "crashes_with_hazard_on_route_before": sum(r["hazard_before"] for r in crashes),
        "decisions": decisions,
        "opposite_lane_decision_share": round(sum(r["otherlane_decisions"] for r in rows) / max(decisions, 1), 4),
    }
    print(json.dumps(summary, indent=1))
    if args.json:
        atomic_write_json(args.json, {**summary, "episodes_detail": rows})


if __name__ == "__main__":
    main()
