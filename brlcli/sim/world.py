"""A driving world: one town in its own pybullet client, the ego car, traffic, the camera and measurements."""

from __future__ import annotations

import math
from dataclasses import asdict, dataclass, field

import numpy as np

from brlcli.classes import CarlaClass
from brlcli.errors import BrlInputError
from brlcli.sim._bullet import connect_direct, quiet_console
from brlcli.sim._bullet import pybullet as pb
from brlcli.sim.camera import CameraConfig, Renderer
from brlcli.sim.roadnet import RoadNetwork
from brlcli.sim.town import Town, load_town
from brlcli.sim.townmap import TownMap
from brlcli.sim.traffic import PEDESTRIAN_SIZE_M, Traffic
from brlcli.sim.vehicle import HEIGHT_M, LENGTH_M, MASS_KG, WIDTH_M, Control, VehicleState, advance
from brlcli.sim.weather import Weather, get_weather

FRAME_DT_S = 0.1
"""Simulated time per frame (CARLA CoRL2017 runs at 10 fps)."""
MIN_COLLISION_SPEED_KMH = 1.0
"""Below this speed no collision intensity is recorded (as in CARLA)."""
FOOTPRINT_SAMPLES = (9, 4)
"""Sample grid over the car's 2-D footprint for the intersection measures (along, across)."""
_PARK_Z_M = -100.0
_SYNC_RADIUS_M = 40.0

# which static classes are solid obstacles (everything but flat ground)
_SOLID = (CarlaClass.BUILDINGS, CarlaClass.FENCES, CarlaClass.POLES, CarlaClass.VEGETATION, CarlaClass.WALLS,
          CarlaClass.TRAFFIC_SIGNS)


@dataclass(frozen=True)
class Measurements:
    """Per-frame measurements with CARLA 0.8's meanings (speed km/h, position m, yaw deg, time s)."""

    forward_speed_kmh: float
    x: float
    y: float
    yaw_deg: float
    game_time_s: float
    collision_vehicles: float
    collision_pedestrians: float
    collision_other: float
    intersection_offroad: float
    intersection_otherlane: float

    def as_dict(self) -> dict[str, float]:
        """Field name -> value."""
        return asdict(self)


@dataclass(frozen=True)
class Frame:
    """One simulated frame: camera images (None when not rendered) and measurements."""

    frame: int
    measurements: Measurements
    rgb: np.ndarray | None = None
    labels: np.ndarray | None = None
    depth: np.ndarray | None = None
    control: Control = field(default_factory=Control)


def _quat_yaw(yaw: float) -> tuple[float, float, float, float]:
    return (0.0, 0.0, math.sin(yaw / 2), math.cos(yaw / 2))


class World:
    """A town with the ego car, traffic and a forward camera, stepped in 0.1 s frames.

    Each world owns its pybullet client (no global state), so several worlds can live in one process.
    """

    def __init__(self, town: Town | str, weather: int | str | Weather = 1, seed: int = 0, vehicles: int = 0,
                 pedestrians: int = 0, camera: CameraConfig | None = None, substeps: int = 2,
                 road_user_contact: bool = True) -> None:
        self.town = town if isinstance(town, Town) else load_town(town)
        self.weather = get_weather(weather)
        if vehicles < 0 or pedestrians < 0:
            raise BrlInputError("vehicle and pedestrian counts must be >= 0")
        if substeps < 1:
            raise BrlInputError("substeps must be >= 1")
        self.seed = int(seed)
        self.camera = camera or CameraConfig()
        self.substeps = substeps
        self.road_user_contact = road_user_contact  # False: the ego car passes through road users (ghost traffic)
        self.network = RoadNetwork(self.town)
        self.map = TownMap(self.network)
        static = self.town.objects.copy()
        static[:, 7] = np.radians(static[:, 7])
        self.renderer = Renderer(self.map, static, self.camera)
        self.traffic = Traffic(self.network, vehicles, pedestrians)
        self._client = connect_direct()
        self._build_physics(static)
        self.ego = VehicleState()
        self._rng = np.random.default_rng(self.seed)
        self._episode = -1
        self.frame_index = 0
        self.rgb_frames = True  # whether rendered frames carry the RGB image (False: labels and depth only, faster)
        self._collisions = np.zeros(3)  # vehicles, pedestrians, other
        u = (np.arange(FOOTPRINT_SAMPLES[0]) + 0.5) / FOOTPRINT_SAMPLES[0] - 0.5
        v = (np.arange(FOOTPRINT_SAMPLES[1]) + 0.5) / FOOTPRINT_SAMPLES[1] - 0.5
        uu, vv = np.meshgrid(u * LENGTH_M, v * WIDTH_M)
        self._foot_u, self._foot_v = uu.ravel(), vv.ravel()

    # ------------------------------------------------------------------------------------------ physics
    def _build_physics(self, static: np.ndarray) -> None:
        c = self._client
        pb.setGravity(0, 0, 0, physicsClientId=c)
        pb.setTimeStep(FRAME_DT_S / self.substeps, physicsClientId=c)
        pb.setPhysicsEngineParameter(deterministicOverlappingPairs=1, numSolverIterations=10, physicsClientId=c)
        self._body_kind: dict[int, int] = {}  # body id -> 0 vehicle, 1 pedestrian, 2 other
        self.body_classes: dict[int, CarlaClass] = {}  # every pybullet body -> its CARLA class
        for cls in _SOLID:
            rows = static[static[:, 0] == cls]
            for chunk in range(0, len(rows), 256):
                part = rows[chunk : chunk + 256]
                shape = pb.createCollisionShapeArray(
                    [pb.GEOM_BOX] * len(part),
                    halfExtents=[[r[4] / 2, r[5] / 2, r[6] / 2] for r in part],
                    collisionFramePositions=[[r[1], r[2], r[3] + r[6] / 2] for r in part],
                    collisionFrameOrientations=[_quat_yaw(r[7]) for r in part],
                    physicsClientId=c,
                )
                body = pb.createMultiBody(0, shape, physicsClientId=c)
                self._body_kind[body] = 2
                self.body_classes[body] = CarlaClass(cls)
        ego_shape = pb.createCollisionShape(pb.GEOM_BOX, halfExtents=[LENGTH_M / 2, WIDTH_M / 2, HEIGHT_M / 2],
                                            physicsClientId=c)
        self._ego_z = HEIGHT_M / 2 + 0.02
        self._ego_body = pb.createMultiBody(MASS_KG, ego_shape, basePosition=[0, 0, self._ego_z], physicsClientId=c)
        pb.changeDynamics(self._ego_body, -1, linearDamping=0.0, angularDamping=0.0, lateralFriction=0.3,
                          restitution=0.0, physicsClientId=c)
        self.body_classes[self._ego_body] = CarlaClass.VEHICLES
        veh_shape = pb.createCollisionShape(pb.GEOM_BOX, halfExtents=[LENGTH_M / 2, WIDTH_M / 2, HEIGHT_M / 2],
                                            physicsClientId=c)
        lp, wp, hp = PEDESTRIAN_SIZE_M
        ped_shape = pb.createCollisionShape(pb.GEOM_BOX, halfExtents=[lp / 2, wp / 2, hp / 2], physicsClientId=c)
        self._veh_bodies, self._ped_bodies = [], []
        for i in range(self.traffic.n_vehicles):
            b = pb.createMultiBody(0, veh_shape, basePosition=[i * 10.0, 0, _PARK_Z_M], physicsClientId=c)
            self._veh_bodies.append(b)
            self._body_kind[b] = 0
            self.body_classes[b] = CarlaClass.VEHICLES
        for i in range(self.traffic.n_pedestrians):
            b = pb.createMultiBody(0, ped_shape, basePosition=[i * 10.0, 50, _PARK_Z_M], physicsClientId=c)
            self._ped_bodies.append(b)
            self._body_kind[b] = 1
            self.body_classes[b] = CarlaClass.PEDESTRIANS
        self._synced = np.zeros(len(self._veh_bodies) + len(self._ped_bodies), bool)
        if not self.road_user_contact:  # outside the paper: road users are seen and move, but never touch the car
            for b in self._veh_bodies + self._ped_bodies:
                pb.setCollisionFilterPair(self._ego_body, b, -1, -1, 0, physicsClientId=c)
        # every episode starts from this saved state, so that an episode does not depend on the ones before it
        self._initial_state = pb.saveState(physicsClientId=c)

    def _sync_traffic(self) -> None:
        """Move traffic bodies near the ego to their poses; park the rest out of the way."""
        c = self._client
        t = self.traffic
        poses = np.concatenate([t.v_pose, t.p_pose])
        heights = [HEIGHT_M / 2 + 0.02] * t.n_vehicles + [PEDESTRIAN_SIZE_M[2] / 2] * t.n_pedestrians
        near = np.hypot(poses[:, 0] - self.ego.x_m, poses[:, 1] - self.ego.y_m) < _SYNC_RADIUS_M
        bodies = self._veh_bodies + self._ped_bodies
        for i in np.flatnonzero(near | self._synced):
            if near[i]:
                pb.resetBasePositionAndOrientation(bodies[i], [poses[i, 0], poses[i, 1], heights[i]],
                                                   _quat_yaw(poses[i, 2]), physicsClientId=c)
            else:
                pb.resetBasePositionAndOrientation(bodies[i], [i * 10.0, 0, _PARK_Z_M], (0, 0, 0, 1),
                                                   physicsClientId=c)
        self._synced = near

    def _place_ego(self) -> None:
        pb.resetBasePositionAndOrientation(self._ego_body, [self.ego.x_m, self.ego.y_m, self._ego_z],
                                           _quat_yaw(self.ego.yaw_rad), physicsClientId=self._client)

    # ------------------------------------------------------------------------------------------ API
    def reset(self, pose: tuple[float, float, float] | None = None, seed: int | None = None) -> Frame:
        """Start an episode at `pose` (x_m, y_m, yaw_deg) or at a spawn pose drawn from the world's generator."""
        if seed is not None:
            self._rng = np.random.default_rng(int(seed))
        self._episode += 1
        if pose is None:
            pose = tuple(self.town.spawn_poses[int(self._rng.integers(len(self.town.spawn_poses)))])
        x, y, yaw_deg = (float(v) for v in pose)
        if not all(math.isfinite(v) for v in (x, y, yaw_deg)):
            raise BrlInputError(f"start pose {pose} is not finite")
        self.ego = VehicleState(x_m=x, y_m=y, yaw_rad=math.radians(yaw_deg))
        pb.restoreState(self._initial_state, physicsClientId=self._client)
        self._synced[:] = False
        self._place_ego()
        self.traffic.reset(np.random.default_rng(self._rng.integers(2**63)), keep_clear=(x, y))
        self._sync_traffic()
        self.frame_index = 0
        self._collisions[:] = 0.0
        self._frame_rng_seed = int(self._rng.integers(2**63))
        return self._make_frame(Control(), render=True)

    def step(self, control: Control, render: bool = True) -> Frame:
        """Advance one 0.1 s frame under `control`; render the camera when `render` is true."""
        if self._episode < 0:
            raise RuntimeError("call reset() before step()")
        ctl = control.clipped()
        c = self._client
        dt = FRAME_DT_S / self.substeps
        self.traffic.step(FRAME_DT_S, self.ego.x_m, self.ego.y_m, self.ego.yaw_rad)
        self._sync_traffic()
        for _ in range(self.substeps):
            speed_before = abs(self.ego.speed_ms) * 3.6
            v, yaw_rate = advance(self.ego, ctl, dt)
            yaw = self.ego.yaw_rad
            pb.resetBaseVelocity(self._ego_body, [v * math.cos(yaw), v * math.sin(yaw), 0.0], [0.0, 0.0, yaw_rate],
                                 physicsClientId=c)
            pb.stepSimulation(physicsClientId=c)
            contacts = pb.getContactPoints(bodyA=self._ego_body, physicsClientId=c)
            if contacts and speed_before >= MIN_COLLISION_SPEED_KMH:
                for cp in contacts:
                    self._collisions[self._body_kind.get(cp[2], 2)] += cp[9] * dt
            pos, orn = pb.getBasePositionAndOrientation(self._ego_body, physicsClientId=c)
            lin, _ = pb.getBaseVelocity(self._ego_body, physicsClientId=c)
            x_, y_, z_, w_ = orn
            yaw = math.atan2(2 * (w_ * z_ + x_ * y_), 1 - 2 * (y_ * y_ + z_ * z_))
            self.ego.x_m, self.ego.y_m, self.ego.yaw_rad = pos[0], pos[1], yaw
            self.ego.speed_ms = lin[0] * math.cos(yaw) + lin[1] * math.sin(yaw)
            self._place_ego()
        self.frame_index += 1
        return self._make_frame(ctl, render)

    def render(self, rgb: bool = True) -> tuple[np.ndarray | None, np.ndarray, np.ndarray]:
        """Camera images at the current state: RGB (H, W, 3) uint8 (None when `rgb` is false; the labels and depth
        are the same either way), labels (H, W) uint8, depth (H, W) float32 m."""
        rng = np.random.default_rng([self._frame_rng_seed, self.frame_index])
        rgb, labels, depth = self.renderer.render(self.ego.x_m, self.ego.y_m, self.ego.yaw_rad,
                                                  self.traffic.boxes(), self.weather, rng, rgb=rgb)
        return rgb, labels, depth  # type: ignore[return-value]

    def _make_frame(self, ctl: Control, render: bool) -> Frame:
        e = self.ego
        cy, sy = math.cos(e.yaw_rad), math.sin(e.yaw_rad)
        fx = e.x_m + cy * self._foot_u - sy * self._foot_v
        fy = e.y_m + sy * self._foot_u + cy * self._foot_v
        offroad, otherlane = self.map.footprint_shares(fx, fy, e.yaw_rad)
        m = Measurements(
            forward_speed_kmh=e.speed_ms * 3.6, x=e.x_m, y=e.y_m,
            yaw_deg=math.degrees(math.atan2(sy, cy)), game_time_s=round(self.frame_index * FRAME_DT_S, 6),
            collision_vehicles=float(self._collisions[0]), collision_pedestrians=float(self._collisions[1]),
            collision_other=float(self._collisions[2]),
            intersection_offroad=offroad, intersection_otherlane=otherlane,
        )
        if render:
            rgb, labels, depth = self.render(rgb=self.rgb_frames)
            frame = Frame(self.frame_index, m, rgb, labels, depth, ctl)
        else:
            frame = Frame(self.frame_index, m, control=ctl)
        return frame

    def set_weather(self, weather: int | str | Weather) -> None:
        """Change the weather (affects RGB only)."""
        self.weather = get_weather(weather)

    def close(self) -> None:
        """Disconnect the pybullet client."""
        if self._client is not None and self._client >= 0:
            try:
                with quiet_console():
                    pb.disconnect(physicsClientId=self._client)
            except pb.error:
                pass
            self._client = -1

    def __enter__(self) -> World:
        return self

    def __exit__(self, *exc: object) -> None:
        self.close()

    def __del__(self) -> None:
        try:
            self.close()
        except Exception:
            pass
