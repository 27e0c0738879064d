"""Traffic: vehicles that follow lanes, turn at junctions and keep their distance; pedestrians on sidewalks.

All agents are advanced together with array operations; only agents that move onto a new path are touched
one by one. Every random choice comes from the generator handed to `Traffic.reset`.
"""

from __future__ import annotations

import numpy as np

from brlcli.classes import CarlaClass
from brlcli.sim.roadnet import RoadNetwork, offset_polyline
from brlcli.sim.vehicle import HEIGHT_M, LENGTH_M, WIDTH_M

CORL_TRAFFIC = {"town01": (20, 50), "town02": (15, 50)}
"""(vehicles, pedestrians) of CoRL2017's traffic per town (navigation with dynamic obstacles)."""
VEHICLE_SPEED_KMH = (20.0, 32.0)
"""Range of the traffic vehicles' cruise speeds, km/h (halved on junction connectors)."""
PEDESTRIAN_SPEED_MS = (0.9, 1.6)
PEDESTRIAN_SIZE_M = (0.5, 0.5, 1.8)
CROSS_RATE_PER_S = 0.01
"""Chance per second that a walking pedestrian starts crossing the road."""
HEADWAY_S = 1.2
STANDSTILL_GAP_M = 3.0
LOOKAHEAD_M = 30.0
LANE_HALF_CORRIDOR_M = 1.6


class _PathTable:
    """Many polylines in one monotonic table so that points on different polylines interpolate in one call."""

    def __init__(self, polylines: list[np.ndarray]) -> None:
        base, pts, cums, starts = 0.0, [], [], []
        self.lengths = np.zeros(len(polylines))
        for i, p in enumerate(polylines):
            cum = np.concatenate([[0.0], np.cumsum(np.linalg.norm(np.diff(p, axis=0), axis=1))])
            starts.append(sum(len(q) for q in pts))
            pts.append(p)
            cums.append(cum + base)
            self.lengths[i] = cum[-1]
            base += cum[-1] + 1000.0
        self.points = np.concatenate(pts)
        self.cum = np.concatenate(cums)
        self.base = np.array([c[0] for c in cums])
        self.first = np.array(starts)
        self.last = np.array([s + len(p) - 2 for s, p in zip(starts, polylines, strict=True)])

    def pose(self, path: np.ndarray, s: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """Positions (x, y in m) and headings (rad) at arc lengths `s` on polylines `path`."""
        g = self.base[path] + np.clip(s, 0.0, self.lengths[path])
        k = np.clip(np.searchsorted(self.cum, g, side="right") - 1, self.first[path], self.last[path])
        a, b = self.points[k], self.points[k + 1]
        seg = np.maximum(self.cum[k + 1] - self.cum[k], 1e-9)
        f = ((g - self.cum[k]) / seg)[:, None]
        p = a + f * (b - a)
        return p[:, 0], p[:, 1], np.arctan2(b[:, 1] - a[:, 1], b[:, 0] - a[:, 0])


class Traffic:
    """Traffic vehicles (CARLA class 10) and pedestrians (class 4) of one world."""

    def __init__(self, network: RoadNetwork, n_vehicles: int, n_pedestrians: int) -> None:
        if n_vehicles < 0 or n_pedestrians < 0:
            raise ValueError("vehicle and pedestrian counts must be >= 0")
        self.net = network
        self.n_vehicles, self.n_pedestrians = n_vehicles, n_pedestrians
        self._paths = _PathTable([p.points for p in network.paths])
        self._is_connector = np.array([p.kind == "connector" for p in network.paths])
        geo = network.town.geometry
        walk_off = geo.lane_width_m + geo.sidewalk_width_m / 2
        walks = []
        for road in network.roads:
            walks.append(offset_polyline(road.centre, walk_off))
            walks.append(offset_polyline(road.centre, -walk_off))
        self._walks = _PathTable(walks)
        self._lane_ids = network.lane_ids
        # vehicle state
        self.v_path = np.zeros(n_vehicles, np.int64)
        self.v_s = np.zeros(n_vehicles)
        self.v_speed = np.zeros(n_vehicles)
        self.v_cruise = np.zeros(n_vehicles)
        self.v_tint = np.zeros(n_vehicles)
        self.v_held = np.zeros(n_vehicles, bool)
        self.v_pose = np.zeros((n_vehicles, 3))  # x, y, yaw (rad)
        # pedestrian state
        self.p_walk = np.zeros(n_pedestrians, np.int64)
        self.p_s = np.zeros(n_pedestrians)
        self.p_dir = np.ones(n_pedestrians)
        self.p_speed = np.zeros(n_pedestrians)
        self.p_tint = np.zeros(n_pedestrians)
        self.p_cross = np.full(n_pedestrians, -1.0)  # crossing progress 0..1, -1 when walking
        self.p_from = np.zeros((n_pedestrians, 2))
        self.p_to = np.zeros((n_pedestrians, 2))
        self.p_held = np.zeros(n_pedestrians, bool)
        self.p_pose = np.zeros((n_pedestrians, 3))
        self._rng = np.random.default_rng(0)

    # ------------------------------------------------------------------------------------------ set-up
    def reset(self, rng: np.random.Generator, keep_clear: tuple[float, float] | None = None,
              clear_radius_m: float = 20.0) -> None:
        """Scatter vehicles on lanes and pedestrians on sidewalks, away from `keep_clear` (x, y)."""
        self._rng = rng
        lengths = self._paths.lengths[self._lane_ids]
        placed: list[tuple[float, float]] = []
        for i in range(self.n_vehicles):
            for _attempt in range(200):
                lane = int(rng.choice(self._lane_ids, p=lengths / lengths.sum()))
                s = float(rng.uniform(0, self._paths.lengths[lane]))
                x, y, _ = self._paths.pose(np.array([lane]), np.array([s]))
                if keep_clear is not None and np.hypot(x[0] - keep_clear[0], y[0] - keep_clear[1]) < clear_radius_m:
                    continue
                if any(np.hypot(x[0] - px, y[0] - py) < 12.0 for px, py in placed):
                    continue
                break
            placed.append((float(x[0]), float(y[0])))
            self.v_path[i], self.v_s[i] = lane, s
        lo, hi = VEHICLE_SPEED_KMH
        self.v_cruise[:] = rng.uniform(lo, hi, self.n_vehicles) / 3.6
        self.v_speed[:] = 0.0
        self.v_tint[:] = rng.uniform(0, 1, self.n_vehicles)
        self.v_held[:] = False
        n_walks = len(self._walks.lengths)
        self.p_walk[:] = rng.integers(0, n_walks, self.n_pedestrians)
        self.p_s[:] = rng.uniform(0, 1, self.n_pedestrians) * self._walks.lengths[self.p_walk]
        self.p_dir[:] = rng.choice([-1.0, 1.0], self.n_pedestrians)
        self.p_speed[:] = rng.uniform(*PEDESTRIAN_SPEED_MS, self.n_pedestrians)
        self.p_tint[:] = rng.uniform(0, 1, self.n_pedestrians)
        self.p_cross[:] = -1.0
        self.p_held[:] = False
        self._update_poses()
        if keep_clear is not None:  # pedestrians too close to the ego start walk from elsewhere
            near = np.hypot(self.p_pose[:, 0] - keep_clear[0], self.p_pose[:, 1] - keep_clear[1]) < 8.0
            self.p_walk[near] = (self.p_walk[near] + 2) % n_walks
            self._update_poses()

    def hold_vehicle(self, i: int, x_m: float, y_m: float, yaw_deg: float) -> None:
        """Park vehicle `i` at a fixed pose until the next reset (for scripted scenarios and tests)."""
        self.v_held[i] = True
        self.v_speed[i] = 0.0
        self.v_pose[i] = (x_m, y_m, np.radians(yaw_deg))

    def hold_pedestrian(self, i: int, x_m: float, y_m: float) -> None:
        """Stand pedestrian `i` still at a fixed position until the next reset."""
        self.p_held[i] = True
        self.p_pose[i] = (x_m, y_m, 0.0)

    # ------------------------------------------------------------------------------------------ update
    def _update_poses(self) -> None:
        free = ~self.v_held
        if free.any():
            x, y, yaw = self._paths.pose(self.v_path[free], self.v_s[free])
            self.v_pose[free] = np.stack([x, y, yaw], axis=1)
        walking = (~self.p_held) & (self.p_cross < 0)
        if walking.any():
            x, y, yaw = self._walks.pose(self.p_walk[walking], self.p_s[walking])
            yaw = np.where(self.p_dir[walking] > 0, yaw, yaw + np.pi)
            self.p_pose[walking] = np.stack([x, y, yaw], axis=1)
        crossing = (~self.p_held) & (self.p_cross >= 0)
        if crossing.any():
            t = self.p_cross[crossing][:, None]
            p = self.p_from[crossing] + t * (self.p_to[crossing] - self.p_from[crossing])
            d = self.p_to[crossing] - self.p_from[crossing]
            self.p_pose[crossing] = np.column_stack([p, np.arctan2(d[:, 1], d[:, 0])])

    def step(self, dt_s: float, ego_x_m: float, ego_y_m: float) -> None:
        """Advance every agent by `dt_s` seconds; the ego car at (x, y) is an obstacle for the vehicles."""
        if self.n_vehicles:
            self._step_vehicles(dt_s, ego_x_m, ego_y_m)
        if self.n_pedestrians:
            self._step_pedestrians(dt_s)
        self._update_poses()

    def _step_vehicles(self, dt_s: float, ego_x: float, ego_y: float) -> None:
        pose = self.v_pose
        obs = np.concatenate([pose[:, :2], [[ego_x, ego_y]], self.p_pose[:, :2]])
        obs_half = np.concatenate([np.full(self.n_vehicles + 1, LENGTH_M / 2),
                                   np.full(self.n_pedestrians, PEDESTRIAN_SIZE_M[0] / 2)])
        c, s = np.cos(pose[:, 2]), np.sin(pose[:, 2])
        dx = obs[None, :, 0] - pose[:, None, 0]  # (V, O)
        dy = obs[None, :, 1] - pose[:, None, 1]
        # only pairs within the look-ahead box can be ahead (|fwd| < LOOKAHEAD_M and |lat| < the corridor), so the
        # rotation runs on those pairs alone: Dense traffic (100 vehicles, 250 pedestrians) has 35,100 pairs
        reach = LOOKAHEAD_M + LANE_HALF_CORRIDOR_M
        near = (np.abs(dx) < reach) & (np.abs(dy) < reach)
        near[np.arange(self.n_vehicles), np.arange(self.n_vehicles)] = False
        vi, oi = np.nonzero(near)
        rx, ry = dx[vi, oi], dy[vi, oi]
        fwd = rx * c[vi] + ry * s[vi]
        lat = -rx * s[vi] + ry * c[vi]
        ahead = (fwd > 0.1) & (fwd < LOOKAHEAD_M) & (np.abs(lat) < LANE_HALF_CORRIDOR_M)
        gap = np.full(self.n_vehicles, np.inf)
        np.minimum.at(gap, vi[ahead], fwd[ahead] - LENGTH_M / 2 - obs_half[oi[ahead]])
        cruise = np.where(self._is_connector[self.v_path], 0.5 * self.v_cruise, self.v_cruise)
        desired = np.clip((gap - STANDSTILL_GAP_M) / HEADWAY_S, 0.0, cruise)
        self.v_speed += np.clip(desired - self.v_speed, -7.0 * dt_s, 2.5 * dt_s)
        self.v_speed[self.v_held] = 0.0
        self.v_s += self.v_speed * dt_s
        over = np.flatnonzero((self.v_s > self._paths.lengths[self.v_path]) & ~self.v_held)
        for i in over:
            while self.v_s[i] > self._paths.lengths[self.v_path[i]]:
                self.v_s[i] -= self._paths.lengths[self.v_path[i]]
                succ = self.net.successors[int(self.v_path[i])]
                self.v_path[i] = succ[int(self._rng.integers(len(succ)))]

    def _step_pedestrians(self, dt_s: float) -> None:
        walking = (~self.p_held) & (self.p_cross < 0)
        self.p_s[walking] += (self.p_dir * self.p_speed * dt_s)[walking]
        length = self._walks.lengths[self.p_walk]
        turn = walking & ((self.p_s < 0) | (self.p_s > length))
        self.p_dir[turn] *= -1.0
        self.p_s[:] = np.clip(self.p_s, 0, length)
        crossing = (~self.p_held) & (self.p_cross >= 0)
        if crossing.any():
            dist = np.maximum(np.linalg.norm(self.p_to - self.p_from, axis=1), 1e-6)
            self.p_cross[crossing] += (self.p_speed * dt_s / dist)[crossing]
            done = crossing & (self.p_cross >= 1.0)
            if done.any():
                other = self.p_walk[done] ^ 1  # the same road's other sidewalk
                frac = self.p_s[done] / self._walks.lengths[self.p_walk[done]]
                self.p_walk[done] = other
                self.p_s[done] = frac * self._walks.lengths[other]  # both sidewalks run along the road
                self.p_cross[done] = -1.0
        draws = self._rng.uniform(size=self.n_pedestrians)
        start = walking & (draws < CROSS_RATE_PER_S * dt_s) & (self.p_s > 10) & (self.p_s < length - 10)
        for i in np.flatnonzero(start):
            other = int(self.p_walk[i] ^ 1)
            frac = self.p_s[i] / self._walks.lengths[self.p_walk[i]]
            x0, y0, _ = self._walks.pose(self.p_walk[i : i + 1], self.p_s[i : i + 1])
            x1, y1, _ = self._walks.pose(np.array([other]), np.array([frac * self._walks.lengths[other]]))
            self.p_from[i] = (x0[0], y0[0])
            self.p_to[i] = (x1[0], y1[0])
            self.p_cross[i] = 0.0

    # ------------------------------------------------------------------------------------------ output
    def boxes(self) -> np.ndarray:
        """Rows (class, x, y, z_bottom, length, width, height, yaw_rad, tint) of every agent, for the camera."""
        v = np.column_stack([np.full(self.n_vehicles, float(CarlaClass.VEHICLES)), self.v_pose[:, :2],
                             np.zeros(self.n_vehicles), np.full(self.n_vehicles, LENGTH_M),
                             np.full(self.n_vehicles, WIDTH_M), np.full(self.n_vehicles, HEIGHT_M),
                             self.v_pose[:, 2], self.v_tint])
        lp, wp, hp = PEDESTRIAN_SIZE_M
        p = np.column_stack([np.full(self.n_pedestrians, float(CarlaClass.PEDESTRIANS)), self.p_pose[:, :2],
                             np.zeros(self.n_pedestrians), np.full(self.n_pedestrians, lp),
                             np.full(self.n_pedestrians, wp), np.full(self.n_pedestrians, hp),
                             self.p_pose[:, 2], self.p_tint])
        return np.concatenate([v, p]) if len(v) or len(p) else np.zeros((0, 9))
