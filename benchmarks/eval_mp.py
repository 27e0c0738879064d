"""Measure the modular-pipeline baseline on bench suites with `run_episode` (one world per town and traffic).

    OMP_NUM_THREADS=1 python benchmarks/eval_mp.py --suite paper
    OMP_NUM_THREADS=1 python benchmarks/eval_mp.py --suite corl2017 --tasks one_curve,navigation --weathers 1 \
        --episodes 0.05 --deploy estimated
"""

from __future__ import annotations

import argparse
import json
import time

from brlcli.baselines.mp import ModularPipelinePolicy
from brlcli.bench.runner import run_episode
from brlcli.bench.suites import build_suite, subset
from brlcli.sim.world import World


def main() -> None:
    """Run the episodes and print one line each and a summary."""
    ap = argparse.ArgumentParser()
    ap.add_argument("--suite", default="paper")
    ap.add_argument("--tasks")
    ap.add_argument("--conditions")
    ap.add_argument("--weathers")
    ap.add_argument("--episodes")
    ap.add_argument("--deploy", default="gt")
    ap.add_argument("--only", help="substring of episode ids to keep")
    ap.add_argument("--out", help="write the result records as JSON lines here")
    args = ap.parse_args()
    specs = subset(build_suite(args.suite, args.conditions, args.tasks, args.weathers), args.episodes)
    if args.only:
        specs = [s for s in specs if args.only in s.id]
    policy = ModularPipelinePolicy(deploy=args.deploy)
    worlds: dict[tuple, World] = {}
    rows = []
    t0 = time.time()
    for spec in specs:
        key = (spec.town, spec.vehicles, spec.pedestrians)
        if key not in worlds:
            worlds[key] = World(spec.town, vehicles=spec.vehicles, pedestrians=spec.pedestrians, seed=0)
        r, _ = run_episode(worlds[key], spec, policy, bench_seed=0)
        rows.append(r)
        either = r["either_steps"] / max(r["steps"], 1)
        print(f"{r['id']:55s} ok={int(r['success'])} col={int(r['collided'])} either={either:.3f} "
              f"t={r['time_s']:.0f}/{r['timeout_s']:.0f}s left={r['final_distance_m']:.0f}m", flush=True)
    n = len(rows)
    if n:
        ok = sum(r["success"] for r in rows)
        col = sum(r["collided"] for r in rows)
        either = sum(r["either_steps"] for r in rows) / max(sum(r["steps"] for r in rows), 1)
        print(f"episodes {n}: success {ok}/{n} = {100 * ok / n:.1f}%  collided {col}  either {100 * either:.2f}% "
              f"of steps  ({time.time() - t0:.0f}s)")
    if args.out:
        with open(args.out, "w", encoding="utf-8") as fh:
            for r in rows:
                fh.write(json.dumps(r) + "\n")


if __name__ == "__main__":
    main()
