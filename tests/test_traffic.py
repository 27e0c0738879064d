"""Traffic: vehicles follow lanes, turn at junctions and keep their distance; pedestrians walk and cross."""

import numpy as np
import pytest

from brlcli.classes import CarlaClass
from brlcli.sim import Command, RoadNetwork, load_town
from brlcli.sim.townmap import LANE_ANGLE_STEPS, LANE_NONE, TownMap
from brlcli.sim.traffic import Traffic
from brlcli.sim.vehicle import LENGTH_M, WIDTH_M


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


# ---------------------------------------------------------------------------------------------- traffic that behaves
@pytest.fixture(scope="module", params=[("town01", 100, 250), ("town02", 70, 150)], ids=["town01", "town02"])
def dense(request) -> dict:
    """Two simulated minutes of NoCrash Dense traffic, ego far away."""
    name, n_v, n_p = request.param
    net = RoadNetwork(load_town(name))
    t = Traffic(net, n_v, n_p)
    t.reset(np.random.default_rng(5))
    out: dict = {"traffic": t, "contacts": 0, "conflicts": 0, "p_in_car": 0, "standing": [], "p_pose": [],
                 "v_pose": [], "v_speed": []}
    for _ in range(1200):
        t.step(0.1, -1e4, -1e4)
        out["contacts"] += len(t.vehicle_contacts())
        inside = np.flatnonzero(t._is_connector[t.v_path])
        conns = t.v_path[inside]
        out["conflicts"] += int(t._conflict[np.ix_(conns, conns)].sum())
        out["standing"].append(float((t.v_speed < 0.1).mean()))
        out["v_pose"].append(t.v_pose.copy())
        out["v_speed"].append(t.v_speed.copy())
        out["p_pose"].append(t.p_pose.copy())
    return out


def test_dense_traffic_has_no_vehicle_contacts(dense) -> None:
    assert dense["contacts"] == 0


def test_conflicting_junction_movements_never_share_a_junction(dense) -> None:
    assert dense["conflicts"] == 0


def test_dense_traffic_does_not_gridlock(dense) -> None:
    standing = np.array(dense["standing"])
    assert standing[-300:].mean() < 0.5  # the last 30 s: most vehicles move
    travelled = np.linalg.norm(np.diff(np.array(dense["v_pose"])[:, :, :2], axis=0), axis=2).sum(axis=0)
    assert np.median(travelled) > 300.0


def test_pedestrians_and_vehicles_never_touch(dense) -> None:
    for v_pose, p_pose in zip(dense["v_pose"], dense["p_pose"], strict=True):
        rel = p_pose[:, None, :2] - v_pose[None, :, :2]
        c, s = np.cos(v_pose[:, 2]), np.sin(v_pose[:, 2])
        fwd, lat = rel[..., 0] * c + rel[..., 1] * s, -rel[..., 0] * s + rel[..., 1] * c
        assert not ((np.abs(fwd) < LENGTH_M / 2 + 0.25) & (np.abs(lat) < WIDTH_M / 2 + 0.25)).any()


def test_conflict_table_separates_crossing_turns(town) -> None:
    net, _ = town
    t = Traffic(net, 0, 0)
    conflicting = t._conflict.sum(axis=1)
    connectors = [p.index for p in net.paths if p.kind == "connector"]
    assert (conflicting[connectors] > 0).mean() > 0.5  # most movements cross or merge with another
    assert (t._conflict == t._conflict.T).all() and not t._conflict.diagonal().any()


def _lane_scenario(town, n_v: int, n_p: int) -> tuple[Traffic, object]:
    net, _ = town
    t = Traffic(net, n_v, n_p)
    t.reset(np.random.default_rng(0))
    lane = max(net.lanes, key=lambda p: p.length_m)
    return t, lane


def test_a_vehicle_stops_for_the_ego_car_on_its_lane(town) -> None:
    t, lane = _lane_scenario(town, 1, 0)
    t.v_path[0], t.v_s[0] = lane.index, 100.0
    x, y, yaw = lane.pose_at(150.0)
    for _ in range(300):
        t.step(0.1, x, y, np.radians(yaw))
    gap = np.hypot(t.v_pose[0, 0] - x, t.v_pose[0, 1] - y) - LENGTH_M
    assert t.v_speed[0] < 0.1 and 1.5 < gap < 6.0


def test_a_vehicle_stops_for_a_pedestrian_on_its_lane(town) -> None:
    t, lane = _lane_scenario(town, 1, 1)
    t.v_path[0], t.v_s[0] = lane.index, 100.0
    x, y, _ = lane.pose_at(150.0)
    t.hold_pedestrian(0, x, y)
    for _ in range(300):
        t.step(0.1, -1e4, -1e4)
    gap = np.hypot(t.v_pose[0, 0] - x, t.v_pose[0, 1] - y) - LENGTH_M / 2
    assert t.v_speed[0] < 0.1 and 1.5 < gap < 6.0


def test_a_vehicle_is_not_held_up_by_the_ego_car_beside_it(town) -> None:
    t, lane = _lane_scenario(town, 1, 0)
    t.v_path[0], t.v_s[0] = lane.index, 100.0
    x, y, yaw = lane.pose_at(100.0)
    left = np.radians(yaw) + np.pi / 2
    for _ in range(50):  # the ego car level with it in the other lane
        t.step(0.1, x + 3.5 * np.cos(left), y + 3.5 * np.sin(left), np.radians(yaw) + np.pi)
    assert t.v_speed[0] > 3.0
