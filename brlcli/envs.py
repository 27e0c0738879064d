"""Gymnasium ids of brl's driving tasks; importing this module registers them (docs/gymnasium.md).

    import gymnasium as gym
    import brlcli.envs  # noqa: F401  (registers the ids)
    env = gym.make("brl/LaneKeeping-v0", town="town01", weather=1, traffic="empty", input="gt")
    obs, info = env.reset(seed=0)

or, without the import, `gym.make("brlcli.envs:brl/LaneKeeping-v0")` (gymnasium imports the module named before the
colon). `import brlcli` does not import this module (nor gymnasium): the CLI stays quick.

`brl/LaneKeeping-v0` is the paper's task, the environment `brl train` and `brl train-rl` train on: the town's lane
keeping training routes, the 30-number state, the four action primitives and the paper's reward.
`brl/Navigation-v0` (issue 20, outside the paper) adds the junction routes, the route-following reward terms and the
route command of the next decision, one-hot, as four more observation entries (34 in all), as
`brl train-rl --task navigation` trains on. Seeding is gymnasium's: `reset(seed=N)` fixes the route, the start pose
and the traffic of the episode and of those after it.

`export_dqn` writes an SB3 DQN (MlpPolicy) trained on either id in the file `brl bench --agent dqn --model FILE`
reads.
"""

from __future__ import annotations

from pathlib import Path
from typing import Any

import gymnasium as gym
import numpy as np

from brlcli.errors import BrlInputError
from brlcli.features import STATE_DIM
from brlcli.reward import RewardParams, RouteRewardParams
from brlcli.sim.camera import CameraConfig
from brlcli.sim.gym_env import TRAFFIC_LEVELS, DrivingEnv
from brlcli.sim.navroutes import TASK_ROUTE_KINDS
from brlcli.sim.roadnet import BRANCH_NAMES, command_branch

LANE_KEEPING_ID = "brl/LaneKeeping-v0"
NAVIGATION_ID = "brl/Navigation-v0"
ENV_IDS = (LANE_KEEPING_ID, NAVIGATION_ID)
LANE_KEEPING_ROUTES = ("training", "lane_keeping", "validation")
"""Route sets a lane-keeping env can drive (the town's; `training` is what brl trains on)."""


def _traffic_levels(town: str, traffic: Any) -> tuple[str, ...]:
    """`traffic` (a level or a list of levels, each episode drawing one) as DrivingEnv's levels; () for empty alone."""
    from brlcli.sim.traffic import NOCRASH_TRAFFIC

    levels = (traffic,) if isinstance(traffic, str) else traffic
    if not isinstance(levels, list | tuple) or not levels or any(t not in TRAFFIC_LEVELS for t in levels):
        raise BrlInputError(f"traffic must be one of {', '.join(TRAFFIC_LEVELS)} or a list of them, got {traffic!r}")
    if tuple(dict.fromkeys(levels)) == ("empty",):
        return ()  # the paper's setting: no road users, and no NoCrash episode end
    if town not in NOCRASH_TRAFFIC:
        raise BrlInputError(f"traffic levels are defined for the shipped towns {', '.join(NOCRASH_TRAFFIC)} only, "
                            f"not '{town}'")
    return tuple(levels)


def _common_kwargs(task: str, town: str, weather: int | str, traffic: Any, input: str, segnet: str | None,
                   target_speed_kmh: float, camera_pitch_deg: float, offroad_end: float | None,
                   otherlane_end: float | None, start_offset_m: float, start_yaw_deg: float
                   ) -> tuple[dict[str, Any], dict[str, Any]]:
    """DrivingEnv's keyword arguments shared by both ids, validated with one-line BrlInputErrors, and the training
    settings `export_dqn` records beside a network (DeepRLConfig's names)."""
    from brlcli.segnet import check_input_source, labeler_for
    from brlcli.sim.town import available_towns, load_town
    from brlcli.sim.weather import get_weather

    if not isinstance(town, str):
        raise BrlInputError(f"town must be a town name or a town file path, got {town!r}")
    shipped = town.lower() in available_towns()
    load_town(town)  # unknown town or bad file: its one-line error before any world is built
    town = town.lower() if shipped else town
    weather_id = get_weather(weather).id
    check_input_source(input, "input")
    if segnet is not None and input != "estimated":
        raise BrlInputError("segnet is only used with input='estimated'")
    try:
        reward = RewardParams(target_speed_kmh=float(target_speed_kmh), road_view="road+line")
        camera = CameraConfig(pitch_deg=float(camera_pitch_deg))
        DrivingEnv.check_episode_rules(offroad_end, start_offset_m, start_yaw_deg, otherlane_end)
    except (TypeError, ValueError) as exc:
        raise BrlInputError(str(exc).splitlines()[0]) from None
    kwargs = {"town": town, "weather": weather_id, "traffic": _traffic_levels(town, traffic), "reward": reward,
              "camera": camera, "labeler": labeler_for(input, segnet, "input"), "offroad_end": offroad_end,
              "otherlane_end": otherlane_end, "start_offset_m": start_offset_m, "start_yaw_deg": start_yaw_deg}
    record = {"task": task, "town": town, "weather": weather_id, "input": input, "segnet": segnet,
              "target_speed_kmh": float(target_speed_kmh), "camera_pitch_deg": float(camera_pitch_deg),
              "offroad_end": offroad_end, "otherlane_end": otherlane_end, "start_offset_m": float(start_offset_m),
              "start_yaw_deg": float(start_yaw_deg)}
    return kwargs, record


class LaneKeepingEnv(DrivingEnv):
    """`brl/LaneKeeping-v0`: the paper's lane keeping, as `brl train` and `brl train-rl` train it.

    Keyword arguments: town (town01, town02 or a town file), weather (CARLA id or name), traffic (empty, regular,
    dense or a list of them, each episode drawing one; NoCrash's counts, a collision with a road user ends the
    episode), input (gt labels or estimated ones from the segmentation net `segnet`, default the shipped net),
    routes (the town's training, lane_keeping or validation routes), target_speed_kmh, camera_pitch_deg and the
    episode rules offroad_end / otherlane_end / start_offset_m / start_yaw_deg (as brl train's options), render_mode.
    """

    def __init__(self, town: str = "town01", weather: int | str = 1, traffic: str | list[str] = "empty",
                 input: str = "gt", segnet: str | None = None, routes: str = "training",
                 target_speed_kmh: float = 20.0, camera_pitch_deg: float = -15.0, offroad_end: float | None = 0.5,
                 otherlane_end: float | None = None, start_offset_m: float = 0.0, start_yaw_deg: float = 0.0,
                 render_mode: str | None = None) -> None:
        if routes not in LANE_KEEPING_ROUTES:
            raise BrlInputError(f"unknown route set '{routes}'; choose one of {', '.join(LANE_KEEPING_ROUTES)}")
        kwargs, self.brl_config = _common_kwargs("lane-keeping", town, weather, traffic, input, segnet,
                                                 target_speed_kmh, camera_pitch_deg, offroad_end, otherlane_end,
                                                 start_offset_m, start_yaw_deg)
        super().__init__(routes=routes, kinds=TASK_ROUTE_KINDS["lane-keeping"], render_mode=render_mode, **kwargs)


class NavigationEnv(DrivingEnv):
    """`brl/Navigation-v0` (outside the paper): lane-keeping and junction routes, the route-following reward, and the
    next decision's route command one-hot (follow lane, left, right, straight) after the 30-number state.

    Keyword arguments as `LaneKeepingEnv`'s (no `routes`: the town's training routes and the planner's junction
    routes), plus junction_weight (how much likelier a junction kind is drawn than a lane-keeping one; default 2).
    """

    def __init__(self, town: str = "town01", weather: int | str = 1, traffic: str | list[str] = "empty",
                 input: str = "gt", segnet: str | None = None, target_speed_kmh: float = 20.0,
                 camera_pitch_deg: float = -15.0, offroad_end: float | None = 0.5, otherlane_end: float | None = None,
                 start_offset_m: float = 0.0, start_yaw_deg: float = 0.0, junction_weight: float | None = None,
                 render_mode: str | None = None) -> None:
        if junction_weight is not None and not (isinstance(junction_weight, int | float) and junction_weight > 0):
            raise BrlInputError(f"junction_weight must be > 0, got {junction_weight!r}")
        kwargs, self.brl_config = _common_kwargs("navigation", town, weather, traffic, input, segnet,
                                                 target_speed_kmh, camera_pitch_deg, offroad_end, otherlane_end,
                                                 start_offset_m, start_yaw_deg)
        super().__init__(routes="navigation", kinds=TASK_ROUTE_KINDS["navigation"], render_mode=render_mode,
                         route_reward=RouteRewardParams(), junction_weight=junction_weight, **kwargs)
        self.observation_space = gym.spaces.Box(0.0, 1.0, shape=(STATE_DIM + len(BRANCH_NAMES),), dtype=np.float32)

    @staticmethod
    def _with_command(obs: np.ndarray, command: int) -> np.ndarray:
        onehot = np.zeros(len(BRANCH_NAMES), np.float32)
        onehot[int(command_branch(int(command)))] = 1.0
        return np.concatenate([obs, onehot])

    def reset(self, *, seed: int | None = None, options: dict[str, Any] | None = None) -> tuple[np.ndarray, dict]:
        """DrivingEnv's reset; the observation carries the first decision's route command."""
        obs, info = super().reset(seed=seed, options=options)
        return self._with_command(obs, info["command"]), info

    def step(self, action: int) -> tuple[np.ndarray, float, bool, bool, dict]:
        """DrivingEnv's step; the observation carries the next decision's route command."""
        obs, reward, terminated, truncated, info = super().step(action)
        return self._with_command(obs, info["command"]), reward, terminated, truncated, info


def export_dqn(model: Any, path: str | Path, env: gym.Env) -> Path:
    """Write an SB3 DQN (MlpPolicy) trained on a brl id as the Q-network file `brl bench --agent dqn --model PATH`
    runs (brlcli.baselines.deeprl's format: a plain state dict, never a pickle); returns the path written."""
    from brlcli.baselines.deeprl import DeepRLConfig, save_model
    from brlcli.sim.gym_env import ACTIONS

    base = env.unwrapped
    if not isinstance(base, LaneKeepingEnv | NavigationEnv):
        raise BrlInputError(f"export_dqn takes the env the model was trained on ({', '.join(ENV_IDS)})")
    q_net = getattr(getattr(model, "q_net", None), "q_net", None)
    if q_net is None or type(model).__name__ != "DQN":
        raise BrlInputError(f"brl bench runs SB3 DQN models with MlpPolicy only, not {type(model).__name__}")
    from torch import nn

    layout = [type(m) for m in q_net]
    if layout != [nn.Linear, nn.ReLU] * (len(layout) // 2) + [nn.Linear] or \
            type(model.q_net.features_extractor).__name__ != "FlattenExtractor":
        raise BrlInputError("brl bench runs MLP Q-networks with ReLU activations and no feature extractor (SB3's "
                            "MlpPolicy defaults)")
    n_in, n_out = base.observation_space.shape[0], len(ACTIONS)
    linears = [m for m in q_net if isinstance(m, nn.Linear)]
    if linears[0].in_features != n_in or linears[-1].out_features != n_out:
        raise BrlInputError(f"the model maps {linears[0].in_features} inputs to {linears[-1].out_features} actions; "
                            f"{base.spec.id if base.spec else type(base).__name__} has {n_in} and {n_out}")
    rec = dict(base.brl_config)
    lr = model.learning_rate if isinstance(model.learning_rate, int | float) else DeepRLConfig.learning_rate
    train_freq = int(model.train_freq.frequency)
    steps = max(int(model.num_timesteps), 1)
    cfg = DeepRLConfig(
        task=rec.pop("task"), town=rec.pop("town"), weather=rec.pop("weather"), input=rec.pop("input"),
        segnet=rec.pop("segnet"), steps=steps, eval_every=-(-steps // train_freq) * train_freq, eval_suite="none",
        seed=int(model.seed or 0), learning_rate=float(lr), buffer_size=int(model.buffer_size),
        learning_starts=int(model.learning_starts), batch_size=int(model.batch_size), gamma=float(model.gamma),
        train_freq=train_freq, target_update_interval=int(model.target_update_interval),
        exploration_fraction=float(model.exploration_fraction),
        exploration_final_eps=float(model.exploration_final_eps),
        net_arch=tuple(m.out_features for m in linears[:-1]), **rec)
    path = Path(path)
    save_model(path, q_net, cfg, int(model.num_timesteps))
    return path


def register_envs() -> None:
    """Register the ids (again only if they are missing)."""
    for env_id, cls in ((LANE_KEEPING_ID, LaneKeepingEnv), (NAVIGATION_ID, NavigationEnv)):
        if env_id not in gym.registry:
            gym.register(id=env_id, entry_point=f"{__name__}:{cls.__name__}")


register_envs()
