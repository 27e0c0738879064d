"""Top-down town maps with routes, as RGB images."""

from __future__ import annotations

import cv2
import numpy as np

from brlcli.classes import LABEL_PALETTE
from brlcli.sim.roadnet import RoadNetwork
from brlcli.sim.townmap import GROUND_CLASS, TownMap

ROUTE_COLOURS = {"straight": (255, 255, 255), "right_curve": (255, 140, 0), "left_curve": (0, 200, 255)}


def town_topdown(net: RoadNetwork, tmap: TownMap, metres_per_px: float = 0.5,
                 routes: bool = True) -> np.ndarray:
    """Render a town from above (north up) with its objects and, optionally, its lane-keeping routes."""
    f = max(1, round(metres_per_px / 0.1))
    ground = tmap.ground[::f, ::f]
    img = LABEL_PALETTE[GROUND_CLASS[ground]].copy()
    img[GROUND_CLASS[ground] == 3] = (60, 90, 50)
    scale = 1.0 / (0.1 * f)

    def px(x: np.ndarray, y: np.ndarray) -> np.ndarray:
        return np.stack([(x - tmap.x0) * scale, (y - tmap.y0) * scale], axis=-1)

    for cls, x, y, _z, length, width, _h, yaw, _t in net.town.objects:
        c, s = np.cos(np.radians(yaw)), np.sin(np.radians(yaw))
        u = np.array([-1, 1, 1, -1]) * length / 2
        v = np.array([-1, -1, 1, 1]) * width / 2
        pts = px(x + c * u - s * v, y + s * u + c * v)
        cv2.fillConvexPoly(img, np.round(pts * 16).astype(np.int32),
                           tuple(int(k) for k in LABEL_PALETTE[int(cls)]), cv2.LINE_AA, 4)
    if routes:
        for spec in (*net.town.training_routes, *net.town.lane_keeping_routes):
            r = net.route(spec.start, spec.goal)
            pts = np.round(px(r.points[:, 0], r.points[:, 1]) * 16).astype(np.int32)
            cv2.polylines(img, [pts], False, ROUTE_COLOURS[spec.kind], 2, cv2.LINE_AA, 4)
            cv2.circle(img, tuple(int(v) for v in pts[0] // 16), 4, ROUTE_COLOURS[spec.kind], -1)
    return np.ascontiguousarray(img[::-1])
