"""Online Bayesian RL training (paper Sec. III / IV): one run per seed, with checkpoints, logs and resume.

Layout of a run directory:
    config.json      resolved configuration + brl version + git commit
    log.csv          one row per learning step (reward and its terms, TD error, components, schedules, ...)
    model.npz        the trained agent (written at the end)
    summary.json     totals and the greedy evaluation on the town's validation routes
    checkpoint/      agent + generator state at the last finished episode (resume restarts from there)
    learning_curve.csv  greedy evaluations every `curve_every` steps (when set)
    model_best.npz   with `keep_best`: the evaluated agent with the best validation figures so far (model.npz is
                     its copy at the end; model_last.npz is the agent at the end of training)
"""

from __future__ import annotations

import csv
import io
import json
import time
from collections.abc import Callable
from dataclasses import asdict, dataclass, field, fields
from pathlib import Path
from typing import Any

import numpy as np

from brlcli.agent import BayesianAgent, BRLParams
from brlcli.errors import BrlInputError
from brlcli.executor import Executor, report, run_tasks
from brlcli.provenance import atomic_write_bytes, atomic_write_json, provenance
from brlcli.reward import RewardParams, RouteRewardParams
from brlcli.segnet import check_input_source, labeler_for
from brlcli.sim.camera import CameraConfig
from brlcli.sim.gym_env import ACTION_NAMES, DrivingEnv
from brlcli.sim.navroutes import TASK_ROUTE_KINDS, TASKS
from brlcli.sim.roadnet import BRANCH_NAMES
from brlcli.sim.weather import get_weather

LOG_COLUMNS = (
    "step", "episode", "decision", "action", "reward", "r_collision", "r_offroad", "r_otherlane", "r_speed",
    "r_road_view", "td_error", "component", "created", "weight", "weight_case", "components", "alpha", "tau",
    "rho", "forward_speed_kmh", "intersection_offroad", "intersection_otherlane", "x", "y", "attempt", "command",
    "r_progress", "r_wrong_turn", "r_heading", "r_lateral",
)
CHECKPOINT_VERSION = 1
RESTART_CHECKS = (1 / 3, 2 / 3)
"""Fractions of an attempt's learning steps after which the trap test of `TrainConfig.restart_below` runs (at the
end of the episode that crosses them): steps 1,500 and 3,000 of 4,500."""
RESTART_WINDOW = 1 / 6
"""Fraction of the learning steps the trap test looks back over (750 of 4,500)."""


VARIANT_PRESETS: dict[str, dict[str, Any]] = {
    "paper": {},
    "reference-code": {},
    "averaging-restart": {"params": {"step_size": "visits"}, "restart_below": -7.0, "max_restarts": 2},
    "action-averaging-restart": {"params": {"step_size": "action-visits"}, "restart_below": -7.0, "max_restarts": 2},
}
"""Named methods: the overrides of `TrainConfig()` each one stands for (a `--set` or `--config` goes on top).
`paper`: eqs. 1-11, Algorithm 1 and Table I as written, with the lane-keeping study's open choices (the TrainConfig
defaults). `reference-code`: the same set-up with the agent of the authors' code (`BRLParams.reference_code()`:
gamma 0.8, rho_rate 3e-5, no alpha decay, Q normalised over actions, m_t by likelihood in the TD error).
`averaging-restart` (outside the paper; docs/lane-keeping-study.md, rounds 8-10): the paper's, with a per-component
step size in eq. 8 (Q[a, m] averages its TD targets: `params.step_size = "visits"`) and a restart of learning from a
fresh agent when training is trapped (mean reward per step below -7 over the last 750 steps at step 1,500 or 3,000
of an attempt; at most two restarts, none after step 4,500 of the run, so at most 9,000 learning steps).
`action-averaging-restart` (outside the paper; rounds 11-12): `averaging-restart` with a per-action step size in eq. 8
(each Q[a, m] averages its own TD targets: `params.step_size = "action-visits"`), which removes the chattering of
equal action values that traps runs; the restart stays as a safety net (it fires on one of eighteen seeds)."""
DEFAULT_VARIANT = "action-averaging-restart"
"""The variant `brl train` uses when none is named: the recommended one, which beats `paper` on the validation routes
by more than the standard error of the difference (docs/lane-keeping-study.md, round 11)."""


TASK_PRESETS: dict[str, dict[str, Any]] = {
    "lane-keeping": {},
    "navigation": {"steps": 27000, "restart_below": None, "params": {"new_q": "nearest"},
                   "branch_restart_below": [-5.0, -9.0, -9.0, -9.0]},
}
"""Overrides a task makes on top of the variant's preset (an option, --config or --set goes on top), chosen on the
nav_validation suite (docs/navigation-study.md): navigation trains four branches, two thirds of the episodes at
junctions, so six times the paper's t_max; without the trap restart, whose reward threshold is the lane-keeping
task's; a new component starts from its nearest component's action values (`new_q = "nearest"`) rather than the
optimistic constant, which otherwise makes an untried junction state look better than a known one; and a trap
restart per branch (follow -5, turns -9), which restarts only a trapped branch."""


DEFAULT_AGENT_OVERRIDES: dict[str, Any] = {"init_scatter": 1e-3}
"""Agent parameters a training run sets beyond `BRLParams()` (none of them is in the paper's Table I): the NIW
prior scatter S0 = 1e-3 I, on the scale of the 30-number state, instead of the reference code's 0.1 I
(docs/lane-keeping-study.md)."""


@dataclass(frozen=True)
class TrainConfig:
    """Everything that determines a training run (saved as `config.json`)."""

    task: str = "lane-keeping"  # or "navigation" (TASKS)
    town: str = "town01"
    weather: int = 1
    input: str = "gt"
    steps: int = 4500
    seed: int = 0
    route_kinds: tuple[str, ...] | None = None  # the task's training routes (TASK_ROUTE_KINDS; None: all of them)
    variant: str = "paper"
    target_speed_kmh: float = 20.0
    evaluate: bool = True
    segnet: str | None = None  # the segmentation net for input "estimated" (None: the shipped one)
    params: dict[str, Any] = field(default_factory=lambda: dict(DEFAULT_AGENT_OVERRIDES))
    curve_every: int = 0  # evaluate greedily on the paper suite every N steps (learning_curve.csv); 0 = never
    camera_pitch_deg: float = -15.0  # pitch of the state camera (deg, - = down); the authors' code uses -30
    road_view: str = "road+line"  # the road-view reward counts "road" or "road+line" (authors' code) state entries
    offroad_end: float | None = 0.5  # end a training episode when the off-road share of the footprint exceeds it
    start_offset_m: float = 0.0  # training episodes start with a lateral offset ~ U(-a, a) m ...
    start_yaw_deg: float = 0.0  # ... and a heading offset ~ U(-b, b) degrees
    otherlane_end: float | None = None  # end a training episode when the share in the opposite lane exceeds it
    restart_below: float | None = None  # outside the paper: restart learning (a fresh agent) when the mean reward
    # per step over the last RESTART_WINDOW of steps is below this at RESTART_CHECKS of an attempt (None: never)
    max_restarts: int = 2  # at most this many restarts, and none that would take a run past 2 x steps; the last
    # attempt always runs to the end
    restart_offroad_above: float | None = None  # outside the paper: ... or when the share of those steps with part of
    # the car off the road is above this (None: the reward test only; needs restart_below)
    command_bootstrap: str = "next-branch"  # navigation only: brlcli.agent.command.BOOTSTRAPS
    branch_restart_below: list[float] | None = None  # navigation only, outside the paper: per-branch trap test
    # (follow, left, right, straight): at RESTART_CHECKS of the steps, a branch whose mean reward per step over its
    # steps among the last RESTART_WINDOW of the run's steps is below its threshold restarts from a fresh agent
    r_progress: float = 5.0  # navigation only: route-following reward terms (RouteRewardParams)
    r_wrong_turn: float = 40.0
    wrong_turn_m: float = 6.0
    r_heading: float = 0.0  # navigation only, outside the paper: cost per rad of heading error against the route
    r_lateral: float = 0.0  # navigation only, outside the paper: cost per m of distance from the route
    junction_weight: float = 2.0  # navigation only: a junction kind's probability relative to a lane-keeping kind
    junction_approaches_m: list[float] = field(default_factory=lambda: [25.0, 60.0])  # navigation only: where the
    # junction routes start before their junction (m)
    straight_as_follow: bool = False  # navigation only, outside the paper: "go straight" acts and learns in the
    # follow branch (three branches learn; the straight one stays empty)
    teams: int = 1  # navigation only, outside the paper: K > 1 trains K command-conditioned agents on shared
    # experience and ships, per command, the branch of the team that earned most on it lately (TeamAgent)
    team_share: float = 0.5  # teams > 1: the probability that a team learns from a step of another team's episode
    no_backward: bool = False  # outside the paper: the agent chooses among forward, right and left only (the first
    # three of the paper's primitives; the privileged oracle never needs backward)
    warm_start_junctions: int = 0  # navigation only, outside the paper: at the end of the episode that reaches
    # this learning step the left, right and straight branches restart from copies of the follow branch
    # (`BayesianAgent.warm_copy`), and later per-branch trap restarts of them copy it too; 0: never
    shared_mixture: bool = False  # navigation only, outside the paper: the commands share one mixture model, each with
    # its own block of action values, alpha and tau (CommandAgent shared_mixture); per-branch restarts forget a block
    committee: int = 1  # navigation only, outside the paper: K > 1 trains K command-conditioned agents apart (members
    # 0..K-1, each the whole run's steps, in member_<k>/) and ships them as one model that acts by majority vote
    member: int = 0  # which committee member a run is: member 0 is the seed's own run, member k > 0 draws its
    # generators from (seed, k) as well
    keep_best: bool = False  # navigation only, outside the paper: model.npz is the curve evaluation (nav_validation)
    # with the highest success (ties: Score, then the later step), not the agent at the end (needs curve_every)

    def __post_init__(self) -> None:
        check_input_source(self.input, "--input")
        if self.task not in TASKS:
            raise BrlInputError(f"unknown task '{self.task}'; choose one of {', '.join(TASKS)}")
        from brlcli.agent.command import BOOTSTRAPS

        if self.command_bootstrap not in BOOTSTRAPS:
            raise BrlInputError(f"command_bootstrap must be next-branch or own-branch, not '{self.command_bootstrap}'")
        if self.branch_restart_below is not None and (self.task != "navigation" or len(self.branch_restart_below)
                                                      != 4):
            raise BrlInputError("branch_restart_below needs --task navigation and four thresholds (follow, left, "
                                "right, straight)")
        if self.keep_best and (self.task != "navigation" or not self.curve_every):
            raise BrlInputError("keep_best needs --task navigation and --curve-every N (it selects on nav_validation; "
                                "lane keeping's curve is the paper suite, which is reported, not chosen on)")
        if isinstance(self.teams, bool) or not isinstance(self.teams, int) or self.teams < 1 \
                or (self.teams > 1 and self.task != "navigation") or not 0.0 < self.team_share <= 1.0:
            raise BrlInputError(f"teams must be an integer >= 1 (more than 1 needs --task navigation) and team_share "
                                f"in (0, 1], got {self.teams!r} and {self.team_share!r}")
        if isinstance(self.warm_start_junctions, bool) or not isinstance(self.warm_start_junctions, int) \
                or self.warm_start_junctions < 0 or (self.warm_start_junctions and self.task != "navigation"):
            raise BrlInputError("warm_start_junctions needs --task navigation and a learning step >= 0 (0: never), "
                                f"got {self.warm_start_junctions!r}")
        if self.shared_mixture and (self.task != "navigation" or self.teams > 1 or self.warm_start_junctions
                                    or self.straight_as_follow):
            raise BrlInputError("shared_mixture needs --task navigation and cannot be combined with teams, "
                                "warm_start_junctions or straight_as_follow")
        for name in ("committee", "member"):
            value = getattr(self, name)
            if isinstance(value, bool) or not isinstance(value, int) or value < (1 if name == "committee" else 0):
                raise BrlInputError(f"{name} must be an integer >= {1 if name == 'committee' else 0}, got {value!r}")
        if self.committee > 1 and (self.task != "navigation" or self.teams > 1 or self.shared_mixture
                                   or self.curve_every or self.keep_best or self.member):
            raise BrlInputError("committee needs --task navigation and cannot be combined with teams, shared_mixture, "
                                "--curve-every or keep_best")
        if not (self.junction_weight > 0 and self.junction_approaches_m
                and all(isinstance(a, int | float) and a > 0 for a in self.junction_approaches_m)):
            raise BrlInputError("junction_weight must be > 0 and junction_approaches_m a non-empty list of distances "
                                "> 0 (m)")
        if self.route_kinds is None:
            object.__setattr__(self, "route_kinds", TASK_ROUTE_KINDS[self.task])
        bad = [k for k in self.route_kinds if k not in TASK_ROUTE_KINDS[self.task]]
        if bad or not self.route_kinds:
            raise BrlInputError(f"route kinds {', '.join(bad) or '(none)'} are not {self.task} routes; choose from "
                                f"{', '.join(TASK_ROUTE_KINDS[self.task])}")
        if self.steps < 1:
            raise BrlInputError("--steps must be at least 1")
        if self.curve_every < 0:
            raise BrlInputError("--curve-every must be >= 0")
        if self.max_restarts < 0:
            raise BrlInputError("max_restarts must be >= 0")
        if self.restart_offroad_above is not None and self.restart_below is None:
            raise BrlInputError("restart_offroad_above needs restart_below (the trap test it extends)")
        if self.restart_offroad_above is not None and not 0.0 <= self.restart_offroad_above <= 1.0:
            raise BrlInputError(f"restart_offroad_above must lie in [0, 1], got {self.restart_offroad_above}")
        try:
            self.reward_params()
            self.route_reward()
            self.camera()
            DrivingEnv.check_episode_rules(self.offroad_end, self.start_offset_m, self.start_yaw_deg,
                                           self.otherlane_end)
        except ValueError as exc:
            raise BrlInputError(f"bad training configuration: {exc}") from None
        if self.variant not in VARIANT_PRESETS:
            raise BrlInputError(f"unknown variant '{self.variant}'; choose one of {', '.join(VARIANT_PRESETS)}")
        get_weather(self.weather)

    def to_dict(self) -> dict[str, Any]:
        """JSON-ready form."""
        d = asdict(self)
        d["route_kinds"] = list(self.route_kinds or ())
        return d

    @classmethod
    def from_dict(cls, d: dict[str, Any]) -> TrainConfig:
        """Inverse of `to_dict`; unknown keys are an error."""
        known = {f.name for f in fields(cls)}
        extra = set(d) - known
        if extra:
            raise BrlInputError(f"unknown training config keys: {', '.join(sorted(extra))}")
        d = dict(d)
        if "road_view" not in d:  # a config written before the study's options: brl 0.1's choices
            d.update(road_view="road", offroad_end=None)
        if d.get("route_kinds") is not None:
            d["route_kinds"] = tuple(d["route_kinds"])
        return cls(**d)

    def member_config(self, member: int) -> TrainConfig:
        """The configuration of committee member `member`'s own run (one agent, that member's generators)."""
        return TrainConfig.from_dict({**self.to_dict(), "committee": 1, "member": member})

    def reward_params(self) -> RewardParams:
        """The reward's parameters for this run."""
        return RewardParams(target_speed_kmh=self.target_speed_kmh, road_view=self.road_view)

    def route_reward(self) -> RouteRewardParams | None:
        """The route-following reward terms of a navigation run (None for lane keeping)."""
        if self.task != "navigation":
            return None
        return RouteRewardParams(self.r_progress, self.r_wrong_turn, self.wrong_turn_m, self.r_heading, self.r_lateral)

    def new_agent(self) -> Any:
        """A fresh agent for this run: the Bayesian agent, or the command-conditioned one for navigation."""
        if self.task == "navigation":
            from brlcli.agent.command import CommandAgent, TeamAgent

            teams = [CommandAgent(state_dim=30, n_actions=self.n_actions, params=self.agent_params(),
                                  bootstrap=self.command_bootstrap, straight_as_follow=self.straight_as_follow,
                                  shared_mixture=self.shared_mixture)
                     for _ in range(self.teams)]
            return TeamAgent(teams) if self.teams > 1 else teams[0]
        return BayesianAgent(state_dim=30, n_actions=self.n_actions, params=self.agent_params())

    @property
    def n_actions(self) -> int:
        """Action primitives the agent chooses among: the first n of `brlcli.sim.gym_env.ACTIONS`."""
        return 3 if self.no_backward else 4

    def camera(self) -> CameraConfig:
        """The state camera of this run (CoRL2017's mount and size, the configured pitch)."""
        return CameraConfig(pitch_deg=self.camera_pitch_deg)

    def agent_params(self) -> BRLParams:
        """The agent's parameters for this run."""
        base = BRLParams.reference_code() if self.variant == "reference-code" else BRLParams()
        return BRLParams.from_dict({**base.to_dict(), **self.params}) if self.params else base


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
    member: int = 0  # committee member (TrainConfig.member)


def _episode_seed(seed: int, episode: int, member: int = 0) -> int:
    return int(np.random.default_rng([seed, episode, 7, *([member] if member else [])]).integers(2**31))


def check_inputs(cfg: TrainConfig) -> None:
    """Fail early, with one line, on inputs a run could only reject after it started."""
    _labeler(cfg)


def _labeler(cfg: TrainConfig) -> Callable[[np.ndarray], np.ndarray] | None:
    return labeler_for(cfg.input, cfg.segnet, "--input")


def _make_env(cfg: TrainConfig) -> DrivingEnv:
    return DrivingEnv(town=cfg.town, weather=cfg.weather,
                      routes="navigation" if cfg.task == "navigation" else "training",
                      kinds=tuple(cfg.route_kinds or ()), reward=cfg.reward_params(), labeler=_labeler(cfg),
                      camera=cfg.camera(), offroad_end=cfg.offroad_end, start_offset_m=cfg.start_offset_m,
                      start_yaw_deg=cfg.start_yaw_deg, otherlane_end=cfg.otherlane_end,
                      route_reward=cfg.route_reward(),
                      junction_weight=cfg.junction_weight if cfg.task == "navigation" else None,
                      junction_approaches_m=tuple(cfg.junction_approaches_m) if cfg.task == "navigation" else None)


def _log_row(step: int, episode: int, decision: int, action: int, reward: float, terms: dict, learn: Any,
             agent: Any, m: dict, attempt: int, command: int) -> list:
    return [step, episode, decision, ACTION_NAMES[action], reward, terms["collision"], terms["offroad"],
            terms["otherlane"], terms["speed"], terms["road_view"], learn.td_error, learn.component,
            int(learn.created), learn.weight, learn.weight_case, agent.n_components, agent.alpha, agent.tau,
            agent.rho, m["forward_speed_kmh"], m["intersection_offroad"], m["intersection_otherlane"], m["x"], m["y"],
            attempt, command, terms.get("progress", 0.0), terms.get("wrong_turn", 0.0),
            terms.get("heading", 0.0), terms.get("lateral", 0.0)]


def _format(v: Any) -> str:
    return repr(float(v)) if isinstance(v, float | np.floating) else str(v)


class _Checkpoint:
    """Agent + generator state at an episode boundary, written atomically."""

    def __init__(self, run_dir: Path) -> None:
        self.dir = run_dir / "checkpoint"

    def save(self, agent: Any, rng: np.random.Generator, step: int, episode: int, log_rows: int,
             stats: dict) -> None:
        self.dir.mkdir(parents=True, exist_ok=True)
        agent.save(self.dir / "agent.npz")
        atomic_write_json(self.dir / "state.json", {"version": CHECKPOINT_VERSION, "step": step, "episode": episode,
                                                   "log_rows": log_rows, "rng": rng.bit_generator.state,
                                                   "stats": stats})

    def load(self, cfg: TrainConfig) -> tuple[Any, np.random.Generator, dict] | None:
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
        if cfg.task == "navigation":
            from brlcli.agent.command import CommandAgent, TeamAgent

            agent: Any = (TeamAgent if cfg.teams > 1 else CommandAgent).load(self.dir / "agent.npz",
                                                                            cfg.command_bootstrap)
        else:
            agent = BayesianAgent.load(self.dir / "agent.npz")
        rng = np.random.default_rng()
        rng.bit_generator.state = state["rng"]
        return agent, rng, state


class _Curve:
    """Greedy paper-suite evaluations during training (learning_curve.csv); rows past a resumed step are redone."""

    def __init__(self, run_dir: Path, cfg: TrainConfig, env: DrivingEnv, step: int) -> None:
        from brlcli.bench.runner import SuiteEvaluator
        from brlcli.curve import CURVE_FILE, read_curve

        self.path = run_dir / CURVE_FILE
        self.rows = [r for r in read_curve(self.path) if r["env_steps"] <= step] if self.path.exists() else []
        self.labeler = env.labeler
        self.camera = cfg.camera()
        from brlcli.settings import setting_name

        self.setting = setting_name(cfg.input, cfg.input, cfg.variant)
        self.task = cfg.task
        self.evaluator = SuiteEvaluator("nav_validation" if cfg.task == "navigation" else "paper")
        self.eval_s = 0.0

    def evaluate(self, agent: Any, step: int) -> dict[str, Any]:
        """Evaluate the agent greedily at `step`, append the row to the curve file and return it."""
        from brlcli.curve import write_curve

        t0 = time.perf_counter()
        policy = greedy_policy(agent, self.task, self.setting, self.labeler, self.camera)
        branch = getattr(agent, "branch", None)
        self.rows.append({"env_steps": step, **self.evaluator.evaluate(policy)})
        if branch is not None:  # evaluation sets the branches; the training loop's step continues in its own
            agent._branch = branch
        write_curve(self.path, self.rows)
        self.eval_s += time.perf_counter() - t0
        return self.rows[-1]

    def close(self) -> None:
        self.evaluator.close()


def greedy_policy(agent: Any, task: str, setting: str, labeler: Callable[[np.ndarray], np.ndarray] | None,
                  camera: CameraConfig) -> Any:
    """The bench policy of a training agent, acting greedily (never with the training generator)."""
    from brlcli.policy import StatePolicy, greedy_brl, greedy_command_brl

    if task == "navigation":
        return StatePolicy("brl", setting, greedy_command_brl(agent), labeler, camera, uses_command=True)
    return StatePolicy("brl", setting, greedy_brl(agent), labeler, camera)


def _better(row: dict[str, Any], best: dict[str, Any] | None) -> bool:
    """keep_best's rule: higher validation success, then higher Score; a tie goes to the later evaluation."""
    return best is None or (row["success"], row["score"]) >= (best["success"], best["score"])


def _nav_eval(row: dict[str, Any]) -> dict[str, Any]:
    """A curve row in the form of the summary's `eval` (evaluate_navigation's)."""
    return {"suite": row["eval_suite"], "success_rate": row["success"], "collision_free_rate": row["collision_free"],
            "either_share": row["either"], "score": row["score"], "episodes": row["episodes"], "step": row["env_steps"]}


def _truncate_log(path: Path, rows: int) -> None:
    """Keep the header and the first `rows` data rows of a log (drops rows of an unfinished episode)."""
    if not path.exists():
        return
    lines = path.read_bytes().split(b"\n")
    atomic_write_bytes(path, b"".join(line + b"\n" for line in lines[: rows + 1]))


def _trapped(cfg: TrainConfig, step: int, stats: dict) -> bool:
    """The trap test at an episode's end: True when this attempt must restart (and records a passed check)."""
    if cfg.restart_below is None or stats["attempt"] >= cfg.max_restarts:
        return False
    done = stats["checks_done"]
    if done >= len(RESTART_CHECKS) or step - stats["attempt_start"] < RESTART_CHECKS[done] * cfg.steps:
        return False
    if step > cfg.steps:  # a restart here would take the run past twice its steps: keep the attempt
        return False
    stats["checks_done"] = done + 1
    off = cfg.restart_offroad_above is not None and np.mean(stats["window_offroad"]) > cfg.restart_offroad_above
    return bool(np.mean(stats["window"]) < cfg.restart_below or off)


def _trapped_branches(cfg: TrainConfig, step: int, stats: dict) -> list[int]:
    """The per-branch trap test at an episode's end: the branches to restart, as keys team * 4 + branch (the
    branch itself without teams), and records a passed check."""
    done = stats["branch_checks_done"]
    if cfg.branch_restart_below is None or done >= len(RESTART_CHECKS) or step < RESTART_CHECKS[done] * cfg.steps:
        return []
    stats["branch_checks_done"] = done + 1
    window = np.asarray(stats["branch_window"], dtype=np.float64).reshape(-1, 2)
    out = []
    for team in range(cfg.teams):
        for k, threshold in enumerate(cfg.branch_restart_below):
            key = team * len(cfg.branch_restart_below) + k
            rewards = window[window[:, 0] == key, 1]
            if rewards.size and rewards.mean() < threshold:
                out.append(key)
    return out


def _team_mask(cfg: TrainConfig, step: int) -> np.ndarray:
    """Which teams learn from learning step `step` of another team's episode (TeamAgent; a function of the seed and
    the step, so that resuming needs no generator state)."""
    return np.random.default_rng([cfg.seed, 7, step]).random(cfg.teams) < cfg.team_share


def _team_means(cfg: TrainConfig, stats: dict) -> np.ndarray:
    """Mean reward per step of each team's own acting steps on each command in the recent window, shape (teams, 4)
    (NaN where a team did not act on a command)."""
    window = np.asarray(stats["branch_window"], dtype=np.float64).reshape(-1, 2)
    out = np.full((cfg.teams, len(BRANCH_NAMES)), np.nan)
    for key in range(out.size):
        rewards = window[window[:, 0] == key, 1]
        if rewards.size:
            out.flat[key] = rewards.mean()
    return out


def _team_choice(team_means: np.ndarray) -> list[int]:
    """Per command, the team with the highest mean reward (`_team_means`; a team that did not act never wins a tie
    against one that did; ties go to the lower team)."""
    return [int(i) for i in np.argmax(np.nan_to_num(team_means, nan=-np.inf), axis=0)]


def _deployable(agent: Any, cfg: TrainConfig, stats: dict) -> Any:
    """The agent to evaluate and ship: itself, or TeamAgent.composed of the best team per command lately."""
    return agent if cfg.teams == 1 else agent.composed(_team_choice(_team_means(cfg, stats)))


def train_run(cfg: TrainConfig, run_dir: Path, resume: bool = False,
              progress: Callable[[Progress], None] | None = None) -> dict[str, Any]:
    """Train one agent; returns the summary. Resumable from the last finished episode."""
    run_dir = Path(run_dir)
    config_path = run_dir / "config.json"
    record = provenance(cfg.to_dict(), kind="train-run")
    if config_path.exists():
        if not resume:
            raise BrlInputError(f"{run_dir} already holds a training run; pass --resume or choose another --out")
        saved = json.loads(config_path.read_text())["config"]
        if TrainConfig.from_dict(saved).to_dict() != cfg.to_dict():
            raise BrlInputError(f"{run_dir} holds a run with another configuration; resume it with the same options")
    run_dir.mkdir(parents=True, exist_ok=True)
    if not config_path.exists():
        atomic_write_json(config_path, record)
    if (run_dir / "summary.json").exists():
        return json.loads((run_dir / "summary.json").read_text())
    if cfg.committee > 1:
        return _train_committee(cfg, run_dir, resume, progress)
    env = _make_env(cfg)
    ckpt = _Checkpoint(run_dir)
    loaded = ckpt.load(cfg) if resume else None
    log_path = run_dir / "log.csv"
    if loaded is None:
        agent = cfg.new_agent()
        rng = np.random.default_rng([cfg.seed, 1, *([cfg.member] if cfg.member else [])])
        step, episode, stats = 0, 0, {"episodes": 0, "goals": 0, "reward_sum": 0.0, "wall_s": 0.0}
        atomic_write_bytes(log_path, (",".join(LOG_COLUMNS) + "\n").encode())
    else:
        agent, rng, state = loaded
        step, episode, stats = state["step"], state["episode"], state["stats"]
        _truncate_log(log_path, state["log_rows"])
    stats.setdefault("attempt", 0)  # restarts (TrainConfig.restart_below): attempt number, its first global step,
    stats.setdefault("attempt_start", 0)  # the checks it passed, the rewards of the trap test's window
    stats.setdefault("checks_done", 0)
    stats.setdefault("window", [])
    stats.setdefault("window_offroad", [])
    stats.setdefault("restarts", [])
    stats.setdefault("branch_window", [])  # [branch, reward] of the last RESTART_WINDOW of steps (branch restarts)
    stats.setdefault("branch_checks_done", 0)
    stats.setdefault("branch_restarts", [])
    stats.setdefault("warm_started", None)  # warm_start_junctions: the step the junction branches were warm-started
    stats.setdefault("best", None)  # keep_best: the best curve row so far (its agent is model_best.npz)
    curve = _Curve(run_dir, cfg, env, step) if cfg.curve_every else None
    nav = cfg.task == "navigation"
    t0 = time.perf_counter() - stats["wall_s"]
    recent: list[float] = []
    td = 0.0
    with open(log_path, "a", newline="") as fh:
        while step - stats["attempt_start"] < cfg.steps:
            obs, reset_info = env.reset(seed=_episode_seed(cfg.seed, episode, cfg.member))
            command = reset_info["command"]
            if cfg.teams > 1:
                agent.start_episode(episode, rng)
            else:
                agent.begin_episode(rng)
            state = obs.astype(np.float64)
            buffer = io.StringIO()
            rows = csv.writer(buffer, lineterminator="\n")
            decision, reached = 0, False
            while step - stats["attempt_start"] < cfg.steps:
                if nav:
                    agent.set_command(command)
                action = agent.act(state, rng)
                obs, reward, terminated, truncated, info = env.step(action)
                next_state = obs.astype(np.float64)
                if decision > 0:  # no learning on the first decision after a reset
                    if cfg.teams > 1:
                        learn = agent.learn(state, action, reward, next_state, info["command"],
                                            _team_mask(cfg, step))
                    elif nav:
                        learn = agent.learn(state, action, reward, next_state, info["command"])
                    else:
                        learn = agent.learn(state, action, reward, next_state)
                    step += 1
                    td = learn.td_error
                    rows.writerow([_format(v) for v in _log_row(step, episode, decision, action, reward,
                                                                info["reward_terms"], learn, agent,
                                                                info["measurements"], stats["attempt"],
                                                                command)])
                    stats["reward_sum"] += reward
                    if cfg.restart_below is not None:
                        stats["window"].append(reward)
                        stats["window_offroad"].append(int(info["measurements"]["intersection_offroad"] > 0.0))
                        if len(stats["window"]) > max(1, round(RESTART_WINDOW * cfg.steps)):
                            del stats["window"][0], stats["window_offroad"][0]
                    if cfg.branch_restart_below is not None or cfg.teams > 1:
                        key = agent.branch + (agent.acting * len(BRANCH_NAMES) if cfg.teams > 1 else 0)
                        stats["branch_window"].append([key, reward])
                        if len(stats["branch_window"]) > max(1, round(RESTART_WINDOW * cfg.steps)):
                            del stats["branch_window"][0]
                    recent = [*recent, reward][-100:]
                    if curve is not None and step % cfg.curve_every == 0:
                        deployable = _deployable(agent, cfg, stats)
                        row = curve.evaluate(deployable, step)
                        if cfg.keep_best and _better(row, stats["best"]):
                            deployable.save(run_dir / "model_best.npz")
                            stats["best"] = {k: row[k] for k in ("env_steps", "success", "score")}
                    if progress and step % 25 == 0:
                        progress(Progress(cfg.seed, step, stats["attempt_start"] + cfg.steps, episode,
                                          float(np.mean(recent)), td,
                                          agent.n_components, member=cfg.member))
                decision += 1
                state = next_state
                command = info["command"]
                if terminated or truncated:
                    reached = terminated
                    break
            fh.write(buffer.getvalue())
            fh.flush()
            episode += 1
            stats["episodes"] = episode
            stats["goals"] += int(reached)
            if _trapped(cfg, step, stats):
                stats["restarts"].append({"step": step, "attempt_steps": step - stats["attempt_start"],
                                          "mean_reward": float(np.mean(stats["window"])),
                                          "offroad_share": float(np.mean(stats["window_offroad"]))})
                stats.update(attempt=stats["attempt"] + 1, attempt_start=step, checks_done=0, window=[],
                             window_offroad=[])
                agent = cfg.new_agent()
            if cfg.warm_start_junctions and stats["warm_started"] is None and step >= cfg.warm_start_junctions:
                stats["warm_started"] = step
                for team in agent.teams if cfg.teams > 1 else [agent]:
                    for k in range(1, len(team.branches)):
                        team.restart_branch(k, warm=True)
            for key in _trapped_branches(cfg, step, stats):
                window = np.asarray(stats["branch_window"]).reshape(-1, 2)
                k = key % len(BRANCH_NAMES)
                record = {"step": step, "branch": k, "mean_reward": float(window[window[:, 0] == key, 1].mean())}
                team = agent
                if cfg.teams > 1:
                    team = agent.teams[key // len(BRANCH_NAMES)]
                    record["team"] = key // len(BRANCH_NAMES)
                stats["branch_restarts"].append(record)
                team.restart_branch(k, warm=bool(k) and stats["warm_started"] is not None)
            stats["wall_s"] = time.perf_counter() - t0
            ckpt.save(agent, rng, step, episode, step, stats)
    wall = time.perf_counter() - t0 - (curve.eval_s if curve is not None else 0.0)  # learning time only
    if cfg.teams > 1:
        team_means = _team_means(cfg, stats)
        agent = _deployable(agent, cfg, stats)
    if cfg.keep_best and stats["best"] is not None:
        agent.save(run_dir / "model_last.npz")
        atomic_write_bytes(run_dir / "model.npz", (run_dir / "model_best.npz").read_bytes())
    else:
        agent.save(run_dir / "model.npz")
    summary: dict[str, Any] = {
        "seed": cfg.seed, "steps": step, "episodes": stats["episodes"], "episodes_reaching_goal": stats["goals"],
        "mean_reward": stats["reward_sum"] / max(step, 1),
        "components": agent.total_components if nav else agent.n_components,
        "alpha": agent.alpha, "tau": agent.tau, "rho": agent.rho, "wall_s": wall, "steps_per_s": step / wall,
    }
    if cfg.restart_below is not None:
        summary.update(attempts=stats["attempt"] + 1, restarts=stats["restarts"],
                       final_attempt_steps=step - stats["attempt_start"])
    env.close()
    if curve is not None:
        curve.close()
    if cfg.branch_restart_below is not None:
        summary["branch_restarts"] = stats["branch_restarts"]
    if cfg.warm_start_junctions:
        summary["junctions_warm_started_at"] = stats["warm_started"]
    if cfg.teams > 1:
        summary["team_rewards"] = {name: [None if np.isnan(v) else float(v) for v in team_means[:, b]]
                                   for b, name in enumerate(BRANCH_NAMES)}
        summary["team_choice"] = dict(zip(BRANCH_NAMES, _team_choice(team_means), strict=True))
    if nav:
        summary["components_per_branch"] = dict(zip(BRANCH_NAMES,
                                                     agent.components_per_branch, strict=True))
    if cfg.keep_best and stats["best"] is not None:
        rows = {r["env_steps"]: r for r in curve.rows}  # type: ignore[union-attr]
        summary["selected_step"] = stats["best"]["env_steps"]
        summary["eval"] = _nav_eval(rows[stats["best"]["env_steps"]])
        if cfg.evaluate:
            summary["eval_last"] = _nav_eval(rows[step]) if step in rows else evaluate_navigation(agent, cfg)
    elif cfg.evaluate and nav:
        summary["eval"] = evaluate_navigation(agent, cfg)
    elif cfg.evaluate:
        from brlcli.evaluate import evaluate_lane_keeping

        ev = evaluate_lane_keeping(agent, town=cfg.town, weather=cfg.weather, labeler=_labeler(cfg),
                                   camera=cfg.camera(), routes="validation")
        summary["eval"] = ev
    atomic_write_json(run_dir / "summary.json", {**provenance(cfg.to_dict()), "summary": summary})
    if progress:
        progress(Progress(cfg.seed, step, step, episode, float(np.mean(recent)) if recent else 0.0, td,
                          agent.n_components, done=True, member=cfg.member))
    return {**provenance(cfg.to_dict()), "summary": summary}


def _train_committee(cfg: TrainConfig, run_dir: Path, resume: bool,
                     progress: Callable[[Progress], None] | None) -> dict[str, Any]:
    """Train (or resume, or read) each member's run in run_dir/member_<k>, then write the committee's model.npz and
    summary.json (its nav_validation figures are the committee's, voting)."""
    from brlcli.agent.command import CommandAgent, CommitteeAgent

    members = []
    for k in range(cfg.committee):
        sub = run_dir / f"member_{k}"
        members.append(train_run(cfg.member_config(k), sub, resume=resume or (sub / "summary.json").exists(),
                                 progress=progress)["summary"])
    agent = CommitteeAgent([CommandAgent.load(run_dir / f"member_{k}" / "model.npz") for k in range(cfg.committee)])
    agent.save(run_dir / "model.npz")
    wall = sum(m["wall_s"] for m in members)
    summary: dict[str, Any] = {
        "seed": cfg.seed, "committee": cfg.committee, "vote": "majority",
        "steps": sum(m["steps"] for m in members), "episodes": sum(m["episodes"] for m in members),
        "episodes_reaching_goal": sum(m["episodes_reaching_goal"] for m in members),
        "mean_reward": float(np.mean([m["mean_reward"] for m in members])),
        "components": agent.total_components, "wall_s": wall, "steps_per_s": sum(m["steps"] for m in members) / wall,
        "members": [{"member": k, **{key: m[key] for key in ("steps", "mean_reward", "wall_s") if key in m},
                     "branch_restarts": len(m.get("branch_restarts", [])),
                     **({"eval_success_rate": m["eval"]["success_rate"]} if "eval" in m else {})}
                    for k, m in enumerate(members)],
    }
    if cfg.evaluate:
        summary["eval"] = evaluate_navigation(agent, cfg)
    atomic_write_json(run_dir / "summary.json", {**provenance(cfg.to_dict()), "summary": summary})
    return {**provenance(cfg.to_dict()), "summary": summary}


def evaluate_navigation(agent: Any, cfg: TrainConfig) -> dict[str, Any]:
    """Greedy success, collision-free and Either shares on the navigation validation suite (nav_validation)."""
    from brlcli.bench.runner import SuiteEvaluator
    from brlcli.settings import setting_name

    evaluator = SuiteEvaluator("nav_validation")
    try:
        policy = greedy_policy(agent, "navigation", setting_name(cfg.input, cfg.input, cfg.variant), _labeler(cfg),
                               cfg.camera())
        figures = evaluator.evaluate(policy)
    finally:
        evaluator.close()
    return {"suite": "nav_validation", "success_rate": figures["success"],
            "collision_free_rate": figures["collision_free"], "either_share": figures["either"],
            "score": figures["score"], "episodes": figures["episodes"]}


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


def _train_task(item: tuple[dict, str, bool]) -> dict[str, Any]:
    """One seed's run in a worker (local process or Ray task); progress goes to the driver through the executor."""
    cfg_dict, run_dir, resume = item
    return train_run(TrainConfig.from_dict(cfg_dict), Path(run_dir), resume=resume, progress=report)


def run_dir_for(out: Path, seed: int) -> Path:
    """Directory of one seed's run inside a training output directory."""
    return Path(out) / f"seed_{seed}"


def check_run_dirs(cfg: TrainConfig, seeds: list[int], out: Path, resume: bool) -> None:
    """Refuse, before anything is written, to overwrite a seed's run without `resume`, or to resume one made with
    another configuration."""
    for s in seeds:
        d = run_dir_for(out, s)
        if not (d / "config.json").exists():
            continue
        if not resume:
            raise BrlInputError(f"{d} already holds a training run; pass --resume or choose another --out")
        try:
            saved = TrainConfig.from_dict(json.loads((d / "config.json").read_text())["config"]).to_dict()
        except (ValueError, KeyError, TypeError):
            raise BrlInputError(f"{d / 'config.json'} is not a brl training configuration") from None
        if saved != TrainConfig.from_dict({**cfg.to_dict(), "seed": s}).to_dict():
            raise BrlInputError(f"{d} holds a run with another configuration; resume it with the same options")


def train_many(cfg: TrainConfig, seeds: list[int], out: Path, workers: int = 1, resume: bool = False,
               progress: Callable[[Progress], None] | None = None, executor: str | Executor = "local",
               ray_address: str | None = None) -> list[dict[str, Any]]:
    """Train one model per seed, one task each on the executor; results (in seed order) do not depend on it.

    Workers write each seed's run directory themselves (checkpoints while they train), so on a Ray cluster `out`
    must be on a filesystem every node mounts at the same path; an interrupted set resumes with `resume`.
    """
    out = Path(out)
    cfgs = [TrainConfig.from_dict({**cfg.to_dict(), "seed": s}) for s in seeds]
    check_run_dirs(cfg, seeds, out, resume)
    check_inputs(cfg)
    ex = executor if isinstance(executor, Executor) else Executor(executor, workers, ray_address)
    ex.connect()  # a bad executor fails before anything is written
    try:
        out.mkdir(parents=True, exist_ok=True)
        atomic_write_json(out / "run.json", provenance({**cfg.to_dict(), "seeds": seeds, "workers": workers},
                                                      kind="train"))
        items = [(c.to_dict(), str(run_dir_for(out, c.seed).resolve()), resume) for c in cfgs]
        if cfg.committee > 1:  # the members first, every (seed, member) one task, then each seed's committee
            members = [(c.member_config(k).to_dict(), str(run_dir_for(out, c.seed).resolve() / f"member_{k}"), resume)
                       for c in cfgs for k in range(cfg.committee)]
            for _ in run_tasks(_train_task, members, executor=ex, on_report=progress):
                pass
        results: list[dict[str, Any]] = [{} for _ in items]
        for i, result in run_tasks(_train_task, items, executor=ex, on_report=progress):
            results[i] = result
    finally:
        if ex is not executor:
            ex.close()
    return results
