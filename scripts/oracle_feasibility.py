"""Issue 20's feasibility check: the privileged expert restricted to the BRL agent's action primitives (`brl bench
--agent oracle`) with a changed decision rate or a fifth `stop` primitive, on a CoRL2017 (or NoCrash) subset.

    python scripts/oracle_feasibility.py --decision-frames 3 --episodes 0.2 --out runs/issue20/corl20_oracle_f3
    python scripts/oracle_feasibility.py --stop braking --episodes 0.2 --out runs/issue20/corl20_oracle_stop
    python scripts/oracle_feasibility.py --backward-brake --episodes 0.2 --out runs/issue20/corl20_oracle_brake
    python scripts/oracle_feasibility.py --suite nocrash --stop braking --out runs/s36/nocrash20_oracle_stop

The output is a `brl bench` results directory (`brl report` reads it); `--tasks` restricts the tasks.
"""

from __future__ import annotations

import argparse
from pathlib import Path

from brlcli.bench.runner import run_bench, suite_version, town_versions
from brlcli.bench.suites import build_suite, subset
from brlcli.policy import PolicySpec
from brlcli.sim.gym_env import ACTIONS, FRAMES_PER_DECISION


def main() -> None:
    """Run one oracle variant on a suite's subset and write its results."""
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--decision-frames", type=int, default=FRAMES_PER_DECISION, help="frames between decisions")
    ap.add_argument("--stop", choices=("never", "braking", "standstill"), default="never",
                    help="when to take a fifth primitive `stop` (outside the paper)")
    ap.add_argument("--turn-steer", type=float, nargs="+", default=[float(ACTIONS[1].steer)],
                    help="steering magnitude(s) of the right / left primitives (the paper's: 0.4; several values give "
                         "a finer steering set, +-each)")
    ap.add_argument("--backward-brake", action="store_true", help="take `backward` to brake while rolling forward")
    ap.add_argument("--suite", choices=("corl2017", "nocrash", "nav_validation_traffic"), default="corl2017")
    ap.add_argument("--episodes", default="0.2", help="deterministic subset of the suite (as brl bench --episodes)")
    ap.add_argument("--tasks", default=None, help="comma-separated tasks of the suite (default: all)")
    ap.add_argument("--workers", type=int, default=1)
    ap.add_argument("--out", type=Path, required=True)
    args = ap.parse_args()
    options = {"decision_frames": args.decision_frames, "stop": args.stop, "backward_brake": args.backward_brake,
               "turn_steer": args.turn_steer if len(args.turn_steer) > 1 else args.turn_steer[0]}
    steer = "" if args.turn_steer == [ACTIONS[1].steer] else "-steer" + "-".join(f"{t:g}" for t in args.turn_steer)
    name = (f"oracle-f{args.decision_frames}{'' if args.stop == 'never' else '-stop-' + args.stop}"
            f"{'-backward-brake' if args.backward_brake else ''}{steer}")
    specs = subset(build_suite(args.suite, None, args.tasks, None), args.episodes)
    config = {"suite": args.suite, "suite_version": suite_version(args.suite), "town_versions": town_versions(specs),
              "policies": [{"kind": "oracle", "name": name, **options}], "deploy": "gt", "seed": 0,
              "selection": {"conditions": None, "tasks": args.tasks, "weathers": None, "episodes": args.episodes},
              "shard": [1, 1]}
    rows = run_bench(specs, [PolicySpec("oracle", name, options)], args.out, config, workers=args.workers,
                     resume=True)
    print(f"{name}: {sum(r['success'] for r in rows)}/{len(rows)} episodes succeeded -> {args.out}")


if __name__ == "__main__":
    main()
