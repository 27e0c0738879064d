"""Gymnasium environment over a brl world: the paper's 30-number state, four action primitives and reward."""

from __future__ import annotations

import math
from collections.abc import Callable
from typing import Any, ClassVar

import gymnasium as gym
import numpy as np

from brlcli.autopilot import Autopilot
from brlcli.errors import BrlInputError
from brlcli.features import STATE_DIM, STATE_OPTIONS, agent_state, road_user_in_view
from brlcli.retired import unknown_action_set
from brlcli.reward import HazardRewardParams, RewardParams, RouteRewardParams, hazard_terms, reward_terms, route_terms
from brlcli.sim.camera import CameraConfig
from brlcli.sim.hazard import hazard_gap_m
from brlcli.sim.vehicle import Control
from brlcli.sim.world import FRAME_DT_S, World

#: The paper's action primitives (reference code values): forward, right, left, backward.
ACTIONS: tuple[Control, ...] = (
    Control(steer=0.0, throttle=0.5),
    Control(steer=0.4, throttle=0.35),
    Control(steer=-0.4, throttle=0.35),
    Control(steer=0.0, throttle=0.4, reverse=True),
)
ACTION_NAMES = ("forward", "right", "left", "backward")
STOP = Control(steer=0.0, throttle=0.0, brake=1.0)
"""A fifth primitive outside the paper (issue 35): no throttle, full brake."""
FINE_STEER = (0.15, 0.05)
"""Steering of the finer turn primitives of the `fine` action set (outside the paper, issue 35): with them (and a
brake) the expert restricted to an agent's actions keeps its lane beside oncoming traffic (docs/navigation-study.md)."""
FINE_ACTIONS = tuple(Control(steer=sign * s, throttle=ACTIONS[1].throttle) for s in FINE_STEER for sign in (1.0, -1.0))
FINE_NAMES = ("right_0.15", "left_0.15", "right_0.05", "left_0.05")
ACTION_SETS: dict[str, tuple[Control, ...]] = {"paper": ACTIONS, "stop": (*ACTIONS, STOP),
                                               "fine": (*ACTIONS, *FINE_ACTIONS),
                                               "fine_stop": (*ACTIONS, *FINE_ACTIONS, STOP)}
"""Action sets: the paper's four primitives; those and `stop`; those and four finer turns, right / left at
FINE_STEER; those and `stop` (all but the first outside the paper). Retired sets: `brlcli.retired`."""
ACTION_SET_NAMES = {"paper": ACTION_NAMES, "stop": (*ACTION_NAMES, "stop"), "fine": (*ACTION_NAMES, *FINE_NAMES),
                    "fine_stop": (*ACTION_NAMES, *FINE_NAMES, "stop")}


def action_set_traits(actions: str) -> list[str]:
    """How action set `actions` differs from the paper's four primitives, for settings: any of 'fine steering' and
    'stop primitive', read off the set's primitives."""
    primitives = ACTION_SETS[actions]
    traits = {"fine steering": FINE_ACTIONS, "stop primitive": (STOP,)}
    return [name for name, members in traits.items() if any(a in primitives for a in members)]


GATE_DRIVER_ACTIONS = {"paper": "stop", "fine": "fine_stop"}
"""A brake gate's driver action sets and the set its runs drive with: the driver's and `stop` last."""
STOP_RULES = ("any", "road_user")
"""Where a model with `stop` may take it: wherever its values pick it, or (outside the paper; issue 35) only where the
state shows a road user (`brlcli.features.road_user_in_view`): the teacher of `learning=imitation` then labels a stop
only there, and the driver, its evaluation and `brl bench` take it only there (`brlcli.agent.command.RoadUserStop`)."""
TRAFFIC_LEVELS = ("empty", "regular", "dense")
"""Training traffic levels (NoCrash's counts per town, `brlcli.sim.traffic.NOCRASH_TRAFFIC`)."""
FRAMES_PER_DECISION = 7
GOAL_TOLERANCE_M = 2.0
STUCK_SPEED_KMH = 1.0
STUCK_TIME_S = 5.0


def route_timeout_s(length_m: float) -> float:
    """CoRL2017 timeout: the route at 10 km/h plus 10 s."""
    return length_m / 1000.0 / 10.0 * 3600.0 + 10.0


def nearest_forward(actions: tuple[Control, ...], steer: float) -> int:
    """The index of the forward-driving primitive (throttle, not reverse) whose steering is nearest `steer` (the first
    of equals): how the oracle and `DrivingEnv.expert_action` quantise the expert's steering."""
    forward = [i for i, a in enumerate(actions) if a.throttle > 0.0 and not a.reverse]
    return min(forward, key=lambda i: abs(actions[i].steer - steer))


def action_distance(a: Control, b: Control) -> float:
    """How far primitive a is from primitive b, in [0, 1]: 0 for the same one, 1 for stop against driving or reverse
    against forward, else their steering difference over 0.4 (the paper's turn), at most 1."""
    if a == b:
        return 0.0
    if (a == STOP) != (b == STOP) or a.reverse != b.reverse:
        return 1.0
    return min(1.0, abs(a.steer - b.steer) / 0.4)


class DrivingEnv(gym.Env):
    """Lane keeping on a town's routes: observation = 30-vector state, 4 discrete actions, the paper's reward.

    An episode starts at a route drawn from `routes` ("training", "lane_keeping" or "validation" of the town) and
    ends at the goal (terminated), at the route's CoRL-style timeout or when stuck (truncated). With a `labeler`
    (RGB -> label image, e.g. the segmentation net) the state comes from estimated labels instead of ground truth.

    `routes="navigation"` (issue 20, outside the paper) drives the town's training routes and the planner's junction
    routes (`brlcli.sim.navroutes.junction_routes`, kinds turn_left / turn_right / go_straight, starting
    `junction_approaches_m` before the junction), drawing a kind (junction kinds `junction_weight` times as likely as
    the others; default KIND_WEIGHTS) and then a route of it, and, with `route_reward`, adds the
    route-following terms to the reward (progress along the route; a wrong turn, farther than `wrong_turn_m` from
    the route, ends the episode). Every step's info carries the route `command` (CARLA code) for the next decision.
    """

    metadata: ClassVar[dict[str, Any]] = {"render_modes": ["rgb_array"], "render_fps": 10}

    def __init__(self, town: str = "town01", weather: int | str = 1, routes: str = "training",
                 kinds: tuple[str, ...] = ("straight", "right_curve", "left_curve"), vehicles: int = 0,
                 pedestrians: int = 0, camera: CameraConfig | None = None, reward: RewardParams | None = None,
                 render_mode: str | None = None,
                 labeler: Callable[[np.ndarray], np.ndarray] | None = None, offroad_end: float | None = None,
                 start_offset_m: float = 0.0, start_yaw_deg: float = 0.0,
                 otherlane_end: float | None = None, route_reward: RouteRewardParams | None = None,
                 junction_weight: float | None = None, junction_approaches_m: tuple[float, ...] | None = None,
                 actions: str = "paper", traffic: tuple[str, ...] = (), hazard: HazardRewardParams | None = None,
                 state: str = "paper", r_stand: float = 0.0, road_user_contact: bool = True,
                 privileged_brake_m: float = 0.0, decision_frames: int = FRAMES_PER_DECISION,
                 stop_rule: str = "any") -> None:
        super().__init__()
        if stop_rule not in STOP_RULES:
            raise BrlInputError(f"unknown stop_rule '{stop_rule}'; choose one of {', '.join(STOP_RULES)}")
        self.stop_rule = stop_rule
        try:
            self.check_decision_frames(decision_frames)
        except ValueError as exc:
            raise BrlInputError(str(exc)) from None
        self.frames_per_decision = decision_frames  # the paper's 7; fewer is outside the paper
        try:
            self.check_traffic_options(actions, traffic, state, r_stand)
        except ValueError as exc:
            raise BrlInputError(str(exc)) from None
        if traffic and (vehicles or pedestrians):
            raise BrlInputError("give either traffic levels or vehicle and pedestrian counts, not both")
        self.actions = ACTION_SETS[actions]
        self.r_stand = float(r_stand)  # outside the paper: the cost per decision of standing where nothing is ahead
        self.privileged_brake_m = float(privileged_brake_m)  # outside the paper: see `step`
        self.state_option = state
        self.hazard = hazard
        self.traffic_levels = tuple(traffic)
        try:
            self.check_episode_rules(offroad_end, start_offset_m, start_yaw_deg, otherlane_end)
        except ValueError as exc:
            raise BrlInputError(str(exc)) from None
        self.otherlane_end = otherlane_end  # ... or more than this share of it is in the opposite lane
        self.offroad_end = offroad_end  # end the episode when more than this share of the footprint is off-road
        self.start_offset_m = float(start_offset_m)  # start pose: lateral offset ~ U(-a, a) m
        self.start_yaw_deg = float(start_yaw_deg)  # and heading offset ~ U(-b, b) degrees
        if traffic:  # one world per traffic level; each episode draws its level
            from brlcli.sim.traffic import NOCRASH_TRAFFIC

            self._worlds = {t: World(town, weather=weather, vehicles=NOCRASH_TRAFFIC[town][t][0],
                                     pedestrians=NOCRASH_TRAFFIC[town][t][1], camera=camera,
                                     road_user_contact=road_user_contact)
                            for t in dict.fromkeys(traffic)}
        else:
            self._worlds = {"": World(town, weather=weather, vehicles=vehicles, pedestrians=pedestrians,
                                      camera=camera, road_user_contact=road_user_contact)}
        self.world = next(iter(self._worlds.values()))
        self.traffic_level = next(iter(self._worlds))
        if routes == "navigation":
            from brlcli.sim.navroutes import JUNCTION_APPROACHES_M, junction_routes

            candidates = list(self.world.town.route_set("training")) + junction_routes(
                self.world.network, tuple(junction_approaches_m or JUNCTION_APPROACHES_M))
        else:
            candidates = list(self.world.town.route_set(routes))
        self.routes = [r for r in candidates if r.kind in kinds]
        self.route_reward = route_reward
        self._by_kind: list[list] | None = None
        if routes == "navigation":
            from brlcli.sim.navroutes import KIND_WEIGHTS

            kinds_here = list(dict.fromkeys(r.kind for r in self.routes))
            self._by_kind = [[r for r in self.routes if r.kind == k] for k in kinds_here]
            kind_weights = KIND_WEIGHTS if junction_weight is None else dict.fromkeys(KIND_WEIGHTS, junction_weight)
            weights = np.array([kind_weights.get(k, 1.0) for k in kinds_here])
            self._kind_cdf = np.cumsum(weights / weights.sum())
        if not self.routes:
            raise BrlInputError(f"town {self.world.town.name} has no {routes} routes of kinds {', '.join(kinds)}")
        self.reward_params = reward or RewardParams()
        self.labeler = labeler  # RGB -> estimated labels (the paper's "estimated" input); None = ground truth
        self.render_mode = render_mode
        for w in self._worlds.values():
            w.rgb_frames = labeler is not None or render_mode == "rgb_array"  # GT states need no RGB image
        self.observation_space = gym.spaces.Box(0.0, 1.0, shape=(STATE_DIM + STATE_OPTIONS[state],),
                                                dtype=np.float32)
        self.action_space = gym.spaces.Discrete(len(self.actions))
        self._rgb: np.ndarray | None = None

    @staticmethod
    def check_decision_frames(decision_frames: int) -> None:
        """ValueError unless decision_frames is an integer in 1..20 (the paper's 7)."""
        if isinstance(decision_frames, bool) or not isinstance(decision_frames, int) or not 1 <= decision_frames <= 20:
            raise ValueError(f"decision_frames must be an integer in 1..20 (the paper's 7), got {decision_frames!r}")

    @staticmethod
    def check_episode_rules(offroad_end: float | None, start_offset_m: float, start_yaw_deg: float,
                            otherlane_end: float | None = None) -> None:
        """ValueError unless offroad_end and otherlane_end are None or in [0, 1] and the start offsets are >= 0."""
        for name, value in (("offroad_end", offroad_end), ("otherlane_end", otherlane_end)):
            if value is not None and not 0.0 <= value <= 1.0:
                raise ValueError(f"{name} must lie in [0, 1], got {value}")
        if not (start_offset_m >= 0 and start_yaw_deg >= 0):
            raise ValueError(f"start_offset_m and start_yaw_deg must be >= 0, got {start_offset_m}, {start_yaw_deg}")

    @staticmethod
    def check_traffic_options(actions: str, traffic: Any, state: str, r_stand: float) -> None:
        """ValueError unless the action set, the traffic levels (a list or tuple), the state option and r_stand >= 0
        are ones this environment knows (issue 35's options, outside the paper)."""
        if actions not in ACTION_SETS:
            raise ValueError(unknown_action_set(actions, ACTION_SETS))
        if state not in STATE_OPTIONS:
            raise ValueError(f"unknown state option '{state}'; choose one of {', '.join(STATE_OPTIONS)}")
        if not isinstance(traffic, list | tuple) or any(t not in TRAFFIC_LEVELS for t in traffic):
            raise ValueError(f"traffic must be a list of levels from {', '.join(TRAFFIC_LEVELS)}, got {traffic!r}")
        if isinstance(r_stand, bool) or not isinstance(r_stand, int | float) or not r_stand >= 0:
            raise ValueError(f"r_stand must be >= 0, got {r_stand!r}")

    def _observe(self, frame: Any) -> np.ndarray:
        self._rgb = frame.rgb
        self._last_m = frame.measurements
        labels = frame.labels if self.labeler is None else self.labeler(frame.rgb)
        self._state = agent_state(labels, frame.depth, self.state_option, frame.measurements.forward_speed_kmh)
        return self._state.astype(np.float32)

    def reset(self, *, seed: int | None = None, options: dict[str, Any] | None = None) -> tuple[np.ndarray, dict]:
        """Draw a route (or take `options['route']`, a route name) and start at its first pose."""
        super().reset(seed=seed)
        name = (options or {}).get("route")
        if name is not None:
            matches = [r for r in self.routes if r.name == name]
            if not matches:
                raise BrlInputError(f"unknown route '{name}'")
            spec = matches[0]
        elif self._by_kind is not None:  # navigation: a kind (KIND_WEIGHTS), then one of its routes
            k = min(int(np.searchsorted(self._kind_cdf, self.np_random.random(), side="right")), len(self._by_kind) - 1)
            group = self._by_kind[k]
            spec = group[int(self.np_random.integers(len(group)))]
        else:
            spec = self.routes[int(self.np_random.integers(len(self.routes)))]
        if len(self._worlds) > 1:
            self.traffic_level = self.traffic_levels[int(self.np_random.integers(len(self.traffic_levels)))]
            self.world = self._worlds[self.traffic_level]
        self.spec_route = spec
        self.route = self.world.network.route(spec.start, spec.goal)
        self.timeout_s = route_timeout_s(self.route.length_m)
        start = spec.start
        if self.start_offset_m > 0 or self.start_yaw_deg > 0:
            lateral, dyaw = self.np_random.uniform(-1.0, 1.0, size=2) * (self.start_offset_m, self.start_yaw_deg)
            yaw = np.radians(start[2])
            start = (start[0] - lateral * np.sin(yaw), start[1] + lateral * np.cos(yaw), start[2] + dyaw)
        frame = self.world.reset(start, seed=int(self.np_random.integers(2**31)))
        self._collision_total = 0.0
        self._road_user_total = 0.0
        self._stuck_s = 0.0
        m = frame.measurements
        self._route_s, _ = self.route.project(m.x, m.y)
        return self._observe(frame), {"route": spec.name, "route_length_m": self.route.length_m,
                                      "command": int(self.route.command_at(self._route_s)),
                                      **({"traffic": self.traffic_level} if self.traffic_levels else {})}

    def step(self, action: int) -> tuple[np.ndarray, float, bool, bool, dict]:
        """Hold the action's control for `decision_frames` frames (the paper's 7), render the last one, and score it.
        With `privileged_brake_m` (in traffic; outside the paper) the control is the stop primitive instead wherever
        the privileged hazard gap along the route (road users predicted 0-2 s ahead, the expert's test) is under that
        distance, and info["overridden"] says so: a driver learns among road users with a teacher's brake."""
        if not self.action_space.contains(action):
            raise BrlInputError(f"action {action!r} is not one of 0..{len(self.actions) - 1}")
        control = self.actions[int(action)]
        overridden = False
        if self.privileged_brake_m > 0 and self.traffic_levels:
            lm = self._last_m
            if hazard_gap_m(self.world.traffic, self.route, lm.x, lm.y, lm.yaw_deg) < self.privileged_brake_m:
                control, overridden = STOP, True
        for k in range(self.frames_per_decision):
            frame = self.world.step(control, render=k == self.frames_per_decision - 1)
        m = frame.measurements
        total = m.collision_vehicles + m.collision_pedestrians + m.collision_other
        collided = total > self._collision_total
        self._collision_total = total
        obs = self._observe(frame)
        hit_road_user = collided and m.collision_vehicles + m.collision_pedestrians > self._road_user_total
        self._road_user_total = m.collision_vehicles + m.collision_pedestrians
        terms = reward_terms(collided, m.intersection_offroad, m.intersection_otherlane, m.forward_speed_kmh,
                             self._state[:STATE_DIM], self.reward_params)
        vt = self.reward_params.target_speed_kmh
        gap, v_target = math.inf, vt
        if self.hazard is not None:
            gap = hazard_gap_m(self.world.traffic, self.route, m.x, m.y, m.yaw_deg, self.hazard.predict_times_s)
            v_target = self.hazard.target_kmh(gap, vt)
            terms = hazard_terms(m.forward_speed_kmh, gap, terms, self.reward_params, self.hazard)
        if self.r_stand and v_target >= vt and abs(m.forward_speed_kmh) < STUCK_SPEED_KMH:
            terms = {**terms, "stand": -self.r_stand, "total": terms["total"] - self.r_stand}
        s, lateral = self.route.project(m.x, m.y)
        wrong_turn = False
        if self.route_reward is not None:
            expected = v_target / 3.6 * self.frames_per_decision * FRAME_DT_S
            extra = route_terms(s - self._route_s, expected, lateral, self.route_reward)
            wrong_turn = extra["wrong_turn"] < 0.0
            terms = {**terms, **extra, "total": terms["total"] + extra["progress"] + extra["wrong_turn"]}
        self._route_s = s
        dist_goal = float(np.hypot(m.x - self.route.goal[0], m.y - self.route.goal[1]))
        terminated = dist_goal <= GOAL_TOLERANCE_M or s >= self.route.length_m - GOAL_TOLERANCE_M
        waiting = v_target < vt  # standing for a hazard is not being stuck
        self._stuck_s = self._stuck_s + self.frames_per_decision * FRAME_DT_S if abs(m.forward_speed_kmh) < \
            STUCK_SPEED_KMH and not waiting else 0.0
        left_lane = (self.offroad_end is not None and m.intersection_offroad > self.offroad_end) or \
            (self.otherlane_end is not None and m.intersection_otherlane > self.otherlane_end)
        crashed = hit_road_user and bool(self.traffic_levels)  # NoCrash: a collision with a road user ends it
        truncated = not terminated and (m.game_time_s >= self.timeout_s or self._stuck_s >= STUCK_TIME_S
                                        or left_lane or wrong_turn or crashed)
        info = {"reward_terms": terms, "measurements": m.as_dict(), "route_s_m": s, "collided": collided,
                "left_lane": left_lane, "wrong_turn": wrong_turn, "command": int(self.route.command_at(s)),
                "crashed": crashed, "hazard_gap_m": gap, "traffic": self.traffic_level, "overridden": overridden}
        return obs, float(terms["total"]), bool(terminated), bool(truncated), info

    def expert_action(self) -> int:
        """The index of the action nearest the privileged expert's control at the last observation (outside the
        paper; the teacher of `learning=imitation`, brlcli.imitation): `stop` where the set has it and the expert wants
        to stand still (a hazard within its stopping gap, or the goal; the oracle's `--stop standstill`), else the
        forward-driving primitive whose steering is nearest the expert's (the oracle's quantisation). Not every
        braking of the expert: it also brakes to slow down for turns, which the 30 numbers cannot tell from standing
        (they carry no speed), so a stop learned there would hold a standing car. With `stop_rule` road_user, a stop
        only where the state shows a road user: elsewhere the agent could not see why."""
        pilot = Autopilot(self.world, self.route, np.random.default_rng(0))
        visible = self.stop_rule == "any" or road_user_in_view(self._state)
        if STOP in self.actions and visible and pilot.must_stop(self._last_m):
            return self.actions.index(STOP)
        return nearest_forward(self.actions, pilot.expert(self._last_m).steer)

    def render(self) -> np.ndarray | None:
        """The last rendered RGB frame."""
        return self._rgb

    def close(self) -> None:
        """Release the worlds' physics clients."""
        for w in self._worlds.values():
            w.close()
