"""Issue 35's evidence on the driver: can the paper's 30-number state drive among road users at all?

    python scripts/state_imitation_evidence.py --iterations 4 --episodes 200 --workers 2 --out runs/NAME

The learned drivers leave their lane among road users (docs/navigation-study.md, 12.6 and 12.15), while the expert
restricted to the same actions (the `fine` set and `stop`) keeps it. Is the state or the learning the limit? This
script imitates the restricted expert on the agent's own input with DAgger (Ross et al., 2011): iteration 0 records
the expert's nearest action (`DrivingEnv.expert_action`, the oracle's quantisation) along the expert's own
drives in the navigation training environment (town01, training weather, the navigation routes, Empty / Regular /
Dense traffic); each later iteration drives a classifier fitted on everything recorded so far and records the
expert's action at the states the classifier visits. The classifier is a small MLP on the 30 numbers and the route
command (or, with `--view`, another input). Its final version and the restricted expert are then driven on
`nav_validation_traffic` (16 routes per traffic level). If imitation on the 30 numbers keeps the car in its lane
among road users, the state is enough and the Bayesian learner is the limit; if not, the state is. Outside the
paper: a diagnostic, not a brl agent. Every random choice is seeded (episode e of iteration i from (i, e); the
classifier's initialisation and batches from the iteration).

The mixture imitator this script had (`--learner mixture`, docs/navigation-study.md 12.16, commit b46319d) is now
a recipe of brl itself: `brl train --task navigation --set learning=imitation` (`brlcli.imitation`).
"""

from __future__ import annotations

import argparse
import json
import os
from concurrent.futures import ProcessPoolExecutor
from pathlib import Path

os.environ.setdefault("OMP_NUM_THREADS", "1")


import numpy as np
import torch

from brlcli.features import STATE_DIM
from brlcli.npzio import save_npz
from brlcli.provenance import atomic_write_json, provenance
from brlcli.reward import RouteRewardParams
from brlcli.sim.gym_env import ACTION_SET_NAMES, DrivingEnv
from brlcli.sim.roadnet import Command

ACTIONS = "fine_stop"
COMMANDS = (int(Command.LANE_FOLLOW), int(Command.TURN_LEFT), int(Command.TURN_RIGHT), int(Command.GO_STRAIGHT))
NAV_KINDS = ("straight", "right_curve", "left_curve", "turn_left", "turn_right", "go_straight")


def features(state: np.ndarray, command: int) -> np.ndarray:
    """The classifier's input: the 30 numbers and the route command one-hot."""
    onehot = np.zeros(len(COMMANDS))
    if command in COMMANDS:
        onehot[COMMANDS.index(command)] = 1.0
    return np.concatenate([np.asarray(state, dtype=np.float64)[:STATE_DIM], onehot])


class Imitator(torch.nn.Module):
    """An MLP from the features to the action set's logits."""

    def __init__(self, n_in: int, n_out: int, hidden: int = 128) -> None:
        super().__init__()
        self.net = torch.nn.Sequential(torch.nn.Linear(n_in, hidden), torch.nn.ReLU(),
                                       torch.nn.Linear(hidden, hidden), torch.nn.ReLU(), torch.nn.Linear(hidden, n_out))

    def forward(self, x: torch.Tensor) -> torch.Tensor:
        """Logits."""
        return self.net(x)


def fit(x: np.ndarray, y: np.ndarray, n_out: int, seed: int, epochs: int = 30) -> Imitator:
    """Cross-entropy fit on (x, y), batches of 256, Adam 1e-3."""
    torch.manual_seed(seed)
    model = Imitator(x.shape[1], n_out)
    opt = torch.optim.Adam(model.parameters(), lr=1e-3)
    xt, yt = torch.as_tensor(x, dtype=torch.float32), torch.as_tensor(y, dtype=torch.long)
    gen = torch.Generator().manual_seed(seed)
    for _ in range(epochs):
        for idx in torch.randperm(len(xt), generator=gen).split(256):
            opt.zero_grad()
            torch.nn.functional.cross_entropy(model(xt[idx]), yt[idx]).backward()
            opt.step()
    return model.eval()


def greedy(model: Imitator, state: np.ndarray, command: int) -> int:
    """The imitator's action: the classifier's most likely one."""
    with torch.no_grad():
        return int(model(torch.as_tensor(features(state, command)[None], dtype=torch.float32)).argmax())


def _episodes(args: tuple[int, list[int], dict | None, str]) -> dict[str, np.ndarray]:
    """Drive episodes of one iteration (the classifier drives from iteration 1 on) and record the expert's labels."""
    iteration, episodes, weights, actions = args
    model: Imitator | None = None
    if weights is not None:
        model = Imitator(STATE_DIM + len(COMMANDS), len(ACTION_SET_NAMES[actions]))
        model.load_state_dict({k: torch.as_tensor(v) for k, v in weights.items()})
        model.eval()
    env = DrivingEnv(routes="navigation", kinds=NAV_KINDS, actions=actions, traffic=("empty", "regular", "dense"),
                     route_reward=RouteRewardParams())
    rows: dict[str, list] = {"x": [], "y": [], "traffic": [], "episode": []}
    goals = crashes = 0
    try:
        for e in episodes:
            obs, info = env.reset(seed=int(np.random.default_rng([iteration, e, 41]).integers(2**31)))
            command = info["command"]
            for _ in range(2000):
                label = env.expert_action()
                rows["x"].append(features(obs, command))
                rows["y"].append(label)
                rows["traffic"].append(env.traffic_level)
                rows["episode"].append(e)
                action = label if model is None else greedy(model, obs, command)
                obs, _, terminated, truncated, info = env.step(action)
                command = info["command"]
                if terminated or truncated:
                    goals += int(terminated)
                    crashes += int(info["crashed"])
                    break
    finally:
        env.close()
    out = {k: np.asarray(v) for k, v in rows.items()}
    out["goals"], out["crashes"] = np.array([goals]), np.array([crashes])
    return out


def _bench(policy: object) -> dict[str, dict[str, float]]:
    """Successes, crashes and the opposite-lane share per traffic level on nav_validation_traffic."""
    from brlcli.bench.runner import run_episode, world_for
    from brlcli.bench.suites import build_suite

    specs = build_suite("nav_validation_traffic")
    worlds: dict = {}
    figures: dict[str, dict[str, float]] = {}
    for spec in specs:
        result = run_episode(world_for(worlds, spec, policy), spec, policy, 0)[0]
        f = figures.setdefault(result["task"], {"episodes": 0, "goals": 0, "crashes": 0, "otherlane_steps": 0,
                                                "steps": 0})
        f["episodes"] += 1
        f["goals"] += int(result["success"])
        f["crashes"] += int(bool(result.get("crashed", result["collided"])))
        f["otherlane_steps"] += result["otherlane_steps"]
        f["steps"] += result["steps"]
    for w in worlds.values():
        w.close()
    return figures


def main() -> None:
    """Record, fit, iterate, bench; print and write the figures."""
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--iterations", type=int, default=4, help="DAgger iterations after the expert's own")
    parser.add_argument("--episodes", type=int, default=200, help="training episodes per iteration")
    parser.add_argument("--workers", type=int, default=2)
    parser.add_argument("--actions", choices=("fine_stop", "fine"), default=ACTIONS,
                        help="the action set imitated: the fine set and stop, or the fine set alone (a gate's driver)")
    parser.add_argument("--out", type=Path, required=True, help="directory for data.npz, imitator.pt, figures.json")
    args = parser.parse_args()
    args.out.mkdir(parents=True, exist_ok=True)
    n_out = len(ACTION_SET_NAMES[args.actions])
    data: dict[str, list[np.ndarray]] = {"x": [], "y": [], "traffic": [], "episode": [], "iteration": []}
    log = []
    model: Imitator | None = None
    for it in range(args.iterations + 1):
        weights: dict | None = None
        if model is not None:
            weights = {k: v.numpy() for k, v in model.state_dict().items()}
        chunks = [list(range(w, args.episodes, args.workers)) for w in range(args.workers)]
        with ProcessPoolExecutor(args.workers) as pool:
            parts = list(pool.map(_episodes, [(it, c, weights, args.actions) for c in chunks]))
        order = np.argsort(np.concatenate([p["episode"] for p in parts]), kind="stable")  # episode order, whatever
        for k in ("x", "y", "traffic", "episode"):  # the number of workers
            data[k].append(np.concatenate([p[k] for p in parts])[order])
        data["iteration"].append(np.full(len(data["y"][-1]), it))
        goals, crashes = sum(int(p["goals"][0]) for p in parts), sum(int(p["crashes"][0]) for p in parts)
        x, y = np.concatenate(data["x"]), np.concatenate(data["y"])
        agree = None
        if model is not None:  # how often the driving classifier agreed with the expert on its own states
            xi = torch.as_tensor(data["x"][-1], dtype=torch.float32)
            agree = float(np.mean([greedy(model, xi[i, :STATE_DIM].numpy(), COMMANDS[int(xi[i, STATE_DIM:].argmax())])
                                   == data["y"][-1][i] for i in range(len(xi))]))
        model = fit(x, y, n_out, seed=it)
        row = {"iteration": it, "driver": "expert" if it == 0 else "imitator", "episodes": args.episodes,
               "goals": goals, "crashes": crashes, "decisions": len(data["y"][-1]),
               "agreement_on_own_states": agree, "data": len(y)}
        log.append(row)
        print(json.dumps(row), flush=True)
    torch.save(model.state_dict(), args.out / "imitator.pt")
    save_npz(args.out / "data.npz", {k: np.concatenate(v) for k, v in data.items()})

    from brlcli.policy import OraclePolicy, StatePolicy

    imitator = model

    def act(state: np.ndarray, command: int) -> int:
        return greedy(imitator, state, command)

    benches = {
        "imitator": _bench(StatePolicy("imitator", "imitation (diagnostic)", act, uses_command=True,
                                       actions=args.actions)),
        "expert_restricted": _bench(OraclePolicy(turn_steer=[0.4, 0.15, 0.05],
                                                       stop="standstill" if args.actions == "fine_stop" else "never")),
    }
    for name, figs in benches.items():
        lane = sum(f["otherlane_steps"] for f in figs.values()) / max(sum(f["steps"] for f in figs.values()), 1)
        print(name, " | ".join(f"{t} {f['goals']}/{f['episodes']} ({f['crashes']})" for t, f in figs.items()),
              f"| opposite lane {100 * lane:.1f} %")
    atomic_write_json(args.out / "figures.json", provenance({"iterations": log, "bench": benches,
                                                              "args": {k: str(v) for k, v in vars(args).items()}},
                                                             kind="state-imitation-evidence"))


if __name__ == "__main__":
    main()
