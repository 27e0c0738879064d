"""The privileged hazard test shared by the expert (`brlcli.autopilot`) and the traffic-aware training reward: the
free distance along a planned route to the nearest road user that is on it or about to be."""

from __future__ import annotations

import math
from typing import Any

import numpy as np

from brlcli.classes import CarlaClass
from brlcli.sim.roadnet import Route
from brlcli.sim.traffic import CAR_CIRCLE_REACH_M, CAR_CIRCLES_M, car_circles
from brlcli.sim.vehicle import LENGTH_M

PATH_AHEAD_M = 25.0
"""How far along its route the expert looks for hazards."""
PREDICT_S = (0.0, 0.5, 1.0, 1.5, 2.0)
"""Times (s) at which each road user's position is predicted at its current velocity: a hazard is a road user
whose current or predicted position lies on the expert's path ahead (crossing traffic at a junction, a pedestrian
stepping out, an oncoming car across a turn)."""
CORRIDOR_HALF_M = {"vehicle": 2.1, "pedestrian": 1.5}
"""Half-width of the path corridor a road user must enter to be a hazard (a car's circle, CAR_CIRCLES_M; a
pedestrian's centre): the expert's half width, 0.9 m, plus the user's half width and a margin."""


def hazard_gap_m(traffic: Any, route: Route, x_m: float, y_m: float, yaw_deg: float,
                 predict_s: tuple[float, ...] = PREDICT_S) -> float:
    """Free distance (m, bumper to the nearest hazard) along `route` ahead of a car at (x, y, yaw); inf when clear.

    Every road user of `traffic` (its `boxes()` and `velocities()`) at `predict_s` (s) at its current velocity is
    tested against the corridor of the next PATH_AHEAD_M of the route (cars as three circles along their length); a
    user behind the car moving its way (following traffic) is no hazard. Privileged: the expert's and the training
    reward's view of traffic, never an agent's input."""
    return hazard_gap_and_user(traffic, route, x_m, y_m, yaw_deg, predict_s)[0]


def hazard_gap_and_user(traffic: Any, route: Route, x_m: float, y_m: float, yaw_deg: float,
                        predict_s: tuple[float, ...] = PREDICT_S) -> tuple[float, int]:
    """`hazard_gap_m` and the row of `traffic.boxes()` of the road user that sets it (-1 when the route is clear)."""
    boxes = traffic.boxes()
    if not len(boxes):
        return math.inf, -1
    vel = traffic.velocities()
    # only users that can reach the path within the prediction horizon
    horizon = PATH_AHEAD_M + CORRIDOR_HALF_M["vehicle"] + LENGTH_M + max(predict_s) * np.linalg.norm(vel, axis=1)
    near = np.hypot(boxes[:, 1] - x_m, boxes[:, 2] - y_m) < horizon
    if not near.any():
        return math.inf, -1
    rows_near = np.flatnonzero(near)
    boxes, vel = boxes[near], vel[near]
    car = boxes[:, 0] == float(CarlaClass.VEHICLES)
    # cars as their three circles, pedestrians as one point; `user` maps each point to its row
    user = np.concatenate([np.repeat(np.flatnonzero(car), len(CAR_CIRCLES_M)), np.flatnonzero(~car)])
    xy = np.concatenate([car_circles(boxes[car, 1:3], boxes[car, 7]), boxes[~car, 1:3]])
    vel = vel[user]
    half = np.where(car, CORRIDOR_HALF_M["vehicle"], CORRIDOR_HALF_M["pedestrian"])[user]
    reach = np.where(car, CAR_CIRCLE_REACH_M, boxes[:, 4] / 2)[user]
    s, _ = route.project(x_m, y_m)
    d = np.arange(0.0, PATH_AHEAD_M + 0.5, 1.0)
    q = np.clip(s + d, 0.0, route.cum_s[-1])
    path = np.column_stack([np.interp(q, route.cum_s, route.points[:, 0]),
                            np.interp(q, route.cum_s, route.points[:, 1])])
    yaw = math.radians(yaw_deg)
    ego_heading = np.array([math.cos(yaw), math.sin(yaw)])
    rel = boxes[user, 1:3] - (x_m, y_m)
    behind = (rel @ ego_heading < 0.0) & (vel @ ego_heading > 0.5)  # following traffic is no hazard
    best, who = math.inf, -1
    for t in predict_s:
        p = xy + t * vel  # (points, 2)
        dist = np.linalg.norm(p[:, None, :] - path[None, :, :], axis=2)  # (points, P)
        hit = (dist < half[:, None]) & ~behind[:, None]
        if hit.any():
            rows, points = np.nonzero(hit)
            gaps = d[points] - LENGTH_M / 2 - reach[rows]
            k = int(np.argmin(gaps))
            if gaps[k] < best:
                best, who = float(gaps[k]), int(rows_near[user[rows[k]]])
    return (max(best, 0.0), who) if best < math.inf else (math.inf, -1)
