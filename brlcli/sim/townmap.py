"""Top-down rasters of a town: ground appearance (-> CARLA class) and lane direction, for sensors and measurements."""

from __future__ import annotations

import cv2
import numpy as np

from brlcli.classes import CarlaClass
from brlcli.sim.roadnet import RoadNetwork, offset_polyline

RESOLUTION_M = 0.1
"""Raster cell size in metres."""

MARGIN_M = 60.0
"""Terrain margin around the road graph, metres."""

CURB_WIDTH_M = 0.25
EDGE_LINE_INSET_M = 0.35

# ground appearance codes
TERRAIN, SIDEWALK, CURB, ROAD, LINE_CENTRE, LINE_EDGE = range(6)
GROUND_CLASS = np.array(
    [CarlaClass.OTHER, CarlaClass.SIDEWALKS, CarlaClass.SIDEWALKS, CarlaClass.ROADS, CarlaClass.ROAD_LINES,
     CarlaClass.ROAD_LINES], dtype=np.uint8,
)

# lane direction codes: 0..LANE_ANGLE_STEPS-1 encode the lane heading; the rest are markers
LANE_ANGLE_STEPS = 252
LANE_JUNCTION = 254
LANE_NONE = 255


class TownMap:
    """Rasterised ground of a town at `RESOLUTION_M`; `ground` holds appearance codes, `lane` direction codes."""

    def __init__(self, network: RoadNetwork) -> None:
        nodes = network.town.nodes_m
        self.x0 = float(nodes[:, 0].min() - MARGIN_M)
        self.y0 = float(nodes[:, 1].min() - MARGIN_M)
        w = int(np.ceil((nodes[:, 0].max() + MARGIN_M - self.x0) / RESOLUTION_M))
        h = int(np.ceil((nodes[:, 1].max() + MARGIN_M - self.y0) / RESOLUTION_M))
        self.shape = (h, w)
        self.ground = np.full((h, w), TERRAIN, np.uint8)
        self.lane = np.full((h, w), LANE_NONE, np.uint8)
        self._draw(network)
        self.ground_class = GROUND_CLASS[self.ground]
        self._is_road = (GROUND_CLASS == CarlaClass.ROADS) | (GROUND_CLASS == CarlaClass.ROAD_LINES)

    # ------------------------------------------------------------------ drawing
    def _px(self, pts: np.ndarray) -> np.ndarray:
        """World metres -> fixed-point pixel coordinates (4 fractional bits) for OpenCV."""
        q = np.empty_like(pts)
        q[..., 0] = (pts[..., 0] - self.x0) / RESOLUTION_M
        q[..., 1] = (pts[..., 1] - self.y0) / RESOLUTION_M
        return np.round(q * 16).astype(np.int32)

    def _band(self, img: np.ndarray, centre: np.ndarray, lo_m: float, hi_m: float, value: int | np.ndarray) -> None:
        a = self._px(offset_polyline(centre, lo_m))
        b = self._px(offset_polyline(centre, hi_m))
        values = np.broadcast_to(np.asarray(value), (len(centre) - 1,))
        for i in range(len(centre) - 1):
            quad = np.stack([a[i], a[i + 1], b[i + 1], b[i]])
            cv2.fillConvexPoly(img, quad, int(values[i]), lineType=cv2.LINE_8, shift=4)

    def _rect(self, img: np.ndarray, x0: float, y0: float, x1: float, y1: float, value: int) -> None:
        quad = self._px(np.array([[x0, y0], [x1, y0], [x1, y1], [x0, y1]]))
        cv2.fillConvexPoly(img, quad, value, lineType=cv2.LINE_8, shift=4)

    def _draw(self, net: RoadNetwork) -> None:
        rh = net.lane_width_m
        sw = net.town.geometry.sidewalk_width_m
        lw = net.town.geometry.line_width_m
        g, lane = self.ground, self.lane
        for road in net.roads:
            c = road.centre
            for side in (-1, 1):
                self._band(g, c, side * rh, side * (rh + sw), SIDEWALK)
                self._band(g, c, side * rh, side * (rh + CURB_WIDTH_M), CURB)
        for road in net.roads:
            c = road.centre
            self._band(g, c, -rh, rh, ROAD)
            self._band(g, c, -lw / 2, lw / 2, LINE_CENTRE)
            for side in (-1, 1):
                self._band(g, c, side * (rh - EDGE_LINE_INSET_M), side * (rh - EDGE_LINE_INSET_M - lw), LINE_EDGE)
            for lane_idx in road.lanes:
                pts = net.paths[lane_idx].points  # a lane's centre line: its band is half a lane either side
                d = np.diff(pts, axis=0)
                self._band(lane, pts, -rh / 2, rh / 2, lane_angle_code(np.arctan2(d[:, 1], d[:, 0])))
        j = net.junction_half_m
        for node in np.flatnonzero(net.is_junction):
            x, y = net.town.nodes_m[node]
            dirs = {(int(np.sign(dx)), int(np.sign(dy)))
                    for dx, dy in (net.town.nodes_m[net.neighbours[node]] - net.town.nodes_m[node])}
            east, north, west, south = ((1, 0) in dirs), ((0, 1) in dirs), ((-1, 0) in dirs), ((0, -1) in dirs)
            ext = {k: (j if present else rh) for k, present in
                   (("e", east), ("n", north), ("w", west), ("s", south))}
            # straight sidewalk across an open side of a T-junction
            if not north:
                self._rect(g, x - j, y + rh, x + j, y + rh + sw, SIDEWALK)
            if not south:
                self._rect(g, x - j, y - rh - sw, x + j, y - rh, SIDEWALK)
            if not east:
                self._rect(g, x + rh, y - j, x + rh + sw, y + j, SIDEWALK)
            if not west:
                self._rect(g, x - rh - sw, y - j, x - rh, y + j, SIDEWALK)
            self._rect(g, x - ext["w"], y - ext["s"], x + ext["e"], y + ext["n"], ROAD)
            self._rect(lane, x - ext["w"], y - ext["s"], x + ext["e"], y + ext["n"], LANE_JUNCTION)
            for sx, sy, has in ((1, 1, east and north), (-1, 1, west and north), (-1, -1, west and south),
                                (1, -1, east and south)):
                if has:
                    self._corner(x, y, sx, sy, rh, sw, j)

    def _corner(self, x: float, y: float, sx: int, sy: int, rh: float, sw: float, j: float) -> None:
        """Rounded curb between two roads of a junction: road, sidewalk ring and terrain by distance to the corner."""
        xs = np.sort([x + sx * rh, x + sx * j])
        ys = np.sort([y + sy * rh, y + sy * j])
        c0, c1 = (int(np.floor((v - self.x0) / RESOLUTION_M)) for v in xs)
        r0, r1 = (int(np.floor((v - self.y0) / RESOLUTION_M)) for v in ys)
        cols = np.arange(c0, c1 + 1)
        rows = np.arange(r0, r1 + 1)
        px = self.x0 + (cols + 0.5) * RESOLUTION_M
        py = self.y0 + (rows + 0.5) * RESOLUTION_M
        d = np.hypot(px[None, :] - (x + sx * j), py[:, None] - (y + sy * j))
        g = self.ground[r0 : r1 + 1, c0 : c1 + 1]
        lane = self.lane[r0 : r1 + 1, c0 : c1 + 1]
        g[d <= j - rh] = SIDEWALK
        g[d <= j - rh - CURB_WIDTH_M] = SIDEWALK
        g[(d <= j - rh) & (d > j - rh - CURB_WIDTH_M)] = CURB
        g[d <= j - rh - sw] = TERRAIN
        lane[d <= j - rh] = LANE_NONE

    # ------------------------------------------------------------------ lookups
    def index(self, x_m: np.ndarray, y_m: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """Raster (row, col) of world points and a mask of points inside the raster."""
        col = np.floor((x_m - self.x0) * (1.0 / RESOLUTION_M)).astype(np.intp)
        row = np.floor((y_m - self.y0) * (1.0 / RESOLUTION_M)).astype(np.intp)
        inside = (row >= 0) & (row < self.shape[0]) & (col >= 0) & (col < self.shape[1])
        # clamp in place (np.maximum/np.minimum: the same integers as np.clip, without its per-call overhead)
        np.minimum(np.maximum(row, 0, out=row), self.shape[0] - 1, out=row)
        np.minimum(np.maximum(col, 0, out=col), self.shape[1] - 1, out=col)
        return row, col, inside

    def footprint_shares(self, x_m: np.ndarray, y_m: np.ndarray, yaw_rad: float) -> tuple[float, float]:
        """Shares (0..1) of sample points that are off the road, and on a lane running against `yaw_rad`."""
        row, col, inside = self.index(x_m, y_m)
        ground = np.where(inside, self.ground[row, col], TERRAIN)
        lane = np.where(inside, self.lane[row, col], LANE_NONE)
        on_road = self._is_road[ground]
        lane_angle = lane.astype(np.float64) * (2 * np.pi / LANE_ANGLE_STEPS)
        against = on_road & (lane < LANE_ANGLE_STEPS) & (np.cos(lane_angle - yaw_rad) < 0.0)
        n = float(len(row))
        return float(np.count_nonzero(~on_road)) / n, float(np.count_nonzero(against)) / n


def lane_angle_code(heading_rad: np.ndarray) -> np.ndarray:
    """Quantise lane headings (radians) to raster codes 0..LANE_ANGLE_STEPS-1."""
    frac = np.mod(heading_rad, 2 * np.pi) / (2 * np.pi)
    return np.round(frac * LANE_ANGLE_STEPS).astype(np.int64) % LANE_ANGLE_STEPS
