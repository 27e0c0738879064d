"""The forward camera: a vectorised CPU rasteriser for flat ground plus boxes, giving RGB, labels and depth.

The ground is flat (z = 0), so every pixel below the horizon hits it at a fixed offset from the car: those
offsets are computed once, and a frame only rotates them by the car's yaw and looks the town's ground raster
up. Boxes (buildings, poles, vehicles, pedestrians...) are culled to the view, their front faces projected
and filled far-to-near (painter's order) into a face-index buffer with OpenCV; labels, per-pixel planar depth
and shading then come from that buffer in a few array operations.
"""

from __future__ import annotations

from dataclasses import dataclass

import cv2
import numpy as np

from brlcli.classes import CarlaClass
from brlcli.sim.townmap import (
    CURB,
    GROUND_CLASS,
    LINE_CENTRE,
    LINE_EDGE,
    ROAD,
    SIDEWALK,
    TERRAIN,
    TownMap,
)
from brlcli.sim.weather import Weather

SKY_DEPTH_M = 1000.0
"""Depth reported for sky pixels (CARLA's far plane), metres."""

NEAR_M = 0.05


@dataclass(frozen=True)
class CameraConfig:
    """Forward camera: image size (px), horizontal FOV (deg), mount on the car (m) and pitch (deg, - = down).

    CARLA's CoRL2017 camera is 800x600, FOV 100, at (2.0, 0, 1.4) m, pitch -15; the default keeps its mount and
    FOV at the 200x88 size used by CARLA's imitation-learning agents.
    """

    width: int = 200
    height: int = 88
    fov_deg: float = 100.0
    x_m: float = 2.0
    y_m: float = 0.0
    z_m: float = 1.4
    pitch_deg: float = -15.0
    max_range_m: float = 120.0

    def __post_init__(self) -> None:
        if not (8 <= self.width <= 4096 and 8 <= self.height <= 4096):
            raise ValueError("camera width and height must be within 8..4096 px")
        if not 10.0 <= self.fov_deg <= 170.0:
            raise ValueError("camera fov_deg must be within 10..170")
        if self.z_m <= 0.1:
            raise ValueError("camera z_m must be above the ground (> 0.1 m)")

    @property
    def focal_px(self) -> float:
        """Focal length in pixels."""
        return (self.width / 2.0) / np.tan(np.radians(self.fov_deg) / 2.0)


# box faces: corner indices (bit 0: +length, bit 1: +width, bit 2: top) and outward normals in the box frame
_FACES = np.array([[1, 3, 7, 5], [0, 4, 6, 2], [2, 6, 7, 3], [0, 1, 5, 4], [4, 5, 7, 6]])
_FACE_NORMALS = np.array([[1, 0, 0], [-1, 0, 0], [0, 1, 0], [0, -1, 0], [0, 0, 1]], dtype=np.float64)
_CORNER_SIGNS = np.array([[(i & 1) * 2 - 1, ((i >> 1) & 1) * 2 - 1, (i >> 2) & 1] for i in range(8)], np.float64)

#: Base colours (RGB 0..1) of ground appearance codes and box classes, before light and weather.
GROUND_COLOURS = np.zeros((6, 3))
GROUND_COLOURS[TERRAIN] = (0.36, 0.42, 0.25)
GROUND_COLOURS[SIDEWALK] = (0.62, 0.60, 0.57)
GROUND_COLOURS[CURB] = (0.52, 0.51, 0.49)
GROUND_COLOURS[ROAD] = (0.30, 0.30, 0.32)
GROUND_COLOURS[LINE_CENTRE] = (0.85, 0.72, 0.25)
GROUND_COLOURS[LINE_EDGE] = (0.88, 0.88, 0.86)
CLASS_COLOURS = np.full((13, 3), 0.5)
CLASS_COLOURS[CarlaClass.BUILDINGS] = (0.62, 0.52, 0.45)
CLASS_COLOURS[CarlaClass.FENCES] = (0.55, 0.45, 0.35)
CLASS_COLOURS[CarlaClass.PEDESTRIANS] = (0.55, 0.25, 0.30)
CLASS_COLOURS[CarlaClass.POLES] = (0.45, 0.45, 0.47)
CLASS_COLOURS[CarlaClass.VEGETATION] = (0.22, 0.45, 0.18)
CLASS_COLOURS[CarlaClass.VEHICLES] = (0.20, 0.25, 0.55)
CLASS_COLOURS[CarlaClass.WALLS] = (0.70, 0.66, 0.58)
CLASS_COLOURS[CarlaClass.TRAFFIC_SIGNS] = (0.80, 0.15, 0.12)
_ROAD_LIKE = np.zeros(6, bool)
_ROAD_LIKE[[ROAD, LINE_CENTRE, LINE_EDGE]] = True


def box_corners(boxes: np.ndarray) -> np.ndarray:
    """World corners (K, 8, 3) of boxes given as rows (class, x, y, z_bottom, length, width, height, yaw_rad, ...)."""
    c, s = np.cos(boxes[:, 7]), np.sin(boxes[:, 7])
    u = _CORNER_SIGNS[None, :, 0] * boxes[:, 4:5] / 2
    v = _CORNER_SIGNS[None, :, 1] * boxes[:, 5:6] / 2
    w = _CORNER_SIGNS[None, :, 2] * boxes[:, 6:7]
    x = boxes[:, 1:2] + c[:, None] * u - s[:, None] * v
    y = boxes[:, 2:3] + s[:, None] * u + c[:, None] * v
    return np.stack([x, y, boxes[:, 3:4] + w], axis=-1)


class Renderer:
    """Renders RGB, CARLA labels and planar depth for a camera on a car in one town."""

    def __init__(self, town_map: TownMap, static_boxes: np.ndarray, camera: CameraConfig) -> None:
        self.map = town_map
        self.camera = camera
        h, w, f = camera.height, camera.width, camera.focal_px
        self.cx, self.cy, self.f = (w - 1) / 2.0, (h - 1) / 2.0, f
        u, v = np.meshgrid(np.arange(w, dtype=np.float64), np.arange(h, dtype=np.float64))
        self._dcam = np.stack([(u - self.cx) / f, (v - self.cy) / f, np.ones_like(u)], axis=-1)  # (H, W, 3)
        p = np.radians(camera.pitch_deg)
        # camera axes (right, down, forward) in the car frame (x forward, y left, z up)
        self._r_cb = np.array([[0.0, np.sin(p), np.cos(p)], [-1.0, 0.0, 0.0], [0.0, -np.cos(p), np.sin(p)]])
        d_b = self._dcam @ self._r_cb.T  # rays in the car frame, scaled so that camera depth = 1
        with np.errstate(divide="ignore"):
            t = np.where(d_b[..., 2] < -1e-9, -camera.z_m / d_b[..., 2], np.inf)
        self.ground_mask = t < 4000.0
        self._ground_t = t[self.ground_mask]  # planar depth of ground pixels, m
        self._ground_ox = camera.x_m + self._ground_t * d_b[..., 0][self.ground_mask]
        self._ground_oy = camera.y_m + self._ground_t * d_b[..., 1][self.ground_mask]
        self._ground_flat = np.flatnonzero(self.ground_mask.ravel())
        self._rows = np.arange(h, dtype=np.float64)
        elev = -np.arcsin(np.clip(d_b[..., 2] / np.linalg.norm(d_b, axis=-1), -1, 1))  # + below horizon
        self._sky_elev = np.clip(-elev, 0.0, np.pi / 2)  # elevation above horizon of each pixel, rad
        self._fresnel = np.clip(1.0 - 6.0 * np.abs(elev), 0.0, 1.0) ** 2  # grazing rays reflect more
        self._static = np.asarray(static_boxes, dtype=np.float64)
        self._static_corners = box_corners(self._static) if len(self._static) else np.zeros((0, 8, 3))
        self._static_radius = 0.5 * np.hypot(self._static[:, 4], self._static[:, 5]) if len(self._static) else None
        rng = np.random.default_rng(12345)
        self._noise = (rng.standard_normal((256, 256)) * 0.035).astype(np.float32)
        self._noise = cv2.GaussianBlur(self._noise, (0, 0), 1.0) * 2.0
        self._weather_cache: dict[int, dict[str, np.ndarray]] = {}

    # --------------------------------------------------------------------------------------------- geometry
    def _camera_pose(self, x_m: float, y_m: float, yaw_rad: float) -> tuple[np.ndarray, np.ndarray]:
        cam = self.camera
        c, s = np.cos(yaw_rad), np.sin(yaw_rad)
        rz = np.array([[c, -s, 0.0], [s, c, 0.0], [0.0, 0.0, 1.0]])
        centre = np.array([x_m + c * cam.x_m - s * cam.y_m, y_m + s * cam.x_m + c * cam.y_m, cam.z_m])
        r_wc = rz @ self._r_cb  # columns: camera axes in the world
        return centre, r_wc

    def _visible_boxes(self, boxes: np.ndarray, corners: np.ndarray, radius: np.ndarray, centre: np.ndarray,
                       r_wc: np.ndarray) -> np.ndarray:
        fwd = r_wc[:2, 2] / max(np.linalg.norm(r_wc[:2, 2]), 1e-9)
        rel = boxes[:, 1:3] - centre[:2]
        along = rel @ fwd
        across = np.abs(rel[:, 0] * fwd[1] - rel[:, 1] * fwd[0])
        half = np.radians(self.camera.fov_deg) / 2 + 0.1
        dist = np.hypot(rel[:, 0], rel[:, 1])
        keep = (dist - radius < self.camera.max_range_m) & (along > -radius)
        keep &= across <= np.tan(min(half, 1.5)) * np.maximum(along, 0) + radius
        return np.flatnonzero(keep)

    # --------------------------------------------------------------------------------------------- render
    def render(self, x_m: float, y_m: float, yaw_rad: float, dynamic_boxes: np.ndarray | None, weather: Weather,
               rng: np.random.Generator | None = None, rgb: bool = True,
               ) -> tuple[np.ndarray | None, np.ndarray, np.ndarray]:
        """RGB (H, W, 3) uint8 (or None), labels (H, W) uint8 CARLA ids, planar depth (H, W) float32 metres."""
        cam = self.camera
        h, w = cam.height, cam.width
        centre, r_wc = self._camera_pose(x_m, y_m, yaw_rad)
        # ---- ground
        c, s = np.cos(yaw_rad), np.sin(yaw_rad)
        gx = x_m + c * self._ground_ox - s * self._ground_oy
        gy = y_m + s * self._ground_ox + c * self._ground_oy
        row, col, inside = self.map.index(gx, gy)
        gcode = np.where(inside, self.map.ground[row, col], TERRAIN)
        # ---- boxes
        parts, corners, radii = [], [], []
        if len(self._static):
            idx = self._visible_boxes(self._static, self._static_corners, self._static_radius, centre, r_wc)
            parts.append(self._static[idx, :9])
            corners.append(self._static_corners[idx])
        if dynamic_boxes is not None and len(dynamic_boxes):
            dyn = np.asarray(dynamic_boxes, dtype=np.float64)
            radius = 0.5 * np.hypot(dyn[:, 4], dyn[:, 5])
            idx = self._visible_boxes(dyn, None, radius, centre, r_wc)  # type: ignore[arg-type]
            parts.append(dyn[idx, :9])
            corners.append(box_corners(dyn[idx]))
        del radii
        face_buf = np.full((h, w), -1, np.int32)
        face_cls: list[int] = []
        face_n: list[np.ndarray] = []
        face_c: list[float] = []
        face_box: list[int] = []
        boxes = np.concatenate(parts) if parts else np.zeros((0, 9))
        if len(boxes):
            allc = np.concatenate(corners)  # (K, 8, 3)
            self._draw_boxes(boxes, allc, centre, r_wc, face_buf, face_cls, face_n, face_c, face_box)
        labels = np.zeros((h, w), np.uint8)
        depth = np.full((h, w), SKY_DEPTH_M, np.float32)
        lab_flat, dep_flat = labels.reshape(-1), depth.reshape(-1)
        lab_flat[self._ground_flat] = GROUND_CLASS[gcode]
        dep_flat[self._ground_flat] = np.minimum(self._ground_t, SKY_DEPTH_M)
        hit = face_buf >= 0
        fids = face_buf[hit]
        if len(face_cls):
            fcls = np.asarray(face_cls, np.uint8)
            labels[hit] = fcls[fids]
            fn = np.asarray(face_n)  # (F, 3) normals in camera coordinates
            fc = np.asarray(face_c)
            denom = np.einsum("ij,ij->i", fn[fids], self._dcam[hit])
            depth[hit] = np.clip(fc[fids] / np.where(np.abs(denom) < 1e-9, 1e-9, denom), NEAR_M, SKY_DEPTH_M)
        if not rgb:
            return None, labels, depth
        image = self._shade(gcode, gx, gy, boxes, face_buf, hit, fids, face_n, face_box, r_wc, depth, weather)
        if weather.rain > 0 and rng is not None:
            self._rain(image, weather, rng)
        return image, labels, depth

    def _draw_boxes(self, boxes: np.ndarray, corners: np.ndarray, centre: np.ndarray, r_wc: np.ndarray,
                    face_buf: np.ndarray, face_cls: list[int], face_n: list[np.ndarray], face_c: list[float],
                    face_box: list[int]) -> None:
        yaw = boxes[:, 7]
        c, s = np.cos(yaw), np.sin(yaw)
        # outward world normals per face (K, 5, 3)
        nx = _FACE_NORMALS[None, :, 0] * c[:, None] - _FACE_NORMALS[None, :, 1] * s[:, None]
        ny = _FACE_NORMALS[None, :, 0] * s[:, None] + _FACE_NORMALS[None, :, 1] * c[:, None]
        nz = np.broadcast_to(_FACE_NORMALS[None, :, 2], nx.shape)
        normals = np.stack([nx, ny, nz], axis=-1)
        fverts = corners[:, _FACES]  # (K, 5, 4, 3)
        facing = np.einsum("kfj,kfj->kf", normals, centre - fverts[:, :, 0]) > 1e-6
        cam_v = (fverts - centre) @ r_wc  # (K, 5, 4, 3) camera coordinates
        cam_n = normals @ r_wc
        z = cam_v[..., 2]
        visible = facing & (z > NEAR_M).any(axis=-1)
        # painter's order: distance from the camera to each box's footprint, far first
        rel = centre[:2] - boxes[:, 1:3]
        lu = np.abs(rel[:, 0] * c + rel[:, 1] * s) - boxes[:, 4] / 2
        lv = np.abs(-rel[:, 0] * s + rel[:, 1] * c) - boxes[:, 5] / 2
        key = np.hypot(np.maximum(lu, 0), np.maximum(lv, 0))
        order = np.argsort(-key, kind="stable")
        f, cx, cy = self.f, self.cx, self.cy
        with np.errstate(divide="ignore", invalid="ignore"):
            proj = np.stack([f * cam_v[..., 0] / z + cx, f * cam_v[..., 1] / z + cy], axis=-1)
        proj = np.nan_to_num(np.clip(proj, -1e5, 1e5))
        fixed = np.round(proj * 16).astype(np.int32)
        all_front = (z > NEAR_M).all(axis=-1)
        lim = float(np.hypot(face_buf.shape[0], face_buf.shape[1]) * 40)
        # per-face constants as Python lists, so that the drawing loop does no small numpy operations
        plane_c = (cam_n * cam_v[:, :, 0]).sum(-1).tolist()  # n . v0 per face (bit-equal to the 3-vector dot)
        box_cls = boxes[:, 0].astype(np.int64).tolist()
        visible_l, front_l = visible.tolist(), all_front.tolist()
        drawn_k: list[int] = []
        drawn_f: list[int] = []
        for k in order.tolist():
            vis_k, front_k = visible_l[k], front_l[k]
            for fi in range(len(vis_k)):
                if not vis_k[fi]:
                    continue
                if front_k[fi]:
                    pts = fixed[k, fi]
                else:
                    poly = _clip_near(cam_v[k, fi])
                    if len(poly) < 3:
                        continue
                    pp = np.stack([f * poly[:, 0] / poly[:, 2] + cx, f * poly[:, 1] / poly[:, 2] + cy], axis=-1)
                    pts = np.round(np.clip(pp, -lim, lim) * 16).astype(np.int32)
                cv2.fillConvexPoly(face_buf, pts, len(face_cls), cv2.LINE_8, 4)
                face_cls.append(box_cls[k])
                face_c.append(plane_c[k][fi])
                face_box.append(k * 8 + fi)
                drawn_k.append(k)
                drawn_f.append(fi)
        face_n.extend(cam_n[drawn_k, drawn_f])

    # --------------------------------------------------------------------------------------------- colour
    def _weather_tables(self, weather: Weather) -> dict[str, np.ndarray]:
        """Per-weather constants (sky image, lit ground colours, wet-road reflection), computed once per weather."""
        cached = self._weather_cache.get(weather.id)
        if cached is not None:
            return cached
        el, az = np.radians(weather.sun_elevation_deg), np.radians(weather.sun_azimuth_deg)
        sun = np.array([np.cos(el) * np.cos(az), np.cos(el) * np.sin(az), np.sin(el)])
        sun_col = np.asarray(weather.sun_colour)
        t = np.clip(self._sky_elev / 0.6, 0, 1)[..., None]
        sky = ((1 - t) * np.asarray(weather.sky_horizon) + t * np.asarray(weather.sky_zenith)).astype(np.float32)
        light = weather.ambient + weather.sun_strength * max(sun[2], 0.0)
        ground = GROUND_COLOURS * light * sun_col
        ground[_ROAD_LIKE] *= 1 - 0.45 * weather.wetness
        fres = self._fresnel.reshape(-1)[self._ground_flat][:, None]
        reflection = (weather.wetness * 0.8 * fres * np.asarray(weather.sky_horizon)).astype(np.float32)
        tables = {"sun": sun, "sun_col": sun_col, "sky": sky, "ground": ground.astype(np.float32),
                  "reflection": reflection, "fog": np.asarray(weather.fog_colour, np.float32)}
        self._weather_cache[weather.id] = tables
        return tables

    def _shade(self, gcode: np.ndarray, gx: np.ndarray, gy: np.ndarray, boxes: np.ndarray, face_buf: np.ndarray,
               hit: np.ndarray, fids: np.ndarray, face_n: list[np.ndarray], face_box: list[int], r_wc: np.ndarray,
               depth: np.ndarray, weather: Weather) -> np.ndarray:
        tables = self._weather_tables(weather)
        img = tables["sky"].copy()
        flat = img.reshape(-1, 3)
        # ground: lit colour per appearance code, a world-fixed texture, and sky reflections on wet road
        tex = self._noise[(gy * 4).astype(np.intp) & 255, (gx * 4).astype(np.intp) & 255]
        ground_rgb = tables["ground"][gcode] * (1.0 + tex[:, None])
        if weather.wetness > 0:
            ground_rgb += tables["reflection"] * _ROAD_LIKE[gcode][:, None]
        flat[self._ground_flat] = ground_rgb
        # boxes: per-box tint, Lambert shading per face
        if len(face_box):
            fb = np.asarray(face_box)
            kbox = fb // 8
            cls = boxes[kbox, 0].astype(np.intp)
            tint = 0.75 + 0.5 * boxes[kbox, 8]
            col = CLASS_COLOURS[cls] * tint[:, None]
            veh = cls == CarlaClass.VEHICLES
            if veh.any():  # vehicles get varied paint
                hue = boxes[kbox[veh], 8]
                col[veh] = np.stack([0.2 + 0.7 * hue, 0.25 + 0.4 * (1 - hue), 0.3 + 0.5 * np.abs(hue - 0.5)], 1)
            n_world = np.asarray(face_n) @ r_wc.T
            lam = np.clip(n_world @ tables["sun"], 0, 1)
            shade = (weather.ambient + weather.sun_strength * lam)[:, None] * tables["sun_col"]
            flat[hit.reshape(-1)] = (col * shade).astype(np.float32)[fids]
        # haze
        fog = 1.0 - np.exp(depth * np.float32(-1.0 / weather.visibility_m))
        img += fog[..., None] * (tables["fog"] - img)
        img *= 255.0
        np.clip(img, 0, 255, out=img)
        return img.astype(np.uint8)

    def _rain(self, image: np.ndarray, weather: Weather, rng: np.random.Generator) -> None:
        h, w = image.shape[:2]
        n = int(weather.rain * 0.02 * h * w)
        x0 = rng.uniform(0, w, n)
        y0 = rng.uniform(-h * 0.1, h, n)
        length = rng.uniform(0.04, 0.12, n) * h
        overlay = image.copy()
        streaks = np.stack([np.stack([x0, y0], 1), np.stack([x0 - 0.15 * length, y0 + length], 1)], 1)
        cv2.polylines(overlay, list(np.round(streaks).astype(np.int32)), False, (200, 205, 215), 1, cv2.LINE_8)
        cv2.addWeighted(overlay, 0.35, image, 0.65, 0.0, dst=image)


def _clip_near(poly: np.ndarray) -> np.ndarray:
    """Clip a convex polygon (N, 3) in camera coordinates to depth z >= NEAR_M (Sutherland-Hodgman)."""
    out = []
    n = len(poly)
    for i in range(n):
        a, b = poly[i], poly[(i + 1) % n]
        ina, inb = a[2] >= NEAR_M, b[2] >= NEAR_M
        if ina:
            out.append(a)
        if ina != inb:
            t = (NEAR_M - a[2]) / (b[2] - a[2])
            out.append(a + t * (b - a))
    return np.asarray(out)
