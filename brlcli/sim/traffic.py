"""Traffic: vehicles that follow lanes, take turns at junctions and brake for whatever is on their path;
pedestrians on sidewalks who cross where no car is near and never walk into one (docs/simulator.md).

All agents are advanced together with array operations (the path test in a compiled kernel,
`brlcli.sim._traffic_kernels`); only agents that reach a junction or a new path are touched one by one. Every
random choice comes from the generator handed to `Traffic.reset`.
"""

from __future__ import annotations

import math

import numpy as np

from brlcli.classes import CarlaClass
from brlcli.sim._traffic_kernels import path_gaps, sample_paths
from brlcli.sim.roadnet import RoadNetwork, offset_polyline
from brlcli.sim.vehicle import HEIGHT_M, LENGTH_M, WIDTH_M

CORL_TRAFFIC = {"town01": (20, 50), "town02": (15, 50)}
"""(vehicles, pedestrians) of CoRL2017's traffic per town (navigation with dynamic obstacles)."""
NOCRASH_TRAFFIC = {
    "town01": {"empty": (0, 0), "regular": (20, 50), "dense": (100, 250)},
    "town02": {"empty": (0, 0), "regular": (15, 50), "dense": (70, 150)},
}
"""(vehicles, pedestrians) of NoCrash's traffic levels per town."""
VEHICLE_SPEED_KMH = (20.0, 32.0)
"""Range of the traffic vehicles' cruise speeds, km/h (halved on junction connectors)."""
PEDESTRIAN_SPEED_MS = (0.9, 1.6)
PEDESTRIAN_SIZE_M = (0.5, 0.5, 1.8)
CROSS_RATE_PER_S = 0.01
"""Chance per second that a walking pedestrian starts crossing the road."""
HEADWAY_S = 1.2
STANDSTILL_GAP_M = 3.0
LOOKAHEAD_M = 30.0
PATH_SAMPLES_M = np.arange(1.5, LOOKAHEAD_M + 0.1, 1.5)
"""Distances (m) ahead of a vehicle's centre, along its lane and the turn it will take, at which its path is
sampled; a road user whose centre is within PATH_HALF_M of a sample is an obstacle on the path (a leader, crossing
traffic in a junction, the ego car, a pedestrian on the road)."""
PATH_HALF_M = {"vehicle": 2.1, "pedestrian": 1.5}
CAR_CIRCLES_M = np.array([-1.5, 0.0, 1.5])
"""A car, as an obstacle, is three circles at these offsets (m) along its heading, so a car standing at an angle (the
ego car in a turn) blocks the path its body covers, not only its centre's."""
CAR_CIRCLE_REACH_M = LENGTH_M / 2 - 1.5
"""How far a car's body reaches beyond its end circles along its heading (m)."""


def car_circles(xy: np.ndarray, yaw_rad: np.ndarray) -> np.ndarray:
    """Centres (N * 3, 2) of the CAR_CIRCLES_M circles of N cars at `xy` (N, 2) heading `yaw_rad` (N,), car-major."""
    heading = np.column_stack([np.cos(yaw_rad), np.sin(yaw_rad)])
    return (xy[:, None, :] + CAR_CIRCLES_M[None, :, None] * heading[:, None, :]).reshape(-1, 2)

JUNCTION_APPROACH_M = 15.0
"""Junction right of way (brl's rule in place of CARLA 0.8's traffic lights; docs/simulator.md): a vehicle this close
to the end of its lane reserves the turn it drew (when the junction came LOOKAHEAD_M ahead) if no conflicting turn
(CONFLICT_M) is driven or reserved, the ego car is not inside the junction and its exit lane has room (SLOT_M),
else it stops at its lane's end. Queue heads are served longest-waiting first (PATIENCE_S)."""
CONFLICT_M = 3.0
"""Two junction connectors whose paths come this close conflict: their vehicles never hold the junction together."""
PATIENCE_S = 6.0
"""A vehicle that has waited this long at a junction claims its turn: no vehicle starts a movement that conflicts
with it until it has gone (no approach is starved)."""
SLOT_M = LENGTH_M + STANDSTILL_GAP_M
"""Queue space one vehicle takes (m). Don't block the box: a vehicle takes a junction's reservation only when the lane
it will leave the junction by has room for it behind its last vehicle, counting the vehicles already in the
junction towards that lane (its turn is drawn when it nears the junction), so a vehicle in a junction can always
leave it and junctions never gridlock."""
CROSS_CLEAR_M = 15.0
"""A pedestrian starts crossing only when no vehicle (the ego car included) is within this distance of its
crossing line."""
PEDESTRIAN_WAIT_S = 1.0
"""A crossing pedestrian stands still while the point 0.8 m ahead of it lies in or near a vehicle's body (the ego
car's included): within 0.3 m of a standing vehicle, or for a moving one within 0.5 m or in the road it covers in
the next PEDESTRIAN_WAIT_S seconds, so it never walks into a car."""
PEDESTRIAN_PATIENCE_S = 4.0
"""A crossing pedestrian that has stood this long for a car (which may in turn wait for it) walks back to the
sidewalk it came from."""


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


def _conflicts(network: RoadNetwork) -> np.ndarray:
    """(P, P) bool: connectors of one junction whose paths come within CONFLICT_M of each other (crossing or merging);
    connectors from the same approach lane do not conflict (their vehicles queue on that lane)."""
    n = len(network.paths)
    out = np.zeros((n, n), bool)
    approach = {c: lane.index for lane in network.paths if lane.kind == "lane" for c in network.successors[lane.index]}
    conns = [p for p in network.paths if p.kind == "connector"]
    dense = {}
    for p in conns:
        seg = np.linalg.norm(np.diff(p.points, axis=0), axis=1)
        cum = np.concatenate([[0.0], np.cumsum(seg)])
        s = np.arange(0.0, cum[-1] + 0.25, 0.5)
        dense[p.index] = np.column_stack([np.interp(s, cum, p.points[:, 0]), np.interp(s, cum, p.points[:, 1])])
    for a in conns:
        for b in conns:
            if a.index < b.index and a.from_node == b.from_node and approach.get(a.index) != approach.get(b.index):
                d = np.linalg.norm(dense[a.index][:, None, :] - dense[b.index][None, :, :], axis=2).min()
                out[a.index, b.index] = out[b.index, a.index] = d < CONFLICT_M
    return out


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
        self.v_go = np.zeros(n_vehicles, bool)  # a vehicle still on its lane holds a reservation of its next connector
        self.v_wait_s = np.zeros(n_vehicles)  # how long a vehicle has waited at its lane's end
        self.v_next = np.full(n_vehicles, -1, np.int64)  # the connector a vehicle nearing a junction will take
        self._path_to = np.array([p.to_node for p in network.paths])
        self._conflict = _conflicts(network)
        self._ends_at_junction = np.array([p.kind == "lane" and bool(network.is_junction[p.to_node])
                                           for p in network.paths])
        self._node_xy = np.asarray(network.town.nodes_m, dtype=float)
        self._node_radius = np.full(len(self._node_xy), 0.0)  # ego inside a junction: nearer its centre than this
        for p in network.paths:
            if p.kind == "lane" and network.is_junction[p.to_node]:
                r = float(np.hypot(*(p.points[-1] - self._node_xy[p.to_node]))) - 1.0
                self._node_radius[p.to_node] = r if self._node_radius[p.to_node] == 0.0 else min(
                    r, self._node_radius[p.to_node])
        self._exit_lane = np.array([network.successors[p.index][0] if p.kind == "connector" else -1
                                    for p in network.paths])
        self._first_successor = np.array([network.successors[p.index][0] for p in network.paths])
        self._ego = np.zeros(2)
        self._ego_yaw, self._ego_speed = 0.0, 0.0
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
        self.p_wait_s = np.zeros(n_pedestrians)  # how long a crossing pedestrian has stood for a car
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
            best, best_clear = (0, 0.0, 0.0, 0.0), -1.0
            for _attempt in range(200):  # the first spot 12 m from every placed vehicle, else the most spacious one
                lane = int(rng.choice(self._lane_ids, p=lengths / lengths.sum()))
                s = float(rng.uniform(0, self._paths.lengths[lane]))
                x, y, _ = self._paths.pose(np.array([lane]), np.array([s]))
                if keep_clear is not None and np.hypot(x[0] - keep_clear[0], y[0] - keep_clear[1]) < clear_radius_m:
                    continue
                clear = min((np.hypot(x[0] - px, y[0] - py) for px, py in placed), default=np.inf)
                if clear > best_clear:
                    best, best_clear = (lane, s, float(x[0]), float(y[0])), clear
                if clear >= 12.0:
                    break
            lane, s, x0, y0 = best
            placed.append((x0, y0))
            self.v_path[i], self.v_s[i] = lane, s
        lo, hi = VEHICLE_SPEED_KMH
        self.v_cruise[:] = rng.uniform(lo, hi, self.n_vehicles) / 3.6
        self.v_speed[:] = 0.0
        self.v_tint[:] = rng.uniform(0, 1, self.n_vehicles)
        self.v_held[:] = False
        self.v_go[:] = False
        self.v_wait_s[:] = 0.0
        self._ego[:] = np.nan  # no ego speed until its second position
        self.v_next[:] = -1
        n_walks = len(self._walks.lengths)
        self.p_walk[:] = rng.integers(0, n_walks, self.n_pedestrians)
        self.p_s[:] = rng.uniform(0, 1, self.n_pedestrians) * self._walks.lengths[self.p_walk]
        self.p_dir[:] = rng.choice([-1.0, 1.0], self.n_pedestrians)
        self.p_speed[:] = rng.uniform(*PEDESTRIAN_SPEED_MS, self.n_pedestrians)
        self.p_tint[:] = rng.uniform(0, 1, self.n_pedestrians)
        self.p_cross[:] = -1.0
        self.p_held[:] = False
        self.p_wait_s[:] = 0.0
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

    def step(self, dt_s: float, ego_x_m: float, ego_y_m: float, ego_yaw_rad: float | None = None) -> None:
        """Advance every agent by `dt_s` seconds; the ego car at (x, y) is an obstacle for the vehicles and pedestrians
        (its heading, when not given, is taken from its motion)."""
        if not (self.n_vehicles or self.n_pedestrians):
            return
        ex, ey = float(self._ego[0]), float(self._ego[1])
        moved = math.hypot(ego_x_m - ex, ego_y_m - ey)  # nan after a reset
        self._ego_speed = moved / dt_s if 1e-6 < moved < 10.0 else 0.0  # a jump is a reset, not a speed
        if ego_yaw_rad is not None:
            self._ego_yaw = float(ego_yaw_rad)
        elif self._ego_speed > 0.0:
            self._ego_yaw = math.atan2(ego_y_m - ey, ego_x_m - ex)
        self._ego[0], self._ego[1] = ego_x_m, ego_y_m
        if self.n_vehicles:
            self._step_vehicles(dt_s, ego_x_m, ego_y_m)
        if self.n_pedestrians:
            self._step_pedestrians(dt_s)
        self._update_poses()

    def _step_vehicles(self, dt_s: float, ego_x: float, ego_y: float) -> None:
        junction_gap = self._junction_stop_gap(dt_s, ego_x, ego_y)  # draws the turn of vehicles nearing a junction
        pose = self.v_pose
        V = self.n_vehicles
        # vehicles (and the ego car) as three circles along their length, pedestrians as one
        car_xy = np.concatenate([pose[:, :2], self._ego[None, :]])
        circles = car_circles(car_xy, np.append(pose[:, 2], self._ego_yaw))
        obs = np.concatenate([circles, self.p_pose[:, :2]])
        n_circles = len(circles)
        owner = np.concatenate([np.repeat(np.arange(V + 1), len(CAR_CIRCLES_M)), np.full(self.n_pedestrians, -1)])
        obs_half = np.concatenate([np.full(n_circles, CAR_CIRCLE_REACH_M), np.full(self.n_pedestrians,
                                                                                  PEDESTRIAN_SIZE_M[0] / 2)])
        corridor = np.concatenate([np.full(n_circles, PATH_HALF_M["vehicle"]),
                                   np.full(self.n_pedestrians, PATH_HALF_M["pedestrian"])])
        gap = path_gaps(pose, self._path_samples(), obs, owner, car_xy, corridor, obs_half, PATH_SAMPLES_M,
                        LOOKAHEAD_M + PATH_HALF_M["vehicle"], LENGTH_M)
        # a leader on the same path by arc length (exact, also between two path samples)
        ds = self.v_s[None, :] - self.v_s[:, None]
        ds[(self.v_path[None, :] != self.v_path[:, None]) | (ds <= 0.0)] = np.inf
        gap = np.minimum(gap, ds.min(axis=1) - LENGTH_M)
        gap = np.minimum(gap, junction_gap)
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
                nxt = int(self.v_next[i])
                self.v_path[i] = nxt if nxt >= 0 else succ[int(self._rng.integers(len(succ)))]
                self.v_next[i] = -1
                self.v_go[i] = False

    def _junction_stop_gap(self, dt_s: float, ego_x: float, ego_y: float) -> np.ndarray:
        """Per vehicle: the distance to its lane's end where it must wait for a junction (inf where it may go)."""
        out = np.full(self.n_vehicles, np.inf)
        remaining = self._paths.lengths[self.v_path] - self.v_s
        for i in np.flatnonzero(self._ends_at_junction[self.v_path] & (remaining < LOOKAHEAD_M) & (self.v_next < 0)):
            succ = self.net.successors[int(self.v_path[i])]  # the turn, drawn once the junction is in sight
            self.v_next[i] = succ[int(self._rng.integers(len(succ)))]
        inside = self._is_connector[self.v_path] & ~self.v_held
        active = np.zeros(len(self._conflict), bool)  # connectors in use: driven on or reserved
        active[self.v_path[inside]] = True
        active[self.v_next[self.v_go]] = True
        claimed = np.zeros_like(active)  # connectors a vehicle has waited PATIENCE_S for: no new conflicting entry
        n_paths = len(self._conflict)
        into = self._exit_lane[self.v_path[inside]]  # where the vehicles inside the junctions will leave them
        ahead = self._exit_lane[self.v_next[self.v_go]]  # ... and where the reserved ones will
        committed = np.bincount(into, minlength=n_paths) + np.bincount(ahead, minlength=n_paths)
        tail = np.full(n_paths, np.inf)  # arc length of each lane's last vehicle
        np.minimum.at(tail, self.v_path, self.v_s)
        near = np.flatnonzero(self._ends_at_junction[self.v_path] & (remaining < JUNCTION_APPROACH_M)
                              & ~self.v_go & ~self.v_held)
        waiting_head: set[int] = set()
        # heads of queues in order of their wait (the longest first), then by how near they are to the junction
        for i in near[np.lexsort((-self.v_s[near], -self.v_wait_s[near]))]:
            lane, conn = int(self.v_path[i]), int(self.v_next[i])
            if lane in waiting_head:  # a vehicle ahead on my lane waits: queue behind it
                out[i] = remaining[i] - LENGTH_M / 2 + STANDSTILL_GAP_M
                continue
            exit_lane = self._exit_lane[conn]
            room = tail[exit_lane] >= SLOT_M * (committed[exit_lane] + 1) + LENGTH_M / 2
            node = int(self._path_to[lane])
            ego_inside = np.hypot(ego_x - self._node_xy[node, 0], ego_y - self._node_xy[node, 1]) \
                < self._node_radius[node]
            clear = not (self._conflict[conn] & (active | claimed)).any()
            if room and clear and not ego_inside:
                self.v_go[i] = True
                active[conn] = True
                committed[exit_lane] += 1
                self.v_wait_s[i] = 0.0
            else:
                out[i] = remaining[i] - LENGTH_M / 2 + STANDSTILL_GAP_M  # stop with the front bumper at the lane end
                waiting_head.add(lane)
                if remaining[i] < LENGTH_M:
                    self.v_wait_s[i] += dt_s
                if self.v_wait_s[i] > PATIENCE_S and room:
                    claimed[conn] = True
        return out

    def _path_samples(self) -> np.ndarray:
        """Per vehicle: its path points (V, K, 2) at PATH_SAMPLES_M ahead, over its path, the next and the one after."""
        p1 = np.where(self.v_next >= 0, self.v_next, self._first_successor[self.v_path])
        chain = np.column_stack([self.v_path, p1, self._first_successor[p1]])
        t = self._paths
        return sample_paths(t.points, t.cum, t.base, t.first, t.last, t.lengths, chain, self.v_s, PATH_SAMPLES_M)

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
            ahead = self.p_pose[:, :2] + 0.8 * (self.p_to - self.p_from) / dist[:, None]
            idx = np.flatnonzero(crossing)
            held_up = idx[self._in_car(ahead[idx])]
            crossing[held_up] = False  # waits for the car to pass
            self.p_wait_s[held_up] += dt_s
            self.p_wait_s[idx[~np.isin(idx, held_up)]] = 0.0
            back = held_up[self.p_wait_s[held_up] > PEDESTRIAN_PATIENCE_S]  # a car that waits for it: turn back
            if len(back):
                self.p_from[back], self.p_to[back] = self.p_to[back].copy(), self.p_from[back].copy()
                self.p_cross[back] = 1.0 - self.p_cross[back]
                came = self.p_walk[back].copy()
                self.p_walk[back] ^= 1  # so that it ends on the sidewalk it came from, where it left it
                self.p_s[back] *= self._walks.lengths[self.p_walk[back]] / self._walks.lengths[came]
                self.p_wait_s[back] = 0.0
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
        cars = np.concatenate([self.v_pose[:, :2], self._ego[None, :]]) if start.any() else None
        for i in np.flatnonzero(start):
            other = int(self.p_walk[i] ^ 1)
            frac = self.p_s[i] / self._walks.lengths[self.p_walk[i]]
            x0, y0, _ = self._walks.pose(self.p_walk[i : i + 1], self.p_s[i : i + 1])
            x1, y1, _ = self._walks.pose(np.array([other]), np.array([frac * self._walks.lengths[other]]))
            a, b = np.array([x0[0], y0[0]]), np.array([x1[0], y1[0]])
            ab = b - a
            t = np.clip(((cars - a) @ ab) / max(float(ab @ ab), 1e-9), 0.0, 1.0)
            if (np.linalg.norm(cars - (a + t[:, None] * ab), axis=1) < CROSS_CLEAR_M).any():
                continue  # a car is near the crossing line: keep walking
            self.p_from[i] = (x0[0], y0[0])
            self.p_to[i] = (x1[0], y1[0])
            self.p_cross[i] = 0.0

    def _in_car(self, points: np.ndarray) -> np.ndarray:
        """Per point (N, 2): whether it lies in a vehicle's body (the ego car's included) or, for a moving one, within
        0.5 m of it or in the road it covers in PEDESTRIAN_WAIT_S."""
        speed = np.append(np.where(self.v_held, 0.0, self.v_speed), self._ego_speed)
        yaw = np.append(self.v_pose[:, 2], self._ego_yaw)
        xy = np.concatenate([self.v_pose[:, :2], self._ego[None, :]])
        rel = points[:, None, :] - xy[None, :, :]  # (N, C, 2)
        fwd = rel[..., 0] * np.cos(yaw) + rel[..., 1] * np.sin(yaw)
        lat = -rel[..., 0] * np.sin(yaw) + rel[..., 1] * np.cos(yaw)
        moving = speed > 0.5
        margin = np.where(moving, 0.5, PEDESTRIAN_SIZE_M[0] / 2 + 0.05)
        ahead = LENGTH_M / 2 + margin + np.where(moving, speed * PEDESTRIAN_WAIT_S, 0.0)
        inside = (fwd > -LENGTH_M / 2 - margin) & (fwd < ahead) & (np.abs(lat) < WIDTH_M / 2 + margin)
        return inside.any(axis=1)

    # ------------------------------------------------------------------------------------------ output
    def velocities(self) -> np.ndarray:
        """Ground velocities (vx, vy in m/s) of every agent, in the row order of `boxes()`."""
        v_speed = np.where(self.v_held, 0.0, self.v_speed)
        v = np.column_stack([v_speed * np.cos(self.v_pose[:, 2]), v_speed * np.sin(self.v_pose[:, 2])])
        p_speed = np.where(self.p_held, 0.0, self.p_speed)
        p = np.column_stack([p_speed * np.cos(self.p_pose[:, 2]), p_speed * np.sin(self.p_pose[:, 2])])
        return np.concatenate([v, p]) if len(v) or len(p) else np.zeros((0, 2))

    def vehicle_contacts(self) -> np.ndarray:
        """Pairs (i, j), i < j, of traffic vehicles whose bodies (LENGTH_M x WIDTH_M rectangles) overlap."""
        xy, yaw = self.v_pose[:, :2], self.v_pose[:, 2]
        i, j = np.nonzero(np.triu(np.linalg.norm(xy[:, None] - xy[None], axis=2) < np.hypot(LENGTH_M, WIDTH_M), 1))
        if not len(i):
            return np.zeros((0, 2), np.int64)
        half = np.array([LENGTH_M / 2, WIDTH_M / 2])
        axes_i = np.stack([np.column_stack([np.cos(yaw[i]), np.sin(yaw[i])]),
                           np.column_stack([-np.sin(yaw[i]), np.cos(yaw[i])])], axis=1)  # (N, 2 axes, 2)
        axes_j = np.stack([np.column_stack([np.cos(yaw[j]), np.sin(yaw[j])]),
                           np.column_stack([-np.sin(yaw[j]), np.cos(yaw[j])])], axis=1)
        d = xy[j] - xy[i]
        separated = np.zeros(len(i), bool)
        for axes in (axes_i, axes_j):  # separating-axis test on the four edge normals
            for a in range(2):
                n = axes[:, a]
                r_i = np.abs(np.einsum("nkc,nc->nk", axes_i, n)) @ half
                r_j = np.abs(np.einsum("nkc,nc->nk", axes_j, n)) @ half
                separated |= np.abs((d * n).sum(axis=1)) > r_i + r_j
        keep = ~separated
        return np.column_stack([i[keep], j[keep]])

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
