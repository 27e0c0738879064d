"""The Gymnasium environment over a brl world."""

from typing import Any

import numpy as np
import pytest
from gymnasium.utils.env_checker import check_env

from brlcli.errors import BrlInputError
from brlcli.sim.gym_env import ACTIONS, DrivingEnv


@pytest.fixture(scope="module")
def env() -> DrivingEnv:
    e = DrivingEnv(town="town01", routes="training")
    yield e
    e.close()


@pytest.mark.parametrize("town", ["town01", "town02"])
def test_env_passes_gymnasium_checker(town: str) -> None:
    env = DrivingEnv(town=town, routes="lane_keeping")
    check_env(env, skip_render_check=True)
    env.close()


def test_observation_is_normalised_state(env: DrivingEnv) -> None:
    obs, info = env.reset(seed=3)
    assert obs.shape == (30,) and obs.dtype == np.float32
    assert obs.sum() == pytest.approx(1.0, abs=1e-5)
    assert info["route_length_m"] > 50


def test_ground_truth_env_renders_no_rgb_unless_asked(env: DrivingEnv) -> None:
    env.reset(seed=3)
    env.step(0)
    assert env.world.rgb_frames is False and env.render() is None
    with DrivingEnv(town="town01", routes="training", render_mode="rgb_array") as shown:
        shown.reset(seed=3)
        obs, *_ = shown.step(0)
        assert shown.render().shape == (shown.world.camera.height, shown.world.camera.width, 3)
    env.reset(seed=3)
    assert np.array_equal(env.step(0)[0], obs)  # the state is the same with or without the RGB image


def test_same_seed_same_episode(env: DrivingEnv) -> None:
    def run(seed: int) -> list:
        obs, _ = env.reset(seed=seed)
        out = [obs]
        for a in [0, 0, 1, 2, 0, 3, 0]:
            obs, r, _term, _trunc, info = env.step(a)
            out.append((obs, r, info["measurements"]["x"], info["measurements"]["y"]))
        return out

    a, b = run(11), run(11)
    np.testing.assert_array_equal(a[0], b[0])
    for x, y in zip(a[1:], b[1:], strict=True):
        np.testing.assert_array_equal(x[0], y[0])
        assert x[1:] == y[1:]


def test_forward_gets_no_speed_penalty_at_cruise_and_reward_terms_named(env: DrivingEnv) -> None:
    env.reset(seed=0, options={"route": env.routes[0].name})
    infos = [env.step(0)[4] for _ in range(8)]
    terms = infos[-1]["reward_terms"]
    assert set(terms) >= {"collision", "offroad", "otherlane", "speed", "road_view", "total"}
    assert infos[-1]["measurements"]["forward_speed_kmh"] > 15
    assert len(ACTIONS) == 4


def test_bad_route_and_action_are_clear_errors(env: DrivingEnv) -> None:
    with pytest.raises(BrlInputError):
        env.reset(seed=0, options={"route": "no-such-route"})
    env.reset(seed=0)
    with pytest.raises(BrlInputError):
        env.step(7)


# ---------------------------------------------------------------------------------------------- traffic (issue 35)
@pytest.fixture(scope="module")
def traffic_env() -> DrivingEnv:
    from brlcli.reward import HazardRewardParams, RouteRewardParams

    e = DrivingEnv(town="town01", routes="navigation", actions="stop", traffic=("regular", "dense"),
                   hazard=HazardRewardParams(), state="nearness", route_reward=RouteRewardParams())
    yield e
    e.close()


def test_traffic_env_passes_gymnasium_checker(traffic_env: DrivingEnv) -> None:
    check_env(traffic_env, skip_render_check=True)
    assert traffic_env.action_space.n == 5 and traffic_env.observation_space.shape == (33,)


def test_the_stop_primitive_brakes_to_a_standstill(traffic_env: DrivingEnv) -> None:
    traffic_env.reset(seed=1)
    for _ in range(4):
        traffic_env.step(0)
    assert traffic_env.world.ego.speed_ms > 1.0
    for _ in range(3):
        *_, info = traffic_env.step(4)
    assert abs(info["measurements"]["forward_speed_kmh"]) < 0.5


def clear_road_users(env: DrivingEnv, pedestrians: bool = True) -> Any:
    """Hold every vehicle (and pedestrian) of the env's world far away; returns its traffic."""
    t = env.world.traffic
    for i in range(t.n_vehicles):
        t.hold_vehicle(i, -1e4 - 10 * i, -1e4, 0.0)
    for i in range(t.n_pedestrians if pedestrians else 0):
        t.hold_pedestrian(i, 1e4 + 10 * i, 1e4)
    return t


def test_a_privileged_brake_stops_the_car_at_a_hazard_and_says_so() -> None:
    from brlcli.reward import RouteRewardParams

    env = DrivingEnv(town="town01", routes="navigation", traffic=("regular",), route_reward=RouteRewardParams(),
                     privileged_brake_m=8.0)
    try:
        env.reset(seed=2)
        t = clear_road_users(env)
        *_, info = env.step(0)
        assert not info["overridden"]  # nothing near: the agent's forward
        m = env.world.ego
        s, _ = env.route.project(m.x_m, m.y_m)
        t.hold_vehicle(0, *env.route.pose_at(s + 9.0))  # a standing car 9 m ahead on the route
        for _ in range(8):
            *_, info = env.step(0)  # the agent keeps asking for forward
        assert info["overridden"] and not info["crashed"]
        assert abs(info["measurements"]["forward_speed_kmh"]) < 0.5
    finally:
        env.close()


def test_the_expert_action_drives_a_route_and_brakes_where_the_set_has_stop() -> None:
    from brlcli.reward import RouteRewardParams
    from brlcli.sim.gym_env import ACTION_SETS, STOP

    env = DrivingEnv(town="town01", routes="navigation", actions="fine", route_reward=RouteRewardParams())
    try:
        env.reset(seed=3)
        for _ in range(200):
            a = env.expert_action()
            assert env.actions[a].throttle > 0 and not env.actions[a].reverse
            *_, terminated, truncated, info = env.step(a)
            if terminated or truncated:
                break
        assert terminated, "the expert's nearest primitives reach the goal of an empty route"
    finally:
        env.close()
    env = DrivingEnv(town="town01", routes="navigation", actions="fine_stop", traffic=("regular",),
                     route_reward=RouteRewardParams())
    try:
        env.reset(seed=2)
        t = clear_road_users(env)
        env.step(0)
        assert env.expert_action() != ACTION_SETS["fine_stop"].index(STOP)
        m = env.world.ego
        s, _ = env.route.project(m.x_m, m.y_m)
        t.hold_vehicle(0, *env.route.pose_at(s + 6.0))  # a standing car 6 m ahead: the expert brakes
        env.step(0)
        assert env.expert_action() == ACTION_SETS["fine_stop"].index(STOP)
    finally:
        env.close()


def test_the_action_distance_is_zero_for_the_same_action_and_one_for_stop_against_driving() -> None:
    from brlcli.sim.gym_env import ACTION_SET_NAMES, ACTION_SETS, action_distance, nearest_forward

    c = dict(zip(ACTION_SET_NAMES["fine_stop"], ACTION_SETS["fine_stop"], strict=True))
    assert action_distance(c["forward"], c["forward"]) == 0.0
    assert action_distance(c["stop"], c["forward"]) == action_distance(c["backward"], c["left"]) == 1.0
    assert action_distance(c["right_0.05"], c["forward"]) == pytest.approx(0.125)
    assert action_distance(c["right"], c["left"]) == 1.0
    names = ACTION_SET_NAMES["fine_stop"]
    assert names[nearest_forward(ACTION_SETS["fine_stop"], 0.07)] == "right_0.05"  # never stop nor backward
    assert names[nearest_forward(ACTION_SETS["fine_stop"], -1.0)] == "left"


def test_episodes_draw_their_traffic_level(traffic_env: DrivingEnv) -> None:
    levels = {traffic_env.reset(seed=s)[1]["traffic"] for s in range(12)}
    assert levels == {"regular", "dense"}


def test_a_car_ahead_lowers_the_target_and_waiting_for_it_is_not_being_stuck(traffic_env: DrivingEnv) -> None:
    obs, info = traffic_env.reset(seed=2)
    t = clear_road_users(traffic_env)
    m = traffic_env.world.ego
    s, _ = traffic_env.route.project(m.x_m, m.y_m)
    x, y, yaw = traffic_env.route.pose_at(s + 9.0)
    t.hold_vehicle(0, x, y, yaw)  # a standing car 9 m ahead on the route
    for _ in range(12):  # about 8 s standing: more than STUCK_TIME_S
        obs, reward, terminated, truncated, info = traffic_env.step(4)
        assert not (terminated or truncated)
    assert info["hazard_gap_m"] < 5.0 and info["reward_terms"]["speed"] == 0.0
    assert info["reward_terms"]["progress"] == 0.0  # no progress is expected at a hazard
    assert obs[31] > 0.5  # the middle column's nearness sees the car


def test_hitting_a_road_user_ends_a_traffic_episode(traffic_env: DrivingEnv) -> None:
    traffic_env.reset(seed=2)
    t = clear_road_users(traffic_env, pedestrians=False)
    m = traffic_env.world.ego
    s, _ = traffic_env.route.project(m.x_m, m.y_m)
    x, y, yaw = traffic_env.route.pose_at(s + 12.0)
    t.hold_vehicle(0, x, y, yaw)
    for _ in range(15):
        *_, truncated, info = traffic_env.step(0)
        if truncated:
            break
    assert truncated and info["crashed"] and info["reward_terms"]["collision"] < 0


def test_unknown_traffic_options_are_one_line_errors() -> None:
    for kwargs, match in (({"actions": "brake"}, "action set"), ({"state": "depth"}, "state option"),
                          ({"traffic": ("heavy",)}, "traffic must be a list of levels"),
                          ({"traffic": ("dense",), "vehicles": 3}, "not both")):
        with pytest.raises(BrlInputError, match=match):
            DrivingEnv(town="town01", **kwargs)


def test_standing_where_nothing_is_ahead_costs_r_stand() -> None:
    env = DrivingEnv(town="town01", routes="navigation", actions="stop", r_stand=50.0)
    env.reset(seed=4)
    *_, info = env.step(4)
    assert info["reward_terms"]["stand"] == -50.0
    *_, info = env.step(0)
    assert "stand" not in info["reward_terms"]
    env.close()
    with pytest.raises(BrlInputError, match="r_stand"):
        DrivingEnv(town="town01", r_stand=-1.0)

