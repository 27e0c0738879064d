"""Traffic: vehicles follow lanes, turn at junctions and keep their distance; pedestrians walk and cross."""

import numpy as np
import pytest

from brlcli.classes import CarlaClass
from brlcli.sim import Command, RoadNetwork, load_town
from brlcli.sim.townmap import LANE_ANGLE_STEPS, LANE_NONE, TownMap
from brlcli.sim.traffic import Traffic
from brlcli.sim.vehicle import LENGTH_M


@pytest.fixture(scope="module")
def town() -> tuple[RoadNetwork, TownMap]:
    net = RoadNetwork(load_town("town01"))
    return net, TownMap(net)


def _lookup(tmap: TownMap, xy: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    row, col, _ = tmap.index(xy[:, 0], xy[:, 1])
    return tmap.ground_class[row, col], tmap.lane[row, col]


@pytest.fixture(scope="module")
def history(town) -> dict:
    """Five simulated minutes of CoRL2017 town01 traffic (20 vehicles, 50 pedestrians), ego far away."""
    net, tmap = town
    t = Traffic(net, 20, 50)
    t.reset(np.random.default_rng(3))
    out = {"v_pose": [], "v_path": [], "v_s": [], "p_pose": [], "p_cross": []}
    for _ in range(3000):
        t.step(0.1, -1e4, -1e4)
        out["v_pose"].append(t.v_pose.copy())
        out["v_path"].append(t.v_path.copy())
        out["v_s"].append(t.v_s.copy())
        out["p_pose"].append(t.p_pose.copy())
        out["p_cross"].append(t.p_cross.copy())
    return {k: np.array(v) for k, v in out.items()}


def test_vehicles_stay_on_the_road_in_their_lane_direction(town, history) -> None:
    _, tmap = town
    pose = history["v_pose"].reshape(-1, 3)
    cls, lane = _lookup(tmap, pose[:, :2])
    assert np.isin(cls, [CarlaClass.ROADS, CarlaClass.ROAD_LINES]).all()
    on_lane = lane < LANE_ANGLE_STEPS
    assert on_lane.mean() > 0.6
    assert lane[~on_lane].max() != LANE_NONE
    lane_heading = lane[on_lane] * (2 * np.pi / LANE_ANGLE_STEPS)
    assert (np.cos(lane_heading - pose[on_lane, 2]) > 0.9).all()  # never against the lane


def test_vehicles_move_and_turn_at_junctions(town, history) -> None:
    net, _ = town
    commands = {net.paths[int(p)].command for p in np.unique(history["v_path"])}
    assert {Command.TURN_LEFT, Command.TURN_RIGHT, Command.GO_STRAIGHT} <= commands
    travelled = np.linalg.norm(np.diff(history["v_pose"][:, :, :2], axis=0), axis=2).sum(axis=0)
    assert (travelled > 500).all()  # every vehicle drove more than 500 m in 5 minutes


def test_vehicles_in_one_lane_keep_their_distance(history) -> None:
    for path, s in zip(history["v_path"], history["v_s"], strict=True):
        order = np.lexsort((s, path))
        same = path[order][1:] == path[order][:-1]
        gaps = np.diff(s[order])[same]
        assert (gaps > LENGTH_M).all()


def test_a_vehicle_stops_behind_a_held_one(town) -> None:
    net, _ = town
    t = Traffic(net, 2, 0)
    t.reset(np.random.default_rng(0))
    lane = max(net.lanes, key=lambda p: p.length_m)
    t.v_path[:] = lane.index
    t.v_s[:] = (200.0, 150.0)
    x, y, yaw = lane.pose_at(200.0)
    t.hold_vehicle(0, x, y, yaw)
    for _ in range(300):
        t.step(0.1, -1e4, -1e4)
    gap = np.hypot(*(t.v_pose[0, :2] - t.v_pose[1, :2])) - LENGTH_M
    assert t.v_speed[1] < 0.1
    assert 1.5 < gap < 6.0


def test_pedestrians_walk_on_sidewalks_and_sometimes_cross(town, history) -> None:
    _, tmap = town
    walking = history["p_cross"] < 0
    pose = history["p_pose"]
    cls, _ = _lookup(tmap, pose[walking][:, :2])
    assert (cls == CarlaClass.SIDEWALKS).mean() > 0.99
    crossing_pose = pose[~walking]
    assert len(crossing_pose) > 100  # some pedestrians cross
    cls, _ = _lookup(tmap, crossing_pose[:, :2])
    assert np.isin(cls, [CarlaClass.ROADS, CarlaClass.ROAD_LINES]).mean() > 0.5
    speed = np.linalg.norm(np.diff(pose[:, :, :2], axis=0), axis=2) / 0.1
    assert speed.max() < 2.0 and np.median(speed) > 0.8


def test_traffic_is_reproducible(town) -> None:
    net, _ = town
    runs = []
    for _ in range(2):
        t = Traffic(net, 5, 10)
        t.reset(np.random.default_rng(9))
        for _ in range(200):
            t.step(0.1, 0.0, 0.0)
        runs.append(t.boxes())
    np.testing.assert_array_equal(runs[0], runs[1])
