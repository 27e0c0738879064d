"""Decision latency of the baselines' policies and bench throughput on lane-keeping episodes (one core).

    python benchmarks/bench_baselines.py [--agents mp,il,dqn,brl] [--frames 300] [--episodes 6]

Per agent: the median time of `policy.decide` on recorded camera frames (GT input), and the simulated frames per
second of whole paper-suite episodes through the bench runner (rendering and physics included).
"""

from __future__ import annotations

import argparse
import os
import statistics
import time

os.environ.setdefault("OMP_NUM_THREADS", "1")

from brlcli.bench.registry import baseline_specs, build_policy
from brlcli.bench.runner import run_episode
from brlcli.bench.suites import build_suite
from brlcli.models import default_model_set
from brlcli.policy import Observation
from brlcli.sim.vehicle import Control
from brlcli.sim.world import World


def _policy(agent: str):
    if agent == "brl":
        return build_policy("brl", "brl", {"model": str(default_model_set() / "seed_0" / "model.npz")})
    name, opts = baseline_specs(agent, None, "gt", None)[0]
    return build_policy(agent, name, opts)


def main() -> None:
    """Time each agent's decisions and episodes (median of repeats)."""
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--agents", default="mp,il,dqn,brl")
    ap.add_argument("--frames", type=int, default=300)
    ap.add_argument("--episodes", type=int, default=6)
    args = ap.parse_args()
    if hasattr(os, "sched_setaffinity"):
        os.sched_setaffinity(0, {sorted(os.sched_getaffinity(0))[0]})
    specs = build_suite("paper", weathers="1")[: args.episodes]
    world = World(specs[0].town, seed=0)
    frames = []
    spec0 = specs[0]
    frame = world.reset(spec0.start, seed=0)
    for _ in range(args.frames):
        frame = world.step(Control(steer=0.0, throttle=0.5), render=True)
        frames.append(frame)
        if len(frames) % 40 == 0:
            frame = world.reset(spec0.start, seed=len(frames))
    for agent in args.agents.split(","):
        policy = _policy(agent)
        policy.reset(spec0, world)
        obs = [Observation(f.rgb, f.labels, f.measurements, 2) for f in frames]
        for o in obs[:10]:
            policy.decide(o)
        t0 = time.perf_counter()
        for o in obs:
            policy.decide(o)
        per_decision_ms = 1000.0 * (time.perf_counter() - t0) / len(obs)
        worlds: dict[str, World] = {}
        rates = []
        for spec in specs:
            w = worlds.setdefault(spec.town, World(spec.town, seed=0))
            t0 = time.perf_counter()
            result, _ = run_episode(w, spec, policy, 0)
            rates.append(result["steps"] / (time.perf_counter() - t0))
        for w in worlds.values():
            w.close()
        print(f"{agent:4s} decide {per_decision_ms:6.2f} ms/decision (every {policy.frames_per_decision} frames); "
              f"paper-suite episodes {statistics.median(rates):5.0f} simulated frames/s (median of {len(specs)})")
    world.close()


if __name__ == "__main__":
    main()
