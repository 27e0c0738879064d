"""Issue 35's probe: continue each member of a navigation committee's learning in traffic (a warm start), then
assemble the committee again.

    python scripts/warm_start_traffic.py --committee runs/s36/fine_c/seed_0 --out runs/s36/fine_ft --steps 10000 \
        [--ghost] [--workers 2]

Every member_<k>/model.npz of `--committee` learns `--steps` more steps (Algorithm 1, its own schedules where they
stopped) in the training environment of its config.json with NoCrash traffic of every level and the hazard reward
(r_hazard 20), its generator seeded from (seed, 99, k); the members land in OUT/member_<k>/model.npz and the voting
committee in OUT/model.npz, beside the committee's config.json. With `--ghost` the traffic is ghost traffic (the car
passes through road users; no hazard reward, as a ghost driver learns: section 12.9). Members run in `--workers`
processes (each member's result does not depend on it). Outside the paper; a probe, not a method
(docs/navigation-study.md sections 12.6 and 12.13).
"""

from __future__ import annotations

import argparse
import json
import shutil
from concurrent.futures import ProcessPoolExecutor
from pathlib import Path

import numpy as np

from brlcli.agent.command import CommandAgent, CommitteeAgent
from brlcli.train import Run, make_env, run_episode
from brlcli.trainconfig import TrainConfig


def _warm_start(job: tuple[Path, Path, int, bool]) -> str:
    """Continue one member's learning in traffic and save it under OUT."""
    path, out, steps, ghost = job
    k = int(path.parent.name.split("_")[1])
    saved = json.loads((path.parent / "config.json").read_text())["config"]
    extra = {"ghost_traffic": True, "r_hazard": 0.0} if ghost else {"r_hazard": 20.0}
    cfg = TrainConfig.from_saved({**saved, "traffic": ["empty", "regular", "dense"], **extra, "steps": steps,
                                  "branch_restart_below": None}, str(path.parent))
    agent = CommandAgent.load(path)
    run = Run(cfg, agent, np.random.default_rng([cfg.seed, 99, k]))
    env = make_env(cfg)
    crashes = 0
    while not run.done:
        rows, _ = run_episode(env, run, [])
        run.episode += 1
        crashes += bool(rows and rows[-1]["crashed"])
    env.close()
    (out / f"member_{k}").mkdir(parents=True, exist_ok=True)
    agent.save(out / f"member_{k}" / "model.npz")
    return f"member {k}: {run.episode} episodes, {crashes} crashes, {agent.total_components} components"


def main() -> None:
    """Warm-start every member in traffic and write the committee."""
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--committee", type=Path, required=True, help="a seed directory with member_<k>/ runs")
    ap.add_argument("--out", type=Path, required=True)
    ap.add_argument("--steps", type=int, default=10000)
    ap.add_argument("--ghost", action="store_true", help="ghost traffic (no contact), no hazard reward")
    ap.add_argument("--workers", type=int, default=1)
    args = ap.parse_args()
    members = sorted(args.committee.glob("member_*/model.npz"), key=lambda p: int(p.parent.name.split("_")[1]))
    with ProcessPoolExecutor(args.workers) as pool:
        for line in pool.map(_warm_start, [(p, args.out, args.steps, args.ghost) for p in members]):
            print(line, flush=True)
    CommitteeAgent([CommandAgent.load(args.out / f"member_{k}" / "model.npz") for k in range(len(members))]).save(
        args.out / "model.npz")
    shutil.copy(args.committee / "config.json", args.out / "config.json")


if __name__ == "__main__":
    main()
