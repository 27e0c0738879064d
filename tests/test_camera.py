"""The camera's geometry checked against an independent pinhole model: side, depth, horizon, labels."""

import numpy as np
import pytest

from brlcli.sim import CameraConfig, CarlaClass, World, get_weather
from brlcli.sim.camera import SKY_DEPTH_M, Renderer


@pytest.fixture(scope="module")
def scene() -> tuple[Renderer, tuple[float, float, float]]:
    world = World("town01")
    route = world.town.lane_keeping_routes[0]
    x, y, yaw_deg = route.start
    renderer = Renderer(world.map, np.zeros((0, 9)), CameraConfig())  # ground only; boxes added per test
    yield renderer, (x, y, np.radians(yaw_deg))
    world.close()


def _box(pose: tuple[float, float, float], ahead: float, left: float, cls: int = CarlaClass.VEHICLES,
         size: tuple[float, float, float] = (1.0, 2.0, 3.0)) -> np.ndarray:
    x, y, yaw = pose
    c, s = np.cos(yaw), np.sin(yaw)
    return np.array([[cls, x + c * ahead - s * left, y + s * ahead + c * left, 0.0, *size, yaw, 0.5]])


def _camera_points(depth: np.ndarray, cam: CameraConfig) -> np.ndarray:
    """Back-project planar depth to car-frame points (x forward, y left, z up) with a textbook pinhole model."""
    h, w = depth.shape
    f = (w / 2) / np.tan(np.radians(cam.fov_deg) / 2)
    u, v = np.meshgrid(np.arange(w), np.arange(h))
    right, down = (u - (w - 1) / 2) / f * depth, (v - (h - 1) / 2) / f * depth
    p = np.radians(cam.pitch_deg)
    x = cam.x_m + depth * np.cos(p) + down * np.sin(p)
    z = cam.z_m + depth * np.sin(p) - down * np.cos(p)
    return np.stack([x, -right + cam.y_m, z], axis=-1)


def test_box_ahead_is_centred_and_sides_are_not_mirrored(scene) -> None:
    r, pose = scene
    w = get_weather(1)
    centre = (r.camera.width - 1) / 2
    cols = {}
    for name, left in (("ahead", 0.0), ("left", 4.0), ("right", -4.0)):
        _, labels, _ = r.render(*pose, _box(pose, 15.0, left), w, rgb=False)
        ys, xs = np.nonzero(labels == CarlaClass.VEHICLES)
        assert len(xs) > 20, name
        cols[name] = xs.mean()
    assert cols["ahead"] == pytest.approx(centre, abs=1.0)
    assert cols["left"] < centre - 15 and cols["right"] > centre + 15


def test_depth_back_projects_onto_the_box_face_and_the_ground(scene) -> None:
    r, pose = scene
    _, labels, depth = r.render(*pose, _box(pose, 12.0, 0.0), get_weather(1), rgb=False)
    pts = _camera_points(depth.astype(np.float64), r.camera)
    box = labels == CarlaClass.VEHICLES
    # the visible face is the box's rear face, 0.5 m before its centre (12 m ahead of the car's origin)
    front = box & (pts[..., 2] < 2.9)
    assert front.sum() > 50
    np.testing.assert_allclose(pts[front][:, 0], 11.5, atol=0.02)
    ground = (labels == CarlaClass.ROADS) & (depth < 60)
    assert ground.sum() > 1000
    np.testing.assert_allclose(pts[ground][:, 2], 0.0, atol=0.02)


def test_horizon_row_follows_the_pitch(scene) -> None:
    r, pose = scene
    _, labels, depth = r.render(*pose, None, get_weather(1), rgb=False)
    cam = r.camera
    f = (cam.width / 2) / np.tan(np.radians(cam.fov_deg) / 2)
    horizon = (cam.height - 1) / 2 + f * np.tan(np.radians(cam.pitch_deg))
    rows_sky = np.flatnonzero((labels == CarlaClass.NONE).all(axis=1))
    assert rows_sky.max() == pytest.approx(horizon, abs=1.5)
    assert (depth[labels == CarlaClass.NONE] == SKY_DEPTH_M).all()


def test_nearer_box_hides_farther_one(scene) -> None:
    r, pose = scene
    boxes = np.concatenate([_box(pose, 25.0, 0.0, CarlaClass.BUILDINGS, (2.0, 6.0, 8.0)),
                            _box(pose, 10.0, 0.0, CarlaClass.PEDESTRIANS, (0.5, 0.5, 1.8))])
    _, labels, depth = r.render(*pose, boxes[::-1].copy(), get_weather(1), rgb=False)
    ped = labels == CarlaClass.PEDESTRIANS
    assert ped.sum() > 10
    assert (depth[ped] < depth[labels == CarlaClass.BUILDINGS].min()).all()


def test_box_partly_behind_the_camera_is_clipped_not_garbled(scene) -> None:
    r, pose = scene
    # a long wall beside the car that starts behind the camera
    _, labels, _ = r.render(*pose, _box(pose, 5.0, 3.0, CarlaClass.WALLS, (30.0, 0.4, 3.0)), get_weather(1),
                            rgb=False)
    wall = labels == CarlaClass.WALLS
    ys, xs = np.nonzero(wall)
    assert len(xs) > 100
    assert xs.mean() < (r.camera.width - 1) / 2  # on the left half only
    assert not wall[:, -20:].any()
