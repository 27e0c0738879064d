"""Towns as versioned data: loading and validating `towns/*.json`."""

from __future__ import annotations

import json
import os
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np

from brlcli.errors import BrlInputError

TOWN_FORMAT = "brl-town"
TOWN_FORMAT_VERSION = 1

#: Columns of a town's object table (one static box per row; metres and degrees, z is the box bottom).
OBJECT_COLUMNS = ("class_id", "x", "y", "z", "length", "width", "height", "yaw_deg", "tint")

#: The three CoRL2017 pose-pair lists a town carries (task 3 reuses `navigation`).
CORL_TASK_POSES = ("straight", "one_curve", "navigation")

#: The kinds of lane-keeping route (paper: straight, right curve, left curve; no junction).
ROUTE_KINDS = ("straight", "right_curve", "left_curve")

#: Named lane-keeping route sets of a town (`routes.<set>` in the file); `validation` is optional (town files
#: made before it existed have none).
ROUTE_SETS = ("training", "lane_keeping", "validation")


class TownFormatError(BrlInputError):
    """A town file is missing a field or has a malformed one."""


@dataclass(frozen=True)
class TownGeometry:
    """Cross-section and junction sizes shared by every road of a town (metres)."""

    lane_width_m: float
    sidewalk_width_m: float
    junction_half_size_m: float
    corner_radius_m: float
    line_width_m: float

    @property
    def road_half_width_m(self) -> float:
        """Half of the carriageway width: one lane per direction."""
        return self.lane_width_m


@dataclass(frozen=True)
class RouteSpec:
    """A lane-keeping route: start and goal poses `(x_m, y_m, yaw_deg)` and its kind."""

    name: str
    kind: str
    start: tuple[float, float, float]
    goal: tuple[float, float, float]


@dataclass(frozen=True)
class Town:
    """A town: road graph on a grid, static objects, spawn poses and named routes."""

    name: str
    version: str
    description: str
    grid_unit_m: float
    geometry: TownGeometry
    nodes_m: np.ndarray  # (N, 2) node positions in metres
    edges: np.ndarray  # (E, 2) node indices, undirected
    objects: np.ndarray  # (K, 9) float64, columns OBJECT_COLUMNS
    spawn_poses: np.ndarray  # (P, 3) x_m, y_m, yaw_deg
    training_routes: tuple[RouteSpec, ...]
    lane_keeping_routes: tuple[RouteSpec, ...]
    validation_routes: tuple[RouteSpec, ...] = ()  # lane keeping for model selection (empty in town files < 1.1)
    corl2017_poses: dict[str, np.ndarray] = field(default_factory=dict)  # task -> (25, 2) spawn indices
    path: str = ""

    @property
    def road_length_m(self) -> float:
        """Total length of the road graph's edges (centre lines, corners not rounded)."""
        d = self.nodes_m[self.edges[:, 0]] - self.nodes_m[self.edges[:, 1]]
        return float(np.abs(d).sum(axis=1).sum()) if len(d) else 0.0

    def route_set(self, name: str) -> tuple[RouteSpec, ...]:
        """A named route set: training, lane_keeping or validation (one-line error if unknown or absent)."""
        sets = {"training": self.training_routes, "lane_keeping": self.lane_keeping_routes,
                "validation": self.validation_routes}
        if name not in sets:
            raise BrlInputError(f"unknown route set '{name}'; choose from {', '.join(ROUTE_SETS)}")
        if not sets[name]:
            raise BrlInputError(f"town {self.name} (version {self.version}, {self.path}) has no {name} routes; "
                                "regenerate it with python -m brlcli.sim.towngen")
        return sets[name]

    @property
    def identity(self) -> dict[str, str]:
        """Name and version, as recorded beside every output made in this town."""
        return {"town": self.name, "town_version": self.version}


def towns_dir() -> Path:
    """Directory holding the shipped town files (env `BRL_TOWNS_DIR` overrides)."""
    env = os.environ.get("BRL_TOWNS_DIR")
    if env:
        return Path(env)
    packaged = Path(__file__).resolve().parent.parent / "data" / "towns"
    if packaged.is_dir():
        return packaged
    return Path(__file__).resolve().parents[2] / "towns"


def available_towns() -> list[str]:
    """Names of the shipped towns."""
    return sorted(p.stem for p in towns_dir().glob("*.json"))


def load_town(name_or_path: str | os.PathLike[str]) -> Town:
    """Load a town by shipped name (`town01`) or by path to a town JSON file."""
    text = str(name_or_path)
    path = Path(text)
    if not (path.suffix == ".json" or os.sep in text or path.exists()):
        path = towns_dir() / f"{text.lower()}.json"
        if not path.exists():
            raise BrlInputError(
                f"unknown town '{text}'; choose one of {', '.join(available_towns())} or give a town file path"
            )
    if not path.is_file():
        raise BrlInputError(f"town file {path} does not exist")
    try:
        raw = json.loads(path.read_text(encoding="utf-8"))
    except (OSError, UnicodeDecodeError, json.JSONDecodeError) as exc:
        raise TownFormatError(f"town file {path} is not valid JSON: {exc}") from None
    return parse_town(raw, source=str(path))


def _get(d: Any, key: str, kind: type | tuple[type, ...], where: str, source: str) -> Any:
    if not isinstance(d, dict) or key not in d:
        raise TownFormatError(f"town file {source}: missing field '{where}{key}'")
    value = d[key]
    if kind is float:
        kind = (int, float)
    if not isinstance(value, kind) or isinstance(value, bool):
        raise TownFormatError(f"town file {source}: field '{where}{key}' has the wrong type")
    return value


def _array(value: Any, cols: int, where: str, source: str, dtype: type = np.float64) -> np.ndarray:
    try:
        arr = np.asarray(value, dtype=dtype)
    except (TypeError, ValueError):
        raise TownFormatError(f"town file {source}: field '{where}' must be a list of numbers") from None
    if arr.ndim != 2 or arr.shape[1] != cols or not np.all(np.isfinite(arr)):
        raise TownFormatError(f"town file {source}: field '{where}' must be rows of {cols} finite numbers")
    return arr


def _pose(value: Any, where: str, source: str) -> tuple[float, float, float]:
    arr = _array([value], 3, where, source)
    return (float(arr[0, 0]), float(arr[0, 1]), float(arr[0, 2]))


def _routes(raw: Any, where: str, source: str) -> tuple[RouteSpec, ...]:
    if not isinstance(raw, list) or not raw:
        raise TownFormatError(f"town file {source}: field '{where}' must be a non-empty list")
    out = []
    for i, r in enumerate(raw):
        w = f"{where}[{i}]."
        kind = _get(r, "kind", str, w, source)
        if kind not in ROUTE_KINDS:
            raise TownFormatError(f"town file {source}: field '{w}kind' must be one of {', '.join(ROUTE_KINDS)}")
        out.append(
            RouteSpec(
                name=_get(r, "name", str, w, source),
                kind=kind,
                start=_pose(_get(r, "start", list, w, source), w + "start", source),
                goal=_pose(_get(r, "goal", list, w, source), w + "goal", source),
            )
        )
    return tuple(out)


def parse_town(raw: Any, source: str = "<dict>") -> Town:
    """Validate a decoded town document and build a `Town` (errors name the offending field)."""
    fmt = _get(raw, "format", str, "", source)
    if fmt != TOWN_FORMAT:
        raise TownFormatError(f"town file {source}: field 'format' must be '{TOWN_FORMAT}'")
    ver = _get(raw, "format_version", int, "", source)
    if ver != TOWN_FORMAT_VERSION:
        raise TownFormatError(
            f"town file {source}: field 'format_version' is {ver}, this brl reads {TOWN_FORMAT_VERSION}"
        )
    geo_raw = _get(raw, "geometry", dict, "", source)
    geometry = TownGeometry(
        **{
            k: float(_get(geo_raw, k, float, "geometry.", source))
            for k in ("lane_width_m", "sidewalk_width_m", "junction_half_size_m", "corner_radius_m", "line_width_m")
        }
    )
    for k, v in vars(geometry).items():
        if v <= 0:
            raise TownFormatError(f"town file {source}: field 'geometry.{k}' must be positive")
    grid = float(_get(raw, "grid_unit_m", float, "", source))
    if grid <= 0:
        raise TownFormatError(f"town file {source}: field 'grid_unit_m' must be positive")
    nodes = _array(_get(raw, "nodes", list, "", source), 2, "nodes", source)
    edges = _array(_get(raw, "edges", list, "", source), 2, "edges", source, dtype=np.int64)
    if len(nodes) < 2 or len(edges) < 1:
        raise TownFormatError(f"town file {source}: field 'nodes'/'edges' must describe at least one road")
    if edges.min() < 0 or edges.max() >= len(nodes):
        raise TownFormatError(f"town file {source}: field 'edges' refers to a node that does not exist")
    d = nodes[edges[:, 0]] - nodes[edges[:, 1]]
    if np.any((d[:, 0] != 0) & (d[:, 1] != 0)) or np.any((d == 0).all(axis=1)):
        raise TownFormatError(f"town file {source}: field 'edges' must be non-empty axis-aligned grid segments")
    obj_raw = _get(raw, "objects", dict, "", source)
    cols = _get(obj_raw, "columns", list, "objects.", source)
    if tuple(cols) != OBJECT_COLUMNS:
        raise TownFormatError(f"town file {source}: field 'objects.columns' must be {list(OBJECT_COLUMNS)}")
    rows = _get(obj_raw, "rows", list, "objects.", source)
    objects = _array(rows, len(OBJECT_COLUMNS), "objects.rows", source) if rows else np.zeros((0, 9))
    if len(objects) and (objects[:, 0].min() < 0 or objects[:, 0].max() > 12 or np.any(objects[:, 4:7] <= 0)):
        raise TownFormatError(
            f"town file {source}: field 'objects.rows' needs class ids 0..12 and positive box sizes"
        )
    spawn = _array(_get(raw, "spawn_poses", list, "", source), 3, "spawn_poses", source)
    routes = _get(raw, "routes", dict, "", source)
    corl_raw = _get(routes, "corl2017", dict, "routes.", source)
    corl: dict[str, np.ndarray] = {}
    for task in CORL_TASK_POSES:
        pairs = _array(_get(corl_raw, task, list, "routes.corl2017.", source), 2, f"routes.corl2017.{task}",
                       source, dtype=np.int64)
        if pairs.min() < 0 or pairs.max() >= len(spawn):
            raise TownFormatError(
                f"town file {source}: field 'routes.corl2017.{task}' refers to a spawn pose that does not exist"
            )
        corl[task] = pairs
    return Town(
        name=_get(raw, "name", str, "", source),
        version=_get(raw, "version", str, "", source),
        description=str(raw.get("description", "")),
        grid_unit_m=grid,
        geometry=geometry,
        nodes_m=nodes * grid,
        edges=edges,
        objects=objects,
        spawn_poses=spawn,
        training_routes=_routes(_get(routes, "training", list, "routes.", source), "routes.training", source),
        lane_keeping_routes=_routes(
            _get(routes, "lane_keeping", list, "routes.", source), "routes.lane_keeping", source
        ),
        validation_routes=(_routes(routes["validation"], "routes.validation", source)
                           if "validation" in routes else ()),
        corl2017_poses=corl,
        path=source,
    )
