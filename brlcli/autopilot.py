"""The privileged expert: pure-pursuit steering along a planned route, speed control, stopping for traffic,
CIL-style noise injection (temporary steering perturbations the expert then recovers from) and, for perception
data, lateral excursions (outside CIL: for a few seconds the car follows a path beside its lane, on a sidewalk or
in the opposite lane, as a failing driving agent does, so that the segmentation net sees those views too)."""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from brlcli.sim.hazard import hazard_gap_m
from brlcli.sim.roadnet import Command, Route
from brlcli.sim.vehicle import MAX_STEER_DEG, WHEELBASE_M, Control
from brlcli.sim.world import FRAME_DT_S, Measurements, World

CRUISE_KMH = 22.0
TURN_KMH = 12.0
STOP_GAP_M = 7.0
"""Free distance ahead (bumper to obstacle) below which the expert brakes to a stop."""


@dataclass(frozen=True)
class NoiseConfig:
    """Steering perturbations: start with `rate_per_s`, last `duration_s`, peak `amplitude` (steer units)."""

    rate_per_s: float = 0.08
    duration_s: tuple[float, float] = (0.5, 1.5)
    amplitude: tuple[float, float] = (0.2, 0.5)


@dataclass(frozen=True)
class ExcursionConfig:
    """Lateral excursions: start with `rate_per_s`; for `duration_s` the applied control follows the route offset
    sideways by `offset_m` (+ = right of the driving direction), drawn from one of `offsets_m`'s ranges (right
    sidewalk, opposite lane, left sidewalk), at `speed_kmh`, ending early when traffic is ahead; the recorded expert
    control stays the clean one."""

    rate_per_s: float = 0.05
    duration_s: tuple[float, float] = (3.0, 8.0)
    offsets_m: tuple[tuple[float, float], ...] = ((2.5, 4.0), (-5.0, -3.0), (-7.5, -6.0))
    speed_kmh: float = 12.0


class Autopilot:
    """Drives a world along a route; `control()` gives the (noisy) applied and the clean expert control."""

    def __init__(self, world: World, route: Route, rng: np.random.Generator, noise: NoiseConfig | None = None,
                 cruise_kmh: float = CRUISE_KMH, excursions: ExcursionConfig | None = None) -> None:
        self.world = world
        self.route = route
        self.rng = rng
        self.noise = noise
        self.cruise_kmh = cruise_kmh
        self.excursions = excursions
        self._excursion_left_s = 0.0
        self._excursion_offset_m = 0.0
        self._noise_left_s = 0.0
        self._noise_total_s = 1.0
        self._noise_peak = 0.0

    def _target_speed(self, s_m: float) -> float:
        cmd = self.route.command_at(s_m, lookahead_m=15.0)
        if cmd == Command.REACH_GOAL:
            return 0.0
        ahead = self.route.points[min(int(np.searchsorted(self.route.cum_s, s_m + 12.0)), len(self.route.points) - 1)]
        here = self.route.points[min(int(np.searchsorted(self.route.cum_s, s_m)), len(self.route.points) - 1)]
        nxt = self.route.points[min(int(np.searchsorted(self.route.cum_s, s_m + 14.0)), len(self.route.points) - 1)]
        d1, d2 = ahead - here, nxt - ahead
        bend = 0.0
        if np.linalg.norm(d1) > 1e-6 and np.linalg.norm(d2) > 1e-6:
            bend = abs(math.atan2(d1[0] * d2[1] - d1[1] * d2[0], float(d1 @ d2)))
        curvy = cmd in (Command.TURN_LEFT, Command.TURN_RIGHT) or bend > 0.08
        return TURN_KMH if curvy else self.cruise_kmh

    def _obstacle_gap(self, m: Measurements) -> float:
        """Free distance (m) to the nearest hazard on the route ahead (`hazard_gap_m`); inf when the path is clear."""
        return hazard_gap_m(self.world.traffic, self.route, m.x, m.y, m.yaw_deg)

    def must_stop(self, m: Measurements) -> bool:
        """Whether the expert wants to stand still: the route's end, or an obstacle closer than STOP_GAP_M ahead."""
        s, _ = self.route.project(m.x, m.y)
        return self._target_speed(s) <= 0.0 or self._obstacle_gap(m) < STOP_GAP_M

    def expert(self, m: Measurements, offset_m: float = 0.0, speed_kmh: float | None = None) -> Control:
        """Clean expert control for the current measurements (along a path `offset_m` right of the route, at most
        `speed_kmh`, during an excursion)."""
        s, _ = self.route.project(m.x, m.y)
        speed = m.forward_speed_kmh
        look = max(5.0, 0.9 * abs(speed) / 3.6)
        k = min(int(np.searchsorted(self.route.cum_s, s + look)), len(self.route.points) - 1)
        tx, ty = self.route.points[k]
        if offset_m:  # the look-ahead point on the route (its points are sparse on straights), moved sideways
            pts, cum = self.route.points, self.route.cum_s
            ahead = min(s + look, float(cum[-1]))
            j = min(max(int(np.searchsorted(cum, ahead)), 1), len(pts) - 1)
            a, b = pts[j - 1], pts[j]
            t = (ahead - cum[j - 1]) / max(cum[j] - cum[j - 1], 1e-9)
            heading = math.atan2(b[1] - a[1], b[0] - a[0])
            tx = a[0] + t * (b[0] - a[0]) + offset_m * math.sin(heading)
            ty = a[1] + t * (b[1] - a[1]) - offset_m * math.cos(heading)
        yaw = math.radians(m.yaw_deg)
        alpha = math.atan2(ty - m.y, tx - m.x) - yaw
        alpha = math.atan2(math.sin(alpha), math.cos(alpha))
        delta = math.atan2(2.0 * WHEELBASE_M * math.sin(alpha), look)
        steer = float(np.clip(-delta / math.radians(MAX_STEER_DEG), -1.0, 1.0))
        target = self._target_speed(s) if speed_kmh is None else min(speed_kmh, self._target_speed(s))
        if self._obstacle_gap(m) < STOP_GAP_M:
            target = 0.0
        err = target - speed
        if target <= 0.0:
            return Control(steer=steer, throttle=0.0, brake=1.0 if speed > 0.5 else 0.5)
        throttle = float(np.clip(0.42 + 0.08 * err, 0.0, 0.85))
        brake = float(np.clip(-0.1 * err, 0.0, 1.0)) if err < -4.0 else 0.0
        return Control(steer=steer, throttle=0.0 if brake > 0 else throttle, brake=brake)

    def control(self, m: Measurements) -> tuple[Control, Control]:
        """(applied control with any injected steering noise, clean expert control)."""
        clean = self.expert(m)
        if self.excursions is not None:
            ex = self.excursions
            if self._excursion_left_s <= 0.0 and self.rng.uniform() < ex.rate_per_s * FRAME_DT_S:
                self._excursion_left_s = float(self.rng.uniform(*ex.duration_s))
                low, high = ex.offsets_m[int(self.rng.integers(len(ex.offsets_m)))]
                self._excursion_offset_m = float(self.rng.uniform(low, high))
            if self._excursion_left_s > 0.0 and self._obstacle_gap(m) < 2.0 * STOP_GAP_M:
                self._excursion_left_s = 0.0  # traffic ahead (oncoming, in the opposite lane): back to the lane
            if self._excursion_left_s > 0.0:
                self._excursion_left_s -= FRAME_DT_S
                return self.expert(m, self._excursion_offset_m, ex.speed_kmh), clean
        if self.noise is None:
            return clean, clean
        if self._noise_left_s <= 0.0 and self.rng.uniform() < self.noise.rate_per_s * FRAME_DT_S:
            self._noise_total_s = float(self.rng.uniform(*self.noise.duration_s))
            self._noise_left_s = self._noise_total_s
            self._noise_peak = float(self.rng.uniform(*self.noise.amplitude)) * float(self.rng.choice([-1.0, 1.0]))
        if self._noise_left_s > 0.0:
            phase = 1.0 - self._noise_left_s / self._noise_total_s  # triangular: up, then down
            shape = 1.0 - abs(2.0 * phase - 1.0)
            self._noise_left_s -= FRAME_DT_S
            noisy = Control(steer=float(np.clip(clean.steer + self._noise_peak * shape, -1, 1)),
                            throttle=clean.throttle, brake=clean.brake, reverse=clean.reverse)
            return noisy, clean
        return clean, clean

    def done(self, m: Measurements) -> bool:
        """True once the car is within 2 m of the route's goal (with excursions: or level with it, beside it)."""
        gx, gy = self.route.goal
        if self.excursions is not None and self.route.project(m.x, m.y)[0] >= self.route.length_m - 2.0:
            return True
        return math.hypot(m.x - gx, m.y - gy) < 2.0
