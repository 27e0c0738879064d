"""The training choices the lane-keeping study varies: road-view share, episode rules, the state camera."""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np
import pytest

from brlcli.classes import CarlaClass
from brlcli.errors import BrlInputError
from brlcli.features import road_share, state_vector
from brlcli.policy import model_camera
from brlcli.reward import RewardParams, reward_terms
from brlcli.sim.camera import CameraConfig
from brlcli.sim.gym_env import DrivingEnv
from brlcli.trainconfig import TrainConfig


def test_road_view_counts_road_lines_when_asked() -> None:
    labels = np.full((10, 10), CarlaClass.SIDEWALKS, np.uint8)
    labels[5:, :4] = CarlaClass.ROADS  # 20 road pixels
    labels[9, 5] = CarlaClass.ROAD_LINES  # one line pixel = 20
    s = state_vector(labels)
    total = 79 + 20 + 20
    assert road_share(s) == pytest.approx(20 / total)
    assert road_share(s, (0, 1)) == pytest.approx(40 / total)
    t_road = reward_terms(False, 0, 0, 25.0, s, RewardParams(road_view="road"))
    t_line = reward_terms(False, 0, 0, 25.0, s, RewardParams(road_view="road+line"))
    assert t_road["road_view"] == pytest.approx(20 * (20 / total - 1))
    assert t_line["road_view"] == pytest.approx(20 * (40 / total - 1))
    with pytest.raises(ValueError, match="road_view"):
        RewardParams(road_view="lines")


@pytest.mark.parametrize(("change", "words"), [
    ({"road_view": "sky"}, "road_view"), ({"offroad_end": 1.5}, "offroad_end"),
    ({"start_offset_m": -1.0}, "start_offset_m"), ({"target_speed_kmh": 0.0}, "target_speed_kmh"),
])
def test_bad_study_options_are_input_errors(change: dict, words: str) -> None:
    with pytest.raises(BrlInputError, match=words):
        TrainConfig(**change)


def test_start_perturbation_is_seeded_and_bounded() -> None:
    env = DrivingEnv("town01", start_offset_m=0.5, start_yaw_deg=5.0)
    plain = DrivingEnv("town01")
    route = env.routes[0].name
    poses = []
    for seed in (1, 1, 2):
        env.reset(seed=seed, options={"route": route})
        poses.append((env.world.ego.x_m, env.world.ego.y_m, env.world.ego.yaw_rad))
    plain.reset(seed=1, options={"route": route})
    ref = (plain.world.ego.x_m, plain.world.ego.y_m, plain.world.ego.yaw_rad)
    assert poses[0] == poses[1] and poses[0] != poses[2]
    for x, y, yaw in poses:
        assert 0 < np.hypot(x - ref[0], y - ref[1]) <= 0.5 + 1e-9
        assert abs(np.degrees(yaw - ref[2])) <= 5.0 + 1e-9
    env.close()
    plain.close()


def test_offroad_end_truncates_the_episode() -> None:
    env = DrivingEnv("town01", offroad_end=0.5)
    env.reset(seed=0, options={"route": env.routes[0].name})
    for _ in range(60):  # hard right onto the sidewalk
        _, _, terminated, truncated, info = env.step(1)
        if truncated or terminated:
            break
    assert truncated and info["left_lane"] and info["measurements"]["intersection_offroad"] > 0.5
    env.close()


def test_bench_sees_through_the_models_training_camera(tmp_path: Path) -> None:
    model = tmp_path / "model.npz"
    (tmp_path / "config.json").write_text(json.dumps({"config": TrainConfig(camera_pitch_deg=-30.0).to_dict()}))
    assert model_camera(model) == CameraConfig(pitch_deg=-30.0)
    (tmp_path / "config.json").write_text(json.dumps({"config": TrainConfig().to_dict()}))
    assert model_camera(model) is None
    assert TrainConfig(camera_pitch_deg=-30.0).camera().pitch_deg == -30.0


def test_configs_written_before_the_study_keep_brl_0_1_choices() -> None:
    old = {k: v for k, v in TrainConfig().to_dict().items()
           if k not in ("camera_pitch_deg", "road_view", "offroad_end", "start_offset_m", "start_yaw_deg",
                        "otherlane_end")}
    old["params"] = {}
    cfg = TrainConfig.from_dict(old)
    assert cfg.road_view == "road" and cfg.offroad_end is None and cfg.agent_params().init_scatter == 0.1
    new = TrainConfig()
    assert new.road_view == "road+line" and new.offroad_end == 0.5 and new.agent_params().init_scatter == 1e-3
    assert TrainConfig.from_dict(new.to_dict()) == new


def test_route_pose_at_walks_the_route() -> None:
    env = DrivingEnv(routes="training", kinds=("right_curve",))
    try:
        env.reset(seed=0)
        route = env.route
        assert route.pose_at(0.0)[:2] == pytest.approx(route.points[0])
        x, y, _yaw = route.pose_at(route.length_m / 2)
        assert route.project(x, y)[0] == pytest.approx(route.length_m / 2, abs=1e-6)
        assert route.pose_at(1e9)[:2] == pytest.approx(route.points[-1])
    finally:
        env.close()
