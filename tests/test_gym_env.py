"""The Gymnasium environment over a brl world."""

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
