"""The privileged expert brakes for every hazard on its path: a pedestrian, a car across its route, users about to
step or drive onto it."""

import math

import numpy as np
import pytest

from brlcli.autopilot import STOP_GAP_M, Autopilot
from brlcli.classes import CarlaClass
from brlcli.sim import World
from brlcli.sim.vehicle import LENGTH_M


@pytest.fixture(scope="module")
def world() -> World:
    w = World("town01", vehicles=1, pedestrians=1, seed=0)
    yield w
    w.close()


def _start(world: World):
    spec = world.town.training_routes[0]
    frame = world.reset(spec.start, seed=1)
    route = world.network.route(spec.start, spec.goal)
    return frame, Autopilot(world, route, np.random.default_rng(0), noise=None)


def _drive(world: World, pilot: Autopilot, frame, seconds: float):
    for _ in range(int(seconds * 10)):
        frame = world.step(pilot.expert(frame.measurements), render=False)
    return frame


def _park_traffic_far(world: World) -> None:
    world.traffic.hold_vehicle(0, -1e4, -1e4, 0.0)
    world.traffic.hold_pedestrian(0, -1e4, 1e4)


def test_the_expert_stops_for_a_pedestrian_on_its_route(world) -> None:
    frame, pilot = _start(world)
    _park_traffic_far(world)
    s, _ = pilot.route.project(frame.measurements.x, frame.measurements.y)
    x, y, _ = pilot.route.pose_at(s + 40.0)
    world.traffic.hold_pedestrian(0, x, y)
    frame = _drive(world, pilot, frame, 20.0)
    m = frame.measurements
    assert abs(m.forward_speed_kmh) < 0.5 and m.collision_pedestrians == 0
    assert math.hypot(m.x - x, m.y - y) - LENGTH_M / 2 < STOP_GAP_M + 2.0


def test_the_expert_stops_for_a_car_across_its_route(world) -> None:
    frame, pilot = _start(world)
    _park_traffic_far(world)
    s, _ = pilot.route.project(frame.measurements.x, frame.measurements.y)
    x, y, yaw = pilot.route.pose_at(s + 40.0)
    world.traffic.hold_vehicle(0, x, y, yaw + 90.0)  # standing across the lane
    frame = _drive(world, pilot, frame, 20.0)
    m = frame.measurements
    assert abs(m.forward_speed_kmh) < 0.5 and m.collision_vehicles == 0


class _FakeTraffic:
    def __init__(self, boxes: np.ndarray, velocities: np.ndarray) -> None:
        self._b, self._v = boxes, velocities

    def boxes(self) -> np.ndarray:
        return self._b

    def velocities(self) -> np.ndarray:
        return self._v


@pytest.mark.parametrize("towards, hazard", [(True, True), (False, False)])
def test_a_pedestrian_about_to_step_onto_the_path_is_a_hazard(world, towards, hazard) -> None:
    frame, pilot = _start(world)
    m = frame.measurements
    s, _ = pilot.route.project(m.x, m.y)
    x, y, yaw = pilot.route.pose_at(s + 12.0)
    left = math.radians(yaw) + math.pi / 2
    px, py = x + 3.0 * math.cos(left), y + 3.0 * math.sin(left)  # 3 m beside the path, walking at 1.5 m/s
    sign = -1.0 if towards else 1.0
    ped = np.array([[float(CarlaClass.PEDESTRIANS), px, py, 0.0, 0.5, 0.5, 1.8, left, 0.0]])
    vel = np.array([[sign * 1.5 * math.cos(left), sign * 1.5 * math.sin(left)]])
    real = world.traffic
    world.traffic = _FakeTraffic(ped, vel)
    try:
        gap = pilot._obstacle_gap(m)
    finally:
        world.traffic = real
    assert math.isfinite(gap) == hazard
