"""Generate the shipped town files from CARLA's Town01/Town02 route-planner graphs.

Run `python -m brlcli.sim.towngen [--out towns]`. The output is deterministic (fixed seeds); a change to this
generator that changes a town must bump that town's version in `TOWN_SPECS`.

Route sets of a town: `training` (the training scenarios), `lane_keeping` (the paper's test routes) and
`validation` (for model selection in sweeps), all lane keeping without a junction. Validation routes are drawn
last, from their own generator, so adding them moved nothing else. Their straights lie on road stretches (either
direction) that no training or test route comes within 8 m of. The only junction-free curves of both towns are
their four corners, and the training and test routes drive every corner of town01 and three of town02 both ways;
validation curves start 15 m before and end 10 m after the arc (training: 25 / 20 m, test: 20 / 25 m), so their
start and goal poses are at least 4 m from every training and test pose but they share those arcs. Only the arc of
town02's corner between junctions (6, 24) and (0, 10) is driven by validation routes alone (its approaches are too
short for the training and test margins); its routes come first.
"""

from __future__ import annotations

import argparse
import json
from pathlib import Path

import numpy as np

from brlcli.classes import CarlaClass
from brlcli.sim.roadnet import PathSegment, RoadNetwork
from brlcli.sim.town import OBJECT_COLUMNS, TOWN_FORMAT, TOWN_FORMAT_VERSION, Town, TownGeometry
from brlcli.sim.townmap import RESOLUTION_M, TERRAIN, TownMap

GRID_UNIT_M = 8.215
GEOMETRY = TownGeometry(
    lane_width_m=4.0, sidewalk_width_m=3.0, junction_half_size_m=9.0, corner_radius_m=20.0, line_width_m=0.15
)

TOWN01_EDGES = (
    "0,0-0,40; 0,40-11,40; 11,40-41,40; 41,40-48,40; 48,40-48,0; 48,0-41,0; 41,0-19,0; 19,0-11,0; 11,0-0,0; "
    "11,0-11,7; 11,7-11,16; 11,16-11,24; 11,24-11,40; 41,0-41,7; 41,7-41,16; 41,16-41,24; 41,24-41,40; "
    "11,24-41,24; 11,16-41,16; 11,7-19,7; 19,7-41,7; 19,0-19,7"
)
TOWN02_EDGES = (
    "0,0-24,0; 24,0-24,10; 24,10-24,16; 24,16-24,24; 24,24-6,24; 6,24-0,24; 0,24-0,10; 0,10-0,0; 0,10-6,10; "
    "6,10-17,10; 17,10-24,10; 6,10-6,16; 6,16-6,24; 6,16-17,16; 17,16-24,16; 17,16-17,10"
)

#: name -> (edges, version, seed, CoRL2017 average route lengths in m: straight, one turn, navigation)
TOWN_SPECS = {
    "town01": (TOWN01_EDGES, "1.1.0", 101, (200.0, 400.0, 770.0),
               "Training town after CARLA Town01 (grid 49 x 41, about 2.9 km of road)."),
    "town02": (TOWN02_EDGES, "1.1.0", 202, (100.0, 170.0, 360.0),
               "Testing town after CARLA Town02 (grid 25 x 25, about 1.3 km of road)."),
}

SPAWN_SPACING_M = 24.0
ROUTE_SAMPLE_M = 2.0
VALIDATION_PER_KIND = 4
VALIDATION_CURVE_BEFORE_M = 15.0
VALIDATION_CURVE_AFTER_M = 10.0
"""Validation curves start 15 m before a corner's arc and end 10 m after it (training: 25 / 20 m, test: 20 / 25 m,
and straights start 6 m (training) or 15 m (test) after an arc): every pose at least 4 m from theirs."""
VALIDATION_STRAIGHT_M = 60.0
"""Length of a validation straight (metres; training straights are 70 m, test straights 90 m)."""
VALIDATION_CLEARANCE_M = 8.0
"""A validation straight keeps this distance from every training and test route (more than the 4 m between the
two lanes of a road, so the opposite direction of a used stretch is not taken either)."""
POSE_CLEARANCE_M = 3.9
"""A validation start or goal is at least this far from every training and test start and goal (metres)."""
LANE_END_MARGIN_M = 2.0


def parse_edges(text: str) -> tuple[np.ndarray, np.ndarray]:
    """CARLA planner edge list 'x,y-x,y; ...' -> (nodes in grid units, edges as node index pairs)."""
    index: dict[tuple[int, int], int] = {}
    edges = []
    for item in text.split(";"):
        a, b = item.strip().split("-")
        ends = []
        for p in (a, b):
            key = tuple(int(v) for v in p.split(","))
            ends.append(index.setdefault(key, len(index)))  # type: ignore[arg-type]
        edges.append(ends)
    nodes = np.array(sorted(index, key=index.get), dtype=np.float64)  # type: ignore[arg-type]
    return nodes, np.array(edges, dtype=np.int64)


def _skeleton(name: str, nodes: np.ndarray, edges: np.ndarray) -> Town:
    return Town(name=name, version="0", description="", grid_unit_m=GRID_UNIT_M, geometry=GEOMETRY,
                nodes_m=nodes * GRID_UNIT_M, edges=edges, objects=np.zeros((0, 9)), spawn_poses=np.zeros((0, 3)),
                training_routes=(), lane_keeping_routes=(), path=f"<generator:{name}>")


class _Placer:
    """Places boxes on free terrain, refusing overlaps with roads, sidewalks and earlier boxes."""

    CELL_M = 0.5

    def __init__(self, tmap: TownMap) -> None:
        f = round(self.CELL_M / RESOLUTION_M)
        h, w = tmap.shape[0] // f, tmap.shape[1] // f
        blocks = tmap.ground[: h * f, : w * f].reshape(h, f, w, f)
        self.busy = (blocks != TERRAIN).any(axis=(1, 3))
        self.x0, self.y0 = tmap.x0, tmap.y0
        self.rows: list[list[float]] = []

    def _cells(self, x: float, y: float, length: float, width: float, yaw: float, pad: float) -> tuple:
        c, s = np.cos(yaw), np.sin(yaw)
        u = np.linspace(-length / 2 - pad, length / 2 + pad, max(2, int(length / 0.25) + 2))
        v = np.linspace(-width / 2 - pad, width / 2 + pad, max(2, int(width / 0.25) + 2))
        uu, vv = np.meshgrid(u, v)
        px = x + c * uu - s * vv
        py = y + s * uu + c * vv
        col = np.floor((px - self.x0) / self.CELL_M).astype(int)
        row = np.floor((py - self.y0) / self.CELL_M).astype(int)
        if row.min() < 0 or col.min() < 0 or row.max() >= self.busy.shape[0] or col.max() >= self.busy.shape[1]:
            return None
        return row, col

    def place(self, cls: int, x: float, y: float, z: float, length: float, width: float, height: float,
              yaw: float, tint: float, pad: float = 0.3, on_free: bool = True) -> bool:
        cells = self._cells(x, y, length, width, yaw, pad if on_free else 0.0)
        if cells is None or (on_free and self.busy[cells].any()):
            return False
        self.busy[cells] = True
        self.rows.append([int(cls), x, y, z, length, width, height, float(np.degrees(yaw)), tint])
        return True


def _frames_along(centre: np.ndarray, step_m: float) -> list[tuple[np.ndarray, np.ndarray, float]]:
    """(point, unit tangent, curvature flag) every `step_m` along a polyline."""
    seg = np.diff(centre, axis=0)
    seglen = np.linalg.norm(seg, axis=1)
    cum = np.concatenate([[0.0], np.cumsum(seglen)])
    out = []
    for s in np.arange(step_m / 2, cum[-1], step_m):
        i = min(int(np.searchsorted(cum, s, side="right") - 1), len(seg) - 1)
        t = seg[i] / seglen[i]
        p = centre[i] + (s - cum[i]) * t
        curved = seglen[i] < 5.0  # arc samples are short segments
        out.append((p, t, curved))
    return out


def place_objects(net: RoadNetwork, tmap: TownMap, rng: np.random.Generator) -> np.ndarray:
    """Street furniture, buildings, walls, fences and vegetation beside every road."""
    geo = net.town.geometry
    rh, sw = geo.lane_width_m, geo.sidewalk_width_m
    placer = _Placer(tmap)
    # poles and traffic signs stand on the sidewalk's outer edge; place them first, without the free check
    for road in net.roads:
        for p, t, curved in _frames_along(road.centre, 28.0):
            if curved:
                continue
            for side in (-1.0, 1.0):
                nrm = side * np.array([t[1], -t[0]])
                q = p + nrm * (rh + sw - 0.35)
                placer.place(CarlaClass.POLES, q[0], q[1], 0.0, 0.3, 0.3, 7.0, np.arctan2(t[1], t[0]), 0.5,
                             on_free=False)
    for li in net.lane_ids:
        lane = net.paths[int(li)]
        end, prev = lane.points[-1], lane.points[-2]
        t = (end - prev) / np.linalg.norm(end - prev)
        right = np.array([t[1], -t[0]])
        q = end - 4.0 * t + right * (rh / 2 + 0.9)
        yaw = np.arctan2(t[1], t[0])
        placer.place(CarlaClass.POLES, q[0], q[1], 0.0, 0.15, 0.15, 2.6, yaw, 0.5, on_free=False)
        placer.place(CarlaClass.TRAFFIC_SIGNS, q[0] + 0.1 * t[0], q[1] + 0.1 * t[1], 1.9, 0.08, 0.9, 0.9,
                     yaw, float(rng.uniform()), on_free=False)
    # buildings, walls, fences, trees behind the sidewalks
    for road in net.roads:
        for side in (-1.0, 1.0):
            frames = _frames_along(road.centre, 2.0)
            k = 0
            while k < len(frames):
                p, t, curved = frames[k]
                nrm = side * np.array([t[1], -t[0]])
                yaw = float(np.arctan2(t[1], t[0]))
                edge = rh + sw
                roll = rng.uniform()
                if curved or roll < 0.18:  # a tree
                    setback = rng.uniform(1.2, 3.0)
                    q = p + nrm * (edge + setback)
                    if placer.place(CarlaClass.VEGETATION, q[0], q[1], 0.0, 0.45, 0.45, 2.6, yaw, rng.uniform(),
                                    pad=1.2):
                        placer.place(CarlaClass.VEGETATION, q[0], q[1], 2.3, 3.2, 3.2, rng.uniform(2.5, 4.0),
                                     yaw + rng.uniform(0, 1.5), rng.uniform(), on_free=False)
                    k += int(rng.integers(3, 6))
                elif roll < 0.30:  # a fence or wall segment along the sidewalk
                    length = float(rng.uniform(8.0, 18.0))
                    q = p + t * length / 2 + nrm * (edge + 0.6)
                    if rng.uniform() < 0.5:
                        placer.place(CarlaClass.FENCES, q[0], q[1], 0.0, length, 0.12, 1.3, yaw, rng.uniform())
                    else:
                        placer.place(CarlaClass.WALLS, q[0], q[1], 0.0, length, 0.45, 2.2, yaw, rng.uniform())
                    k += int(length / 2.0) + 1
                else:  # a building
                    length = float(rng.uniform(9.0, 24.0))
                    depth = float(rng.uniform(8.0, 16.0))
                    setback = float(rng.uniform(0.5, 3.0))
                    q = p + t * length / 2 + nrm * (edge + setback + depth / 2)
                    height = float(rng.uniform(5, 22))
                    if not placer.place(CarlaClass.BUILDINGS, q[0], q[1], 0.0, length, depth, height, yaw,
                                        rng.uniform()):
                        length = float(rng.uniform(5.0, 8.0))  # a smaller one may still fit
                        q = p + t * length / 2 + nrm * (edge + setback + depth / 2)
                        placer.place(CarlaClass.BUILDINGS, q[0], q[1], 0.0, length, depth, height, yaw, rng.uniform())
                    k += int(length / 2.0) + int(rng.integers(1, 3))
    rows = np.array(placer.rows, dtype=np.float64)
    rows[:, 1:] = np.round(rows[:, 1:], 3)
    return rows


def spawn_poses(net: RoadNetwork) -> np.ndarray:
    """Poses on straight lane stretches every `SPAWN_SPACING_M`."""
    poses = []
    for lane in net.lanes:
        for s in np.arange(8.0, lane.length_m - 8.0, SPAWN_SPACING_M):
            _x0, _y0, h0 = lane.pose_at(s - 5.0)
            x, y, h = lane.pose_at(s)
            _x1, _y1, h1 = lane.pose_at(s + 5.0)
            if abs((h1 - h0 + 180) % 360 - 180) < 1.0:
                poses.append([round(x, 3), round(y, 3), round(h, 3)])
    return np.array(poses)


def count_turns(points: np.ndarray) -> int:
    """Number of quarter turns along a polyline (corners and junction turns)."""
    d = np.diff(points, axis=0)
    keep = np.linalg.norm(d, axis=1) > 0.2
    h = np.unwrap(np.arctan2(d[keep, 1], d[keep, 0]))
    return round(np.abs(np.diff(h)).sum() / (np.pi / 2)) if len(h) > 1 else 0


def corl_pairs(net: RoadNetwork, poses: np.ndarray, targets: tuple[float, float, float],
               rng: np.random.Generator) -> dict[str, list[list[int]]]:
    """25 start/goal spawn-index pairs per CoRL2017 task, with mean route length near CARLA's."""
    cand: dict[str, list[tuple[int, int, float]]] = {"straight": [], "one_curve": [], "navigation": []}
    for i, a in enumerate(poses):
        for j, b in enumerate(poses):
            if i == j:
                continue
            try:
                r = net.route(tuple(a), tuple(b))
            except Exception:
                continue
            if r.length_m < 40.0:
                continue
            turns = count_turns(r.points)
            kind = "straight" if turns == 0 else "one_curve" if turns == 1 else "navigation"
            cand[kind].append((i, j, r.length_m))
    out = {}
    for kind, target in zip(("straight", "one_curve", "navigation"), targets, strict=True):
        pool = [c for c in cand[kind] if 0.6 * target <= c[2] <= 1.4 * target] or cand[kind]
        best, best_err = None, np.inf
        for _ in range(300):
            pick = rng.choice(len(pool), size=min(25, len(pool)), replace=False)
            err = abs(np.mean([pool[k][2] for k in pick]) - target)
            if err < best_err:
                best, best_err = pick, err
        out[kind] = [[pool[k][0], pool[k][1]] for k in sorted(best)]  # type: ignore[union-attr]
    return out


def lane_keeping_routes(net: RoadNetwork, prefix: str, before_m: float, after_m: float,
                        straight_len_m: float, offset_m: float) -> list[dict]:
    """Routes inside one lane (no junction): every corner of the town both ways, and straight stretches."""
    routes = []
    counts = {"straight": 0, "right_curve": 0, "left_curve": 0}
    for lane in net.lanes:
        d = np.diff(lane.points, axis=0)
        h = np.unwrap(np.arctan2(d[:, 1], d[:, 0]))
        # turning points (vertices where the heading changes), grouped into corners split by long segments
        tp = np.flatnonzero(np.abs(np.diff(h)) > 1e-3) + 1
        if len(tp):
            groups = np.split(tp, np.flatnonzero(np.diff(lane.cum_s[tp]) > 3.0) + 1)
            for g in groups:
                s0, s1 = float(lane.cum_s[g[0]]), float(lane.cum_s[g[-1]])
                kind = "left_curve" if h[g[-1]] > h[g[0] - 1] else "right_curve"
                a, b = s0 - before_m, s1 + after_m
                if a >= 2.0 and b <= lane.length_m - 2.0:
                    counts[kind] += 1
                    routes.append({"name": f"{prefix}_{kind}_{counts[kind]}", "kind": kind,
                                   "start": [round(v, 3) for v in lane.pose_at(a)],
                                   "goal": [round(v, 3) for v in lane.pose_at(b)]})
        # straights: longest turn-free stretch of the lane
        bounds = np.concatenate([[0.0], lane.cum_s[tp] if len(tp) else [], [lane.length_m]])
        gaps = np.diff(bounds)
        k = int(np.argmax(gaps))
        a = bounds[k] + offset_m
        if gaps[k] >= straight_len_m + offset_m + 4.0:
            counts["straight"] += 1
            routes.append({"name": f"{prefix}_straight_{counts['straight']}", "kind": "straight",
                           "start": [round(v, 3) for v in lane.pose_at(a)],
                           "goal": [round(v, 3) for v in lane.pose_at(a + straight_len_m)]})
    return routes


def _pick(routes: list[dict], per_kind: int, rng: np.random.Generator) -> list[dict]:
    out = []
    for kind in ("straight", "right_curve", "left_curve"):
        pool = [r for r in routes if r["kind"] == kind]
        pick = sorted(rng.choice(len(pool), size=min(per_kind, len(pool)), replace=False))
        out.extend(pool[i] for i in pick)
    return out


def route_points(net: RoadNetwork, start: tuple | list, goal: tuple | list, step_m: float = 1.0) -> np.ndarray:
    """Points every `step_m` metres along the planned route from `start` to `goal` (both ends included)."""
    r = net.route(tuple(start), tuple(goal))  # type: ignore[arg-type]
    s = np.append(np.arange(0.0, r.length_m, step_m), r.length_m)
    return np.stack([np.interp(s, r.cum_s, r.points[:, 0]), np.interp(s, r.cum_s, r.points[:, 1])], axis=1)


def _route_doc(lane: PathSegment, kind: str, a: float, b: float) -> dict:
    return {"name": "", "kind": kind, "start": [round(v, 3) for v in lane.pose_at(a)],
            "goal": [round(v, 3) for v in lane.pose_at(b)]}


def validation_routes(net: RoadNetwork, taken: list[dict], rng: np.random.Generator,
                      per_kind: int = VALIDATION_PER_KIND) -> list[dict]:
    """Validation routes: curves on every corner from other poses than `taken`, straights on untouched stretches.

    Curves sharing the least of their length with `taken` routes come first; straights keep
    `VALIDATION_CLEARANCE_M` from every taken route and from corners, spread over roads (picked with `rng`).
    """
    taken_pts = np.concatenate([route_points(net, r["start"], r["goal"]) for r in taken])
    taken_poses = np.array([r[k][:2] for r in taken for k in ("start", "goal")], dtype=np.float64)

    def own_poses(doc: dict) -> bool:
        ends = np.array([doc["start"][:2], doc["goal"][:2]])
        return bool(np.linalg.norm(ends[:, None] - taken_poses[None], axis=2).min() >= POSE_CLEARANCE_M)

    def clear(points: np.ndarray, margin: float) -> np.ndarray:
        d = np.linalg.norm(points[:, None, :] - taken_pts[None, :, :], axis=2).min(axis=1)
        return d > margin

    curves: dict[str, list[tuple[bool, dict]]] = {"right_curve": [], "left_curve": []}
    straights: dict[int, list[dict]] = {}
    for lane in net.lanes:
        d = np.diff(lane.points, axis=0)
        h = np.unwrap(np.arctan2(d[:, 1], d[:, 0]))
        tp = np.flatnonzero(np.abs(np.diff(h)) > 1e-3) + 1
        arcs = np.split(tp, np.flatnonzero(np.diff(lane.cum_s[tp]) > 3.0) + 1) if len(tp) else []
        for g in arcs:
            s0, s1 = float(lane.cum_s[g[0]]), float(lane.cum_s[g[-1]])
            kind = "left_curve" if h[g[-1]] > h[g[0] - 1] else "right_curve"
            a, b = s0 - VALIDATION_CURVE_BEFORE_M, s1 + VALIDATION_CURVE_AFTER_M
            if a >= LANE_END_MARGIN_M and b <= lane.length_m - LANE_END_MARGIN_M:
                pts = np.array([lane.pose_at(v)[:2] for v in np.arange(a, b, 1.0)])
                shared = float(1.0 - clear(pts, VALIDATION_CLEARANCE_M).mean())  # share of the route near taken ones
                doc = _route_doc(lane, kind, a, b)
                if own_poses(doc):
                    curves[kind].append((shared, doc))
        # free stretches: away from the lane ends, the arcs and every taken route
        s = np.arange(LANE_END_MARGIN_M, lane.length_m - LANE_END_MARGIN_M + 1e-9, 1.0)
        free = clear(np.array([lane.pose_at(v)[:2] for v in s]), VALIDATION_CLEARANCE_M)
        for g in arcs:
            free &= (s < float(lane.cum_s[g[0]]) - 1.0) | (s > float(lane.cum_s[g[-1]]) + 1.0)
        edges = np.flatnonzero(np.diff(np.concatenate([[0], free.astype(int), [0]])))
        for lo, hi in zip(edges[::2], edges[1::2], strict=True):
            a0, a1 = float(s[lo]), float(s[hi - 1])
            if a1 - a0 >= VALIDATION_STRAIGHT_M:
                a = round((a0 + a1 - VALIDATION_STRAIGHT_M) / 2.0, 1)  # centred in the free stretch
                straights.setdefault(lane.road, []).append(_route_doc(lane, "straight", a, a + VALIDATION_STRAIGHT_M))
    out: list[dict] = []
    roads = sorted(straights)
    queues = [list(straights[roads[i]]) for i in rng.permutation(len(roads))]
    for q in queues:  # shuffle each road's stretches (both directions), then take one per road in turn
        q[:] = [q[i] for i in rng.permutation(len(q))]
    picked: list[dict] = []
    while len(picked) < per_kind and any(queues):
        for q in queues:
            if q and len(picked) < per_kind:
                picked.append(q.pop(0))
    out.extend(sorted(picked, key=lambda r: (r["start"][0], r["start"][1])))
    for kind in ("right_curve", "left_curve"):  # least shared first, then in lane order
        ranked = [doc for _, (_, doc) in sorted(enumerate(curves[kind]), key=lambda x: (x[1][0], x[0]))]
        out.extend(ranked[:per_kind])
    counts = dict.fromkeys(("straight", "right_curve", "left_curve"), 0)
    for r in out:
        counts[r["kind"]] += 1
        r["name"] = f"val_{r['kind']}_{counts[r['kind']]}"
    return [{"name": r["name"], "kind": r["kind"], "start": r["start"], "goal": r["goal"]} for r in out]


def generate(name: str) -> dict:
    """Build the town document for one of `TOWN_SPECS`."""
    edges_text, version, seed, targets, description = TOWN_SPECS[name]
    rng = np.random.default_rng(seed)
    nodes, edges = parse_edges(edges_text)
    net = RoadNetwork(_skeleton(name, nodes, edges))
    tmap = TownMap(net)
    objects = place_objects(net, tmap, rng)
    poses = spawn_poses(net)
    train = lane_keeping_routes(net, "train", 25.0, 20.0, 70.0, 6.0)
    test = lane_keeping_routes(net, "test", 20.0, 25.0, 90.0, 15.0)
    training, lane_keeping = _pick(train, 4, rng), _pick(test, 4, rng)
    corl = corl_pairs(net, poses, targets, rng)
    validation = validation_routes(net, training + lane_keeping, np.random.default_rng([seed, 12]))
    doc = {
        "format": TOWN_FORMAT,
        "format_version": TOWN_FORMAT_VERSION,
        "name": name,
        "version": version,
        "description": description,
        "grid_unit_m": GRID_UNIT_M,
        "geometry": {k: getattr(GEOMETRY, k) for k in vars(GEOMETRY)},
        "nodes": nodes.astype(int).tolist(),
        "edges": edges.tolist(),
        "objects": {"columns": list(OBJECT_COLUMNS), "rows": objects.tolist()},
        "spawn_poses": poses.tolist(),
        "routes": {
            "training": training,
            "lane_keeping": lane_keeping,
            "validation": validation,
            "corl2017": corl,
        },
    }
    return doc


def write_town(doc: dict, out_dir: Path) -> Path:
    """Write a town document as compact, diff-friendly JSON (one object row per line)."""
    out_dir.mkdir(parents=True, exist_ok=True)
    rows = doc["objects"]["rows"]
    body = dict(doc)
    body["objects"] = {"columns": doc["objects"]["columns"], "rows": "__ROWS__"}
    text = json.dumps(body, indent=1)
    row_text = "[\n" + ",\n".join("   " + json.dumps([int(r[0]), *r[1:]]) for r in rows) + "\n  ]"
    text = text.replace('"__ROWS__"', row_text)
    path = out_dir / f"{doc['name']}.json"
    tmp = path.with_suffix(".json.tmp")
    tmp.write_text(text + "\n", encoding="utf-8")
    tmp.replace(path)
    return path


def main() -> None:
    """Command-line entry: regenerate the shipped towns."""
    ap = argparse.ArgumentParser(description=__doc__)
    ap.add_argument("--out", default="towns")
    ap.add_argument("names", nargs="*", default=sorted(TOWN_SPECS))
    args = ap.parse_args()
    for name in args.names:
        path = write_town(generate(name), Path(args.out))
        print(f"wrote {path}")


if __name__ == "__main__":
    main()
