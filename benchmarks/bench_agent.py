"""Agent and training throughput, pinned to one CPU core.

    python benchmarks/bench_agent.py [--repeats 5]

Figures: microseconds per `action_probabilities` and per `learn` (update path) with 1, 100 and 1,000
components (D = 30, 4 actions); learning steps per second of `brl train` (simulator + agent, GT input, no
evaluation) over 1,000 steps. Each figure is the median of `--repeats` runs.
"""

from __future__ import annotations

import argparse
import os
import statistics
import tempfile
import time
from pathlib import Path

os.environ.setdefault("OMP_NUM_THREADS", "1")
os.environ.setdefault("OPENBLAS_NUM_THREADS", "1")

import numpy as np

from brlcli.agent import BayesianAgent, BRLParams
from brlcli.train import TrainConfig, train_run


def _agent_with(m: int) -> BayesianAgent:
    agent = BayesianAgent(30, 4, BRLParams(max_components=max(m, 2)))
    rng = np.random.default_rng(0)
    while agent.n_components < m:  # far, badly rewarded states create components
        s = rng.dirichlet(np.ones(30))
        agent.learn(s, int(rng.integers(4)), -60.0, rng.dirichlet(np.ones(30)))
    return agent


def _time_per_call(fn, n: int) -> float:
    t0 = time.perf_counter()
    for _ in range(n):
        fn()
    return (time.perf_counter() - t0) / n * 1e6


def main() -> None:
    """Run the agent micro-benchmarks and the training throughput benchmark."""
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--repeats", type=int, default=5)
    args = ap.parse_args()
    if hasattr(os, "sched_setaffinity"):
        os.sched_setaffinity(0, {sorted(os.sched_getaffinity(0))[0]})
    for m in (1, 100, 1000):
        with tempfile.TemporaryDirectory() as tmp:
            model = Path(tmp) / f"agent_{m}.npz"
            _agent_with(m).save(model)
            probs, learn = [], []
            for _ in range(args.repeats):
                agent = BayesianAgent.load(model)
                s = agent.means[0].copy()
                probs.append(_time_per_call(lambda agent=agent, s=s: agent.action_probabilities(s), 200))
                learn.append(_time_per_call(lambda agent=agent, s=s: agent.learn(s, 0, 0.0, s), 100))
        print(f"components {m:5d}: action_probabilities {statistics.median(probs):8.1f} us   "
              f"learn {statistics.median(learn):8.1f} us")
    rates = []
    for _ in range(args.repeats):
        with tempfile.TemporaryDirectory() as tmp:
            t0 = time.perf_counter()
            train_run(TrainConfig(steps=1000, evaluate=False), Path(tmp) / "run")
            rates.append(1000 / (time.perf_counter() - t0))
    print(f"training (GT input, town01, 1,000 steps incl. set-up): {statistics.median(rates):.0f} learning steps/s")


if __name__ == "__main__":
    main()
