"""The modular-pipeline baseline: ground projection, lane keeping through the bench runner, input checks."""

import math

import numpy as np
import pytest

from brlcli.baselines.mp import BirdsEye, GroundProjection, ModularPipelinePolicy, junction_path, track_lane
from brlcli.bench.runner import run_episode
from brlcli.bench.suites import build_suite
from brlcli.errors import BrlInputError
from brlcli.sim import CameraConfig, CarlaClass, World
from brlcli.sim.camera import Renderer
from brlcli.sim.roadnet import Command


def _pinhole(cam: CameraConfig, x: float, y: float) -> tuple[float, float]:
    """Textbook pinhole: car-frame ground point -> pixel, rotating by the pitch about the camera's right axis."""
    f = (cam.width / 2) / math.tan(math.radians(cam.fov_deg) / 2)
    dx, dy, dz = x - cam.x_m, y - cam.y_m, -cam.z_m
    p = math.radians(-cam.pitch_deg)  # downward tilt
    forward = dx * math.cos(p) - dz * math.sin(p)
    down = -dx * math.sin(p) - dz * math.cos(p)
    right = -dy
    return (cam.width - 1) / 2 + f * right / forward, (cam.height - 1) / 2 + f * down / forward


@pytest.mark.parametrize("point", [(10.0, 0.0), (8.0, 2.5), (20.0, -4.0), (5.0, -1.0)])
def test_ground_point_projects_to_the_pinhole_pixel_and_back(point: tuple[float, float]) -> None:
    cam = CameraConfig()
    proj = GroundProjection(cam)
    u, v, front = proj.ground_to_pixel(np.array(point[0]), np.array(point[1]))
    assert front
    eu, ev = _pinhole(cam, *point)
    assert float(u) == pytest.approx(eu, abs=1e-6) and float(v) == pytest.approx(ev, abs=1e-6)
    x, y, below = proj.pixel_to_ground(u, v)
    assert below
    assert float(x) == pytest.approx(point[0], abs=1e-6) and float(y) == pytest.approx(point[1], abs=1e-6)


def test_pixel_to_ground_matches_the_simulator_camera() -> None:
    world = World("town02")
    try:
        renderer: Renderer = world.renderer
        proj = GroundProjection(world.camera)
        vv, uu = np.nonzero(renderer.ground_mask)
        x, y, below = proj.pixel_to_ground(uu, vv)
        assert below.all()
        near = renderer._ground_t < 60.0
        np.testing.assert_allclose(x[near], renderer._ground_ox[near], atol=1e-6)
        np.testing.assert_allclose(y[near], renderer._ground_oy[near], atol=1e-6)
    finally:
        world.close()


def test_lane_tracker_finds_the_right_lane_on_a_synthetic_road() -> None:
    bev = BirdsEye(CameraConfig())
    grid = np.full(bev.shape, CarlaClass.SIDEWALKS, np.uint8)
    ys = bev.ys_m[None, :]
    offset = 0.6  # the car is 0.6 m left of its lane centre
    grid[:, ((ys > -2 - offset) & (ys < 6 - offset))[0]] = CarlaClass.ROADS
    grid[:, (np.abs(ys - (2 - offset)) < 0.1)[0]] = CarlaClass.ROAD_LINES
    lane = track_lane(grid, bev.xs_m, bev.ys_m)
    assert lane.coef is not None
    assert lane.y_at(8.0) == pytest.approx(-offset, abs=0.15)


def test_turn_paths_end_in_the_branch_lane() -> None:
    right, _ = junction_path(Command.TURN_RIGHT, 3.0)
    left, _ = junction_path(Command.TURN_LEFT, 3.0)
    assert right[-1, 0] == pytest.approx(3.0 + 7.0, abs=0.05) and right[-1, 1] < -15
    assert left[-1, 0] == pytest.approx(3.0 + 11.0, abs=0.05) and left[-1, 1] > 15


def test_policy_keeps_the_lane_through_a_curve() -> None:
    spec = next(s for s in build_suite("paper", weathers="1") if s.town == "town02" and s.task == "right_curve")
    world = World(spec.town, vehicles=spec.vehicles, pedestrians=spec.pedestrians, seed=0)
    try:
        policy = ModularPipelinePolicy()
        result, _ = run_episode(world, spec, policy, bench_seed=0)
    finally:
        world.close()
    assert result["success"] and not result["collided"]
    assert result["either_steps"] <= 0.02 * result["steps"]
    assert result["setting"] == "MP-DG"


def test_bad_deploy_is_an_input_error() -> None:
    with pytest.raises(BrlInputError):
        ModularPipelinePolicy(deploy="gtt")
