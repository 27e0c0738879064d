"""The training configuration of `brl train` and `brl sweep`: `TrainConfig`, the named methods and task presets, and
its resolution from layers (`brlcli.config`): defaults -> method preset -> task preset -> `--config` -> options ->
`--set`, validated once into a frozen `TrainConfig`.
"""

from __future__ import annotations

import json
from collections.abc import Sequence
from dataclasses import asdict, dataclass, field, replace
from typing import Any

from brlcli.agent import BRLParams
from brlcli.config import Layer, check_known_keys, merge_layer, resolve
from brlcli.errors import BrlInputError
from brlcli.retired import RETIRED_CONFIG, RETIRED_PARAMS, drop_retired, refuse_retired
from brlcli.reward import HazardRewardParams, RewardParams, RouteRewardParams
from brlcli.segnet import check_input_source
from brlcli.sim.camera import CameraConfig
from brlcli.sim.gym_env import ACTION_SETS, GATE_DRIVER_ACTIONS, STOP, STOP_RULES, DrivingEnv
from brlcli.sim.navroutes import TASK_ROUTE_KINDS, TASKS
from brlcli.sim.weather import get_weather

VARIANT_PRESETS: dict[str, dict[str, Any]] = {
    "paper": {},
    "reference-code": {},
    "averaging-restart": {"params": {"step_size": "visits"}, "restart_below": -7.0, "max_restarts": 2},
    "action-averaging-restart": {"params": {"step_size": "action-visits"}, "restart_below": -7.0, "max_restarts": 2},
    "action-averaging-committee": {"params": {"step_size": "action-visits"}, "restart_below": -7.0, "max_restarts": 2,
                                   "committee": 5},
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
equal action values that traps runs; the restart stays as a safety net (it fires on one of eighteen seeds).
`action-averaging-committee` (outside the paper; issue 34): five `action-averaging-restart` agents trained apart
(members 0-4 of the seed) that drive by majority vote, so that a run's own wrong greedy action at a curve is
outvoted (docs/lane-keeping-study.md, issue 34)."""
DEFAULT_VARIANT = "action-averaging-committee"
"""The variant `brl train` uses when none is named: the recommended one, chosen on the validation routes from six
start poses on seeds 0-17 (docs/lane-keeping-study.md, issue 34)."""

TASK_PRESETS: dict[str, dict[str, Any]] = {
    "lane-keeping": {},
    "navigation": {"steps": 27000, "restart_below": None, "params": {"new_q": "nearest"},
                   "branch_restart_below": [-5.0, -9.0, -9.0, -9.0], "committee": 1, "learning": "imitation",
                   "actions": "fine_stop", "decision_frames": 3, "stop_rule": "road_user",
                   "traffic": ["empty", "regular", "dense"], "state": "road_users_weighted"},
}
"""Overrides a task makes on top of the variant's preset (an option, --config or --set goes on top), chosen on the
validation suites (docs/navigation-study.md). Navigation (outside the paper; what models/brl_nav ships, section
12.18): one command-conditioned mixture per seed that learns by imitation of the privileged expert (DAgger, 8
iterations of 300 episodes in Empty, Regular and Dense town01 traffic), with the fine steering primitives and `stop`,
a decision every 3 frames, `stop` only where the state shows a road user, and the state with vehicle and pedestrian
pixels weighted 5 times (`state = "road_users_weighted"`, section 12.23; `--set state=paper` trains the paper's
state, the preset of sections 12.18-12.19); its fit uses the agent parameters below (`new_q = "nearest"`: a new
component starts from its nearest component's action values). Its steps and restarts (unused by imitation) are those
of the empty-road committees of issue 20 (models/brl_nav_empty), which `--set learning=td --set actions=paper --set
decision_frames=7 --set stop_rule=any --set 'traffic=[]' --set committee=7 --set state=paper` trains: six times the
paper's t_max, no lane-keeping trap restart, a trap restart per branch (follow -5, turns -9)."""

NAVIGATION_TD_RECIPE: dict[str, Any] = {"learning": "td", "actions": "paper", "decision_frames": 7, "stop_rule": "any",
                                        "traffic": [], "committee": 7, "state": "paper"}
"""The keys that turn the navigation preset back into the empty-road TD committees of issue 20 (models/brl_nav_empty;
`--set learning=td --set actions=paper --set decision_frames=7 --set stop_rule=any --set 'traffic=[]' --set
committee=7 --set state=paper`)."""


def set_options(values: dict[str, Any]) -> list[str]:
    """Config values as `brl train` options: `--set KEY=VALUE` each, VALUE in JSON (which --set reads)."""
    return [a for key, value in values.items() for a in ("--set", f"{key}={json.dumps(value)}")]


LEARNING = ("td", "imitation")
"""How a navigation model learns (`TrainConfig.learning`): TD learning on the reward (the paper's), or imitation."""

DEFAULT_AGENT_OVERRIDES: dict[str, Any] = {"init_scatter": 1e-3}
"""Agent parameters a training run sets beyond `BRLParams()` (none of them is in the paper's Table I): the NIW
prior scatter S0 = 1e-3 I, on the scale of the 30-number state, instead of the reference code's 0.1 I
(docs/lane-keeping-study.md)."""

OPEN = ("params",)
"""Config tables whose keys are checked by their owner (params.*: BRLParams.from_dict), not against the defaults."""
RESERVED_KEYS = {"seed": "seeds come from --seed or --seeds", "member": "committee members are numbered by brl train"}
"""Training config keys an input layer may not set."""


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
    curve_every: int = 0  # greedy evaluation on the task's evaluation suite every N steps (learning_curve.csv); 0: no
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
    branch_restart_below: list[float] | None = None  # navigation only, outside the paper: per-branch trap test
    # (follow, left, right, straight): at RESTART_CHECKS of the steps, a branch whose mean reward per step over its
    # steps among the last RESTART_WINDOW of the run's steps is below its threshold restarts from a fresh agent
    r_progress: float = 5.0  # navigation only: route-following reward terms (RouteRewardParams)
    r_wrong_turn: float = 40.0
    wrong_turn_m: float = 6.0
    junction_weight: float = 2.0  # navigation only: a junction kind's probability relative to a lane-keeping kind
    junction_approaches_m: list[float] = field(default_factory=lambda: [25.0, 60.0])  # navigation only: where the
    # junction routes start before their junction (m)
    committee: int = 1  # outside the paper: K > 1 trains K agents apart (members 0..K-1, each the whole run's steps,
    # in member_<k>/) and ships them as one model that acts by majority vote
    member: int = 0  # which committee member a run is: member 0 is the seed's own run, member k > 0 draws its
    # generators from (seed, k) as well
    actions: str = "paper"  # outside the paper when "stop": the four primitives and a fifth, stop (ACTION_SETS)
    traffic: list[str] = field(default_factory=list)  # outside the paper: NoCrash traffic levels of the training
    # episodes (each episode draws one; [] = no traffic); a collision with a road user ends an episode
    r_hazard: float = 0.0  # outside the paper, > 0: the hazard reward (HazardRewardParams): the target speed falls to
    # zero near a road user on the route; 0 = the paper's reward
    hazard_stop_m: float = 4.0
    hazard_slow_m: float = 15.0
    hazard_predict_s: float = 0.0  # how far ahead the hazard reward predicts road users (s; the expert's: 2)
    r_stand: float = 0.0  # outside the paper: cost per decision of standing still (< 1 km/h) with no hazard ahead
    state: str = "paper"  # the agent's state (STATE_OPTIONS): "paper" (30 numbers), "nearness" or "speed" (outside it)
    brake_gate_steps: int = 0  # outside the paper, > 0: after the navigation model (the driver) is trained on empty
    # roads, a brake gate (`brlcli.agent.gate`: go or stop) learns this many steps in `traffic` with the hazard reward
    ghost_traffic: bool = False  # outside the paper: with `traffic`, the car passes through road users (seen, moving,
    # braking for it; no contact, no crash); a brake gate's driver then trains among them, the gate in real traffic
    privileged_brake_m: float = 0.0  # outside the paper, > 0: in traffic, the training environment takes the stop
    # primitive wherever the privileged hazard gap on the route is under this (m), and the agent does not learn from
    # those decisions (a driver learns its lanes among road users with a teacher's brake; a brake gate over it stops)
    decision_frames: int = 7  # frames between decisions, each action held for them (the paper's 7, 0.7 s; fewer is
    # outside the paper): the agent decides, and learns, every decision_frames frames
    stop_rule: str = "any"  # where the stop primitive may be taken (STOP_RULES): "any", or "road_user" (outside the
    # paper; imitation only): only where the state shows a road user, for the teacher's labels and the driver alike
    learning: str = "td"  # how the navigation model (a gated run's driver) learns: "td", Algorithm 1 on the reward;
    # "imitation" (outside the paper, `brlcli.imitation`): DAgger in the same mixture, fitted by Algorithm 1's learning
    # step to the privileged expert's nearest action of the set (its budget: the two keys below, not `steps`)
    imitation_iterations: int = 8  # DAgger iterations after the expert's own (4 drove 14 / 5 / 3 of 16 validation
    # routes against 8's 16 / 11 / 1; navigation-study 12.17)
    imitation_episodes: int = 300  # training episodes per iteration
    imitation_rho: float = 0.03  # the fit's creation distance: a new component wherever a recorded state is farther
    # than this (l_inf) from every component of its branch and an action's value falls 2 below its target
    imitation_stop_weight: float = 1.0  # the teacher's cost of driving where the expert stands, in units of its cost
    # of a needless stop (>= 1; outside the paper): the fit then stops where p(stand | state) > 1 / (1 + weight)
    driver_model: str | None = None  # the frozen driver of a brake gate's own run (set by brl train: the seed's
    # driver/model.npz; or an existing navigation model.npz or member set, then only the gate is trained)

    def __post_init__(self) -> None:
        check_input_source(self.input, "--input")
        if self.task not in TASKS:
            raise BrlInputError(f"unknown task '{self.task}'; choose one of {', '.join(TASKS)}")
        if self.variant not in VARIANT_PRESETS:
            raise BrlInputError(f"unknown variant '{self.variant}'; choose one of {', '.join(VARIANT_PRESETS)}")
        if self.branch_restart_below is not None and (self.task != "navigation" or len(self.branch_restart_below)
                                                      != 4):
            raise BrlInputError("branch_restart_below needs --task navigation and four thresholds (follow, left, "
                                "right, straight)")
        for name in ("committee", "member"):
            value = getattr(self, name)
            if isinstance(value, bool) or not isinstance(value, int) or value < (1 if name == "committee" else 0):
                raise BrlInputError(f"{name} must be an integer >= {1 if name == 'committee' else 0}, got {value!r}")
        if self.committee > 1 and (self.curve_every or self.member):
            raise BrlInputError("committee cannot be combined with --curve-every (evaluate the members' own runs)")
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
        if self.seed < 0:
            raise BrlInputError(f"--seed must be >= 0, got {self.seed}")
        if self.curve_every < 0:
            raise BrlInputError("--curve-every must be >= 0")
        if self.max_restarts < 0:
            raise BrlInputError("max_restarts must be >= 0")
        try:
            DrivingEnv.check_traffic_options(self.actions, self.traffic, self.state, self.r_stand)
            self.reward_params()
            self.route_reward()
            self.hazard_reward()
            self.camera()
            DrivingEnv.check_episode_rules(self.offroad_end, self.start_offset_m, self.start_yaw_deg,
                                           self.otherlane_end)
            DrivingEnv.check_decision_frames(self.decision_frames)
        except ValueError as exc:
            raise BrlInputError(f"bad training configuration: {exc}") from None
        get_weather(self.weather)
        if not isinstance(self.ghost_traffic, bool) or (self.ghost_traffic and not self.traffic):
            raise BrlInputError("ghost_traffic is true or false and needs traffic levels (e.g. --set "
                                "'traffic=[\"regular\",\"dense\"]')")
        if isinstance(self.privileged_brake_m, bool) or not isinstance(self.privileged_brake_m, int | float) or \
                self.privileged_brake_m < 0:
            raise BrlInputError(f"privileged_brake_m must be a distance >= 0 (m), got {self.privileged_brake_m!r}")
        if self.privileged_brake_m and (self.task != "navigation" or not self.traffic or self.ghost_traffic
                                        or self.driver_model is not None):
            raise BrlInputError("privileged_brake_m trains a navigation driver in real traffic: it needs --task "
                                "navigation and traffic levels, without ghost_traffic or driver_model")
        self._check_gate()
        self._check_learning()
        self._check_stop_rule()

    def _check_stop_rule(self) -> None:
        """The road-user stop rule: an imitating model whose own action set has the stop primitive."""
        if self.stop_rule not in STOP_RULES:
            raise BrlInputError(f"unknown stop_rule '{self.stop_rule}'; choose one of {', '.join(STOP_RULES)}")
        if self.stop_rule != "any" and (self.learning != "imitation" or STOP not in ACTION_SETS[self.actions]
                                        or self.brake_gate_steps or self.driver_model is not None):
            raise BrlInputError(f"stop_rule={self.stop_rule} (the navigation preset's) needs learning=imitation and an "
                                "action set with the stop primitive (actions=stop or fine_stop), without a brake "
                                "gate; add --set stop_rule=any for any other recipe")

    def _check_learning(self) -> None:
        """Imitation's options: a navigation model of its own, none of TD learning's hooks."""
        if self.learning not in LEARNING:
            raise BrlInputError(f"unknown learning '{self.learning}'; choose one of {', '.join(LEARNING)}")
        for name in ("imitation_iterations", "imitation_episodes"):
            value = getattr(self, name)
            if isinstance(value, bool) or not isinstance(value, int) or value < (0 if "iterations" in name else 1):
                raise BrlInputError(f"{name} must be an integer >= {0 if 'iterations' in name else 1}, got {value!r}")
        if isinstance(self.imitation_stop_weight, bool) or not isinstance(self.imitation_stop_weight, int | float) \
                or not 1 <= self.imitation_stop_weight <= 100:
            raise BrlInputError(f"imitation_stop_weight must be a number in [1, 100], got "
                                f"{self.imitation_stop_weight!r}")
        if isinstance(self.imitation_rho, bool) or not isinstance(self.imitation_rho, int | float) or \
                not 0 < self.imitation_rho <= 1:
            raise BrlInputError(f"imitation_rho must be a distance in (0, 1], got {self.imitation_rho!r}")
        if self.learning == "td":
            return
        if self.task != "navigation" or self.driver_model is not None:
            raise BrlInputError("learning=imitation trains a navigation model (or a gated run's driver): it needs "
                                "--task navigation and no driver_model")
        td_only = [name for name, on in (("curve_every", self.curve_every), ("ghost_traffic", self.ghost_traffic),
                                         ("privileged_brake_m", self.privileged_brake_m)) if on]
        if td_only:  # (the trap restarts of a preset simply do not apply: imitation has no reward to test)
            raise BrlInputError(f"learning=imitation has no TD learning steps: drop {', '.join(td_only)}")

    def _check_gate(self) -> None:
        """The brake gate's options: a navigation run with traffic and the hazard reward, a driver's action set."""
        gated = self.brake_gate_steps or self.driver_model is not None
        if isinstance(self.brake_gate_steps, bool) or not isinstance(self.brake_gate_steps, int) or \
                self.brake_gate_steps < 0:
            raise BrlInputError(f"brake_gate_steps must be an integer >= 0, got {self.brake_gate_steps!r}")
        if not gated:
            return
        if self.task != "navigation" or not self.traffic or not self.r_hazard:
            raise BrlInputError("a brake gate needs --task navigation, traffic levels and the hazard reward (e.g. "
                                "--set 'traffic=[\"empty\",\"regular\",\"dense\"]' --set r_hazard=20)")
        if self.actions not in GATE_DRIVER_ACTIONS:
            raise BrlInputError(f"a brake gate adds the stop primitive to its driver's actions: set actions to one "
                                f"of {', '.join(GATE_DRIVER_ACTIONS)}, not '{self.actions}'")
        if self.driver_model is not None:
            from brlcli.agent.command import is_command_model

            if self.ghost_traffic:
                raise BrlInputError("a brake gate learns in real traffic: drop ghost_traffic when giving driver_model "
                                    "(ghost_traffic with brake_gate_steps trains the driver among ghost road users)")

            if self.committee > 1:
                raise BrlInputError("a run over an existing driver_model trains one brake gate; drop committee")
            if not is_command_model(self.driver_model):
                raise BrlInputError(f"driver_model {self.driver_model} is not a navigation model (the model.npz of "
                                    f"brl train --task navigation, or a directory of its committee members)")

    @property
    def trains_driver_then_gate(self) -> bool:
        """Whether this run trains its driver (in driver/) and then a brake gate over it (in gate/)."""
        return bool(self.brake_gate_steps) and self.driver_model is None

    @property
    def env_actions(self) -> str:
        """The action set of the training environment: the driver's and `stop` for a brake gate's run."""
        return GATE_DRIVER_ACTIONS[self.actions] if self.driver_model is not None else self.actions

    def driver_config(self) -> TrainConfig:
        """The configuration of a gated run's driver: the same run without the gate's options, on empty roads unless
        it learns among (ghost) road users or by imitation of the expert in the run's traffic."""
        if self.ghost_traffic or self.privileged_brake_m or self.learning == "imitation":  # the driver trains among
            # (ghost) road users, without the gate's reward
            return replace(self, brake_gate_steps=0, r_hazard=0.0, r_stand=0.0)
        return replace(self, brake_gate_steps=0, traffic=[], r_hazard=0.0, r_stand=0.0)

    def gate_config(self, driver_model: str) -> TrainConfig:
        """The configuration of a gated run's gate: `brake_gate_steps` learning steps over the frozen driver."""
        return replace(self, steps=self.brake_gate_steps, brake_gate_steps=0, driver_model=driver_model,
                       ghost_traffic=False, privileged_brake_m=0.0, learning="td",
                       committee=1, member=0, restart_below=None, branch_restart_below=None, curve_every=0)

    def to_dict(self) -> dict[str, Any]:
        """JSON-ready form."""
        d = asdict(self)
        d["route_kinds"] = list(self.route_kinds or ())
        return d

    @classmethod
    def from_dict(cls, d: dict[str, Any]) -> TrainConfig:
        """Inverse of `to_dict`; unknown keys are an error."""
        check_known_keys(cls, d, "training")
        d = dict(d)
        if "road_view" not in d:  # a config written before the study's options: brl 0.1's choices
            d.update(road_view="road", offroad_end=None)
        if d.get("route_kinds") is not None:
            d["route_kinds"] = tuple(d["route_kinds"])
        return cls(**d)

    @classmethod
    def from_saved(cls, d: dict[str, Any], where: str) -> TrainConfig:
        """A configuration an earlier brl saved (`where`: its file): retired keys at their off values are dropped, a
        run that used a retired knob is refused with one line."""
        d = drop_retired(d, RETIRED_CONFIG, where)
        if isinstance(d.get("params"), dict):
            d["params"] = drop_retired(d["params"], RETIRED_PARAMS, where)
        try:
            return cls.from_dict(d)
        except BrlInputError as exc:
            raise BrlInputError(f"{where} is not a configuration this brl can run: {exc}") from None
        except (TypeError, ValueError):
            raise BrlInputError(f"{where} is not a brl training configuration") from None

    def for_seed(self, seed: int) -> TrainConfig:
        """The same configuration for another seed."""
        return replace(self, seed=seed)

    def member_config(self, member: int) -> TrainConfig:
        """The configuration of committee member `member`'s own run (one agent, that member's generators)."""
        return replace(self, committee=1, member=member)

    def reward_params(self) -> RewardParams:
        """The reward's parameters for this run."""
        return RewardParams(target_speed_kmh=self.target_speed_kmh, road_view=self.road_view)

    def route_reward(self) -> RouteRewardParams | None:
        """The route-following reward terms of a navigation run (None for lane keeping)."""
        if self.task != "navigation":
            return None
        return RouteRewardParams(self.r_progress, self.r_wrong_turn, self.wrong_turn_m)

    def hazard_reward(self) -> HazardRewardParams | None:
        """The hazard reward terms (None when r_hazard is 0: the paper's reward)."""
        if not self.r_hazard:
            return None
        return HazardRewardParams(self.r_hazard, self.hazard_stop_m, self.hazard_slow_m, self.hazard_predict_s)

    def camera(self) -> CameraConfig:
        """The state camera of this run (CoRL2017's mount and size, the configured pitch)."""
        return CameraConfig(pitch_deg=self.camera_pitch_deg)

    def agent_params(self) -> BRLParams:
        """The agent's parameters for this run."""
        base = BRLParams.reference_code() if self.variant == "reference-code" else BRLParams()
        return BRLParams.from_dict({**base.to_dict(), **self.params}) if self.params else base


def variant_of(layers: Sequence[Layer], default: str) -> str:
    """The variant the layers name (the last one that sets it), else `default`; unknown names are an error."""
    name = default
    for layer in layers:
        if "variant" in layer.values:
            name = layer.values["variant"]
    if not isinstance(name, str) or name not in VARIANT_PRESETS:
        raise BrlInputError(f"unknown variant {json.dumps(name, default=str)}; choose one of "
                            f"{', '.join(VARIANT_PRESETS)}")
    return name


def resolve_train_config(layers: Sequence[Layer], default_variant: str = DEFAULT_VARIANT,
                         fill_segnet: bool = True) -> TrainConfig:
    """The training configuration of `layers` (`brlcli.config.command_layers`, or a sweep grid's tables): the
    defaults, the named variant's preset, the task's preset, then the layers in order; one-line errors. With
    `fill_segnet`, estimated input without a net gets the shipped one (recorded in the config)."""
    for layer in layers:
        refuse_retired(layer.values, RETIRED_CONFIG)
        if isinstance(layer.values.get("params"), dict):
            refuse_retired(layer.values["params"], RETIRED_PARAMS, "params.")
        for key, why in RESERVED_KEYS.items():
            if key in layer.values:
                raise BrlInputError(f"{layer.source} cannot set {key}: {why}")
    defaults = {**TrainConfig().to_dict(), "route_kinds": None}  # None: the task's routes (TASK_ROUTE_KINDS)
    variant = variant_of(layers, default_variant)
    base = merge_layer(defaults, {**VARIANT_PRESETS[variant], "variant": variant}, "", defaults, open_tables=OPEN)
    task = next((layer.values["task"] for layer in reversed(layers) if "task" in layer.values), defaults["task"])
    preset = TASK_PRESETS.get(task, {}) if isinstance(task, str) else {}  # an unknown task: TrainConfig says so
    base = merge_layer(base, preset, "", defaults, open_tables=OPEN)
    cfg = resolve(TrainConfig, layers, "training", base=base, defaults=defaults, open_tables=OPEN)
    try:
        cfg.agent_params()  # validates params.* (BRLParams.from_dict)
    except ValueError as exc:
        raise BrlInputError(" ".join(str(exc).split())) from None
    if fill_segnet and cfg.input == "estimated" and cfg.segnet is None:
        from brlcli.models import default_segnet_path

        cfg = replace(cfg, segnet=str(default_segnet_path()))
    if cfg.segnet is not None and cfg.input != "estimated":
        raise BrlInputError("--segnet is only used with --input estimated")
    from brlcli.sim.town import load_town

    load_town(cfg.town)  # an unknown town or a bad town file fails here
    return cfg
