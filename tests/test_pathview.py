"""The path state option (issue 35, outside the paper): the nearness of the nearest road user on the car's planned
path, from the label image, the speed, the route command and the held control (`brlcli.pathview`)."""

import math

import numpy as np
import pytest

from brlcli.features import DYNAMIC_CATEGORY, N_CATEGORIES, N_REGIONS, STATE_DIM, state_vector
from brlcli.pathview import PathView, path_nearness
from brlcli.sim import World
from brlcli.sim.roadnet import Command
from brlcli.sim.vehicle import Control

FORWARD = Control(throttle=0.5)


@pytest.fixture(scope="module")
def world():
    w = World("town01", vehicles=1, pedestrians=0)
    yield w
    w.close()


def _view_with_vehicle(w: World, ahead_m: float, left_m: float) -> tuple[float, np.ndarray]:
    """Path nearness and the 30-number state with the one vehicle held `ahead_m` ahead and `left_m` to the left."""
    spec = next(r for r in w.town.lane_keeping_routes if r.kind == "straight")
    w.reset(spec.start)
    yaw = math.radians(spec.start[2])
    x = spec.start[0] + ahead_m * math.cos(yaw) - left_m * math.sin(yaw)
    y = spec.start[1] + ahead_m * math.sin(yaw) + left_m * math.cos(yaw)
    w.traffic.hold_vehicle(0, x, y, spec.start[2] + (180.0 if left_m > 2.0 else 0.0))
    view = PathView(7)
    view.reset(w)
    frame = w.step(Control(), render=True)
    near = view.update(frame.labels, frame.measurements.forward_speed_kmh, int(Command.LANE_FOLLOW), None)
    return near, state_vector(frame.labels)


def _road_user_share(state: np.ndarray) -> float:
    return float(state[:STATE_DIM].reshape(N_REGIONS, N_CATEGORIES)[:, DYNAMIC_CATEGORY].sum())


def test_a_vehicle_in_the_lane_ahead_is_near_on_the_path(world):
    near, state = _view_with_vehicle(world, 10.0, 0.0)
    assert _road_user_share(state) > 0.0
    assert 0.6 < near < 1.0  # a gap of a few metres to its rear bumper: 1 - gap / 30


def test_an_oncoming_vehicle_beside_the_path_is_in_the_state_but_not_on_the_path(world):
    near, state = _view_with_vehicle(world, 10.0, 4.0)
    assert _road_user_share(state) > 0.0  # the paper's state sees it as it sees the one ahead
    assert near == 0.0


def test_a_far_vehicle_and_a_clear_road_give_zero():
    assert path_nearness(math.inf) == 0.0 and path_nearness(45.0) == 0.0
    assert path_nearness(0.0) == 1.0 and path_nearness(15.0) == pytest.approx(0.5)
