"""The modular-pipeline (MP) baseline of CARLA's CoRL2017 paper: perception, a rule-based local planner, control.

Perception projects the (ground-truth or estimated) label image onto the ground plane in the car frame (flat-ground
inverse perspective mapping, precomputed once per camera) and gives a bird's-eye grid of classes. The local planner
tracks the right lane row by row in that grid (right curb and centre line), fits its centre line, and runs a small
state machine on the route command: follow the lane, or at a junction (whose entry lies 10 m after the command
appears) drive a planned quarter circle (left, right) or a straight line through it by dead reckoning from the
measured speed and its own steering, then go back to lane following. Pure pursuit steers and a PI controller holds
the target speed; the car brakes for vehicle or pedestrian pixels in the corridor ahead.

The policy is not privileged: it reads only the label image (or the RGB image through the segmentation net), the
measured forward speed and the high-level command; from the world it takes only the camera configuration.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field
from typing import Any

import numpy as np

from brlcli.classes import CarlaClass
from brlcli.episode import EpisodeSpec
from brlcli.segnet import labeler_for
from brlcli.sim.camera import CameraConfig
from brlcli.sim.roadnet import Command
from brlcli.sim.vehicle import MAX_STEER_DEG, STEER_TAU_S, WHEELBASE_M, Control
from brlcli.sim.world import FRAME_DT_S

LANE_WIDTH_M = 4.0
HALF_LANE_M = LANE_WIDTH_M / 2
JUNCTION_LEAD_M = 10.0
"""The route command appears this far before the junction entry (CARLA planner convention, brl's roadnet)."""
JUNCTION_HALF_M = 9.0
RIGHT_TURN_RADIUS_M = 7.0
"""Right lane to right lane of the right branch, from the junction entry: concentric with the 5 m curb."""
LEFT_TURN_RADIUS_M = 11.0
"""Right lane to right lane of the left branch, from the junction entry."""
CRUISE_KMH = 20.0
CURVE_KMH = 14.0
TURN_KMH = 10.0
STOP_GAP_M = 8.0
"""Obstacle this close ahead of the car's origin (front bumper at 2.25 m): brake to a stop."""
SLOW_GAP_M = 14.0
CORRIDOR_HALF_M = 1.5

BEV_RES_M = 0.2
BEV_X_M = (0.0, 32.0)
BEV_Y_M = (-16.0, 16.0)
UNKNOWN = 255

_ROADLIKE = np.zeros(256, bool)
_ROADLIKE[[CarlaClass.ROADS, CarlaClass.ROAD_LINES]] = True
_OBSTACLE = np.zeros(256, bool)
_OBSTACLE[[CarlaClass.VEHICLES, CarlaClass.PEDESTRIANS]] = True
_OFFROAD = ~_ROADLIKE & ~_OBSTACLE
_OFFROAD[[UNKNOWN, CarlaClass.NONE]] = False


class GroundProjection:
    """Flat-ground pinhole geometry of a CameraConfig in the car frame (x forward, y left, z up; metres, pixels)."""

    def __init__(self, camera: CameraConfig) -> None:
        self.camera = camera
        self.f_px = camera.focal_px
        self.cx_px, self.cy_px = (camera.width - 1) / 2.0, (camera.height - 1) / 2.0
        p = math.radians(camera.pitch_deg)
        self.centre_m = np.array([camera.x_m, camera.y_m, camera.z_m])
        self.fwd = np.array([math.cos(p), 0.0, math.sin(p)])
        self.down = np.array([math.sin(p), 0.0, -math.cos(p)])
        self.right = np.array([0.0, -1.0, 0.0])

    def ground_to_pixel(self, x_m: np.ndarray, y_m: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """Pixel (u, v) of ground points (z = 0) in the car frame, and a mask of points in front of the camera."""
        rel = np.stack([np.asarray(x_m, float), np.asarray(y_m, float), np.zeros(np.shape(x_m))], -1) - self.centre_m
        depth = rel @ self.fwd
        safe = np.where(depth > 1e-6, depth, 1.0)
        u = self.cx_px + self.f_px * (rel @ self.right) / safe
        v = self.cy_px + self.f_px * (rel @ self.down) / safe
        return u, v, depth > 1e-6

    def pixel_to_ground(self, u_px: np.ndarray, v_px: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """Ground point (x, y) in the car frame of pixels, and a mask of pixels below the horizon."""
        u, v = np.asarray(u_px, float), np.asarray(v_px, float)
        ray = (self.fwd + ((u - self.cx_px) / self.f_px)[..., None] * self.right
               + ((v - self.cy_px) / self.f_px)[..., None] * self.down)
        below = ray[..., 2] < -1e-9
        t = np.where(below, -self.centre_m[2] / np.where(below, ray[..., 2], -1.0), np.nan)
        return self.centre_m[0] + t * ray[..., 0], self.centre_m[1] + t * ray[..., 1], below


class BirdsEye:
    """Label image -> bird's-eye class grid in the car frame (rows: x forward from BEV_X_M, cols: y from BEV_Y_M)."""

    def __init__(self, camera: CameraConfig, res_m: float = BEV_RES_M) -> None:
        self.proj = GroundProjection(camera)
        self.res_m = res_m
        self.xs_m = np.arange(BEV_X_M[0] + res_m / 2, BEV_X_M[1], res_m)
        self.ys_m = np.arange(BEV_Y_M[0] + res_m / 2, BEV_Y_M[1], res_m)
        gx, gy = np.meshgrid(self.xs_m, self.ys_m, indexing="ij")
        u, v, front = self.proj.ground_to_pixel(gx, gy)
        ui, vi = np.round(u).astype(np.intp), np.round(v).astype(np.intp)
        inside = front & (ui >= 0) & (ui < camera.width) & (vi >= 0) & (vi < camera.height)
        self.shape = gx.shape
        self._cell = np.flatnonzero(inside.ravel())  # cells seen by a pixel (gather)
        self._cell_pix = (vi.ravel()[self._cell] * camera.width + ui.ravel()[self._cell])
        # scatter: every ground pixel to its cell (keeps thin road lines and small obstacles near the car)
        uu, vv = np.meshgrid(np.arange(camera.width), np.arange(camera.height))
        px, py, below = self.proj.pixel_to_ground(uu, vv)
        col = np.floor((py - BEV_Y_M[0]) / res_m)
        row = np.floor((px - BEV_X_M[0]) / res_m)
        ok = below & (row >= 0) & (row < self.shape[0]) & (col >= 0) & (col < self.shape[1])
        self._pix = np.flatnonzero(ok.ravel())
        self._pix_cell = (row.ravel()[self._pix] * self.shape[1] + col.ravel()[self._pix]).astype(np.intp)

    def grid(self, labels: np.ndarray) -> np.ndarray:
        """Class grid (uint8, UNKNOWN where no pixel looks); road lines and obstacles from any pixel win."""
        flat = labels.reshape(-1)
        out = np.full(self.shape[0] * self.shape[1], UNKNOWN, np.uint8)
        out[self._cell] = flat[self._cell_pix]
        scattered = flat[self._pix]
        for cls in (CarlaClass.ROAD_LINES, CarlaClass.PEDESTRIANS, CarlaClass.VEHICLES):
            hit = scattered == cls
            out[self._pix_cell[hit]] = cls
        return out.reshape(self.shape)


@dataclass
class LaneEstimate:
    """Lane-centre samples (x, y in the car frame, m) found in the bird's-eye grid and their quadratic fit."""

    xs_m: np.ndarray
    ys_m: np.ndarray
    coef: np.ndarray | None = None  # y = c0 + c1 x + c2 x^2
    right_open_x_m: float = math.inf  # nearest row with no right curb near the lane (a road to the right)
    left_open_x_m: float = math.inf

    def y_at(self, x_m: float) -> float:
        """Lane-centre lateral offset at `x_m` (0 without a fit)."""
        return float(self.ys_at(np.asarray(x_m)))

    def ys_at(self, xs_m: np.ndarray) -> np.ndarray:
        """Lane-centre lateral offsets at many `xs_m` (zeros without a fit)."""
        if self.coef is None:
            return np.zeros(np.shape(xs_m))
        return self.coef[0] + self.coef[1] * xs_m + self.coef[2] * xs_m * xs_m


def find_lane_start(grid: np.ndarray, xs_m: np.ndarray, ys_m: np.ndarray, hint_m: float = 0.0,
                    x_range_m: tuple[float, float] = (5.0, 8.0)) -> float | None:
    """Lateral offset (m) of the right-lane centre nearest `hint_m` in near rows: a right curb with road 4 m beyond."""
    rows = np.flatnonzero((xs_m >= x_range_m[0]) & (xs_m <= x_range_m[1]))
    road = _ROADLIKE[grid[rows]]
    off = _OFFROAD[grid[rows]]
    res = ys_m[1] - ys_m[0]
    span = int(LANE_WIDTH_M / res + 0.5)
    curb = off[:, :-1] & road[:, 1:]  # off-road cell with road on its left
    # road over at least 90 % of the next 4 m to the left of the curb
    csum = np.concatenate([np.zeros((len(rows), 1)), np.cumsum(road, axis=1)], axis=1)
    k = np.arange(road.shape[1] - 1)
    hi = np.minimum(k + 1 + span, road.shape[1])
    wide = (csum[:, hi] - csum[:, k + 1]) >= 0.9 * span
    r_idx, c_idx = np.nonzero(curb & wide)
    if not len(c_idx):
        return None
    cand = ys_m[c_idx] + res / 2 + HALF_LANE_M
    return float(cand[np.argmin(np.abs(cand - hint_m))])


def track_lane(grid: np.ndarray, xs_m: np.ndarray, ys_m: np.ndarray, y0_m: float = 0.0, x_min_m: float = 4.6,
               x_max_m: float = 20.0) -> LaneEstimate:
    """Follow the right lane's centre row by row: the right curb and the centre line on either side of it."""
    road = _ROADLIKE[grid]
    off = _OFFROAD[grid]
    line = grid == CarlaClass.ROAD_LINES
    rows = np.flatnonzero((xs_m >= x_min_m) & (xs_m <= x_max_m))[::2]
    y_ref, slope = y0_m, 0.0
    res = ys_m[1] - ys_m[0]
    out_x, out_y = [], []
    right_open, left_open = math.inf, math.inf
    last_x, y_ref_prev = None, y0_m
    for r in rows:
        x = xs_m[r]
        if x > min(right_open, left_open):
            break
        cos_t = 1.0 / math.sqrt(1.0 + slope * slope)
        half = HALF_LANE_M / cos_t
        gate = 0.8 if out_x else 1.5
        # right curb: nearest off-road cell right of the lane centre
        lo = y_ref - 2.2 * half - 1.0
        sel = (ys_m < y_ref - 0.3) & (ys_m > lo)
        cand = np.flatnonzero(sel & off[r])
        curb = ys_m[cand.max()] + res / 2 if len(cand) else math.nan
        seen_right = np.count_nonzero(sel & (grid[r] != UNKNOWN)) >= 0.8 * np.count_nonzero(sel)
        # centre line: nearest road-line cell left of the lane centre, with road beyond it
        sel_l = (ys_m > y_ref + 0.5 * half) & (ys_m < y_ref + 1.6 * half)
        cand = np.flatnonzero(sel_l & line[r])
        centre = ys_m[cand.min()] if len(cand) else math.nan
        if not math.isnan(centre) and abs(centre - (y_ref + half)) > gate:
            centre = math.nan
        if not math.isnan(curb) and abs(curb - (y_ref - half)) > gate:
            curb = math.nan
        if not math.isnan(centre):
            beyond = (ys_m > centre + 0.5) & (ys_m < centre + 3.0)
            if np.count_nonzero(road[r] & beyond) < 0.5 * np.count_nonzero(beyond & (grid[r] != UNKNOWN)):
                centre = math.nan  # an edge line (off-road beyond it), not the centre line
        if math.isnan(curb) and seen_right and right_open == math.inf:
            wide = (ys_m < y_ref - 0.3) & (ys_m > y_ref - 6.0)
            if np.count_nonzero(road[r] & wide) >= 0.9 * np.count_nonzero(wide):
                right_open = x
        if math.isnan(centre) and left_open == math.inf:
            wide = (ys_m > y_ref + 0.3) & (ys_m < y_ref + 9.0)
            known = np.count_nonzero(wide & (grid[r] != UNKNOWN))
            if known >= 0.8 * np.count_nonzero(wide) and np.count_nonzero(road[r] & wide) >= 0.95 * known:
                left_open = x
        if not math.isnan(curb) and not math.isnan(centre):
            if abs((centre - curb) * cos_t - LANE_WIDTH_M) < 0.6:
                y = 0.5 * (curb + centre)
            elif abs(centre - half - y_ref) <= abs(curb + half - y_ref):
                y = centre - half
            else:
                y = curb + half
        elif not math.isnan(curb):
            y = curb + half
        elif not math.isnan(centre):
            y = centre - half
        else:
            y_ref += slope * (xs_m[rows[1]] - xs_m[rows[0]]) if len(rows) > 1 else 0.0
            continue
        if last_x is not None and x > last_x:
            slope = float(np.clip(0.6 * slope + 0.4 * (y - y_ref_prev) / (x - last_x), -1.2, 1.2))
        y_ref_prev, last_x = y, x
        y_ref = y + slope * (xs_m[rows[1]] - xs_m[rows[0]]) if len(rows) > 1 else y
        out_x.append(x)
        out_y.append(y)
    xa, ya = np.asarray(out_x), np.asarray(out_y)
    keep = xa < min(right_open, left_open) - 4.0  # the junction's rounded corners start about 4 m earlier
    est = LaneEstimate(xa[keep], ya[keep], None, right_open, left_open)
    if len(est.xs_m) >= 4:
        xa, ya = est.xs_m, est.ys_m
        w = 1.0 / (1.0 + 0.05 * xa)
        deg = 2 if xa.max() - xa.min() > 6.0 else 1
        c = np.polyfit(xa, ya, deg, w=w)[::-1]
        est.coef = np.concatenate([c, np.zeros(3 - len(c))])
    return est


@dataclass
class Manoeuvre:
    """A planned path through a junction in the lane frame at its start; the car's pose is dead-reckoned in it."""

    command: int
    path: np.ndarray  # (N, 2) polyline, 0.2 m spacing
    end_s_m: float  # arc length at which lane following takes over
    pose: list[float] = field(default_factory=lambda: [0.0, 0.0, 0.0])  # x, y (m), yaw (rad)
    s_m: float = 0.0


def junction_path(command: int, entry_m: float, step_m: float = 0.2) -> tuple[np.ndarray, float]:
    """Polyline through a junction whose entry is `entry_m` ahead (lane frame) and where lane following resumes."""
    pre = np.arange(-2.0, max(entry_m, 0.0), step_m)
    pts = [np.stack([pre, np.zeros_like(pre)], 1)]
    x0 = max(entry_m, 0.0)
    if command in (Command.TURN_LEFT, Command.TURN_RIGHT):
        radius = LEFT_TURN_RADIUS_M if command == Command.TURN_LEFT else RIGHT_TURN_RADIUS_M
        side = 1.0 if command == Command.TURN_LEFT else -1.0
        ang = np.arange(0.0, math.pi / 2, step_m / radius)
        pts.append(np.stack([x0 + radius * np.sin(ang), side * radius * (1 - np.cos(ang))], 1))
        tail = np.arange(0.0, 15.0, step_m)
        pts.append(np.stack([np.full_like(tail, x0 + radius), side * (radius + tail)], 1))
        end = len(pre) * step_m + radius * math.pi / 2 + 1.0
    else:
        ahead = np.arange(0.0, 2 * JUNCTION_HALF_M + 15.0, step_m)
        pts.append(np.stack([x0 + ahead, np.zeros_like(ahead)], 1))
        end = len(pre) * step_m + 2 * JUNCTION_HALF_M - 2.0
    return np.concatenate(pts), end


def pure_pursuit_steer(x_m: float, y_m: float) -> float:
    """Steer command [-1, 1] (+ right) to reach the car-frame point (x forward, y left) on a circle from the origin."""
    d2 = x_m * x_m + y_m * y_m
    if d2 < 1e-6:
        return 0.0
    delta = math.atan(2.0 * WHEELBASE_M * y_m / d2)
    return float(np.clip(-delta / math.radians(MAX_STEER_DEG), -1.0, 1.0))


class ModularPipelinePolicy:
    """CARLA's modular pipeline: label image -> bird's-eye grid -> lane / junction planner -> pure pursuit and PI."""

    frames_per_decision = 1
    needs_camera = True

    def __init__(self, name: str = "mp", deploy: str = "gt", segnet: str | None = None) -> None:
        self.labeler = labeler_for(deploy, segnet)
        self.name = name
        self.deploy = deploy
        self.setting = "MP-DG" if deploy == "gt" else "MP-DE"
        self.bev: BirdsEye | None = None
        self._reset_state()

    def _reset_state(self) -> None:
        self.prev_command = -1  # no command seen yet
        self.entry_m: float | None = None  # distance ahead to the next junction's entry, dead-reckoned
        self.done_command = False  # the current junction command has been driven
        self.lane_hint_y: float | None = None  # where the lane should be after a junction (car frame, m)
        self.manoeuvre: Manoeuvre | None = None
        self.steer_state_rad = 0.0
        self.last_control = Control()
        self.speed_int = 0.0
        self.lane: LaneEstimate | None = None
        self.lane_lost_frames = 0

    def reset(self, spec: EpisodeSpec, world: Any) -> None:
        """New episode: take the camera configuration (nothing else) from the world and clear the planner."""
        camera = getattr(world, "camera", None) or CameraConfig()
        if self.bev is None or self.bev.proj.camera != camera:
            self.bev = BirdsEye(camera)
        self._reset_state()

    # ------------------------------------------------------------------------------------ dead reckoning
    def _advance_pose(self, speed_ms: float) -> float:
        """Integrate the last control over one frame with the measured speed; returns yaw change (rad)."""
        target = -self.last_control.steer * math.radians(MAX_STEER_DEG)
        n = 4
        dt = FRAME_DT_S / n
        dyaw = 0.0
        m = self.manoeuvre
        for _ in range(n):
            self.steer_state_rad += (target - self.steer_state_rad) * min(1.0, dt / STEER_TAU_S)
            rate = speed_ms * math.tan(self.steer_state_rad) / WHEELBASE_M
            dyaw += rate * dt
            if m is not None:
                m.pose[2] += rate * dt
                m.pose[0] += speed_ms * math.cos(m.pose[2]) * dt
                m.pose[1] += speed_ms * math.sin(m.pose[2]) * dt
        return dyaw

    # ------------------------------------------------------------------------------------ planning
    def _start_manoeuvre(self, command: int, entry_m: float, lane: LaneEstimate | None) -> None:
        path, end = junction_path(command, entry_m)
        self.manoeuvre = Manoeuvre(command, path, end)
        self.manoeuvre.s_m = 2.0
        if lane is not None and lane.coef is not None:
            self._anchor(lane, 1.0)

    def _anchor(self, lane: LaneEstimate, gain: float) -> None:
        """Correct the dead-reckoned lateral offset and heading in the manoeuvre's lane frame from a lane fit."""
        m = self.manoeuvre
        assert m is not None and lane.coef is not None
        b, a = np.polyfit(lane.xs_m, lane.ys_m, 1)  # straight before a junction: a line is the better anchor
        psi = math.atan(float(np.clip(b, -0.3, 0.3)))
        a = float(np.clip(a, -1.5, 1.5))
        m.pose[1] += gain * (-a * math.cos(psi) - m.pose[1])
        m.pose[2] += gain * (-psi - m.pose[2])

    def _manoeuvre_target(self, lookahead_m: float) -> tuple[float, float, np.ndarray]:
        """Pure-pursuit target in the car frame and the path ahead (car frame) for the hazard corridor."""
        m = self.manoeuvre
        assert m is not None
        x, y, yaw = m.pose
        i0 = int(m.s_m / 0.2)
        window = m.path[max(i0 - 10, 0): i0 + 60]
        d = np.hypot(window[:, 0] - x, window[:, 1] - y)
        i = max(i0 - 10, 0) + int(np.argmin(d))
        m.s_m = max(m.s_m, i * 0.2)
        j = min(i + int(lookahead_m / 0.2), len(m.path) - 1)
        c, s = math.cos(yaw), math.sin(yaw)
        ahead = m.path[i: i + 60] - (x, y)
        car = np.stack([ahead[:, 0] * c + ahead[:, 1] * s, -ahead[:, 0] * s + ahead[:, 1] * c], 1)
        tx, ty = m.path[j, 0] - x, m.path[j, 1] - y
        return tx * c + ty * s, -tx * s + ty * c, car

    def _hazard_gap(self, grid: np.ndarray, path_car: np.ndarray) -> float:
        """Distance (m, from the car's origin) to the nearest vehicle or pedestrian cell within the corridor."""
        assert self.bev is not None
        obst = np.argwhere(_OBSTACLE[grid])
        if not len(obst) or not len(path_car):
            return math.inf
        ox = self.bev.xs_m[obst[:, 0]]
        oy = self.bev.ys_m[obst[:, 1]]
        near = ox < SLOW_GAP_M + 4.0
        if not near.any():
            return math.inf
        ox, oy = ox[near], oy[near]
        d = np.hypot(ox[:, None] - path_car[None, :, 0], oy[:, None] - path_car[None, :, 1]).min(axis=1)
        inside = d < CORRIDOR_HALF_M
        return float(ox[inside].min()) if inside.any() else math.inf

    @property
    def needs_rgb(self) -> bool:
        """Whether decisions need the RGB image (only to estimate labels; ground-truth labels need none)."""
        return self.labeler is not None

    def decide(self, obs: Any) -> Control:
        """Control for one frame from the label image, the measured speed and the route command."""
        assert self.bev is not None, "reset() first"
        labels = obs.labels if self.labeler is None else self.labeler(obs.rgb)
        speed_kmh = float(obs.measurements.forward_speed_kmh)
        speed_ms = max(speed_kmh, 0.0) / 3.6
        command = int(obs.command)
        self._advance_pose(speed_ms)
        grid = self.bev.grid(labels)
        turn_cmd = command in (Command.TURN_LEFT, Command.TURN_RIGHT, Command.GO_STRAIGHT)
        if not turn_cmd:
            self.done_command = False
        if self.entry_m is not None:
            self.entry_m -= speed_ms * FRAME_DT_S
        # ---- lane perception (only rows before the junction while one is ahead)
        if self.lane_hint_y is not None:
            y0 = self.lane_hint_y
        elif self.lane is not None and self.lane.coef is not None:
            y0 = self.lane.y_at(6.0)
        else:
            y0 = 0.0
        x_max = 20.0 if self.entry_m is None else self.entry_m + 0.5
        lane = track_lane(grid, self.bev.xs_m, self.bev.ys_m, float(np.clip(y0, -1.5, 1.5)), x_max_m=x_max)
        if lane.coef is None and x_max > 9.0:  # lost: look for a right curb with a lane beside it
            y_start = find_lane_start(grid, self.bev.xs_m, self.bev.ys_m, y0)
            if y_start is not None:
                lane = track_lane(grid, self.bev.xs_m, self.bev.ys_m, float(np.clip(y_start, -4.0, 4.0)),
                                  x_max_m=x_max)
        if lane.coef is not None:
            self.lane_hint_y = None
            self.lane_lost_frames = 0
            self.lane = lane
        else:
            self.lane_lost_frames += 1
            if self.lane is not None and self.lane_lost_frames < 10:
                lane = self.lane  # hold the last estimate for a moment
        # ---- junction: plan at the command's onset (the entry lies JUNCTION_LEAD_M ahead), re-anchor until entry
        if turn_cmd and not self.done_command and self.manoeuvre is None:
            if self.prev_command == Command.LANE_FOLLOW:
                self.entry_m = JUNCTION_LEAD_M - speed_ms * FRAME_DT_S
            else:  # the episode began inside the command window: find the entry in the grid
                opening = min(lane.right_open_x_m, lane.left_open_x_m)
                self.entry_m = opening - 4.0 if math.isfinite(opening) else JUNCTION_LEAD_M - 1.0
            self._start_manoeuvre(command, self.entry_m, lane if lane.coef is not None else None)
        elif self.manoeuvre is not None and self.entry_m is not None and self.entry_m > 1.0 and \
                self.lane_lost_frames == 0 and len(lane.xs_m) >= 5 and np.ptp(lane.xs_m) >= 3.0:
            self._anchor(lane, 0.3)
        self.prev_command = command
        # ---- steering target
        lookahead_m = float(np.clip(0.9 * speed_ms + 3.5, 4.5, 8.0))
        m = self.manoeuvre
        if m is not None:
            turning = m.command != Command.GO_STRAIGHT
            tx, ty, path_car = self._manoeuvre_target(3.5 if turning and (self.entry_m or 0.0) < 4.0 else lookahead_m)
            steer = pure_pursuit_steer(tx, ty)
            target_kmh = TURN_KMH if turning else CURVE_KMH
            if m.s_m >= m.end_s_m:
                hx, hy, _ = self._manoeuvre_target(6.0)
                self.lane_hint_y = float(np.clip(hy, -1.5, 1.5))
                self.manoeuvre, self.entry_m, self.done_command, self.lane = None, None, True, None
        else:
            if lane.coef is not None:
                ty = lane.y_at(lookahead_m)
                steer = pure_pursuit_steer(lookahead_m, ty)
                curv = abs(2.0 * lane.coef[2]) + abs(lane.y_at(12.0) - lane.y_at(4.0)) / 60.0
            else:
                steer, curv = 0.0, 0.0
            xs = np.arange(2.0, 16.0, 0.5)
            path_car = np.stack([xs, lane.ys_at(xs)], 1)
            target_kmh = CURVE_KMH if curv > 0.02 or lane.coef is None else CRUISE_KMH
            if command == Command.REACH_GOAL:
                target_kmh = TURN_KMH
        gap = self._hazard_gap(grid, path_car)
        if gap < STOP_GAP_M:
            target_kmh = 0.0
        elif gap < SLOW_GAP_M:
            target_kmh = min(target_kmh, TURN_KMH * (gap - STOP_GAP_M) / (SLOW_GAP_M - STOP_GAP_M) + 3.0)
        control = Control(steer=steer, **self._speed_control(target_kmh, speed_kmh))
        self.last_control = control
        return control

    def _speed_control(self, target_kmh: float, speed_kmh: float) -> dict[str, float]:
        """PI speed control: throttle or brake."""
        if target_kmh <= 0.0:
            self.speed_int = 0.0
            return {"throttle": 0.0, "brake": 1.0 if speed_kmh > 0.5 else 0.5}
        err = target_kmh - speed_kmh
        self.speed_int = float(np.clip(self.speed_int + err * FRAME_DT_S, -10.0, 10.0))
        feed = target_kmh / 46.0  # steady-state throttle is about speed / 46 km/h
        throttle = float(np.clip(feed + 0.06 * err + 0.02 * self.speed_int, 0.0, 0.85))
        if err < -3.0:
            return {"throttle": 0.0, "brake": float(np.clip(-0.08 * err, 0.0, 1.0))}
        return {"throttle": throttle, "brake": 0.0}
