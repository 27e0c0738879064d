"""Agent and training throughput, pinned to one CPU core (issue 11).

    python benchmarks/bench_agent.py [--repeats 5] [--baseline-src DIR] [--full-run] [--json FILE]

Figures (each the median of `--repeats` runs):
- act + learn: microseconds per pair `act(s_t, rng)` then `learn(s_t, a_t, r_t, s_{t+1})`, the pair a training
  step makes, with 1, 200 and 1,000 components (D = 30, 4 actions), on a fixed stream of states near the
  components with rewards that update (never create), so M stays fixed. Each repeat loads the same model file.
- `brl train` learning steps per second (simulator + agent, GT input, town01, no evaluation, 1,000 steps
  including set-up), and the agent's share of it: the time inside `BayesianAgent.act` and `.learn` (wrapped with
  perf_counter) over the run's wall time. `--full-run` adds one default-length run (4,500 steps).
- With `--baseline-src DIR` (a checkout of the previous implementation, e.g.
  `git worktree add /tmp/agent-base 75a3316`), the same act + learn workload and training run are timed with that
  package's `BayesianAgent` in a subprocess, interleaved with the current one, and the speed-up is printed.
The models are built with the current package and saved as version-1 .npz files, which both implementations read.
"""

from __future__ import annotations

import argparse
import json
import os
import statistics
import subprocess
import sys
import tempfile
import time
from collections.abc import Callable
from pathlib import Path
from typing import Any

os.environ.setdefault("OMP_NUM_THREADS", "1")
os.environ.setdefault("OPENBLAS_NUM_THREADS", "1")
os.environ.setdefault("MKL_NUM_THREADS", "1")

import numpy as np

COMPONENTS = (1, 200, 1000)
PAIRS = 300
D, A = 30, 4


def _pin() -> None:
    """Run on one CPU core."""
    if hasattr(os, "sched_setaffinity"):
        os.sched_setaffinity(0, {sorted(os.sched_getaffinity(0))[0]})


def build_inputs(out: Path) -> None:
    """Write, for every component count, a model file and a fixed stream of (states, rewards) near its components."""
    from brlcli.agent import BayesianAgent, BRLParams

    for m in COMPONENTS:
        rng = np.random.default_rng(m)
        agent = BayesianAgent(D, A, BRLParams(max_components=max(m, 2)))
        while agent.n_components < m:  # far, badly rewarded states create components
            agent.learn(rng.dirichlet(np.full(D, 0.1)), int(rng.integers(A)), -60.0, rng.dirichlet(np.full(D, 0.1)))
        means = agent.means
        for k in range(2 * m):  # then some updates, so that the components are not all alike
            s = np.abs(means[k % m] + rng.normal(0.0, 0.003, D))
            agent.learn(s / s.sum(), int(rng.integers(A)), float(rng.uniform(-9.0, 0.0)), s / s.sum())
        agent.save(out / f"agent_{m}.npz")
        states = np.abs(agent.means[np.arange(PAIRS + 1) % m] + rng.normal(0.0, 0.003, (PAIRS + 1, D)))
        np.savez(out / f"stream_{m}.npz", states=states / states.sum(axis=1, keepdims=True),
                 rewards=rng.uniform(-9.0, 0.0, PAIRS))  # TD error > T_l: every learn() updates


def worker_agent(inputs: Path) -> dict[str, float]:
    """Microseconds per act + learn pair for each component count (one repeat), and the first pair's cost."""
    t0 = time.perf_counter()
    from brlcli.agent import BayesianAgent

    out: dict[str, float] = {"import_ms": (time.perf_counter() - t0) * 1e3}
    for m in COMPONENTS:
        agent = BayesianAgent.load(inputs / f"agent_{m}.npz")
        with np.load(inputs / f"stream_{m}.npz") as npz:
            states, rewards = list(npz["states"]), npz["rewards"].tolist()
        rng = np.random.default_rng(0)
        t0 = time.perf_counter()
        a = agent.act(states[0], rng)
        agent.learn(states[0], a, rewards[0], states[1])
        first = time.perf_counter() - t0
        t0 = time.perf_counter()
        for k in range(1, PAIRS):
            a = agent.act(states[k], rng)
            agent.learn(states[k], a, rewards[k], states[k + 1])
        out[f"pair_us_{m}"] = (time.perf_counter() - t0) / (PAIRS - 1) * 1e6
        out[f"first_pair_ms_{m}"] = first * 1e3
        assert agent.n_components == m
    return out


def worker_train(steps: int) -> dict[str, float]:
    """`brl train` learning steps/s over `steps` steps and the share of the wall time spent in act + learn."""
    from brlcli.agent import BayesianAgent
    from brlcli.train import train_run
    from brlcli.trainconfig import TrainConfig

    inside = [0.0]

    def timed(fn: Callable) -> Callable:
        def wrapper(*args: Any, **kwargs: Any) -> Any:
            t0 = time.perf_counter()
            try:
                return fn(*args, **kwargs)
            finally:
                inside[0] += time.perf_counter() - t0
        return wrapper

    BayesianAgent.act = timed(BayesianAgent.act)
    BayesianAgent.learn = timed(BayesianAgent.learn)
    with tempfile.TemporaryDirectory() as tmp:
        t0 = time.perf_counter()
        summary = train_run(TrainConfig(steps=steps, evaluate=False), Path(tmp) / "run")["summary"]
        wall = time.perf_counter() - t0
    return {"steps_per_s": steps / wall, "agent_share": inside[0] / wall, "agent_us_per_step": inside[0] / steps * 1e6,
            "components": summary["components"]}


def _run_worker(src: Path, args: list[str]) -> dict[str, float]:
    """Run this script as a worker with `src` first on PYTHONPATH; return its JSON result."""
    env = {**os.environ, "PYTHONPATH": os.pathsep.join([str(src), os.environ.get("PYTHONPATH", "")]).rstrip(os.pathsep)}
    proc = subprocess.run([sys.executable, __file__, *args], env=env, capture_output=True, text=True, check=False)
    if proc.returncode != 0:
        raise SystemExit(f"worker {args} with {src} failed:\n{proc.stderr}")
    return json.loads(proc.stdout.strip().splitlines()[-1])


def _median(rows: list[dict[str, float]], key: str) -> float:
    return statistics.median(r[key] for r in rows)


def main() -> None:
    """Run the benchmarks (see the module docstring)."""
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--repeats", type=int, default=5)
    ap.add_argument("--baseline-src", type=Path, help="source tree of the previous implementation")
    ap.add_argument("--train-steps", type=int, default=1000)
    ap.add_argument("--full-run", action="store_true", help="also one default-length (4,500-step) training run")
    ap.add_argument("--json", type=Path, help="write every figure here")
    ap.add_argument("--worker-agent", type=Path, help=argparse.SUPPRESS)
    ap.add_argument("--worker-train", type=int, help=argparse.SUPPRESS)
    args = ap.parse_args()
    _pin()
    if args.worker_agent:
        print(json.dumps(worker_agent(args.worker_agent)))
        return
    if args.worker_train:
        print(json.dumps(worker_train(args.worker_train)))
        return

    here = Path(__file__).resolve().parents[1]
    sources = {"new": here} | ({"old": args.baseline_src.resolve()} if args.baseline_src else {})
    results: dict[str, dict[str, list[dict[str, float]]]] = {k: {"agent": [], "train": []} for k in sources}
    with tempfile.TemporaryDirectory() as tmp:
        inputs = Path(tmp)
        sys.path.insert(0, str(here))
        build_inputs(inputs)
        for _ in range(args.repeats):  # interleaved, so that both see the same machine load
            for name, src in sources.items():
                results[name]["agent"].append(_run_worker(src, ["--worker-agent", str(inputs)]))
                results[name]["train"].append(_run_worker(src, ["--worker-train", str(args.train_steps)]))
        full = {name: _run_worker(src, ["--worker-train", "4500"]) for name, src in sources.items()} \
            if args.full_run else {}

    report: dict[str, object] = {"repeats": args.repeats, "train_steps": args.train_steps}
    for name in sources:
        agent, train = results[name]["agent"], results[name]["train"]
        fig = {f"pair_us_{m}": _median(agent, f"pair_us_{m}") for m in COMPONENTS}
        fig |= {f"first_pair_ms_{m}": _median(agent, f"first_pair_ms_{m}") for m in COMPONENTS}
        fig |= {k: _median(train, k) for k in ("steps_per_s", "agent_share", "agent_us_per_step", "components")}
        fig["import_ms"] = _median(agent, "import_ms")
        if name in full:
            fig |= {f"full_{k}": v for k, v in full[name].items()}
        report[name] = fig
        print(f"[{name}] act + learn per pair: " + " / ".join(f"{fig[f'pair_us_{m}']:.1f}" for m in COMPONENTS)
              + f" us at {' / '.join(map(str, COMPONENTS))} components; first pair in a fresh process "
              + " / ".join(f"{fig[f'first_pair_ms_{m}']:.2f}" for m in COMPONENTS) + " ms; import "
              + f"{fig['import_ms']:.0f} ms")
        print(f"[{name}] brl train: {fig['steps_per_s']:.0f} learning steps/s ({args.train_steps} steps incl. set-up, "
              f"{fig['components']:.0f} components at the end); agent act + learn {fig['agent_us_per_step']:.0f} "
              f"us/step = {100 * fig['agent_share']:.1f} % of the wall time")
        if name in full:
            print(f"[{name}] default run (4,500 steps): {fig['full_steps_per_s']:.0f} learning steps/s, "
                  f"{fig['full_components']:.0f} components, agent {fig['full_agent_us_per_step']:.0f} us/step = "
                  f"{100 * fig['full_agent_share']:.1f} %")
    if "old" in report:
        new, old = report["new"], report["old"]
        speed = {m: old[f"pair_us_{m}"] / new[f"pair_us_{m}"] for m in COMPONENTS}  # type: ignore[index]
        report["speedup_pair"] = speed
        print("speed-up of act + learn over the baseline: "
              + " / ".join(f"{speed[m]:.1f}x" for m in COMPONENTS)
              + f"; brl train steps/s {new['steps_per_s'] / old['steps_per_s']:.2f}x")  # type: ignore[index]
    if args.json:
        args.json.write_text(json.dumps(report, indent=2))


if __name__ == "__main__":
    main()
