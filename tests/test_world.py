"""The simulator's must-show behaviours: lane measures, collisions, labels, weather, determinism, speed, depth."""

from __future__ import annotations

import math

import numpy as np
import pytest

from brlcli.errors import BrlInputError
from brlcli.sim import CarlaClass, Control, World, load_town
from brlcli.sim.traffic import PEDESTRIAN_SIZE_M
from brlcli.sim.vehicle import LENGTH_M, WIDTH_M

FORWARD = Control(steer=0.0, throttle=0.5)
RIGHT = Control(steer=0.4, throttle=0.35)
LEFT = Control(steer=-0.4, throttle=0.35)
SOLID_CLASSES = (CarlaClass.BUILDINGS, CarlaClass.FENCES, CarlaClass.POLES, CarlaClass.VEGETATION, CarlaClass.WALLS,
                 CarlaClass.TRAFFIC_SIGNS)


# ------------------------------------------------------------------------------------------ fixtures and helpers


@pytest.fixture(scope="module")
def world():
    w = World("town01")
    yield w
    w.close()


@pytest.fixture(scope="module")
def traffic_world():
    """One traffic vehicle and one pedestrian, to be held in place by each test."""
    w = World("town01", vehicles=1, pedestrians=1)
    yield w
    w.close()


def _wrap(a: float) -> float:
    return (a + 180.0) % 360.0 - 180.0


def _route_heading_deg(route, s: float) -> float:
    i = int(np.clip(np.searchsorted(route.cum_s, s, side="right") - 1, 0, len(route.points) - 2))
    d = route.points[i + 1] - route.points[i]
    return math.degrees(math.atan2(d[1], d[0]))


def _route_point(route, s: float) -> np.ndarray:
    s = min(max(s, 0.0), route.length_m)
    return np.array([np.interp(s, route.cum_s, route.points[:, 0]), np.interp(s, route.cum_s, route.points[:, 1])])


def _lane_keeping_steer(route, m, target_lateral_m: float = 0.0) -> float:
    """Proportional steer towards a lateral offset from the route (+ right) and along its heading.

    Being right of the target (lateral too large) needs a left turn, i.e. negative steer (+ steer is right);
    pointing clockwise of the route (route heading - yaw > 0) also needs a left turn.
    """
    s, lat = route.project(m.x, m.y)
    heading_err = _wrap(_route_heading_deg(route, s + 3.0) - m.yaw_deg)
    return float(np.clip(-(0.3 * (lat - target_lateral_m) + 0.03 * heading_err), -1.0, 1.0))


def _straight_spec(town):
    return next(r for r in town.lane_keeping_routes if r.kind == "straight")


def _far_corner(town) -> tuple[float, float]:
    x, y = town.nodes_m.max(axis=0) + 45.0
    return float(x), float(y)


def _park_traffic(w: World) -> None:
    """Hold every traffic agent far outside the town (call after reset)."""
    fx, fy = _far_corner(w.town)
    for i in range(w.traffic.n_vehicles):
        w.traffic.hold_vehicle(i, fx + 12.0 * i, fy, 0.0)
    for i in range(w.traffic.n_pedestrians):
        w.traffic.hold_pedestrian(i, fx + 2.0 * i, fy + 30.0)


def _ahead(pose, dist_m: float) -> tuple[float, float]:
    yaw = math.radians(pose[2])
    return pose[0] + dist_m * math.cos(yaw), pose[1] + dist_m * math.sin(yaw)


def _along(pose, m) -> float:
    """Signed displacement of the car from `pose` along the pose's heading."""
    yaw = math.radians(pose[2])
    return (m.x - pose[0]) * math.cos(yaw) + (m.y - pose[1]) * math.sin(yaw)


def _free_face(town, cls: int, clearance_m: float = 8.0):
    """A vertical face of a static box of class `cls` with a clear straight approach of `clearance_m`.

    Returns (start pose facing the face, point on the face, outward unit normal). The start pose puts the car's
    centre `clearance_m + LENGTH_M / 2` in front of the face; no other solid box comes near the approach corridor.
    """
    obj = town.objects
    solid = np.flatnonzero(np.isin(obj[:, 0], SOLID_CLASSES))
    for k in np.flatnonzero(obj[:, 0] == cls):
        _, x, y, _, length, width, height, yaw_deg, _ = obj[k]
        for face in range(4):
            half = (length if face % 2 == 0 else width) / 2
            span = width if face % 2 == 0 else length
            if span < 4.0 or height < 1.5:
                continue
            ang = math.radians(yaw_deg) + face * math.pi / 2
            n = np.array([math.cos(ang), math.sin(ang)])
            face_pt = np.array([x, y]) + half * n
            start = face_pt + (clearance_m + LENGTH_M / 2) * n
            a = start + 3.0 * n  # behind the car's rear
            u = -n
            corridor = clearance_m + LENGTH_M / 2 + 3.0
            clear = True
            for j in solid:
                if j == k:
                    continue
                p = obj[j, 1:3] - a
                r = 0.5 * math.hypot(obj[j, 4], obj[j, 5])
                along = float(p @ u)
                across = abs(float(p[0] * u[1] - p[1] * u[0]))
                if -r < along < corridor + r and across < WIDTH_M / 2 + 0.75 + r:
                    clear = False
                    break
            if clear:
                return (float(start[0]), float(start[1]), math.degrees(ang) + 180.0), face_pt, n
    raise AssertionError(f"no free face of class {cls}")


# ------------------------------------------------------------------------------------------ lane measures


def test_driving_the_lane_centre_keeps_intersections_at_zero(world):
    spec = _straight_spec(world.town)
    route = world.network.route(spec.start, spec.goal)
    m = world.reset(spec.start).measurements
    assert (m.intersection_offroad, m.intersection_otherlane) == (0.0, 0.0)
    s0, _ = route.project(m.x, m.y)
    offroad, otherlane, lateral = [], [], []
    for _ in range(100):
        m = world.step(Control(steer=_lane_keeping_steer(route, m), throttle=0.5), render=False).measurements
        offroad.append(m.intersection_offroad)
        otherlane.append(m.intersection_otherlane)
        lateral.append(route.project(m.x, m.y)[1])
    assert max(offroad) == 0.0
    assert max(otherlane) == 0.0
    assert max(abs(v) for v in lateral) < 0.3
    assert route.project(m.x, m.y)[0] - s0 > 30.0


def _drive_to_offset(w: World, target_lateral_m: float, frames: int = 60):
    spec = _straight_spec(w.town)
    route = w.network.route(spec.start, spec.goal)
    m = w.reset(spec.start).measurements
    rows = []
    for _ in range(frames):
        steer = _lane_keeping_steer(route, m, target_lateral_m)
        m = w.step(Control(steer=steer, throttle=0.5), render=False).measurements
        rows.append((steer, route.project(m.x, m.y)[1], m.intersection_offroad, m.intersection_otherlane))
    return np.array(rows)


def test_steering_left_into_the_opposite_lane_raises_otherlane(world):
    lane_w = world.town.geometry.lane_width_m
    rows = _drive_to_offset(world, -lane_w)  # the centre of the opposite lane
    steer, lateral, offroad, otherlane = rows.T
    assert steer[0] < -0.5  # the move starts with a left (negative) steer
    assert lateral.min() < -0.9 * lane_w  # and the car really went left of its lane
    hits = np.flatnonzero(otherlane > 0.8)
    assert len(hits) > 0
    assert np.all(offroad[hits] < 0.1)
    assert np.all(lateral[hits] < -lane_w / 2)
    # once fully in the other lane, the whole footprint counts
    assert otherlane[-1] == pytest.approx(1.0)
    # the share rises with the offset: nothing in the own lane, everything a lane width away
    assert otherlane[np.abs(lateral) < 0.25].max() == 0.0


def test_steering_right_onto_the_sidewalk_raises_offroad(world):
    geo = world.town.geometry
    rows = _drive_to_offset(world, geo.lane_width_m / 2 + geo.sidewalk_width_m / 2)  # the middle of the sidewalk
    steer, lateral, offroad, otherlane = rows.T
    assert steer[0] > 0.5
    assert lateral.max() > geo.lane_width_m / 2 + WIDTH_M / 2
    hits = np.flatnonzero(offroad > 0.5)
    assert len(hits) > 0
    assert np.all(lateral[hits] > geo.lane_width_m / 2 - WIDTH_M / 2)
    assert otherlane.max() == 0.0
    assert offroad[-1] == pytest.approx(1.0)
    assert offroad[np.abs(lateral) < 0.25].max() == 0.0


# ------------------------------------------------------------------------------------------ collisions


@pytest.mark.parametrize("cls", [CarlaClass.BUILDINGS, CarlaClass.WALLS])
def test_hitting_a_static_object_raises_collision_other_only(traffic_world, cls):
    w = traffic_world
    pose, face_pt, n = _free_face(w.town, int(cls))
    f = w.reset(pose)
    _park_traffic(w)
    m = f.measurements
    assert (m.collision_vehicles, m.collision_pedestrians, m.collision_other) == (0.0, 0.0, 0.0)
    # the camera sees the object straight ahead
    assert f.labels[f.labels.shape[0] // 3, f.labels.shape[1] // 2] == cls
    first = None
    for i in range(60):
        m = w.step(FORWARD, render=False).measurements
        gap = float((np.array([m.x, m.y]) - face_pt) @ n) - LENGTH_M / 2  # car front to the face
        if first is None and m.collision_other > 0:
            first = i
            assert gap < 0.5, "collision reported before the car reached the object"
        if first is None:  # contacts are found at the start of a physics substep: at most one substep late
            assert gap > -0.5
    assert first is not None, "driving into the object never raised collision_other"
    assert m.collision_other > 0.0
    assert m.collision_vehicles == 0.0
    assert m.collision_pedestrians == 0.0
    # the car stopped at the face instead of driving through it
    centre_to_face = float((np.array([m.x, m.y]) - face_pt) @ n)
    assert centre_to_face == pytest.approx(LENGTH_M / 2, abs=0.5)
    assert abs(m.forward_speed_kmh) < 5.0


def test_collision_intensity_grows_with_the_impact_speed(traffic_world):
    w = traffic_world
    pose, _, _ = _free_face(w.town, int(CarlaClass.WALLS))
    totals = []
    for throttle in (0.3, 1.0):
        w.reset(pose)
        _park_traffic(w)
        for _ in range(60):
            m = w.step(Control(throttle=throttle), render=False).measurements
        assert m.collision_vehicles == m.collision_pedestrians == 0.0
        totals.append(m.collision_other)
    assert 0.0 < totals[0] < totals[1]


def _hit_agent(w: World, kind: str, dist_m: float = 10.0, frames: int = 45):
    spec = _straight_spec(w.town)
    w.reset(spec.start)
    _park_traffic(w)
    x, y = _ahead(spec.start, dist_m)
    if kind == "vehicle":
        w.traffic.hold_vehicle(0, x, y, spec.start[2])
    else:
        w.traffic.hold_pedestrian(0, x, y)
    frames_out = [w.step(FORWARD) for _ in range(frames)]
    return spec, frames_out


def test_hitting_a_vehicle_raises_collision_vehicles_only(traffic_world):
    spec, frames = _hit_agent(traffic_world, "vehicle")
    m = frames[-1].measurements
    assert m.collision_vehicles > 0.0
    assert m.collision_pedestrians == 0.0
    assert m.collision_other == 0.0
    # nose to tail: the car stops one car length behind the held vehicle's centre
    assert 10.0 - _along(spec.start, m) == pytest.approx(LENGTH_M, abs=0.5)
    # before the contact nothing was recorded, and the vehicle was visible ahead
    before = [f for f in frames if 10.0 - _along(spec.start, f.measurements) > LENGTH_M + 1.0]
    assert before and all(f.measurements.collision_vehicles == 0.0 for f in before)
    assert any(np.any(f.labels == CarlaClass.VEHICLES) for f in before)


def test_hitting_a_pedestrian_raises_collision_pedestrians_only(traffic_world):
    spec, frames = _hit_agent(traffic_world, "pedestrian")
    m = frames[-1].measurements
    assert m.collision_pedestrians > 0.0
    assert m.collision_vehicles == 0.0
    assert m.collision_other == 0.0
    assert 10.0 - _along(spec.start, m) == pytest.approx(LENGTH_M / 2 + PEDESTRIAN_SIZE_M[0] / 2, abs=0.5)
    before = [f for f in frames if 10.0 - _along(spec.start, f.measurements) > LENGTH_M]
    assert before and all(f.measurements.collision_pedestrians == 0.0 for f in before)
    assert any(np.any(f.labels == CarlaClass.PEDESTRIANS) for f in before)


def test_without_road_user_contact_the_car_drives_through_a_vehicle_it_sees():
    """Ghost traffic (issue 35, outside the paper): the held vehicle is in view, but the car passes through it."""
    with World("town01", vehicles=1, pedestrians=1, road_user_contact=False) as w:
        spec, frames = _hit_agent(w, "vehicle", frames=60)
    m = frames[-1].measurements
    assert (m.collision_vehicles, m.collision_pedestrians, m.collision_other) == (0.0, 0.0, 0.0)
    assert _along(spec.start, m) > 10.0 + LENGTH_M  # past the vehicle
    assert any(np.any(f.labels == CarlaClass.VEHICLES) for f in frames)


def test_no_collision_when_standing_still(traffic_world):
    w = traffic_world
    spec = _straight_spec(w.town)
    w.reset(spec.start)
    _park_traffic(w)
    for _ in range(20):
        m = w.step(Control(), render=False).measurements
        assert (m.collision_vehicles, m.collision_pedestrians, m.collision_other) == (0.0, 0.0, 0.0)
    assert m.forward_speed_kmh == 0.0
    assert (m.x, m.y) == pytest.approx(spec.start[:2], abs=1e-6)


def test_no_collision_below_one_kmh(traffic_world):
    """Creeping into a parked vehicle below 1 km/h touches it but records no collision (as in CARLA)."""
    w = traffic_world
    spec = _straight_spec(w.town)
    w.reset(spec.start)
    _park_traffic(w)
    gap = 0.1
    w.traffic.hold_vehicle(0, *_ahead(spec.start, LENGTH_M + gap), spec.start[2])
    speeds = []
    for _ in range(40):
        m = w.step(Control(throttle=0.1), render=False).measurements
        speeds.append(m.forward_speed_kmh)
    assert max(speeds) < 1.0
    # the car was stopped by the vehicle: without it, throttle 0.1 would have carried it much further
    assert _along(spec.start, m) == pytest.approx(gap, abs=0.05)
    assert abs(speeds[-1]) < 0.05
    assert (m.collision_vehicles, m.collision_pedestrians, m.collision_other) == (0.0, 0.0, 0.0)


# ------------------------------------------------------------------------------------------ camera


def test_label_images_of_a_drive_show_the_town_classes(world):
    spec = next(r for r in world.town.lane_keeping_routes if r.kind == "right_curve")
    route = world.network.route(spec.start, spec.goal)
    f = world.reset(spec.start)
    seen = set(np.unique(f.labels).tolist())
    h, wd = f.labels.shape
    for _ in range(60):
        m = f.measurements
        f = world.step(Control(steer=_lane_keeping_steer(route, m), throttle=0.5))
        assert f.labels.shape == (h, wd) and f.labels.dtype == np.uint8
        assert f.rgb.shape == (h, wd, 3) and f.rgb.dtype == np.uint8
        assert f.depth.shape == (h, wd) and f.depth.dtype == np.float32
        # driving the lane centre, the ground just ahead of the bonnet is road
        assert f.labels[-1, wd // 2] in (CarlaClass.ROADS, CarlaClass.ROAD_LINES)
        seen |= set(np.unique(f.labels).tolist())
    for cls in (CarlaClass.ROADS, CarlaClass.ROAD_LINES, CarlaClass.SIDEWALKS, CarlaClass.BUILDINGS):
        assert cls in seen, f"{cls.name} never appeared in the label images"
    assert max(seen) <= 12


def test_weather_changes_rgb_but_not_labels():
    spec = _straight_spec(load_town("town01"))
    frames = {}
    for wid in (1, 6, 8):
        with World("town01", weather=wid, seed=5, vehicles=3, pedestrians=5) as w:
            fr = [w.reset(spec.start, seed=5)]
            fr += [w.step(Control(steer=0.05, throttle=0.5)) for _ in range(5)]
            frames[wid] = fr
    for wid in (6, 8):
        for a, b in zip(frames[1], frames[wid], strict=True):
            np.testing.assert_array_equal(a.labels, b.labels)
            np.testing.assert_array_equal(a.depth, b.depth)
            assert a.measurements == b.measurements
            diff = np.abs(a.rgb.astype(np.int16) - b.rgb.astype(np.int16)).mean()
            assert diff > 10.0, f"weather {wid} looks like weather 1 (mean |diff| {diff:.1f})"
    rain_vs_sunset = np.abs(frames[6][0].rgb.astype(np.int16) - frames[8][0].rgb.astype(np.int16)).mean()
    assert rain_vs_sunset > 10.0


def test_set_weather_changes_only_the_rgb(world):
    spec = _straight_spec(world.town)
    try:
        a = world.reset(spec.start)
        world.set_weather("ClearSunset")
        b = world.reset(spec.start)
    finally:
        world.set_weather(1)
    np.testing.assert_array_equal(a.labels, b.labels)
    assert np.abs(a.rgb.astype(np.int16) - b.rgb.astype(np.int16)).mean() > 10.0


def test_depth_in_front_of_a_wall(world):
    pose, face_pt, n = _free_face(world.town, int(CarlaClass.BUILDINGS))
    cam = world.camera
    dist = 3.0  # horizontal distance camera -> face
    car = face_pt + (dist + cam.x_m) * n
    f = world.reset((float(car[0]), float(car[1]), pose[2]))
    h, w = f.depth.shape
    rows, cols = slice(h // 2 - 1, h // 2 + 1), slice(w // 2 - 1, w // 2 + 1)
    assert np.all(f.labels[rows, cols] == CarlaClass.BUILDINGS)
    centre = float(f.depth[rows, cols].mean())
    assert centre == pytest.approx(dist, rel=0.10)
    # planar depth along the optical axis: the axis is pitched down, so it meets the face at dist / cos(pitch)
    assert centre == pytest.approx(dist / math.cos(math.radians(cam.pitch_deg)), rel=0.02)
    # further back, the same pixel sees the wall further away
    car2 = face_pt + (dist + 1.0 + cam.x_m) * n
    f2 = world.reset((float(car2[0]), float(car2[1]), pose[2]))
    assert float(f2.depth[rows, cols].mean()) == pytest.approx(centre + 1.0 / math.cos(math.radians(cam.pitch_deg)),
                                                               rel=0.03)


def test_depth_of_sky_and_ground(world):
    spec = _straight_spec(world.town)
    f = world.reset(spec.start)
    sky = f.labels == CarlaClass.NONE
    assert sky.sum() > 100
    assert np.all(f.depth[sky] == 1000.0)
    assert np.all(f.depth[~sky] < 1000.0)
    assert sky[0].any() and not sky[-1].any()  # sky at the top, ground at the bottom
    # a ground pixel's planar depth is the camera height over the ray's downward slope
    cam = world.camera
    h, w = f.depth.shape
    v = h - 1
    dy = (v - (h - 1) / 2) / cam.focal_px
    p = math.radians(-cam.pitch_deg)
    expected = cam.z_m / (math.sin(p) + dy * math.cos(p))
    assert float(f.depth[v, (w - 1) // 2]) == pytest.approx(expected, rel=0.01)


# ------------------------------------------------------------------------------------------ determinism


def _run(w: World, seed: int, frames: int = 30, render: bool = True, pose=None):
    out = [w.reset(pose, seed=seed)]
    boxes = [w.traffic.boxes().copy()]
    for i in range(frames):
        out.append(w.step(Control(steer=0.3 * math.sin(i / 4), throttle=0.6, brake=0.1 * (i % 7 == 0)), render))
        boxes.append(w.traffic.boxes().copy())
    return out, boxes


def _frame_bytes(f) -> tuple:
    return (f.rgb.tobytes(), f.labels.tobytes(), f.depth.tobytes())


@pytest.fixture(scope="module")
def traffic_pair():
    a = World("town01", seed=11, vehicles=5, pedestrians=10)
    b = World("town01", seed=11, vehicles=5, pedestrians=10)
    yield a, b
    a.close()
    b.close()


def test_same_seed_gives_bit_identical_frames(traffic_pair):
    a, b = traffic_pair
    fa, boxes_a = _run(a, seed=11)
    fb, boxes_b = _run(b, seed=11)
    assert len(fa) == len(fb) == 31
    for x, y in zip(fa, fb, strict=True):
        assert x.measurements == y.measurements
        assert _frame_bytes(x) == _frame_bytes(y)
    for x, y in zip(boxes_a, boxes_b, strict=True):
        assert x.tobytes() == y.tobytes()
    # the run did something: the car moved and the traffic moved
    assert math.hypot(fa[-1].measurements.x - fa[0].measurements.x, fa[-1].measurements.y - fa[0].measurements.y) > 5
    assert not np.array_equal(boxes_a[0][:, 1:3], boxes_a[-1][:, 1:3])
    assert fa[-1].measurements.game_time_s == pytest.approx(3.0)
    # a world that already ran an episode replays it exactly after a reset with the same seed
    fa2, boxes_a2 = _run(a, seed=11)
    for x, y in zip(fa, fa2, strict=True):
        assert x.measurements == y.measurements
        assert _frame_bytes(x) == _frame_bytes(y)
    assert all(x.tobytes() == y.tobytes() for x, y in zip(boxes_a, boxes_a2, strict=True))


def test_different_seed_gives_different_traffic(traffic_pair):
    a, _ = traffic_pair
    spec = _straight_spec(a.town)
    _, boxes_11 = _run(a, seed=11, frames=5, render=False, pose=spec.start)
    _, boxes_12 = _run(a, seed=12, frames=5, render=False, pose=spec.start)
    assert boxes_11[0].shape == boxes_12[0].shape == (15, 9)
    for x, y in zip(boxes_11, boxes_12, strict=True):
        assert not np.allclose(x[:, 1:3], y[:, 1:3])
    # every agent starts somewhere else
    assert np.all(np.hypot(*(boxes_11[0][:, 1:3] - boxes_12[0][:, 1:3]).T) > 0.5)


def test_render_false_returns_no_images_and_the_same_measurements(traffic_pair):
    a, _ = traffic_pair
    on, boxes_on = _run(a, seed=21, frames=60, render=True)
    off, boxes_off = _run(a, seed=21, frames=60, render=False)
    for f in off[1:]:
        assert f.rgb is None and f.labels is None and f.depth is None
    for f in on:
        assert f.rgb is not None and f.labels is not None and f.depth is not None
    assert [f.measurements for f in on] == [f.measurements for f in off]
    assert [f.frame for f in on] == [f.frame for f in off] == list(range(61))
    # rendering does not disturb the traffic either
    for x, y in zip(boxes_on, boxes_off, strict=True):
        assert x.tobytes() == y.tobytes()
    # and a later frame rendered on demand equals the one rendered while stepping
    rgb, labels, depth = a.render()
    assert (rgb.tobytes(), labels.tobytes(), depth.tobytes()) == _frame_bytes(on[-1])


def test_labels_only_render_skips_the_rgb_image_and_keeps_labels_and_depth(traffic_pair):
    a, _ = traffic_pair
    frames, _ = _run(a, seed=23, frames=8, render=True)
    rgb, labels, depth = a.render(rgb=False)
    assert rgb is None
    assert (labels.tobytes(), depth.tobytes()) == _frame_bytes(frames[-1])[1:]
    a.rgb_frames = False  # what a ground-truth training environment sets
    try:
        off, _ = _run(a, seed=23, frames=8, render=True)
    finally:
        a.rgb_frames = True
    assert all(f.rgb is None for f in off)
    assert [(f.labels.tobytes(), f.depth.tobytes()) for f in off] == \
        [_frame_bytes(f)[1:] for f in frames]


def test_two_worlds_step_independently(world):
    spec = _straight_spec(world.town)
    controls = [Control(steer=0.1 * math.sin(i / 3), throttle=0.5) for i in range(25)]
    world.reset(spec.start)
    reference = [world.step(c, render=False).measurements for c in controls]
    with World("town01") as other:
        # both egos start on the very same spot: a shared physics scene would make them collide
        world.reset(spec.start)
        other.reset(spec.start)
        for c, ref in zip(controls, reference, strict=True):
            mo = other.step(Control(steer=-0.6, throttle=1.0), render=False).measurements
            m = world.step(c, render=False).measurements
            assert m == ref
            assert mo.collision_other == mo.collision_vehicles == 0.0
        assert math.hypot(mo.x - m.x, mo.y - m.y) > 5.0
        # a reset of one world leaves the other one's state alone
        before = (world.ego.x_m, world.ego.y_m, world.ego.yaw_rad)
        other.reset(spec.goal)
        assert (world.ego.x_m, world.ego.y_m, world.ego.yaw_rad) == before


# ------------------------------------------------------------------------------------------ vehicle model


def _long_straight_lane(w: World):
    straight = [p for p in w.network.lanes if len(p.points) == 2]
    return max(straight, key=lambda p: p.length_m)


def test_throttle_half_settles_between_20_and_35_kmh(world):
    lane = _long_straight_lane(world)
    assert lane.length_m > 180.0
    start, goal = lane.pose_at(3.0), lane.pose_at(lane.length_m - 3.0)
    route = world.network.route(start, goal)
    m = world.reset(start).measurements
    speeds = []
    for _ in range(200):
        m = world.step(Control(steer=_lane_keeping_steer(route, m), throttle=0.5), render=False).measurements
        speeds.append(m.forward_speed_kmh)
        assert m.collision_other == 0.0
    speeds = np.array(speeds)
    assert np.all(np.diff(speeds) > -1e-6)  # accelerates monotonically towards the cruise speed
    tail = speeds[-20:]
    assert 20.0 <= tail.mean() <= 35.0
    assert tail.max() - tail.min() < 1.0  # settled
    # a lighter throttle (the turn primitive's) cruises slower
    m = world.reset(start).measurements
    for _ in range(200):
        m = world.step(Control(steer=_lane_keeping_steer(route, m), throttle=0.35), render=False).measurements
    assert 12.0 < m.forward_speed_kmh < tail.mean() - 3.0


def test_reverse_gives_negative_speed(world):
    lane = _long_straight_lane(world)
    start = lane.pose_at(lane.length_m / 2)
    world.reset(start)
    speeds = []
    for _ in range(40):
        m = world.step(Control(throttle=0.4, reverse=True), render=False).measurements
        speeds.append(m.forward_speed_kmh)
    assert all(s < 0.0 for s in speeds)
    assert speeds[-1] < -10.0
    assert _along(start, m) < -5.0  # it went backwards
    assert _wrap(m.yaw_deg - start[2]) == pytest.approx(0.0, abs=0.5)  # facing the same way


def test_brake_stops_without_reversing(world):
    lane = _long_straight_lane(world)
    start = lane.pose_at(10.0)
    world.reset(start)
    for _ in range(50):
        m = world.step(Control(throttle=0.5), render=False).measurements
    assert m.forward_speed_kmh > 15.0
    for _ in range(30):
        m = world.step(Control(brake=1.0), render=False).measurements
        assert m.forward_speed_kmh >= 0.0
    assert m.forward_speed_kmh == 0.0


def test_steer_sign_and_yaw_convention(world):
    """+ steer turns clockwise (to the right), so yaw (counter-clockwise degrees) decreases."""
    lane = _long_straight_lane(world)
    start = lane.pose_at(10.0)
    for steer, sign in ((0.3, -1.0), (-0.3, 1.0)):
        world.reset(start)
        for _ in range(20):
            m = world.step(Control(steer=steer, throttle=0.5), render=False).measurements
        assert sign * _wrap(m.yaw_deg - start[2]) > 10.0
        # the car moved towards the side it steered to
        yaw = math.radians(start[2])
        left = -(m.x - start[0]) * math.sin(yaw) + (m.y - start[1]) * math.cos(yaw)
        assert sign * left > 0.2


# ------------------------------------------------------------------------------------------ the turn primitive


@pytest.mark.parametrize("kind", ["right_curve", "left_curve"])
def test_turn_primitives_reach_the_goal_of_a_curve(world, kind):
    """Only the paper's three primitives, each held for 7 frames, chosen from the offset/heading to the route."""
    spec = next(r for r in world.town.lane_keeping_routes if r.kind == kind)
    route = world.network.route(spec.start, spec.goal)
    goal = np.asarray(route.goal)
    m = world.reset(spec.start).measurements
    best, chosen, offroad = np.inf, [], []
    for _ in range(40):
        s, _ = route.project(m.x, m.y)
        # bearing of a point 8 m further along the route: combines the lateral offset and the heading error
        target = _route_point(route, s + 8.0)
        alpha = _wrap(math.degrees(math.atan2(target[1] - m.y, target[0] - m.x)) - m.yaw_deg)
        ctl = LEFT if alpha > 8.0 else RIGHT if alpha < -8.0 else FORWARD
        chosen.append(ctl)
        for _ in range(7):
            m = world.step(ctl, render=False).measurements
            offroad.append(m.intersection_offroad)
            best = min(best, float(np.hypot(m.x - goal[0], m.y - goal[1])))
        if best < 3.0:
            break
    assert best < 3.0, f"the car got only {best:.1f} m close to the goal"
    assert max(offroad) < 0.2
    turn = RIGHT if kind == "right_curve" else LEFT
    assert chosen.count(turn) >= 2  # the curve was taken with the turn primitive
    assert _wrap(m.yaw_deg - spec.start[2]) == pytest.approx(-90.0 if kind == "right_curve" else 90.0, abs=25.0)


# ------------------------------------------------------------------------------------------ API edges


def test_step_before_reset_is_an_error():
    with World("town02") as w:
        with pytest.raises(RuntimeError):
            w.step(Control())


def test_bad_arguments_are_input_errors():
    with pytest.raises(BrlInputError):
        World("no_such_town")
    with pytest.raises(BrlInputError):
        World("town02", weather=2)
    with pytest.raises(BrlInputError):
        World("town02", vehicles=-1)


def test_non_finite_start_pose_is_an_input_error(world):
    with pytest.raises(BrlInputError):
        world.reset((float("nan"), 0.0, 0.0))


def test_reset_without_pose_uses_a_spawn_pose(world):
    f = world.reset(seed=3)
    m = f.measurements
    d = np.hypot(world.town.spawn_poses[:, 0] - m.x, world.town.spawn_poses[:, 1] - m.y)
    k = int(np.argmin(d))
    assert d[k] < 1e-6
    assert _wrap(m.yaw_deg - world.town.spawn_poses[k, 2]) == pytest.approx(0.0, abs=1e-6)
    assert (m.game_time_s, f.frame, m.forward_speed_kmh) == (0.0, 0, 0.0)


def test_out_of_range_controls_are_clipped(world):
    spec = _straight_spec(world.town)
    world.reset(spec.start)
    a = [world.step(Control(steer=5.0, throttle=3.0), render=False).measurements for _ in range(10)]
    world.reset(spec.start)
    b = [world.step(Control(steer=1.0, throttle=1.0), render=False).measurements for _ in range(10)]
    assert a == b
    world.reset(spec.start)
    c = world.step(Control(steer=float("nan"), throttle=float("nan")), render=False)
    assert c.control == Control(0.0, 0.0, 0.0, False)
    assert c.measurements.forward_speed_kmh == 0.0
