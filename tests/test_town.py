"""Towns as data: loading, validation errors, CoRL2017 route statistics and the route planner."""

from __future__ import annotations

import itertools
import json
import math
from pathlib import Path

import numpy as np
import pytest

from brlcli.errors import BrlInputError
from brlcli.sim import Command, RoadNetwork, load_town
from brlcli.sim.town import CORL_TASK_POSES, ROUTE_KINDS, TownFormatError, available_towns

TOWNS_DIR = Path(__file__).resolve().parents[1] / "towns"

#: Expected mean CoRL2017 route length (m) per town and task (CARLA's figures).
CORL_MEAN_LENGTH_M = {
    "town01": {"straight": 200.0, "one_curve": 400.0, "navigation": 770.0},
    "town02": {"straight": 100.0, "one_curve": 170.0, "navigation": 360.0},
}


@pytest.fixture(scope="module", params=["town01", "town02"])
def town_net(request):
    town = load_town(request.param)
    return town, RoadNetwork(town)


def _heading_deg(d: np.ndarray) -> float:
    return math.degrees(math.atan2(d[1], d[0]))


def _wrap(a: float) -> float:
    return (a + 180.0) % 360.0 - 180.0


# ------------------------------------------------------------------------------------------ loading


def test_shipped_towns_are_listed():
    assert {"town01", "town02"} <= set(available_towns())


@pytest.mark.parametrize(("name", "lo_m", "hi_m"), [("town01", 2800.0, 3000.0), ("town02", 1250.0, 1450.0)])
def test_road_length(name, lo_m, hi_m):
    town = load_town(name)
    assert town.name == name
    assert lo_m <= town.road_length_m <= hi_m


def test_load_by_path_equals_load_by_name():
    a = load_town("town01")
    b = load_town(TOWNS_DIR / "town01.json")
    assert a.name == b.name
    np.testing.assert_array_equal(a.nodes_m, b.nodes_m)
    np.testing.assert_array_equal(a.objects, b.objects)


def test_routes_present(town_net):
    town, _ = town_net
    assert len(town.training_routes) > 0
    kinds = {r.kind for r in town.lane_keeping_routes}
    assert kinds == set(ROUTE_KINDS)
    assert town.spawn_poses.ndim == 2 and town.spawn_poses.shape[1] == 3
    assert town.objects.shape[1] == 9 and len(town.objects) > 0


def test_lane_keeping_routes_have_their_kind(town_net):
    """A straight route keeps its heading; a right curve turns clockwise (-90 deg), a left curve +90 deg."""
    town, net = town_net
    expected = {"straight": 0.0, "right_curve": -90.0, "left_curve": 90.0}
    for spec in town.lane_keeping_routes:
        turn = _wrap(spec.goal[2] - spec.start[2])
        assert turn == pytest.approx(expected[spec.kind], abs=1.0), spec.name
        route = net.route(spec.start, spec.goal)
        assert not route.commands, f"{spec.name}: a lane-keeping route must not cross a junction"
        pts = route.points
        geo_turn = _wrap(_heading_deg(pts[-1] - pts[-2]) - _heading_deg(pts[1] - pts[0]))
        assert geo_turn == pytest.approx(expected[spec.kind], abs=5.0), spec.name
        assert route.length_m > 30.0


def test_spawn_poses_lie_on_lane_centres(town_net):
    town, net = town_net
    for pose in town.spawn_poses:
        pid, _, dist = net.locate(*pose, lanes_only=True)
        assert dist < 0.05
        lane = net.paths[pid]
        # the lane runs the way the spawn pose faces (right-hand traffic)
        k = int(np.argmin(np.linalg.norm(lane.points - pose[:2], axis=1)))
        k = min(k, len(lane.points) - 2)
        assert abs(_wrap(_heading_deg(lane.points[k + 1] - lane.points[k]) - pose[2])) < 45.0


@pytest.mark.parametrize("task", CORL_TASK_POSES)
def test_corl2017_pairs_and_mean_length(town_net, task):
    town, net = town_net
    pairs = town.corl2017_poses[task]
    assert pairs.shape == (25, 2)
    lengths = [net.route(tuple(town.spawn_poses[a]), tuple(town.spawn_poses[b])).length_m for a, b in pairs]
    expected = CORL_MEAN_LENGTH_M[town.name][task]
    assert float(np.mean(lengths)) == pytest.approx(expected, rel=0.15)


# ------------------------------------------------------------------------------------------ malformed towns


def _raw() -> dict:
    return json.loads((TOWNS_DIR / "town01.json").read_text(encoding="utf-8"))


def _write(tmp_path: Path, raw: dict) -> Path:
    p = tmp_path / "bad_town.json"
    p.write_text(json.dumps(raw), encoding="utf-8")
    return p


def _del_lane_width(raw):
    del raw["geometry"]["lane_width_m"]


def _wrong_type_grid(raw):
    raw["grid_unit_m"] = "eight"


def _wrong_type_geometry(raw):
    raw["geometry"]["sidewalk_width_m"] = [3.0]


def _bool_version(raw):
    raw["format_version"] = True


def _version_99(raw):
    raw["format_version"] = 99


def _bad_edge(raw):
    raw["edges"].append([0, len(raw["nodes"]) + 5])


def _del_routes_training(raw):
    del raw["routes"]["training"]


def _bad_route_kind(raw):
    raw["routes"]["lane_keeping"][0]["kind"] = "zigzag"


def _bad_corl_index(raw):
    raw["routes"]["corl2017"]["straight"][0] = [0, 10_000]


def _bad_nodes(raw):
    raw["nodes"][0] = ["a", "b"]


def _negative_geometry(raw):
    raw["geometry"]["corner_radius_m"] = -1.0


def _del_spawn(raw):
    del raw["spawn_poses"]


@pytest.mark.parametrize(
    ("mutate", "field", "words"),
    [
        (_del_lane_width, "geometry.lane_width_m", "missing"),
        (_wrong_type_grid, "grid_unit_m", "wrong type"),
        (_wrong_type_geometry, "geometry.sidewalk_width_m", "wrong type"),
        (_bool_version, "format_version", "wrong type"),
        (_version_99, "format_version", "99"),
        (_bad_edge, "edges", "node"),
        (_del_routes_training, "routes.training", "missing"),
        (_bad_route_kind, "routes.lane_keeping[0].kind", "straight"),
        (_bad_corl_index, "routes.corl2017.straight", "spawn"),
        (_bad_nodes, "nodes", "numbers"),
        (_negative_geometry, "geometry.corner_radius_m", "positive"),
        (_del_spawn, "spawn_poses", "missing"),
    ],
)
def test_malformed_town_names_the_field(tmp_path, mutate, field, words):
    raw = _raw()
    mutate(raw)
    with pytest.raises(TownFormatError) as info:
        load_town(_write(tmp_path, raw))
    msg = str(info.value)
    assert f"'{field}'" in msg
    assert words in msg
    assert "\n" not in msg and "\r" not in msg
    assert isinstance(info.value, BrlInputError)


def test_dead_end_road_is_a_format_error_naming_edges(tmp_path):
    """A valid-looking file whose road graph has a dead end loads, but no road network can be built from it."""
    raw = _raw()
    x, y = raw["nodes"][0]
    raw["nodes"].append([x, y - 10])
    raw["edges"].append([0, len(raw["nodes"]) - 1])
    town = load_town(_write(tmp_path, raw))
    with pytest.raises(TownFormatError) as info:
        RoadNetwork(town)
    msg = str(info.value)
    assert "'edges'" in msg and "dead end" in msg
    assert "\n" not in msg


def test_invalid_json_is_a_one_line_format_error(tmp_path):
    p = tmp_path / "broken.json"
    p.write_text('{"format": "brl-town",\n "format_version": 1,,}', encoding="utf-8")
    with pytest.raises(TownFormatError) as info:
        load_town(p)
    assert "\n" not in str(info.value)
    assert "JSON" in str(info.value)


def test_unmodified_copy_loads(tmp_path):
    """The mutation tests start from a valid document: an untouched copy must load."""
    town = load_town(_write(tmp_path, _raw()))
    assert town.name == "town01"


@pytest.mark.parametrize("name", ["town99", "Nowhere"])
def test_unknown_town_name(name):
    with pytest.raises(BrlInputError) as info:
        load_town(name)
    assert not isinstance(info.value, TownFormatError)
    assert name in str(info.value)
    assert "town01" in str(info.value)


def test_missing_town_file(tmp_path):
    with pytest.raises(BrlInputError):
        load_town(tmp_path / "absent.json")


# ------------------------------------------------------------------------------------------ route planner


def test_route_on_one_lane_has_the_arc_length_difference(town_net):
    town, net = town_net
    located = [net.locate(*pose, lanes_only=True) for pose in town.spawn_poses]
    by_lane: dict[int, list[tuple[float, int]]] = {}
    for i, (pid, s, _) in enumerate(located):
        by_lane.setdefault(pid, []).append((s, i))
    checked = 0
    for pid, items in by_lane.items():
        items.sort()
        for (sa, ia), (sb, ib) in itertools.pairwise(items):
            if sb - sa < 1.0:
                continue
            route = net.route(tuple(town.spawn_poses[ia]), tuple(town.spawn_poses[ib]))
            assert route.path_ids == [pid]
            assert route.length_m == pytest.approx(sb - sa, abs=1e-6)
            # its end points are the two spawn positions
            np.testing.assert_allclose(route.points[0], town.spawn_poses[ia, :2], atol=1e-6)
            np.testing.assert_allclose(route.points[-1], town.spawn_poses[ib, :2], atol=1e-6)
            checked += 1
    assert checked >= 10


def test_route_backwards_on_a_lane_goes_around(town_net):
    """From a later to an earlier point of the same lane there is no U-turn: the route leaves and comes back."""
    _town, net = town_net
    lane = max(net.lanes, key=lambda p: p.length_m)
    a, b = lane.pose_at(0.2 * lane.length_m), lane.pose_at(0.8 * lane.length_m)
    route = net.route(b, a)
    # the route starts in the direction the start pose faces (it must not drive against the lane)
    first = _heading_deg(route.points[1] - route.points[0])
    assert abs(_wrap(first - b[2])) < 45.0
    assert route.length_m > 0.6 * lane.length_m
    assert len(route.path_ids) > 2
    assert route.commands


def test_corl2017_routes_start_along_the_spawn_heading(town_net):
    town, net = town_net
    wrong = []
    for task, pairs in town.corl2017_poses.items():
        for a, b in pairs:
            start = tuple(town.spawn_poses[a])
            route = net.route(start, tuple(town.spawn_poses[b]))
            if abs(_wrap(_heading_deg(route.points[1] - route.points[0]) - start[2])) > 45.0:
                wrong.append((task, int(a), int(b)))
    assert wrong == []


def _connector_cases(net: RoadNetwork):
    """(incoming lane, connector, outgoing lane) for every junction connector."""
    pred = {}
    for p in net.paths:
        if p.kind == "lane":
            for c in net.successors[p.index]:
                pred[c] = p.index
    for c in net.paths:
        if c.kind == "connector":
            yield net.paths[pred[c.index]], c, net.paths[net.successors[c.index][0]]


def test_junction_commands_match_the_geometry(town_net):
    _town, net = town_net
    seen = set()
    for lane_in, conn, lane_out in _connector_cases(net):
        h_in = _heading_deg(lane_in.points[-1] - lane_in.points[-2])
        h_out = _heading_deg(lane_out.points[1] - lane_out.points[0])
        turn = _wrap(h_out - h_in)
        expected = {90.0: Command.TURN_LEFT, -90.0: Command.TURN_RIGHT, 0.0: Command.GO_STRAIGHT}
        key = min(expected, key=lambda k: abs(k - turn))
        assert abs(key - turn) < 5.0
        assert conn.command == expected[key]
        seen.add(conn.command)
    assert seen == {Command.TURN_LEFT, Command.TURN_RIGHT, Command.GO_STRAIGHT}


def test_route_through_a_junction_gives_the_turn_command(town_net):
    _town, net = town_net
    found = {}
    for lane_in, conn, lane_out in _connector_cases(net):
        if conn.command in found or lane_in.length_m < 40.0 or lane_out.length_m < 20.0:
            continue
        start = lane_in.pose_at(lane_in.length_m - 30.0)
        goal = lane_out.pose_at(15.0)
        route = net.route(start, goal)
        assert route.path_ids == [lane_in.index, conn.index, lane_out.index]
        assert route.length_m == pytest.approx(30.0 + conn.length_m + 15.0, abs=1e-6)
        j_start = 30.0
        assert route.command_at(j_start - 25.0) == Command.LANE_FOLLOW  # far before the junction
        assert route.command_at(j_start - 5.0) == conn.command  # approaching it
        assert route.command_at(j_start + conn.length_m / 2) == conn.command  # inside it
        assert route.command_at(route.length_m - 0.5) == Command.REACH_GOAL
        found[conn.command] = route
    assert set(found) == {Command.TURN_LEFT, Command.TURN_RIGHT, Command.GO_STRAIGHT}
    # turns bend the route the right way: left is counter-clockwise
    for cmd, sign in ((Command.TURN_LEFT, 1.0), (Command.TURN_RIGHT, -1.0)):
        pts = found[cmd].points
        turn = _wrap(_heading_deg(pts[-1] - pts[-2]) - _heading_deg(pts[1] - pts[0]))
        assert turn == pytest.approx(sign * 90.0, abs=5.0)


def test_route_project_sign_convention(town_net):
    """`project` reports + lateral to the right of travel, and the arc length along the route."""
    town, net = town_net
    spec = next(r for r in town.lane_keeping_routes if r.kind == "straight")
    route = net.route(spec.start, spec.goal)
    yaw = math.radians(spec.start[2])
    fwd = np.array([math.cos(yaw), math.sin(yaw)])
    right = np.array([math.sin(yaw), -math.cos(yaw)])
    p = np.asarray(spec.start[:2]) + 20.0 * fwd + 1.5 * right
    s, lat = route.project(*p)
    assert s == pytest.approx(20.0, abs=1e-6)
    assert lat == pytest.approx(1.5, abs=1e-6)
    s, lat = route.project(*(np.asarray(spec.start[:2]) + 10.0 * fwd - 2.0 * right))
    assert (s, lat) == pytest.approx((10.0, -2.0), abs=1e-6)


# ------------------------------------------------------------------------------------------ validation routes


def test_validation_routes_are_lane_keeping_routes_of_every_kind(town_net):
    town, net = town_net
    assert {r.kind for r in town.validation_routes} == set(ROUTE_KINDS)
    assert 3 <= len(town.validation_routes) // len(ROUTE_KINDS) <= 4
    expected = {"straight": 0.0, "right_curve": -90.0, "left_curve": 90.0}
    for spec in town.validation_routes:
        assert _wrap(spec.goal[2] - spec.start[2]) == pytest.approx(expected[spec.kind], abs=1.0), spec.name
        route = net.route(spec.start, spec.goal)
        assert not route.commands, f"{spec.name}: a validation route must not cross a junction"
        assert route.length_m > 30.0


def test_validation_routes_share_no_pose_and_their_straights_no_road(town_net):
    """No validation start or goal within 3.9 m of a training or test one; validation straights keep 8 m from every
    training and test route (so neither direction of a used stretch); curves may share a corner's arc."""
    from brlcli.sim.towngen import route_points

    town, net = town_net
    taken = [*town.training_routes, *town.lane_keeping_routes]
    names = [r.name for r in [*taken, *town.validation_routes]]
    assert len(set(names)) == len(names)
    poses = np.array([p[:2] for r in taken for p in (r.start, r.goal)])
    taken_pts = np.concatenate([route_points(net, r.start, r.goal) for r in taken])
    for spec in town.validation_routes:
        for pose in (spec.start, spec.goal):
            assert np.linalg.norm(poses - np.array(pose[:2]), axis=1).min() >= 3.9, spec.name
        if spec.kind == "straight":
            pts = route_points(net, spec.start, spec.goal)
            gap = np.linalg.norm(pts[:, None] - taken_pts[None], axis=2).min()
            assert gap > 8.0, f"{spec.name} comes within {gap:.1f} m of a training or test route"


def test_town_file_without_validation_routes_loads_and_says_so(tmp_path):
    raw = _raw()
    del raw["routes"]["validation"]
    town = load_town(_write(tmp_path, raw))
    assert town.validation_routes == ()
    assert len(town.route_set("lane_keeping")) == len(town.lane_keeping_routes)
    with pytest.raises(BrlInputError, match="has no validation routes"):
        town.route_set("validation")
    with pytest.raises(BrlInputError, match="unknown route set"):
        town.route_set("holdout")


@pytest.mark.slow
def test_towngen_reproduces_the_shipped_town():
    """The generator is deterministic: it rebuilds the shipped town02 (the faster one) exactly."""
    from brlcli.sim.towngen import generate

    doc = generate("town02")
    shipped = json.loads((TOWNS_DIR / "town02.json").read_text(encoding="utf-8"))
    assert json.loads(json.dumps(doc)) == shipped
