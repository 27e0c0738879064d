"""Road network: centre lines, directed lanes, junction connectors, the lane graph and the route planner."""

from __future__ import annotations

import itertools
from dataclasses import dataclass, field
from enum import IntEnum

import numpy as np
from scipy.sparse import csr_matrix
from scipy.sparse.csgraph import dijkstra

from brlcli.errors import BrlInputError
from brlcli.sim.town import Town, TownFormatError

ARC_STEP_DEG = 5.0
"""Angular sampling of corner arcs and junction curves (degrees)."""


class Command(IntEnum):
    """High-level route commands, with CARLA 0.8 planner codes."""

    REACH_GOAL = 0
    LANE_FOLLOW = 2
    TURN_LEFT = 3
    TURN_RIGHT = 4
    GO_STRAIGHT = 5


BRANCH_COMMANDS = (Command.LANE_FOLLOW, Command.TURN_LEFT, Command.TURN_RIGHT, Command.GO_STRAIGHT)
"""The commands a command-conditioned policy has a branch for (CIL's four; REACH_GOAL drives as LANE_FOLLOW)."""
BRANCH_NAMES = ("follow", "left", "right", "straight")


def command_branch(command: int | np.ndarray) -> np.ndarray:
    """Branch index of CARLA command codes (2 follow -> 0, 3 left -> 1, 4 right -> 2, 5 straight -> 3; else 0)."""
    cmd = np.asarray(command, dtype=np.int64)
    out = np.zeros(cmd.shape, dtype=np.int64)
    for i, c in enumerate(BRANCH_COMMANDS):
        out[cmd == int(c)] = i
    return out


@dataclass(frozen=True)
class PathSegment:
    """One drivable path of the lane graph: a directed lane between two junctions, or a junction connector."""

    index: int
    kind: str  # "lane" or "connector"
    points: np.ndarray  # (N, 2) metres
    cum_s: np.ndarray  # (N,) arc length at each point, metres
    command: Command  # LANE_FOLLOW for lanes; the turn for connectors
    from_node: int
    to_node: int
    road: int  # index of the road (chain) a lane lies on; -1 for connectors
    opposite: int = -1  # index of the lane of the same road in the other direction; -1 for connectors

    @property
    def length_m(self) -> float:
        """Arc length of the path in metres."""
        return float(self.cum_s[-1])

    def pose_at(self, s_m: float) -> tuple[float, float, float]:
        """Position (m) and heading (deg) at arc length `s_m` along the path."""
        s = float(np.clip(s_m, 0.0, self.length_m))
        i = int(np.clip(np.searchsorted(self.cum_s, s, side="right") - 1, 0, len(self.points) - 2))
        d = self.points[i + 1] - self.points[i]
        seg = float(self.cum_s[i + 1] - self.cum_s[i])
        f = (s - self.cum_s[i]) / seg if seg > 0 else 0.0
        p = self.points[i] + f * d
        return float(p[0]), float(p[1]), float(np.degrees(np.arctan2(d[1], d[0])))


@dataclass(frozen=True)
class Road:
    """A road between two junctions: its centre line (through corners) and its two lanes."""

    index: int
    centre: np.ndarray  # (N, 2) metres, from `from_node` towards `to_node`
    from_node: int
    to_node: int
    lanes: tuple[int, int]  # (forward lane path index, backward lane path index)


def _cumlen(points: np.ndarray) -> np.ndarray:
    return np.concatenate([[0.0], np.cumsum(np.linalg.norm(np.diff(points, axis=0), axis=1))])


def offset_polyline(points: np.ndarray, offset_m: float) -> np.ndarray:
    """Offset a polyline sideways (positive = to the right of travel) with mitred joints."""
    d = np.diff(points, axis=0)
    d /= np.linalg.norm(d, axis=1, keepdims=True)
    right = np.stack([d[:, 1], -d[:, 0]], axis=1)
    vn = np.empty_like(points)
    vn[0], vn[-1] = right[0], right[-1]
    if len(points) > 2:
        avg = right[:-1] + right[1:]
        avg /= np.linalg.norm(avg, axis=1, keepdims=True)
        cos_half = np.sum(avg * right[1:], axis=1, keepdims=True)
        vn[1:-1] = avg / np.maximum(cos_half, 0.2)
    return points + offset_m * vn


def _bezier(p0: np.ndarray, h0: np.ndarray, p3: np.ndarray, h3: np.ndarray, n: int) -> np.ndarray:
    """Cubic Bezier from p0 heading h0 to p3 heading h3 (a near-circular quarter turn for perpendicular ends)."""
    chord = float(np.linalg.norm(p3 - p0))
    k = 0.5523 * chord / np.sqrt(2.0)
    p1, p2 = p0 + k * h0, p3 - k * h3
    t = np.linspace(0.0, 1.0, n)[:, None]
    return (1 - t) ** 3 * p0 + 3 * (1 - t) ** 2 * t * p1 + 3 * (1 - t) * t**2 * p2 + t**3 * p3


def _unit(v: np.ndarray) -> np.ndarray:
    return v / np.linalg.norm(v)


class RoadNetwork:
    """Roads, lanes and junction connectors derived from a town's grid graph (right-hand traffic)."""

    def __init__(self, town: Town) -> None:
        self.town = town
        geo = town.geometry
        self.lane_width_m = geo.lane_width_m
        self.junction_half_m = geo.junction_half_size_m
        self.corner_radius_m = geo.corner_radius_m
        nodes = town.nodes_m
        n = len(nodes)
        self.neighbours: list[list[int]] = [[] for _ in range(n)]
        for a, b in town.edges:
            self.neighbours[int(a)].append(int(b))
            self.neighbours[int(b)].append(int(a))
        deg = np.array([len(v) for v in self.neighbours])
        if np.any(deg == 1):
            bad = int(np.flatnonzero(deg == 1)[0])
            raise TownFormatError(f"town file {town.path}: field 'edges' leaves node {bad} as a dead end")
        self.is_junction = deg >= 3
        if not self.is_junction.any():
            raise TownFormatError(f"town file {town.path}: field 'edges' must form at least one junction")
        self.roads: list[Road] = []
        self.paths: list[PathSegment] = []
        self._build_roads()
        self._build_connectors()
        self._build_graph()

    # ----------------------------------------------------------------- construction
    def _direction(self, a: int, b: int) -> np.ndarray:
        return _unit(self.town.nodes_m[b] - self.town.nodes_m[a])

    def _chain_centre(self, chain: list[int]) -> np.ndarray:
        nodes = self.town.nodes_m
        j, r = self.junction_half_m, self.corner_radius_m
        pts = [nodes[chain[0]] + j * self._direction(chain[0], chain[1])]
        for i in range(1, len(chain) - 1):
            d_in, d_out = self._direction(chain[i - 1], chain[i]), self._direction(chain[i], chain[i + 1])
            if abs(float(np.dot(d_in, d_out))) > 0.5:  # straight through a degree-2 node
                continue
            start, centre = nodes[chain[i]] - r * d_in, nodes[chain[i]] - r * d_in + r * d_out
            a0 = np.arctan2(*(start - centre)[::-1])
            turn = np.sign(d_in[0] * d_out[1] - d_in[1] * d_out[0])  # +1 left (ccw), -1 right
            steps = int(np.ceil(90.0 / ARC_STEP_DEG))
            ang = a0 + turn * np.linspace(0.0, np.pi / 2, steps + 1)
            pts.extend(centre + r * np.stack([np.cos(ang), np.sin(ang)], axis=1))
        pts.append(nodes[chain[-1]] - j * self._direction(chain[-2], chain[-1]))
        centre = np.asarray(pts, dtype=np.float64)
        keep = np.concatenate([[True], np.linalg.norm(np.diff(centre, axis=0), axis=1) > 1e-6])
        return centre[keep]

    def _build_roads(self) -> None:
        seen: set[tuple[int, int]] = set()
        for start in np.flatnonzero(self.is_junction):
            for nb in self.neighbours[int(start)]:
                if (int(start), nb) in seen:
                    continue
                chain = [int(start), nb]
                while not self.is_junction[chain[-1]]:
                    nxt = [v for v in self.neighbours[chain[-1]] if v != chain[-2]]
                    chain.append(nxt[0])
                for a, b in itertools.pairwise(chain):
                    seen.add((a, b))
                    seen.add((b, a))
                self._check_lengths(chain)
                centre = self._chain_centre(chain)
                road_idx = len(self.roads)
                fwd_pts = offset_polyline(centre, self.lane_width_m / 2)
                bwd_pts = offset_polyline(centre[::-1].copy(), self.lane_width_m / 2)
                fi, bi = len(self.paths), len(self.paths) + 1
                self.paths.append(PathSegment(fi, "lane", fwd_pts, _cumlen(fwd_pts), Command.LANE_FOLLOW,
                                              chain[0], chain[-1], road_idx, bi))
                self.paths.append(PathSegment(bi, "lane", bwd_pts, _cumlen(bwd_pts), Command.LANE_FOLLOW,
                                              chain[-1], chain[0], road_idx, fi))
                self.roads.append(Road(road_idx, centre, chain[0], chain[-1], (fi, bi)))

    def _check_lengths(self, chain: list[int]) -> None:
        nodes = self.town.nodes_m
        for i in range(len(chain) - 1):
            a, b = chain[i], chain[i + 1]
            need = 0.0
            for node, other in ((a, b), (b, a)):
                if self.is_junction[node]:
                    need += self.junction_half_m
                else:
                    d1 = self._direction(node, other)
                    others = [v for v in self.neighbours[node] if v != other]
                    d2 = self._direction(node, others[0])
                    if abs(float(np.dot(d1, d2))) < 0.5:
                        need += self.corner_radius_m
            if float(np.linalg.norm(nodes[b] - nodes[a])) < need + 1.0:
                raise TownFormatError(
                    f"town file {self.town.path}: field 'edges' has edge {a}-{b} too short for its junctions/corners"
                )

    def _build_connectors(self) -> None:
        incoming: dict[int, list[int]] = {}
        outgoing: dict[int, list[int]] = {}
        for p in self.paths:
            incoming.setdefault(p.to_node, []).append(p.index)
            outgoing.setdefault(p.from_node, []).append(p.index)
        for node in np.flatnonzero(self.is_junction):
            node = int(node)
            for li in incoming.get(node, []):
                lane_in = self.paths[li]
                p0 = lane_in.points[-1]
                h0 = _unit(lane_in.points[-1] - lane_in.points[-2])
                for lo in outgoing.get(node, []):
                    lane_out = self.paths[lo]
                    if lane_out.road == lane_in.road:
                        continue  # no U-turns
                    p3 = lane_out.points[0]
                    h3 = _unit(lane_out.points[1] - lane_out.points[0])
                    cross = float(h0[0] * h3[1] - h0[1] * h3[0])
                    if float(np.dot(h0, h3)) > 0.7:
                        cmd, pts = Command.GO_STRAIGHT, np.stack([p0, p3])
                    else:
                        cmd = Command.TURN_LEFT if cross > 0 else Command.TURN_RIGHT
                        pts = _bezier(p0, h0, p3, h3, int(90.0 / ARC_STEP_DEG) + 1)
                    self.paths.append(PathSegment(len(self.paths), "connector", pts, _cumlen(pts), cmd,
                                                  node, node, -1, -1))
        self.lane_ids = np.array([p.index for p in self.paths if p.kind == "lane"])

    def _build_graph(self) -> None:
        """Successor lists and a sparse graph whose edge u->v weighs the length of v."""
        n = len(self.paths)
        self.successors: list[list[int]] = [[] for _ in range(n)]
        ends_in: dict[tuple[int, int], list[int]] = {}
        for p in self.paths:
            if p.kind == "connector":
                ends_in.setdefault((p.from_node, round(p.points[0][0] * 100), round(p.points[0][1] * 100)),
                                   []).append(p.index)
        lane_start = {}
        for p in self.paths:
            if p.kind == "lane":
                lane_start[(round(p.points[0][0] * 100), round(p.points[0][1] * 100))] = p.index
        rows, cols, w = [], [], []
        for p in self.paths:
            if p.kind == "lane":
                key = (p.to_node, round(p.points[-1][0] * 100), round(p.points[-1][1] * 100))
                succ = ends_in.get(key, [])
            else:
                succ = [lane_start[(round(p.points[-1][0] * 100), round(p.points[-1][1] * 100))]]
            self.successors[p.index] = succ
            for s in succ:
                rows.append(p.index)
                cols.append(s)
                w.append(self.paths[s].length_m)
        self._graph = csr_matrix((w, (rows, cols)), shape=(n, n))
        # flat segment table for fast nearest-path queries
        seg_a, seg_b, seg_path, seg_s = [], [], [], []
        for p in self.paths:
            seg_a.append(p.points[:-1])
            seg_b.append(p.points[1:])
            seg_path.append(np.full(len(p.points) - 1, p.index))
            seg_s.append(p.cum_s[:-1])
        self._seg_a = np.concatenate(seg_a)
        self._seg_b = np.concatenate(seg_b)
        self._seg_path = np.concatenate(seg_path)
        self._seg_s = np.concatenate(seg_s)
        self._seg_is_lane = np.array([self.paths[i].kind == "lane" for i in self._seg_path])

    # ----------------------------------------------------------------- queries
    @property
    def lanes(self) -> list[PathSegment]:
        """The directed lanes (no connectors)."""
        return [self.paths[i] for i in self.lane_ids]

    def locate(self, x_m: float, y_m: float, yaw_deg: float | None = None,
               lanes_only: bool = False) -> tuple[int, float, float]:
        """Nearest path to a pose: (path index, arc length s in m, lateral distance in m).

        With a heading, paths running against it by more than 90 degrees are skipped.
        """
        p = np.array([x_m, y_m])
        ab = self._seg_b - self._seg_a
        ln2 = np.einsum("ij,ij->i", ab, ab)
        t = np.clip(np.einsum("ij,ij->i", p - self._seg_a, ab) / ln2, 0.0, 1.0)
        proj = self._seg_a + t[:, None] * ab
        dist = np.linalg.norm(proj - p, axis=1)
        if yaw_deg is not None:
            h = np.array([np.cos(np.radians(yaw_deg)), np.sin(np.radians(yaw_deg))])
            dist = np.where(ab @ h > 0, dist, np.inf)
        if lanes_only:
            dist = np.where(self._seg_is_lane, dist, np.inf)
        k = int(np.argmin(dist))
        if not np.isfinite(dist[k]):
            raise BrlInputError(f"no lane runs along the pose ({x_m:.1f}, {y_m:.1f}, {yaw_deg})")
        s = float(self._seg_s[k] + t[k] * np.sqrt(ln2[k]))
        return int(self._seg_path[k]), s, float(dist[k])

    def route(self, start: tuple[float, float, float], goal: tuple[float, float, float]) -> Route:
        """Shortest route along the lane graph from a start pose to a goal pose (x_m, y_m, yaw_deg)."""
        pa, sa, _ = self.locate(*start, lanes_only=True)
        pb, sb, _ = self.locate(*goal, lanes_only=True)
        if pa == pb and sb >= sa:
            return Route(self, [pa], sa, sb)
        dist, pred = dijkstra(self._graph, directed=True, indices=pa, return_predecessors=True)
        last = pb
        if pa == pb:  # goal behind the start on the same lane: leave the lane and come back round
            entries = [u for u in range(len(self.paths)) if pa in self.successors[u] and np.isfinite(dist[u])]
            if not entries:
                raise BrlInputError(f"no route from {start} to {goal}")
            last = min(entries, key=lambda u: dist[u])
        elif not np.isfinite(dist[pb]):
            raise BrlInputError(f"no route from {start} to {goal}")
        chain = [last]
        while chain[-1] != pa:
            chain.append(int(pred[chain[-1]]))
        if pa == pb:
            chain.insert(0, pb)
        return Route(self, chain[::-1], sa, sb)


@dataclass
class Route:
    """A planned route: a sequence of paths from arc length `s_start_m` on the first to `s_end_m` on the last."""

    network: RoadNetwork
    path_ids: list[int]
    s_start_m: float
    s_end_m: float
    points: np.ndarray = field(init=False)  # (N, 2) polyline of the whole route
    cum_s: np.ndarray = field(init=False)
    commands: list[tuple[float, float, Command]] = field(init=False)  # (junction start s, end s, command)

    def __post_init__(self) -> None:
        pieces, commands, offset = [], [], 0.0
        for k, pid in enumerate(self.path_ids):
            path = self.network.paths[pid]
            lo = self.s_start_m if k == 0 else 0.0
            hi = self.s_end_m if k == len(self.path_ids) - 1 else path.length_m
            inner = (path.cum_s > lo) & (path.cum_s < hi)
            pts = np.vstack([path.pose_at(lo)[:2], path.points[inner], path.pose_at(hi)[:2]])
            if path.kind == "connector":
                commands.append((offset, offset + hi - lo, path.command))
            pieces.append(pts if not pieces else pts[1:])
            offset += hi - lo
        self.points = np.vstack(pieces)
        self.cum_s = _cumlen(self.points)
        self.commands = commands

    @property
    def length_m(self) -> float:
        """Length of the route along its lanes, metres."""
        return float(self.cum_s[-1])

    @property
    def goal(self) -> tuple[float, float]:
        """Goal position (m)."""
        return float(self.points[-1, 0]), float(self.points[-1, 1])

    def heading_at(self, s_m: float) -> float:
        """The route's direction (rad, as yaw: atan2 of dy and dx) at arc length `s_m`, clamped to the route."""
        k = int(np.clip(np.searchsorted(self.cum_s, s_m, side="right") - 1, 0, len(self.points) - 2))
        dx, dy = self.points[k + 1] - self.points[k]
        return float(np.arctan2(dy, dx))

    def pose_at(self, s_m: float) -> tuple[float, float, float]:
        """The pose (x_m, y_m, yaw_deg) on the route at arc length `s_m`, clamped to the route."""
        s_m = min(max(float(s_m), 0.0), self.length_m)
        k = int(np.clip(np.searchsorted(self.cum_s, s_m, side="right") - 1, 0, len(self.points) - 2))
        seg = self.cum_s[k + 1] - self.cum_s[k]
        t = (s_m - self.cum_s[k]) / seg if seg > 0 else 0.0
        x, y = self.points[k] + t * (self.points[k + 1] - self.points[k])
        return float(x), float(y), float(np.degrees(self.heading_at(s_m)))

    def project(self, x_m: float, y_m: float) -> tuple[float, float]:
        """Arc length along the route (m) of the nearest point to (x, y), and the signed lateral offset (m, + right)."""
        a, b = self.points[:-1], self.points[1:]
        ab = b - a
        ln2 = np.maximum(np.einsum("ij,ij->i", ab, ab), 1e-12)
        p = np.array([x_m, y_m])
        t = np.clip(np.einsum("ij,ij->i", p - a, ab) / ln2, 0.0, 1.0)
        proj = a + t[:, None] * ab
        d = np.linalg.norm(proj - p, axis=1)
        k = int(np.argmin(d))
        side = np.sign(ab[k, 1] * (p - a[k])[0] - ab[k, 0] * (p - a[k])[1])
        return float(self.cum_s[k] + t[k] * np.sqrt(ln2[k])), float(side * d[k])

    def command_at(self, s_m: float, lookahead_m: float = 10.0) -> Command:
        """High-level command at route arc length `s_m`: the next junction's turn within `lookahead_m`."""
        if s_m >= self.length_m - 2.0:
            return Command.REACH_GOAL
        for start, end, cmd in self.commands:
            if start - lookahead_m <= s_m <= end:
                return cmd
        return Command.LANE_FOLLOW


REPLAN_OFFSET_M = 3.0
"""`Navigator` replans when the car is more than this far (m) from its route, on a lane (the lane's half width plus
a margin: a car in its own lane of the route is within about 1 m)."""


class Navigator:
    """An episode's route commands, replanned from the car's pose as CARLA 0.8's planner does.

    CARLA's planner (`carla/planner/planner.py`) recomputes the route from the car's position whenever the car enters
    a new node of its grid away from a junction, so a car that missed a turn gets the commands of a new route to the
    goal. Replanning from a pose on the route gives the same route, so brl replans only when the car is more than
    REPLAN_OFFSET_M from its route and on a lane (not inside a junction) along its heading.
    """

    def __init__(self, network: RoadNetwork, start: tuple[float, float, float],
                 goal: tuple[float, float, float]) -> None:
        self.network = network
        self.goal = goal
        self.route = network.route(start, goal)
        self.replans = 0

    def command(self, x_m: float, y_m: float, yaw_deg: float) -> Command:
        """The command for the car at (x_m, y_m) heading yaw_deg, replanning first if it has left its route."""
        s, offset = self.route.project(x_m, y_m)
        if abs(offset) > REPLAN_OFFSET_M and self._replan(x_m, y_m, yaw_deg):
            s, _ = self.route.project(x_m, y_m)
        return self.route.command_at(s)

    def _replan(self, x_m: float, y_m: float, yaw_deg: float) -> bool:
        """Plan anew from the pose when it lies on a lane along its heading; True when the route changed."""
        try:
            path, _, dist = self.network.locate(x_m, y_m, yaw_deg)
            if self.network.paths[path].kind == "connector" or dist > self.network.lane_width_m / 2:
                return False
            self.route = self.network.route((x_m, y_m, yaw_deg), self.goal)
        except BrlInputError:  # no lane along the heading, or no route from it: keep the old commands
            return False
        self.replans += 1
        return True
