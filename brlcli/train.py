"""Online Bayesian RL training (paper Sec. III / IV, Algorithm 1): one run per seed, with checkpoints, logs, resume.

The loop (`train_run`, `run_episode`) drives one `Learner` (the paper's agent, or the command-conditioned one for
navigation) through episodes of the training environment; everything a method adds around Algorithm 1 is a `Hook`
called after each learning step and at each episode's end: the trap restart (`TrapRestart`), the per-branch trap
restart (`BranchRestart`), the learning curve (`LearningCurve`) and the progress reports (`ProgressReport`).

Layout of a run directory:
    config.json      resolved configuration + brl version + git commit
    log.csv          one row per learning step (reward and its terms, TD error, components, schedules, ...; LOG_COLUMNS)
    model.npz        the trained agent (written at the end)
    summary.json     totals and the greedy evaluation on the task's validation routes
    checkpoint/      agent + generator state at the last finished episode (resume restarts from there)
    learning_curve.csv  greedy evaluations every `curve_every` steps (when set)
A committee run (`committee` > 1) holds its members' runs in member_<k>/ and the committee's model.npz and summary.
An imitation run (`learning = "imitation"`, `brlcli.imitation`) has iterations.csv and iterations/ instead of log.csv
and checkpoint/.
"""

from __future__ import annotations

import csv
import itertools
import json
import time
from collections.abc import Callable, Sequence
from dataclasses import asdict, dataclass, field, fields
from pathlib import Path
from typing import Any, Protocol

import numpy as np

from brlcli.agent import BayesianAgent, LearnStep
from brlcli.agent.command import CommandAgent
from brlcli.errors import BrlInputError
from brlcli.executor import Executor, report, run_tasks
from brlcli.features import STATE_DIM, STATE_OPTIONS
from brlcli.outdir import refuse_existing
from brlcli.provenance import atomic_write_bytes, atomic_write_json, provenance
from brlcli.segnet import labeler_for
from brlcli.sim.camera import CameraConfig
from brlcli.sim.gym_env import ACTION_SET_NAMES, ACTION_SETS, FRAMES_PER_DECISION, DrivingEnv
from brlcli.sim.roadnet import BRANCH_NAMES, Command
from brlcli.trainconfig import TrainConfig

LOG_COLUMNS = (
    "step", "episode", "decision", "action", "reward", "r_collision", "r_offroad", "r_otherlane", "r_speed",
    "r_road_view", "td_error", "component", "created", "weight", "weight_case", "components", "alpha", "tau",
    "rho", "forward_speed_kmh", "intersection_offroad", "intersection_otherlane", "x", "y", "attempt", "command",
    "r_progress", "r_wrong_turn",
)
"""Columns of log.csv, one row per learning step (`log_row`)."""
TRAFFIC_LOG_COLUMNS = ("r_hazard", "hazard_gap_m", "crashed", "traffic")  # r_hazard includes r_stand
"""Columns log.csv adds for a run with traffic or the hazard reward (outside the paper)."""


def log_columns(cfg: TrainConfig) -> tuple[str, ...]:
    """The log.csv columns of a run: LOG_COLUMNS, and TRAFFIC_LOG_COLUMNS with traffic or the hazard reward."""
    return LOG_COLUMNS + (TRAFFIC_LOG_COLUMNS if cfg.traffic or cfg.r_hazard or cfg.r_stand else ())
CHECKPOINT_VERSION = 1
RESTART_CHECKS = (1 / 3, 2 / 3)
"""Fractions of an attempt's learning steps after which the trap test of `TrainConfig.restart_below` runs (at the
end of the episode that crosses them): steps 1,500 and 3,000 of 4,500."""
RESTART_WINDOW = 1 / 6
"""Fraction of the learning steps the trap test looks back over (750 of 4,500)."""
PROGRESS_EVERY = 25
"""Learning steps between two progress reports."""


# ----------------------------------------------------------------------------------------------------------
# What the loop drives


class Learner(Protocol):
    """What the training loop drives: a Bayesian agent that acts and learns under the route command of each step."""

    def act(self, state: np.ndarray, command: int, rng: np.random.Generator) -> int:
        """The behaviour policy's action (eq. 11) for a state under a command."""

    def learn(self, state: np.ndarray, action: int, reward: float, next_state: np.ndarray, command: int,
              next_command: int) -> LearnStep:
        """One step of Algorithm 1 on (s_t, a_t, r_t, s_{t+1}), with the commands at t and t+1."""

    def branch(self, command: int) -> BayesianAgent:
        """The Bayesian agent that acts and learns under a command."""

    @property
    def total_components(self) -> int:
        """Mixture components of the whole learner."""

    def save(self, path: Path) -> None:
        """Write the learner's model file."""


class LaneKeepingLearner:
    """The paper's agent in the loop's protocol: lane keeping has no route commands, so they are ignored."""

    def __init__(self, agent: BayesianAgent) -> None:
        self.agent = agent

    def act(self, state: np.ndarray, command: int, rng: np.random.Generator) -> int:
        """The agent's behaviour action (eq. 11)."""
        return self.agent.act(state, rng)

    def learn(self, state: np.ndarray, action: int, reward: float, next_state: np.ndarray, command: int,
              next_command: int) -> LearnStep:
        """Algorithm 1's step (`BayesianAgent.learn`)."""
        return self.agent.learn(state, action, reward, next_state)

    def branch(self, command: int) -> BayesianAgent:
        """The agent itself, whatever the command."""
        return self.agent

    @property
    def total_components(self) -> int:
        """The agent's mixture components."""
        return self.agent.n_components

    def save(self, path: Path) -> None:
        """Write the agent's model file (`BayesianAgent.save`)."""
        self.agent.save(path)


def _state_and_action_sizes(cfg: TrainConfig) -> tuple[int, int]:
    """The run's state size (the paper's 30 and its state option's numbers) and its number of actions."""
    return STATE_DIM + STATE_OPTIONS[cfg.state], len(ACTION_SETS[cfg.actions])


def new_learner(cfg: TrainConfig) -> Learner:
    """A fresh learner for this run: the paper's agent, the command-conditioned one for navigation, or a brake gate
    over its frozen driver."""
    dim, n_actions = _state_and_action_sizes(cfg)
    if cfg.driver_model is not None:
        return _new_gate(cfg, dim, n_actions)
    if cfg.task == "navigation":
        return CommandAgent(state_dim=dim, n_actions=n_actions, params=cfg.agent_params())
    return LaneKeepingLearner(BayesianAgent(state_dim=dim, n_actions=n_actions, params=cfg.agent_params()))


def _new_gate(cfg: TrainConfig, dim: int, n_actions: int) -> Learner:
    """A fresh brake gate over the run's driver (BrlInputError for a driver of another state size or action set)."""
    from brlcli.agent.gate import BrakeGatedAgent

    return BrakeGatedAgent(_gate_driver(cfg, dim, n_actions), params=cfg.agent_params())  # type: ignore[return-value]


def _gate_driver(cfg: TrainConfig, dim: int, n_actions: int) -> Any:
    """The run's frozen driver (`driver_model`), checked against the run's state size and action set."""
    from brlcli.agent.command import CommandAgent, CommitteeAgent, load_navigation_agent

    driver = load_navigation_agent(cfg.driver_model)  # type: ignore[arg-type]
    if not isinstance(driver, CommandAgent | CommitteeAgent):
        raise BrlInputError(f"driver_model {cfg.driver_model} is already brake-gated; give its driver")
    if (driver.state_dim, driver.n_actions) != (dim, n_actions):
        raise BrlInputError(f"driver_model {cfg.driver_model} has state size {driver.state_dim} and {driver.n_actions} "
                            f"actions, but state '{cfg.state}' and actions '{cfg.actions}' need {dim} and {n_actions}")
    return driver


def _check_driver(cfg: TrainConfig) -> None:
    """A `driver_model` that cannot work under the run's state and actions fails here, before anything is written."""
    if cfg.driver_model is not None:
        _gate_driver(cfg, *_state_and_action_sizes(cfg))


def load_learner(cfg: TrainConfig, path: Path) -> Learner:
    """The learner of a checkpoint or model file of this run's task."""
    if cfg.driver_model is not None:
        from brlcli.agent.gate import BrakeGatedAgent

        return BrakeGatedAgent.load(path)  # type: ignore[return-value]
    if cfg.task == "navigation":
        return CommandAgent.load(path)
    return LaneKeepingLearner(BayesianAgent.load(path))


def deployable(agent: Learner) -> Any:
    """The model a learner ships and benches (the paper's agent itself for lane keeping)."""
    return agent.agent if isinstance(agent, LaneKeepingLearner) else agent


# ----------------------------------------------------------------------------------------------------------
# The run in progress


@dataclass
class RunStats:
    """A run's running statistics (saved in its checkpoint): totals, and the state of the trap tests."""

    episodes: int = 0
    goals: int = 0
    reward_sum: float = 0.0
    wall_s: float = 0.0
    attempt: int = 0  # the trap restart's attempt, its first learning step, the checks it passed
    attempt_start: int = 0
    checks_done: int = 0
    window: list[float] = field(default_factory=list)  # rewards of the trap test's window
    window_offroad: list[int] = field(default_factory=list)  # whether the car was partly off the road there
    restarts: list[dict[str, Any]] = field(default_factory=list)
    branch_window: list[list[float]] = field(default_factory=list)  # [branch, reward] of the per-branch test
    branch_checks_done: int = 0
    branch_restarts: list[dict[str, Any]] = field(default_factory=list)

    def to_dict(self) -> dict[str, Any]:
        """JSON-ready form."""
        return asdict(self)

    @classmethod
    def from_dict(cls, d: dict[str, Any]) -> RunStats:
        """Inverse of `to_dict` (keys of retired knobs in an older brl's checkpoint are ignored)."""
        known = {f.name for f in fields(cls)}
        return cls(**{k: v for k, v in d.items() if k in known})


@dataclass
class Run:
    """A training run in progress: the learner, its generator, the counters and the statistics."""

    cfg: TrainConfig
    agent: Learner
    rng: np.random.Generator
    step: int = 0
    episode: int = 0
    stats: RunStats = field(default_factory=RunStats)
    command: int = int(Command.LANE_FOLLOW)  # the command of the last decision acted on

    @classmethod
    def start(cls, cfg: TrainConfig) -> Run:
        """A fresh run: a new learner, the run's generator from (seed[, member])."""
        return cls(cfg, new_learner(cfg), np.random.default_rng([cfg.seed, 1, *([cfg.member] if cfg.member else [])]))

    @property
    def done(self) -> bool:
        """Whether the current attempt has taken its learning steps."""
        return self.step - self.stats.attempt_start >= self.cfg.steps


class Hook:
    """Something a method adds around Algorithm 1, called by the loop (the SB3 callback's place)."""

    def on_step(self, run: Run, reward: float, learned: LearnStep, command: int, info: dict[str, Any]) -> None:
        """After each learning step (`run.step` counts it)."""

    def on_episode_end(self, run: Run) -> None:
        """After each episode (before the checkpoint)."""

    def close(self) -> None:
        """At the end of the run."""


# ----------------------------------------------------------------------------------------------------------
# Algorithm 1


def episode_seed(seed: int, episode: int, member: int = 0) -> int:
    """The environment seed of a training episode (route, start pose), a function of (seed, episode[, member])."""
    return int(np.random.default_rng([seed, episode, 7, *([member] if member else [])]).integers(2**31))


def run_episode(env: DrivingEnv, run: Run, hooks: Sequence[Hook]) -> tuple[list[dict[str, Any]], bool]:
    """One training episode: act (eq. 11), step, learn from (s_t, a_t, r_t, s_{t+1}) until the episode or the
    attempt ends; returns the episode's log rows and whether it reached its goal."""
    obs, info = env.reset(seed=episode_seed(run.cfg.seed, run.episode, run.cfg.member))
    state, command = obs.astype(np.float64), info["command"]
    rows: list[dict[str, Any]] = []
    for decision in itertools.count():
        if run.done:
            return rows, False
        run.command = command
        action = run.agent.act(state, command, run.rng)
        obs, reward, terminated, truncated, info = env.step(action)
        next_state = obs.astype(np.float64)
        if decision > 0 and not info.get("overridden"):  # nor where a privileged brake took the car's control
            learned = run.agent.learn(state, action, reward, next_state, command, info["command"])
            run.step += 1
            run.stats.reward_sum += reward
            rows.append(log_row(run, decision, action, reward, learned, info, command))
            for hook in hooks:
                hook.on_step(run, reward, learned, command, info)
        state, command = next_state, info["command"]
        if terminated or truncated:
            return rows, terminated
    raise AssertionError("unreachable")


def train_run(cfg: TrainConfig, run_dir: Path, resume: bool = False,
              progress: Callable[[Progress], None] | None = None, drive_workers: int = 1) -> dict[str, Any]:
    """Train one agent; returns the summary record. Resumable from the last finished episode. An imitation run
    drives each iteration on `drive_workers` local processes (the same model whatever their number)."""
    run_dir = Path(run_dir)
    check_run_dir(cfg, run_dir, resume)
    _check_driver(cfg)
    run_dir.mkdir(parents=True, exist_ok=True)
    if not (run_dir / "config.json").exists():
        atomic_write_json(run_dir / "config.json", provenance(cfg.to_dict(), kind="train-run"))
    if (run_dir / "summary.json").exists():
        return json.loads((run_dir / "summary.json").read_text())
    if cfg.trains_driver_then_gate:
        return _train_gated(cfg, run_dir, progress)
    if cfg.committee > 1:
        return _train_committee(cfg, run_dir, resume, progress)
    if cfg.learning == "imitation":
        return _train_imitation(cfg, run_dir, progress, drive_workers)
    env = make_env(cfg)
    checkpoint = Checkpoint(run_dir)
    run = checkpoint.load(cfg) if resume else None
    log = TrainingLog(run_dir / "log.csv", keep_rows=None if run is None else run.step, columns=log_columns(cfg))
    run = run or Run.start(cfg)
    curve = LearningCurve(run_dir, cfg, env.labeler, run.step) if cfg.curve_every else None
    reporter = ProgressReport(progress) if progress else None
    hooks = [h for h in (TrapRestart(cfg) if cfg.restart_below is not None else None,
                         BranchRestart(cfg) if cfg.branch_restart_below is not None and cfg.driver_model is None
                         else None,
                         curve, reporter) if h is not None]
    t0 = time.perf_counter() - run.stats.wall_s
    while not run.done:
        rows, reached = run_episode(env, run, hooks)
        log.append(rows)
        run.episode += 1
        run.stats.episodes = run.episode
        run.stats.goals += int(reached)
        for hook in hooks:
            hook.on_episode_end(run)
        run.stats.wall_s = time.perf_counter() - t0
        checkpoint.save(run)
    wall = time.perf_counter() - t0 - (curve.eval_s if curve is not None else 0.0)  # learning time only
    run.agent.save(run_dir / "model.npz")
    env.close()
    for hook in hooks:
        hook.close()
    record = {**provenance(cfg.to_dict()), "summary": _summary(run, wall)}
    atomic_write_json(run_dir / "summary.json", record)
    if reporter:
        reporter.finish(run)
    return record


def _train_imitation(cfg: TrainConfig, run_dir: Path, progress: Callable[[Progress], None] | None,
                     drive_workers: int = 1) -> dict[str, Any]:
    """Train (or resume) a navigation model by imitation (`brlcli.imitation`), evaluate it, write summary.json."""
    from brlcli.imitation import train_imitation

    def report(done: int, total: int, agreement: float, components: int, finished: bool = False) -> None:
        if progress is not None:  # the bar's reward column shows the driver's agreement with the expert
            progress(Progress(cfg.seed, done, total, done, agreement, 0.0, components, finished, cfg.member))

    record = train_imitation(cfg, run_dir, make_env, report, drive_workers)
    summary = record["summary"]
    if cfg.evaluate:
        summary["eval"] = evaluate_greedy(CommandAgent.load(run_dir / "model.npz"), cfg)
    atomic_write_json(run_dir / "summary.json", record)
    report(summary["episodes"], summary["episodes"], summary["imitation"]["last_agreement"] or 0.0,
           summary["components"], finished=True)
    return record


def _summary(run: Run, wall_s: float) -> dict[str, Any]:
    """A finished run's summary.json: totals, schedules, restarts and the greedy evaluation."""
    cfg, stats, agent = run.cfg, run.stats, run.agent
    last = agent.branch(run.command)  # the branch that acted last
    summary: dict[str, Any] = {
        "seed": cfg.seed, "steps": run.step, "episodes": stats.episodes, "episodes_reaching_goal": stats.goals,
        "mean_reward": stats.reward_sum / max(run.step, 1), "components": agent.total_components,
        "alpha": last.alpha, "tau": last.tau, "rho": last.rho, "wall_s": wall_s, "steps_per_s": run.step / wall_s,
    }
    if cfg.restart_below is not None:
        summary.update(attempts=stats.attempt + 1, restarts=stats.restarts,
                       final_attempt_steps=run.step - stats.attempt_start)
    if cfg.branch_restart_below is not None:
        summary["branch_restarts"] = stats.branch_restarts
    if cfg.task == "navigation" and cfg.driver_model is None:
        summary["components_per_branch"] = dict(zip(BRANCH_NAMES, agent.components_per_branch, strict=True))
    if cfg.evaluate:
        summary["eval"] = evaluate_greedy(deployable(agent), cfg)
    return summary


# ----------------------------------------------------------------------------------------------------------
# Hooks


def _window_length(cfg: TrainConfig) -> int:
    return max(1, round(RESTART_WINDOW * cfg.steps))


class TrapRestart(Hook):
    """The trap restart (outside the paper; `restart_below`): at RESTART_CHECKS of an attempt's steps, an attempt
    whose mean reward per step over the last RESTART_WINDOW of them is below `restart_below` restarts learning from a
    fresh agent (the same generator, the next routes); at most `max_restarts`, none past the run's `steps`."""

    def __init__(self, cfg: TrainConfig) -> None:
        self.cfg = cfg

    def on_step(self, run: Run, reward: float, learned: LearnStep, command: int, info: dict[str, Any]) -> None:
        """Keep the window's rewards (and whether the car was partly off the road)."""
        stats = run.stats
        stats.window.append(reward)
        stats.window_offroad.append(int(info["measurements"]["intersection_offroad"] > 0.0))
        if len(stats.window) > _window_length(self.cfg):
            del stats.window[0], stats.window_offroad[0]

    def trapped(self, run: Run) -> bool:
        """The trap test at an episode's end: True when this attempt must restart (and records a passed check)."""
        cfg, stats = self.cfg, run.stats
        if stats.attempt >= cfg.max_restarts or stats.checks_done >= len(RESTART_CHECKS):
            return False
        if run.step - stats.attempt_start < RESTART_CHECKS[stats.checks_done] * cfg.steps:
            return False
        if run.step > cfg.steps:  # a restart here would take the run past twice its steps: keep the attempt
            return False
        stats.checks_done += 1
        return bool(np.mean(stats.window) < cfg.restart_below)

    def on_episode_end(self, run: Run) -> None:
        """Restart from a fresh agent when trapped."""
        if not self.trapped(run):
            return
        stats = run.stats
        stats.restarts.append({"step": run.step, "attempt_steps": run.step - stats.attempt_start,
                               "mean_reward": float(np.mean(stats.window)),
                               "offroad_share": float(np.mean(stats.window_offroad))})
        stats.attempt, stats.attempt_start, stats.checks_done = stats.attempt + 1, run.step, 0
        stats.window, stats.window_offroad = [], []
        run.agent = new_learner(self.cfg)


class BranchRestart(Hook):
    """The per-branch trap restart (navigation, outside the paper; `branch_restart_below`): at RESTART_CHECKS of the
    run's steps, a branch whose mean reward per step over its steps among the last RESTART_WINDOW of the run's steps
    is below its threshold restarts from a fresh agent."""

    def __init__(self, cfg: TrainConfig) -> None:
        self.cfg = cfg
        self.thresholds = list(cfg.branch_restart_below or [])

    def on_step(self, run: Run, reward: float, learned: LearnStep, command: int, info: dict[str, Any]) -> None:
        """Keep [branch, reward] of the window."""
        window = run.stats.branch_window
        window.append([CommandAgent.branch_of(command), reward])
        if len(window) > _window_length(self.cfg):
            del window[0]

    def trapped(self, run: Run) -> list[int]:
        """The branches to restart at this episode's end (and records a passed check)."""
        stats = run.stats
        done = stats.branch_checks_done
        if done >= len(RESTART_CHECKS) or run.step < RESTART_CHECKS[done] * self.cfg.steps:
            return []
        stats.branch_checks_done = done + 1
        window = np.asarray(stats.branch_window, dtype=np.float64).reshape(-1, 2)
        return [k for k, threshold in enumerate(self.thresholds)
                if (rewards := window[window[:, 0] == k, 1]).size and rewards.mean() < threshold]

    def on_episode_end(self, run: Run) -> None:
        """Restart the trapped branches."""
        for k in self.trapped(run):
            window = np.asarray(run.stats.branch_window).reshape(-1, 2)
            run.stats.branch_restarts.append({"step": run.step, "branch": k,
                                              "mean_reward": float(window[window[:, 0] == k, 1].mean())})
            run.agent.restart_branch(k)  # type: ignore[attr-defined]


class LearningCurve(Hook):
    """Greedy evaluations on the task's evaluation suite every `curve_every` steps (learning_curve.csv; rows past a
    resumed step are redone). Evaluation never touches the training generators."""

    def __init__(self, run_dir: Path, cfg: TrainConfig, labels: Callable[[np.ndarray], np.ndarray] | None,
                 step: int) -> None:
        from brlcli.bench.runner import SuiteEvaluator
        from brlcli.curve import CURVE_FILE, read_curve
        from brlcli.settings import setting_name

        self.path = run_dir / CURVE_FILE
        self.rows = [r for r in read_curve(self.path) if r["env_steps"] <= step] if self.path.exists() else []
        self.cfg = cfg
        self.labeler = labels
        self.setting = setting_name(cfg.input, cfg.input, cfg.variant)
        self.evaluator = SuiteEvaluator("nav_validation" if cfg.task == "navigation" else "paper")
        self.eval_s = 0.0

    def on_step(self, run: Run, reward: float, learned: LearnStep, command: int, info: dict[str, Any]) -> None:
        """Evaluate at every `curve_every`-th step."""
        if run.step % self.cfg.curve_every == 0:
            self.evaluate(run.agent, run.step)

    def evaluate(self, agent: Learner, step: int) -> dict[str, Any]:
        """Evaluate the agent greedily at `step`, append the row to the curve file and return it."""
        from brlcli.curve import write_curve

        t0 = time.perf_counter()
        policy = greedy_policy(deployable(agent), self.cfg.task, self.setting, self.labeler, self.cfg.camera(),
                               self.cfg.actions, self.cfg.state, self.cfg.decision_frames, self.cfg.stop_rule)
        self.rows.append({"env_steps": step, **self.evaluator.evaluate(policy)})
        write_curve(self.path, self.rows)
        self.eval_s += time.perf_counter() - t0
        return self.rows[-1]

    def close(self) -> None:
        """Release the evaluation's worlds."""
        self.evaluator.close()


@dataclass
class Progress:
    """A progress report from a running training (for bars and logs)."""

    seed: int
    step: int
    steps: int
    episode: int
    mean_reward: float
    td_error: float
    components: int
    done: bool = False
    member: int = 0  # committee member (TrainConfig.member); GATE_MEMBER for a brake gate's run


GATE_MEMBER = -1
"""`Progress.member` of a brake gate's run."""


def _progress_member(cfg: TrainConfig) -> int:
    return GATE_MEMBER if cfg.driver_model is not None else cfg.member


class ProgressReport(Hook):
    """A `Progress` every PROGRESS_EVERY learning steps: mean reward of the last 100 steps, TD error, components."""

    def __init__(self, progress: Callable[[Progress], None]) -> None:
        self.progress = progress
        self.recent: list[float] = []
        self.td_error = 0.0

    def on_step(self, run: Run, reward: float, learned: LearnStep, command: int, info: dict[str, Any]) -> None:
        """Report every PROGRESS_EVERY steps."""
        self.recent = [*self.recent, reward][-100:]
        self.td_error = learned.td_error
        if run.step % PROGRESS_EVERY == 0:
            self.progress(Progress(run.cfg.seed, run.step, run.stats.attempt_start + run.cfg.steps, run.episode,
                                   float(np.mean(self.recent)), learned.td_error, learned.n_components,
                                   member=_progress_member(run.cfg)))

    def finish(self, run: Run) -> None:
        """The last report, when the run's summary is written."""
        self.progress(Progress(run.cfg.seed, run.step, run.step, run.episode,
                               float(np.mean(self.recent)) if self.recent else 0.0, self.td_error,
                               run.agent.branch(run.command).n_components, done=True,
                               member=_progress_member(run.cfg)))


# ----------------------------------------------------------------------------------------------------------
# Files of a run


def log_row(run: Run, decision: int, action: int, reward: float, learned: LearnStep, info: dict[str, Any],
            command: int) -> dict[str, Any]:
    """One learning step's log.csv row, by column name (LOG_COLUMNS)."""
    terms, m = info["reward_terms"], info["measurements"]
    return {"step": run.step, "episode": run.episode, "decision": decision,
            "action": ACTION_SET_NAMES[run.cfg.env_actions][action],
            "reward": reward, "r_collision": terms["collision"], "r_offroad": terms["offroad"],
            "r_otherlane": terms["otherlane"], "r_speed": terms["speed"], "r_road_view": terms["road_view"],
            "td_error": learned.td_error, "component": learned.component, "created": int(learned.created),
            "weight": learned.weight, "weight_case": learned.weight_case, "components": learned.n_components,
            "alpha": learned.alpha, "tau": learned.tau, "rho": learned.rho,
            "forward_speed_kmh": m["forward_speed_kmh"], "intersection_offroad": m["intersection_offroad"],
            "intersection_otherlane": m["intersection_otherlane"], "x": m["x"], "y": m["y"],
            "attempt": run.stats.attempt, "command": command, "r_progress": terms.get("progress", 0.0),
            "r_wrong_turn": terms.get("wrong_turn", 0.0),
            "r_hazard": terms.get("hazard", 0.0) + terms.get("stand", 0.0),
            "hazard_gap_m": min(float(info.get("hazard_gap_m", np.inf)), 1e3),
            "crashed": int(info.get("crashed", False)), "traffic": info.get("traffic", "")}


def _format(v: Any) -> str:
    return repr(float(v)) if isinstance(v, float | np.floating) else str(v)


class TrainingLog:
    """log.csv: the header, then an episode's rows at a time (flushed); a resumed run keeps its first rows."""

    def __init__(self, path: Path, keep_rows: int | None, columns: tuple[str, ...] = LOG_COLUMNS) -> None:
        self.columns = columns
        self.path = path
        if keep_rows is None:
            atomic_write_bytes(path, (",".join(columns) + "\n").encode())
        elif path.exists():  # drop the rows of an unfinished episode
            lines = path.read_bytes().split(b"\n")
            atomic_write_bytes(path, b"".join(line + b"\n" for line in lines[: keep_rows + 1]))

    def append(self, rows: Sequence[dict[str, Any]]) -> None:
        """Append rows, each value under its column name."""
        with open(self.path, "a", newline="") as fh:
            csv.writer(fh, lineterminator="\n").writerows([_format(row[c]) for c in self.columns] for row in rows)


class Checkpoint:
    """Agent + generator state at an episode boundary, written atomically."""

    def __init__(self, run_dir: Path) -> None:
        self.dir = run_dir / "checkpoint"

    def save(self, run: Run) -> None:
        """Write the learner, then the state that names the step, episode, generator and statistics."""
        self.dir.mkdir(parents=True, exist_ok=True)
        run.agent.save(self.dir / "agent.npz")
        atomic_write_json(self.dir / "state.json", {"version": CHECKPOINT_VERSION, "step": run.step,
                                                   "episode": run.episode, "log_rows": run.step,
                                                   "rng": run.rng.bit_generator.state, "stats": run.stats.to_dict()})

    def load(self, cfg: TrainConfig) -> Run | None:
        """The run at its last checkpoint (None without one)."""
        state_path = self.dir / "state.json"
        if not state_path.exists():
            return None
        try:
            state = json.loads(state_path.read_text())
        except json.JSONDecodeError:
            raise BrlInputError(f"checkpoint {state_path} is corrupt; delete the run directory to start over") from None
        if state.get("version") != CHECKPOINT_VERSION:
            raise BrlInputError(f"checkpoint {state_path} has version {state.get('version')}, this brl reads "
                                f"{CHECKPOINT_VERSION}")
        rng = np.random.default_rng()
        rng.bit_generator.state = state["rng"]
        return Run(cfg, load_learner(cfg, self.dir / "agent.npz"), rng, state["step"], state["episode"],
                   RunStats.from_dict(state["stats"]))


def check_run_dir(cfg: TrainConfig, run_dir: Path, resume: bool) -> None:
    """Refuse, before anything is written, to overwrite a run without `resume`, or to resume one made with another
    configuration."""
    path = Path(run_dir) / "config.json"
    if not path.exists():
        return
    refuse_existing(run_dir, "a training run", resume)
    try:
        saved = json.loads(path.read_text())["config"]
    except (OSError, ValueError, KeyError, TypeError):
        raise BrlInputError(f"{path} is not a brl training configuration") from None
    refuse_existing(run_dir, "a training run", resume, TrainConfig.from_saved(saved, str(path)) == cfg)


# ----------------------------------------------------------------------------------------------------------
# Environment, evaluation, committees, model sets


def labeler(cfg: TrainConfig) -> Callable[[np.ndarray], np.ndarray] | None:
    """The run's labeler: None for ground-truth labels, the segmentation net for estimated input."""
    return labeler_for(cfg.input, cfg.segnet, "--input")


def make_env(cfg: TrainConfig) -> DrivingEnv:
    """The run's training environment: its town, weather, routes, reward, state camera and episode rules."""
    nav = cfg.task == "navigation"
    return DrivingEnv(town=cfg.town, weather=cfg.weather, routes="navigation" if nav else "training",
                      kinds=tuple(cfg.route_kinds or ()), reward=cfg.reward_params(), labeler=labeler(cfg),
                      camera=cfg.camera(), offroad_end=cfg.offroad_end, start_offset_m=cfg.start_offset_m,
                      start_yaw_deg=cfg.start_yaw_deg, otherlane_end=cfg.otherlane_end,
                      route_reward=cfg.route_reward(), junction_weight=cfg.junction_weight if nav else None,
                      junction_approaches_m=tuple(cfg.junction_approaches_m) if nav else None,
                      actions=cfg.env_actions, traffic=tuple(cfg.traffic), hazard=cfg.hazard_reward(), state=cfg.state,
                      r_stand=cfg.r_stand, road_user_contact=not cfg.ghost_traffic,
                      privileged_brake_m=cfg.privileged_brake_m, decision_frames=cfg.decision_frames,
                      stop_rule=cfg.stop_rule)


def greedy_policy(model: Any, task: str, setting: str, labels: Callable[[np.ndarray], np.ndarray] | None,
                  camera: CameraConfig, actions: str = "paper", state: str = "paper",
                  decision_frames: int = FRAMES_PER_DECISION, stop_rule: str = "any") -> Any:
    """The bench policy of a trained model, acting greedily (never with the training generator), with the stop
    primitive where `stop_rule` allows it."""
    from brlcli.policy import StatePolicy, greedy_brl, greedy_command_brl, with_stop_rule

    if task == "navigation":
        model = with_stop_rule(model, actions, stop_rule)
        return StatePolicy("brl", setting, greedy_command_brl(model), labels, camera, uses_command=True,
                           actions=actions, state=state, decision_frames=decision_frames)
    return StatePolicy("brl", setting, greedy_brl(model), labels, camera, actions=actions, state=state,
                       decision_frames=decision_frames)


EVALUATION_SUITES = {"lane-keeping": "validation_starts", "navigation": "nav_validation"}
"""The suite a task's end-of-run greedy evaluation drives (chosen on, never reported): lane keeping's validation
routes of both towns from six start poses, navigation's planner routes."""


def evaluate_greedy(model: Any, cfg: TrainConfig) -> dict[str, Any]:
    """Greedy success, collision-free and Either shares and the Score on the task's evaluation suite; lane keeping's
    in the run's own weather (ground-truth labels do not depend on it; `brl bench --suite validation_starts` drives
    all three)."""
    from brlcli.bench.runner import SuiteEvaluator
    from brlcli.settings import setting_name

    suite = "nav_validation_traffic" if cfg.traffic and cfg.task == "navigation" else EVALUATION_SUITES[cfg.task]
    weathers = str(cfg.weather) if suite == "validation_starts" else None
    evaluator = SuiteEvaluator(suite, weathers=weathers)
    try:
        policy = greedy_policy(model, cfg.task, setting_name(cfg.input, cfg.input, cfg.variant), labeler(cfg),
                               cfg.camera(), cfg.env_actions, cfg.state, cfg.decision_frames, cfg.stop_rule)
        figures = evaluator.evaluate(policy)
    finally:
        evaluator.close()
    return {"suite": suite, "success_rate": figures["success"], "collision_free_rate": figures["collision_free"],
            "either_share": figures["either"], "score": figures["score"], "episodes": figures["episodes"]}


def _train_committee(cfg: TrainConfig, run_dir: Path, resume: bool,
                     progress: Callable[[Progress], None] | None) -> dict[str, Any]:
    """Train (or resume, or read) each member's run in run_dir/member_<k>, then write the committee's model.npz and
    summary.json (its evaluation figures are the committee's, voting)."""
    from brlcli.agent.command import CommitteeAgent
    from brlcli.agent.committee import LaneKeepingCommittee

    members = []
    for k in range(cfg.committee):
        sub = run_dir / f"member_{k}"
        members.append(train_run(cfg.member_config(k), sub, resume=resume or (sub / "summary.json").exists(),
                                 progress=progress)["summary"])
    paths = [run_dir / f"member_{k}" / "model.npz" for k in range(cfg.committee)]
    agent: Any = (CommitteeAgent([CommandAgent.load(p) for p in paths]) if cfg.task == "navigation"
                  else LaneKeepingCommittee([BayesianAgent.load(p) for p in paths]))
    agent.save(run_dir / "model.npz")
    wall = sum(m["wall_s"] for m in members)
    summary: dict[str, Any] = {
        "seed": cfg.seed, "committee": cfg.committee, "vote": "majority",
        "steps": sum(m["steps"] for m in members), "episodes": sum(m["episodes"] for m in members),
        "episodes_reaching_goal": sum(m["episodes_reaching_goal"] for m in members),
        "mean_reward": float(np.mean([m["mean_reward"] for m in members])),
        "components": agent.total_components, "wall_s": wall, "steps_per_s": sum(m["steps"] for m in members) / wall,
        "members": [{"member": k, **{key: m[key] for key in ("steps", "mean_reward", "wall_s") if key in m},
                     "branch_restarts": len(m.get("branch_restarts", [])), "restarts": m.get("restarts", []),
                     **({"eval_success_rate": m["eval"]["success_rate"], "eval_score": m["eval"]["score"]}
                        if "eval" in m else {})}
                    for k, m in enumerate(members)],
    }
    if cfg.evaluate:
        summary["eval"] = evaluate_greedy(agent, cfg)
    record = {**provenance(cfg.to_dict()), "summary": summary}
    atomic_write_json(run_dir / "summary.json", record)
    return record


def _train_gated(cfg: TrainConfig, run_dir: Path, progress: Callable[[Progress], None] | None) -> dict[str, Any]:
    """Train (or resume, or read) the driver in run_dir/driver (on empty roads, committee included), then the brake
    gate over it in run_dir/gate (in traffic, `brake_gate_steps` steps); the seed's model.npz is the gated model and
    its summary.json holds both parts (the evaluation is the gated model's, on nav_validation_traffic)."""
    driver = train_run(cfg.driver_config(), run_dir / "driver", resume=True, progress=progress)["summary"]
    gate_cfg = cfg.gate_config(str((run_dir / "driver" / "model.npz").resolve()))
    gate = train_run(gate_cfg, run_dir / "gate", resume=True, progress=progress)["summary"]
    atomic_write_bytes(run_dir / "model.npz", (run_dir / "gate" / "model.npz").read_bytes())
    summary: dict[str, Any] = {
        "seed": cfg.seed, "steps": driver["steps"] + gate["steps"], "episodes": driver["episodes"] + gate["episodes"],
        "wall_s": driver["wall_s"] + gate["wall_s"], "components": gate["components"],
        "steps_per_s": (driver["steps"] + gate["steps"]) / max(driver["wall_s"] + gate["wall_s"], 1e-9),
        "driver": {k: driver[k] for k in ("steps", "episodes", "components", "wall_s", "committee", "learning")
                   if k in driver},
        "gate": {k: v for k, v in gate.items() if k != "eval"},
        **({"eval": gate["eval"]} if "eval" in gate else {}),
    }
    record = {**provenance(cfg.to_dict()), "summary": summary}
    atomic_write_json(run_dir / "summary.json", record)
    return record


def parse_seeds(text: str) -> list[int]:
    """'0-8' or '0,3,5' or '4' -> list of seeds."""
    out: list[int] = []
    try:
        for part in text.split(","):
            part = part.strip()
            if "-" in part[1:]:
                a, b = part.split("-", 1) if not part.startswith("-") else (part, "")
                lo, hi = int(a), int(b)
                if hi < lo:
                    raise ValueError
                out.extend(range(lo, hi + 1))
            elif part:
                out.append(int(part))
    except ValueError:
        raise BrlInputError(f"--seeds '{text}' is not a list like 0-8 or 0,2,5") from None
    if not out or any(s < 0 for s in out):
        raise BrlInputError(f"--seeds '{text}' must name non-negative seeds")
    return sorted(set(out))


def _members_config(cfg: TrainConfig) -> TrainConfig:
    """The configuration whose committee members a run trains: its driver's for a brake-gated run."""
    return cfg.driver_config() if cfg.trains_driver_then_gate else cfg


def _members_dir(cfg: TrainConfig, run_dir: Path) -> Path:
    """Where a run's committee members live: run_dir, or run_dir/driver for a brake-gated run."""
    return run_dir / "driver" if cfg.trains_driver_then_gate else run_dir


def run_dir_for(out: Path, seed: int) -> Path:
    """Directory of one seed's run inside a training output directory."""
    return Path(out) / f"seed_{seed}"


def _train_task(item: tuple[TrainConfig, str, bool, int]) -> dict[str, Any]:
    """One run in a worker (local process or Ray task); progress goes to the driver through the executor."""
    cfg, run_dir, resume, drive_workers = item
    return train_run(cfg, Path(run_dir), resume=resume, progress=report, drive_workers=drive_workers)


def train_many(cfg: TrainConfig, seeds: list[int], out: Path, workers: int = 1, resume: bool = False,
               progress: Callable[[Progress], None] | None = None, executor: str | Executor = "local",
               ray_address: str | None = None) -> list[dict[str, Any]]:
    """Train one model per seed, one task each on the executor; results (in seed order) do not depend on it.

    A single imitation run on the local executor (one seed, no committee) runs in this process and drives its
    iterations on all `workers` instead (`brlcli.imitation.drive_iteration`; the same model).

    Every seed's run directory and the inputs are checked before anything is written. Workers write each seed's run
    directory themselves (checkpoints while they train), so on a Ray cluster `out` must be on a filesystem every node
    mounts at the same path; an interrupted set resumes with `resume`.
    """
    out = Path(out)
    cfgs = [cfg.for_seed(s) for s in seeds]
    for c in cfgs:
        check_run_dir(c, run_dir_for(out, c.seed), resume)
    labeler(cfg)  # a bad segmentation net fails here, with one line
    _check_driver(cfg)  # ... and a driver of another state size or action set
    ex = executor if isinstance(executor, Executor) else Executor(executor, workers, ray_address)
    ex.connect()  # a bad executor fails before anything is written
    try:
        out.mkdir(parents=True, exist_ok=True)
        atomic_write_json(out / "run.json", provenance({**cfg.to_dict(), "seeds": seeds, "workers": workers},
                                                      kind="train"))
        if cfg.committee > 1:  # the members first, every (seed, member) one task, then each seed's committee
            members = [(_members_config(c).member_config(k), str(_members_dir(c, run_dir_for(out, c.seed)).resolve()
                                                                  / f"member_{k}"), resume, 1)
                       for c in cfgs for k in range(cfg.committee)]
            for _ in run_tasks(_train_task, members, executor=ex, on_report=progress):
                pass
        drive_workers = ex.workers if ex.kind == "local" and len(cfgs) == 1 else 1  # a lone run gets every worker
        items = [(c, str(run_dir_for(out, c.seed).resolve()), resume, drive_workers) for c in cfgs]
        results: list[dict[str, Any]] = [{} for _ in items]
        for i, result in run_tasks(_train_task, items, executor=ex, on_report=progress):
            results[i] = result
    finally:
        if ex is not executor:
            ex.close()
    return results
