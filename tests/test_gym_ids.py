"""The Gymnasium ids brl/LaneKeeping-v0 and brl/Navigation-v0 (brlcli.envs, docs/gymnasium.md)."""

from __future__ import annotations

import subprocess
import sys
import warnings

import gymnasium as gym
import numpy as np
import pytest
from gymnasium.utils.env_checker import check_env

from brlcli.envs import ENV_IDS, LANE_KEEPING_ID, NAVIGATION_ID, export_dqn
from brlcli.errors import BrlInputError


def test_import_brlcli_leaves_gymnasium_unimported() -> None:
    code = "import sys, brlcli; assert 'gymnasium' not in sys.modules and 'brlcli.envs' not in sys.modules"
    subprocess.run([sys.executable, "-c", code], check=True)


def test_the_module_colon_id_form_registers_the_ids_itself() -> None:
    code = ("import gymnasium as gym; env = gym.make('brlcli.envs:brl/Navigation-v0'); "
            "print(env.observation_space.shape, env.action_space.n)")
    out = subprocess.run([sys.executable, "-c", code], check=True, capture_output=True, text=True).stdout
    assert out.split() == ["(34,)", "4"]


@pytest.mark.parametrize(("env_id", "obs_dim"), [(LANE_KEEPING_ID, 30), (NAVIGATION_ID, 34)])
def test_ids_pass_the_env_checker_and_seeded_resets_repeat(env_id: str, obs_dim: int) -> None:
    env = gym.make(env_id)  # with gymnasium's passive checker
    try:
        assert env.observation_space.shape == (obs_dim,) and env.action_space.n == 4
        with warnings.catch_warnings():
            warnings.simplefilter("error")  # the checkers only warn: any warning fails
            check_env(env.unwrapped)
            obs, info = env.reset(seed=7)
            again, info_again = env.reset(seed=7)
            np.testing.assert_array_equal(obs, again)
            assert info == info_again
            for _ in range(20):
                obs, reward, terminated, truncated, info = env.step(env.action_space.sample())
                assert env.observation_space.contains(obs) and np.isfinite(reward)
                if terminated or truncated:
                    env.reset()
    finally:
        env.close()


def test_navigation_observation_ends_with_the_command_one_hot() -> None:
    from brlcli.sim.roadnet import command_branch

    env = gym.make(NAVIGATION_ID, traffic=["regular", "dense"])
    try:
        obs, info = env.reset(seed=1)
        for _ in range(5):
            onehot = np.zeros(4, np.float32)
            onehot[int(command_branch(info["command"]))] = 1.0
            np.testing.assert_array_equal(obs[30:], onehot)
            assert info["traffic"] in ("regular", "dense")
            obs, _, _, _, info = env.step(0)
    finally:
        env.close()


@pytest.mark.parametrize(("kwargs", "message"), [
    ({"town": "town09"}, "unknown town 'town09'"),
    ({"traffic": "heavy"}, "traffic must be one of empty, regular, dense"),
    ({"traffic": ["regular", "rush"]}, "traffic must be one of empty, regular, dense"),
    ({"input": "rgb"}, "input must be gt or estimated"),
    ({"segnet": "net.pt"}, "segnet is only used with input='estimated'"),
    ({"weather": 99}, "unknown weather '99'"),
    ({"offroad_end": 2.0}, "offroad_end must lie in [0, 1]"),
    ({"routes": "everything"}, "unknown route set 'everything'"),
])
def test_bad_keywords_raise_one_line_errors(kwargs: dict, message: str) -> None:
    with pytest.raises(BrlInputError) as exc:
        gym.make(LANE_KEEPING_ID, **kwargs)
    assert message in str(exc.value) and "\n" not in str(exc.value)


def test_navigation_refuses_a_bad_junction_weight_and_an_unknown_keyword() -> None:
    with pytest.raises(BrlInputError, match="junction_weight must be > 0"):
        gym.make(NAVIGATION_ID, junction_weight=0)
    with pytest.raises(TypeError, match="twon"):
        gym.make(NAVIGATION_ID, twon="town01")


def test_both_ids_are_registered() -> None:
    assert set(ENV_IDS) <= set(gym.registry)


def test_an_exported_sb3_dqn_benches_with_the_same_greedy_actions(tmp_path) -> None:
    pytest.importorskip("stable_baselines3")
    from stable_baselines3 import DQN

    from brlcli.baselines.deeprl import DeepRLPolicy, greedy_action_fn, load_model

    env = gym.make(LANE_KEEPING_ID, weather="WetNoon")
    try:
        model = DQN("MlpPolicy", env, policy_kwargs={"net_arch": [32, 16]}, seed=0, device="cpu")
        path = export_dqn(model, tmp_path / "drl.pt", env)
        net, meta = load_model(path)
        assert meta["train"]["task"] == "lane-keeping" and meta["train"]["weather"] == 3
        assert meta["train"]["net_arch"] == [32, 16]
        act = greedy_action_fn(net)
        states = np.random.default_rng(0).random((16, 30), dtype=np.float32)
        assert [act(s) for s in states] == [int(model.predict(s, deterministic=True)[0]) for s in states]
        assert DeepRLPolicy(model=str(path)).setting == "DQN-TGDG"
        with pytest.raises(BrlInputError, match="SB3 DQN models with MlpPolicy only"):
            export_dqn(object(), tmp_path / "x.pt", env)
        import torch

        tanh = DQN("MlpPolicy", env, policy_kwargs={"activation_fn": torch.nn.Tanh}, device="cpu")
        with pytest.raises(BrlInputError, match="ReLU activations"):
            export_dqn(tanh, tmp_path / "x.pt", env)
    finally:
        env.close()


@pytest.mark.slow
def test_estimated_input_passes_the_env_checker() -> None:
    env = gym.make(LANE_KEEPING_ID, input="estimated")  # the shipped segmentation net
    try:
        check_env(env.unwrapped)
        obs, _ = env.reset(seed=0)
        np.testing.assert_array_equal(obs, env.reset(seed=0)[0])
    finally:
        env.close()
