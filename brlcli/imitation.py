"""A navigation model fitted by imitation in the agent's own mixture (issue 35; outside the paper).

`brl train --task navigation --set learning=imitation` replaces Algorithm 1's TD learning on the reward by DAgger
(Ross et al., 2011) in the same command-conditioned Bayesian mixture: iteration 0 records, along the privileged
expert's own drives in the run's training environment, the action of the run's set nearest the expert's control
(`DrivingEnv.expert_action`); each later iteration drives the mixture fitted so far, greedily, and records the
expert's action at the states it visits. After every iteration the mixture is fitted anew on everything recorded
(`fit_mixture`): Algorithm 1's own learning step, component creation included, on the teacher's reward of every
action at every recorded state (-IMITATION_TEACHER x the action's distance from the expert's, no bootstrapping),
once through the data in a seeded order. Why (docs/navigation-study.md 12.16): TD learning on the route reward
cannot learn the small steering differences that keep a car in lane beside oncoming traffic (TD error std 11-12
against a value gap of 2.5 for 0.05 of steering), while the same mixture fitted to the expert's labels drives.

The agent's input stays the camera state; the expert is privileged and only labels. With `brake_gate_steps`, the
run's driver is this model and the brake gate learns over it by TD in traffic as before.

Layout (the run directory of `brlcli.train`, with iterations in place of learning steps):
    config.json             resolved configuration + brl version + git commit
    iterations/data_<i>.npz states, commands, the expert's and the driver's actions, traffic level, episode of
                            iteration i, and its totals (episodes, goals, crashes, seconds)
    iterations/model_<i>.npz the mixture fitted on iterations 0..i
    iterations.csv          one row per iteration (goals, crashes, decisions, agreement with the expert, components)
    model.npz, summary.json as every run
An interrupted run resumes at the first iteration without both files: it loses at most the iteration in flight.
Every random choice is seeded: episode e of iteration i from (seed, i, e[, member]), the fit's order from
(seed, i[, member]); greedy acting draws nothing. Iterations run one after the other; with several drive workers
an iteration's episodes are driven in blocks on local processes and joined in episode order (the same records).
"""

from __future__ import annotations

import csv
import io
import time
from collections.abc import Callable
from dataclasses import replace
from functools import partial
from itertools import pairwise
from pathlib import Path
from typing import Any

import numpy as np

from brlcli.agent.command import CommandAgent
from brlcli.executor import report as report_to_driver
from brlcli.executor import run_tasks
from brlcli.npzio import save_npz
from brlcli.policy import with_stop_rule
from brlcli.provenance import atomic_write_bytes, provenance
from brlcli.sim.gym_env import ACTION_SETS, STOP, DrivingEnv, action_distance
from brlcli.sim.roadnet import BRANCH_NAMES
from brlcli.trainconfig import TrainConfig

IMITATION_TEACHER = 20.0
"""The teacher's reward scale: an action's reward is -IMITATION_TEACHER x its distance from the expert's action."""
IMITATION_THRESHOLDS = {"T_l": -2.0, "T_u": -1.0}
"""The fit's TD thresholds (over the run's agent parameters): with `TrainConfig.imitation_rho` as rho, a new component
wherever a state is farther than rho (l_inf) from every component and an action's value falls 2 below its target (the
navigation preset's rho 0.1 -> 0.01 and T_l -10 give 71 components and 72 % held-out agreement; 12.16)."""
_NO_DRAWS = np.random.default_rng(0)
"""Greedy acting never draws from it (`BayesianAgent.act(greedy=True)`)."""
ITERATION_COLUMNS = ("iteration", "driver", "episodes", "goals", "crashes", "decisions", "agreement", "data",
                     "components", "wall_s")
"""Columns of iterations.csv."""


def teacher_distances(controls: tuple, stop_weight: float = 1.0) -> np.ndarray:
    """(action, label) -> the teacher's distance: `action_distance`, and `stop_weight` for a driving action where the
    label is `stop` (a missed stop costs that many needless ones)."""
    out = np.array([[action_distance(a, b) for b in controls] for a in controls])
    if STOP in controls:
        stop = controls.index(STOP)
        out[np.arange(len(controls)) != stop, stop] *= stop_weight
    return out


def fit_mixture(states: np.ndarray, commands: np.ndarray, labels: np.ndarray, cfg: TrainConfig,
                order_seed: list[int]) -> CommandAgent:
    """A command-conditioned mixture fitted by Algorithm 1's learning step to the teacher's reward of every action
    at every recorded state (-IMITATION_TEACHER x `action_distance` from the label, next value 0): one pass in the
    order drawn from `order_seed`."""
    controls = ACTION_SETS[cfg.actions]
    rho = cfg.imitation_rho
    params = replace(cfg.agent_params(), rho_init=rho, rho_final=rho, **IMITATION_THRESHOLDS)
    agent = CommandAgent(states.shape[1], len(controls), params)
    rewards = -IMITATION_TEACHER * teacher_distances(controls, cfg.imitation_stop_weight)
    by_label = np.ascontiguousarray(rewards.T)  # by_label[label][a]: action a's reward where the expert took label
    for i in np.random.default_rng(order_seed).permutation(len(labels)):
        agent.branch(int(commands[i])).learn_every_action(states[i], by_label[labels[i]])
    return agent


def _seed_tail(cfg: TrainConfig) -> list[int]:
    return [cfg.member] if cfg.member else []


def record_iteration(env: DrivingEnv, cfg: TrainConfig, iteration: int, driver: Any,
                     on_episode: Callable[[int], None] | None = None,
                     episodes: range | None = None) -> dict[str, np.ndarray]:
    """Drive one iteration's episodes (all, or `episodes` of them; the expert in iteration 0, else `driver`
    greedily, under the run's `stop_rule`) and record, at every decision, the state, the command, the expert's action
    and the action taken. `on_episode(k)` after the k-th episode driven here."""
    rows: dict[str, list[Any]] = {"states": [], "commands": [], "labels": [], "actions": [], "traffic": [],
                                  "episode": []}
    goals = crashes = 0
    if driver is not None:
        driver = with_stop_rule(driver, cfg.actions, cfg.stop_rule)
    t0 = time.perf_counter()
    episodes = range(cfg.imitation_episodes) if episodes is None else episodes
    for k, e in enumerate(episodes):
        seed = int(np.random.default_rng([cfg.seed, iteration, e, 43, *_seed_tail(cfg)]).integers(2**31))
        obs, info = env.reset(seed=seed)
        while True:
            state, command = obs.astype(np.float64), int(info["command"])
            label = env.expert_action()
            action = label if driver is None else driver.act(state, command, _NO_DRAWS, greedy=True)
            for key, value in zip(rows, (state, command, label, action, env.traffic_level, e), strict=True):
                rows[key].append(value)
            obs, _, terminated, truncated, info = env.step(action)
            if terminated or truncated:
                goals += int(terminated)
                crashes += int(bool(info.get("crashed", False)))
                break
        if on_episode is not None:
            on_episode(k + 1)
    out = {key: np.asarray(v) for key, v in rows.items()}
    out["states"] = out["states"].reshape(len(rows["labels"]), -1)
    out["traffic"] = out["traffic"].astype(str)
    out.update(goals=np.array(goals), crashes=np.array(crashes), wall_s=np.array(time.perf_counter() - t0))
    return out


DRIVE_CHUNKS_PER_WORKER = 4
"""With several drive workers, an iteration's episodes go out in this many blocks per worker (progress, balance)."""


def _drive_block(env: DrivingEnv, item: tuple[TrainConfig, int, str | None, int, int]) -> dict[str, np.ndarray]:
    """One block of an iteration's episodes in a worker process: the driver read from its model file."""
    cfg, iteration, driver_path, first, stop = item
    driver = CommandAgent.load(driver_path) if driver_path is not None else None
    return record_iteration(env, cfg, iteration, driver, lambda _k: report_to_driver(1),
                            episodes=range(first, stop))


def drive_iteration(cfg: TrainConfig, iteration: int, env: DrivingEnv | None, driver: Any, driver_path: Path | None,
                    make_env: Callable[[TrainConfig], DrivingEnv], workers: int,
                    on_episode: Callable[[int], None] | None = None) -> dict[str, np.ndarray]:
    """`record_iteration` over all the iteration's episodes: in this process where the run's environment `env` is
    given (with `driver`), else in blocks of episodes on `workers` local processes, each with its own environment
    (`make_env(cfg)`, a module-level function) and the driver read from `driver_path`. Episode e's seed is the same
    either way and the blocks are joined in episode order, so the records do not depend on where they were driven."""
    if env is not None:
        return record_iteration(env, cfg, iteration, driver, on_episode)
    n = cfg.imitation_episodes
    bounds = np.linspace(0, n, min(n, workers * DRIVE_CHUNKS_PER_WORKER) + 1).round().astype(int)
    items = [(cfg, iteration, None if driver_path is None else str(driver_path), int(a), int(b))
             for a, b in pairwise(bounds)]
    done = 0

    def count(_message: Any) -> None:
        nonlocal done
        done += 1
        if on_episode is not None:
            on_episode(done)

    t0 = time.perf_counter()
    parts: list[dict[str, np.ndarray]] = [{} for _ in items]
    for i, part in run_tasks(_drive_block, items, executor="local", workers=workers,
                             setup=partial(make_env, cfg), on_report=count):
        parts[i] = part
    out = {key: np.concatenate([p[key] for p in parts]) for key in ("states", "commands", "labels", "actions",
                                                                      "traffic", "episode")}
    out.update(goals=np.array(sum(int(p["goals"]) for p in parts)),
               crashes=np.array(sum(int(p["crashes"]) for p in parts)),
               wall_s=np.array(time.perf_counter() - t0))
    return out


def _load_npz(path: Path) -> dict[str, np.ndarray]:
    with np.load(path, allow_pickle=False) as z:
        return {k: z[k] for k in z.files}


def _iteration_row(iteration: int, data: dict[str, np.ndarray], n_data: int, agent: CommandAgent,
                   fit_s: float) -> dict[str, Any]:
    agreement = float(np.mean(data["actions"] == data["labels"])) if iteration else ""
    return {"iteration": iteration, "driver": "expert" if iteration == 0 else "mixture",
            "episodes": len(np.unique(data["episode"])), "goals": int(data["goals"]),
            "crashes": int(data["crashes"]), "decisions": len(data["labels"]), "agreement": agreement,
            "data": n_data, "components": agent.total_components, "wall_s": float(data["wall_s"]) + fit_s}


def _write_log(path: Path, rows: list[dict[str, Any]]) -> None:
    buf = io.StringIO()
    writer = csv.DictWriter(buf, ITERATION_COLUMNS, lineterminator="\n")
    writer.writeheader()
    writer.writerows(rows)
    atomic_write_bytes(path, buf.getvalue().encode())


def train_imitation(cfg: TrainConfig, run_dir: Path, make_env: Callable[[TrainConfig], DrivingEnv],
                    progress: Callable[[int, int, float, int], None] | None = None,
                    drive_workers: int = 1) -> dict[str, Any]:
    """Train (or resume) one imitation run in run_dir (config.json already written); returns the summary record
    without its evaluation. `progress(episodes_done, episodes_total, agreement, components)` after each episode.
    With `drive_workers` > 1 each iteration's drives run on that many local processes (`drive_iteration`; the same
    records); the fit stays in this process."""
    it_dir = run_dir / "iterations"
    it_dir.mkdir(exist_ok=True)
    total = (cfg.imitation_iterations + 1) * cfg.imitation_episodes
    env: DrivingEnv | None = None
    data: list[dict[str, np.ndarray]] = []
    rows: list[dict[str, Any]] = []
    agent: CommandAgent | None = None
    try:
        for it in range(cfg.imitation_iterations + 1):
            data_path, model_path = it_dir / f"data_{it}.npz", it_dir / f"model_{it}.npz"
            if data_path.exists() and model_path.exists():  # done before an interruption
                data.append(_load_npz(data_path))
                agent = CommandAgent.load(model_path)
                fit_s = float(data[-1]["fit_s"])
            else:
                agreement = float(rows[-1]["agreement"] or 0.0) if rows else 0.0
                components = agent.total_components if agent is not None else 0
                done = it * cfg.imitation_episodes

                def report(e: int, done: int = done, agree: float = agreement, comps: int = components) -> None:
                    if progress is not None:
                        progress(done + e, total, agree, comps)

                if drive_workers <= 1:
                    env = env or make_env(cfg)
                part = drive_iteration(cfg, it, env, agent, it_dir / f"model_{it - 1}.npz" if it else None, make_env,
                                       drive_workers, report)
                data.append(part)
                t_fit = time.perf_counter()
                agent = fit_mixture(*(np.concatenate([d[k] for d in data]) for k in ("states", "commands", "labels")),
                                    cfg=cfg, order_seed=[cfg.seed, it, 44, *_seed_tail(cfg)])
                fit_s = time.perf_counter() - t_fit
                save_npz(data_path, {**part, "fit_s": np.array(fit_s)})
                agent.save(model_path)  # data first: a model file means its data is there
            rows.append(_iteration_row(it, data[-1], sum(len(d["labels"]) for d in data), agent, fit_s))
            _write_log(run_dir / "iterations.csv", rows)
    finally:
        if env is not None:
            env.close()
    assert agent is not None
    agent.save(run_dir / "model.npz")
    decisions = sum(len(d["labels"]) for d in data)
    wall = sum(r["wall_s"] for r in rows)
    last = rows[-1]
    summary: dict[str, Any] = {
        "seed": cfg.seed, "learning": "imitation", "steps": decisions, "episodes": total,
        "episodes_reaching_goal": sum(r["goals"] for r in rows), "components": agent.total_components,
        "components_per_branch": dict(zip(BRANCH_NAMES, agent.components_per_branch, strict=True)),
        "wall_s": wall, "steps_per_s": decisions / max(wall, 1e-9),
        "imitation": {"iterations": cfg.imitation_iterations, "episodes_per_iteration": cfg.imitation_episodes,
                      "last_agreement": last["agreement"] if last["agreement"] != "" else None,
                      "last_goals": last["goals"], "last_crashes": last["crashes"]},
    }
    return {**provenance(cfg.to_dict()), "summary": summary}
