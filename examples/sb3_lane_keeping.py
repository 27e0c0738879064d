"""Train a Stable-Baselines3 DQN on brl/LaneKeeping-v0 through gymnasium.make, save it, and bench it with brl bench.

    python examples/sb3_lane_keeping.py             # 10,000 env steps, then the paper suite's 66 episodes
    python examples/sb3_lane_keeping.py --steps 100000 --out runs/sb3_dqn_100k

Writes OUT/sb3_dqn.zip (SB3's own file, for SB3: DQN.load), OUT/drl.pt (the same Q-network in the file
`brl bench --agent dqn --model` reads: brl never unpickles SB3's zip) and OUT/bench/ (brl bench's output), by
running

    brl bench --agent dqn --model OUT/drl.pt --suite paper --workers 2 --out OUT/bench

See docs/gymnasium.md (ids, keyword arguments, spaces, the measured time of this example).
"""

from __future__ import annotations

import argparse
import subprocess
import sys
import time
from pathlib import Path

import gymnasium as gym
import torch
from stable_baselines3 import DQN
from stable_baselines3.common.logger import Logger

from brlcli.envs import export_dqn


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--steps", type=int, default=10_000, help="environment steps (decisions) to train")
    ap.add_argument("--episodes", help="brl bench's --episodes: a count or a fraction of the suite (default: all)")
    ap.add_argument("--workers", type=int, default=2, help="brl bench's worker processes")
    ap.add_argument("--out", default="runs/sb3_lane_keeping", help="output directory (must not exist)")
    ap.add_argument("--seed", type=int, default=0)
    args = ap.parse_args()
    out = Path(args.out)
    if out.exists():
        sys.exit(f"{out} exists; give another --out")
    torch.set_num_threads(1)  # small MLP: one thread is fastest

    t0 = time.perf_counter()
    env = gym.make("brlcli.envs:brl/LaneKeeping-v0", town="town01", weather=1, traffic="empty", input="gt")
    # brl train-rl's DQN hyperparameters (brlcli.baselines.deeprl.DeepRLConfig), on a smaller budget
    model = DQN("MlpPolicy", env, learning_rate=5e-4, buffer_size=100_000, learning_starts=1_000, batch_size=64,
                gamma=0.9, train_freq=4, target_update_interval=1_000, exploration_fraction=0.3,
                exploration_final_eps=0.05, policy_kwargs={"net_arch": [64, 64]}, seed=args.seed, device="cpu")
    model.set_logger(Logger(folder=None, output_formats=[]))  # no empty /tmp/SB3-* directory
    model.learn(total_timesteps=args.steps)
    t_train = time.perf_counter() - t0
    out.mkdir(parents=True)
    model.save(out / "sb3_dqn.zip")
    drl = export_dqn(model, out / "drl.pt", env)
    env.close()
    print(f"trained {args.steps} steps in {t_train:.1f} s; wrote {out / 'sb3_dqn.zip'} and {drl}")

    cmd = ["brl", "bench", "--agent", "dqn", "--model", str(drl), "--suite", "paper", "--workers", str(args.workers),
           *(["--episodes", args.episodes] if args.episodes else []), "--out", str(out / "bench")]
    print("$", " ".join(cmd), flush=True)
    t1 = time.perf_counter()
    rc = subprocess.call([sys.executable, "-m", "brlcli", *cmd[1:]])
    print(f"bench: {time.perf_counter() - t1:.1f} s; total {time.perf_counter() - t0:.1f} s")
    return rc


if __name__ == "__main__":
    sys.exit(main())
