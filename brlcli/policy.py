"""The driving-policy interface, below both the bench and the baselines, and the policies of brl's own agents.

A policy sees an `Observation` every `frames_per_decision` simulator frames and returns the `Control` to hold.
Policies travel to worker processes (local or Ray) as a `PolicySpec` (kind, name, plain options) and are rebuilt
there by the policy registry (`brlcli.bench.registry.build_policy`), which sits above the baselines it builds.
Here: the interface (`Observation`, `Policy`, `PolicySpec`), `StatePolicy` (any greedy function of the 30-number
state), the trained BRL models (`BRLPolicy`), the privileged expert (`AutopilotPolicy`) and the expert restricted to
the BRL agent's actions (`OraclePolicy`).
"""

from __future__ import annotations

import json
from collections.abc import Callable
from dataclasses import dataclass, field
from pathlib import Path
from typing import TYPE_CHECKING, Any, Protocol

import numpy as np

from brlcli.errors import BrlInputError
from brlcli.features import STATE_DIM, STATE_OPTIONS, agent_state
from brlcli.retired import RETIRED_CONFIG, retired_message, unknown_action_set
from brlcli.segnet import check_input_source, labeler_for
from brlcli.settings import setting_name
from brlcli.sim.camera import CameraConfig
from brlcli.sim.gym_env import (
    ACTION_SETS,
    ACTIONS,
    FRAMES_PER_DECISION,
    GATE_DRIVER_ACTIONS,
    STOP,
    STOP_RULES,
    action_set_traits,
    nearest_forward,
)
from brlcli.sim.vehicle import Control

if TYPE_CHECKING:
    from brlcli.episode import EpisodeSpec
    from brlcli.sim.world import World

PATH_OPTIONS = ("model", "segnet")
"""Options of a PolicySpec that name files (resolved to absolute paths before they travel to a worker)."""


@dataclass
class Observation:
    """What a policy sees at a decision: camera images, measurements and the route command."""

    rgb: np.ndarray | None
    labels: np.ndarray | None
    measurements: Any
    command: int
    depth: np.ndarray | None = None


class Policy(Protocol):
    """A driving policy the bench can run (BRL models, baselines)."""

    name: str
    setting: str
    frames_per_decision: int

    def reset(self, spec: EpisodeSpec, world: World) -> None:
        """Start of an episode (privileged policies may keep the world to read the route and the traffic)."""

    def decide(self, obs: Observation) -> Control:
        """Control to hold until the next decision."""


@dataclass
class PolicySpec:
    """How to build a policy in a worker process (policies are rebuilt there, never pickled)."""

    kind: str
    name: str
    options: dict[str, Any] = field(default_factory=dict)

    def with_absolute_paths(self) -> PolicySpec:
        """The same spec with its file options absolute (a worker may run in another directory)."""
        opts = {k: (str(Path(v).resolve()) if k in PATH_OPTIONS and v is not None else v)
                for k, v in self.options.items()}
        return PolicySpec(self.kind, self.name, opts)


def _training_config(model_path: Path) -> dict[str, Any]:
    """The training configuration in the config.json beside a BRL model, or a member set's first member's ({} without
    one)."""
    from brlcli.agent.committee import committee_members, model_file

    cfg = (committee_members(model_path) or [Path(model_file(model_path))])[0].parent / "config.json"
    if not cfg.exists():
        return {}
    try:
        config = json.loads(cfg.read_text())["config"]
    except (json.JSONDecodeError, KeyError, TypeError):
        raise BrlInputError(f"{cfg} is not a brl training config") from None
    if not isinstance(config, dict):
        raise BrlInputError(f"{cfg} is not a brl training config")
    return config


def model_training_input(model_path: Path) -> str:
    """'gt' or 'estimated': the input a BRL model was trained on, from the config.json beside it (default gt)."""
    return str(_training_config(model_path).get("input", "gt"))


def model_task(model_path: Path) -> str:
    """'lane-keeping' or 'navigation': the task of a BRL model (its config.json's `task`; lane keeping without)."""
    return str(_training_config(model_path).get("task", "lane-keeping"))


def model_variant(model_path: Path) -> str:
    """The method variant a BRL model was trained with (its config.json's `variant`; 'paper' without one)."""
    return str(_training_config(model_path).get("variant", "paper"))


def model_state_option(model_path: Path) -> str:
    """The state option a BRL model was trained with (its config.json's `state`; 'paper' without one)."""
    return str(_training_config(model_path).get("state", "paper"))


def model_camera(model_path: Path) -> CameraConfig | None:
    """The state camera a BRL model was trained with (its config.json's camera_pitch_deg); None = the default."""
    pitch = _training_config(model_path).get("camera_pitch_deg")
    if pitch is None or float(pitch) == CameraConfig().pitch_deg:
        return None
    return CameraConfig(pitch_deg=float(pitch))


class StatePolicy:
    """A bench policy from any greedy function of the agent's state (BRL agent, DQN network), decided every
    `decision_frames` frames (the paper's 7) on the ground-truth labels or, with a `labeler`, on the segmentation net's
    labels of the RGB image; the action index picks from `actions` (ACTION_SETS) and the state is the `state`
    option's (STATE_OPTIONS)."""

    def __init__(self, name: str, setting: str, act: Callable[..., int],
                 labeler: Callable[[np.ndarray], np.ndarray] | None = None,
                 camera: CameraConfig | None = None, uses_command: bool = False, actions: str = "paper",
                 state: str = "paper", decision_frames: int = FRAMES_PER_DECISION) -> None:
        self.uses_command = uses_command  # act(state, command) instead of act(state)
        self.frames_per_decision = decision_frames
        self.name = name
        self.setting = setting
        self.act = act
        self.labeler = labeler
        self.camera = None if camera == CameraConfig() else camera  # None: the bench's default camera
        self.actions = ACTION_SETS[actions]
        self.state_option = state
        self.needs_depth = state == "nearness"

    @property
    def needs_rgb(self) -> bool:
        """Whether decisions need the RGB image (only to estimate labels; ground-truth labels need none)."""
        return self.labeler is not None

    def reset(self, spec: EpisodeSpec, world: Any) -> None:
        """Greedy state policy: nothing to reset."""

    def decide(self, obs: Observation) -> Control:
        """The action primitive chosen on the (ground-truth or estimated) label image's state."""
        labels = obs.labels if self.labeler is None else self.labeler(obs.rgb)
        speed = obs.measurements.forward_speed_kmh if self.state_option == "speed" else 0.0
        state = agent_state(labels, obs.depth, self.state_option, speed)
        if self.uses_command:
            return self.actions[int(self.act(state, obs.command))]
        return self.actions[int(self.act(state))]


def greedy_brl(agent: Any) -> Callable[[np.ndarray], int]:
    """state -> the BRL agent's greedy action (greedy acting never draws from the generator)."""
    rng = np.random.default_rng(0)
    return lambda state: agent.act(np.asarray(state, dtype=np.float64), rng, greedy=True)


def greedy_command_brl(agent: Any) -> Callable[[np.ndarray, int], int]:
    """(state, command) -> the greedy action of the command's branch of a command-conditioned BRL agent."""
    rng = np.random.default_rng(0)

    def act(state: np.ndarray, command: int) -> int:
        return agent.act(np.asarray(state, dtype=np.float64), command, rng, greedy=True)

    return act


def with_stop_rule(agent: Any, actions: str, stop_rule: str) -> Any:
    """A navigation model as it drives under `stop_rule` (STOP_RULES): itself, or with "road_user" its stop primitive
    taken only where the state shows a road user (`RoadUserStop`)."""
    if stop_rule == "any":
        return agent
    from brlcli.agent.command import RoadUserStop

    return RoadUserStop(agent, ACTION_SETS[actions].index(STOP))


class BRLPolicy(StatePolicy):
    """A trained Bayesian RL model deployed greedily on GT or estimated labels (a decision every 7 frames, or its
    training's `decision_frames`); a
    command-conditioned model (task navigation) acts with the branch of the route command."""

    def __init__(self, name: str, model: str, deploy: str = "gt", segnet: str | None = None) -> None:
        from brlcli.agent.command import is_command_model, load_navigation_agent
        from brlcli.agent.committee import load_lane_keeping_agent

        check_input_source(deploy)
        self.task = model_task(Path(model))
        command = is_command_model(model)
        if command != (self.task == "navigation"):
            raise BrlInputError(f"model {model} is {'' if command else 'not '}command-conditioned but its "
                                f"config.json says task {self.task}")
        self.agent = load_navigation_agent(model) if command else load_lane_keeping_agent(model)
        config = _training_config(Path(model))
        actions, state = str(config.get("actions", "paper")), str(config.get("state", "paper"))
        gated = bool(config.get("brake_gate_steps") or config.get("driver_model"))
        if gated and actions in GATE_DRIVER_ACTIONS:  # a brake gate's driver set and `stop`
            actions = GATE_DRIVER_ACTIONS[actions]
        if actions not in ACTION_SETS:
            raise BrlInputError(f"model {model}: {unknown_action_set(actions, ACTION_SETS)}")
        if state not in STATE_OPTIONS:
            raise BrlInputError(f"model {model}: its config.json names state '{state}', which this brl does not know "
                                f"({', '.join(STATE_OPTIONS)})")
        dim, n_actions = STATE_DIM + STATE_OPTIONS[state], len(ACTION_SETS[actions])
        if self.agent.state_dim == STATE_DIM and self.agent.n_actions == len(ACTIONS) - 1:
            raise BrlInputError(f"model {model} has no backward primitive: "
                                f"{retired_message('no_backward', RETIRED_CONFIG['no_backward'])}")
        if self.agent.state_dim != dim or self.agent.n_actions != n_actions:
            raise BrlInputError(f"model {model} has state size {self.agent.state_dim} and {self.agent.n_actions} "
                                f"actions, but its config.json's state '{state}' and action set '{actions}' need {dim} "
                                f"and {n_actions}")
        self.variant = model_variant(Path(model))
        label = self.variant if self.task == "lane-keeping" else f"{self.variant}, navigation"
        if self.task == "navigation":
            traits = action_set_traits(actions)
            brake = "brake gate" if gated else "stop primitive" if "stop primitive" in traits else "no brake"
            label += "".join(f", {t}" for t in traits if t != "stop primitive") + f", {brake}"
        if config.get("learning") == "imitation":
            label += ", imitating driver" if gated else ", imitation"
        if state != "paper":
            label += f", {state} state"
        stop_rule = str(config.get("stop_rule", "any"))
        if stop_rule not in STOP_RULES:
            raise BrlInputError(f"model {model}: its config.json names stop_rule '{stop_rule}', which this brl does "
                                f"not know ({', '.join(STOP_RULES)})")
        if stop_rule != "any":
            self.agent = with_stop_rule(self.agent, actions, stop_rule)
            label += ", stop only for road users in view"
        frames = int(config.get("decision_frames", FRAMES_PER_DECISION))
        if frames != FRAMES_PER_DECISION:
            label += f", a decision every {frames} frames"
        super().__init__(name, setting_name(model_training_input(Path(model)), deploy, label),
                         greedy_command_brl(self.agent) if command else greedy_brl(self.agent),
                         labeler_for(deploy, segnet), model_camera(Path(model)), uses_command=command,
                         actions=actions, state=state, decision_frames=frames)


class AutopilotPolicy:
    """The privileged expert of `brl collect` (route, lane geometry, traffic; no noise): a reference upper bound."""

    frames_per_decision = 1
    needs_camera = False
    setting = "autopilot"

    def __init__(self, name: str = "autopilot") -> None:
        self.name = name
        self._pilot: Any = None

    def reset(self, spec: EpisodeSpec, world: Any) -> None:
        """Plan the episode's route and drive it."""
        from brlcli.autopilot import Autopilot

        route = world.network.route(spec.start, spec.goal)
        self._pilot = Autopilot(world, route, np.random.default_rng(0), noise=None)

    def decide(self, obs: Observation) -> Control:
        """The expert's control for the current measurements."""
        return self._pilot.expert(obs.measurements)


STOP_ACTION = STOP
"""The fifth action primitive outside the paper (issue 20 feasibility check, issue 35 agent): brake to a stop."""
ORACLE_STOPS = ("never", "braking", "standstill")
"""When the oracle takes STOP_ACTION: never (the paper's actions), whenever the expert brakes, or only when the
expert wants to stand still (an obstacle ahead, the goal)."""


class OraclePolicy(AutopilotPolicy):
    """The privileged expert restricted to the BRL agent's action primitives (its steering quantised to forward,
    right or left: the nearest of 0 and +-`turn_steer`) and to a decision every `decision_frames` frames: whether
    the agent's action set can drive a route at all (issue 20's feasibility check; a list of `turn_steer` values gives
    a finer steering set, +-each, issue 35's check). The paper's primitives cannot
    brake, so the oracle does not stop for traffic unless `backward_brake` takes `backward` (reverse throttle) while
    the expert brakes and the car rolls forward, or `stop` adds a fifth primitive (no throttle, full brake; outside
    the paper), taken whenever the expert brakes (`stop="braking"`) or only when it wants to stand still, for an
    obstacle or at the goal (`stop="standstill"`); all measured in docs/navigation-study.md."""

    setting = "oracle"
    needs_camera = False

    def __init__(self, name: str = "oracle", decision_frames: int = FRAMES_PER_DECISION,
                 turn_steer: float | list[float] = float(ACTIONS[1].steer), stop: str = "never",
                 backward_brake: bool = False) -> None:
        super().__init__(name)
        if isinstance(decision_frames, bool) or not isinstance(decision_frames, int) or decision_frames < 1:
            raise BrlInputError(f"oracle decision_frames must be a positive integer, got {decision_frames!r}")
        steers = [turn_steer] if isinstance(turn_steer, int | float) else list(turn_steer)
        if not steers or any(isinstance(t, bool) or not isinstance(t, int | float) or not 0.0 < t <= 1.0
                             for t in steers):
            raise BrlInputError(f"oracle turn_steer must lie in (0, 1] (or be a list of such), got {turn_steer!r}")
        self.frames_per_decision = decision_frames
        forward, right = ACTIONS[0], ACTIONS[1]
        self._primitives = (forward, *(Control(steer=sign * float(t), throttle=right.throttle)
                                       for t in steers for sign in (1.0, -1.0)))
        if stop not in ORACLE_STOPS:
            raise BrlInputError(f"oracle stop must be one of {', '.join(ORACLE_STOPS)}, got {stop!r}")
        self._stop = stop
        self._backward_brake = bool(backward_brake)

    def decide(self, obs: Observation) -> Control:
        """`stop` or `backward` when the expert brakes (if enabled), else the primitive whose steering is nearest the
        expert's."""
        expert = self._pilot.expert(obs.measurements)
        if (self._stop == "braking" and expert.brake > 0.0) or \
                (self._stop == "standstill" and self._pilot.must_stop(obs.measurements)):
            return STOP_ACTION
        if self._backward_brake and expert.brake > 0.0 and obs.measurements.forward_speed_kmh > 0.0:
            return ACTIONS[3]
        return self._primitives[nearest_forward(self._primitives, expert.steer)]


