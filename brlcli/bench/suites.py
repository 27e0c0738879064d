"""Benchmark suites as lists of episode specifications: the paper's lane-keeping table, CoRL2017 and NoCrash."""

from __future__ import annotations

import hashlib
from dataclasses import replace

import numpy as np

from brlcli.episode import EpisodeSpec
from brlcli.errors import BrlInputError
from brlcli.sim.gym_env import route_timeout_s
from brlcli.sim.roadnet import RoadNetwork
from brlcli.sim.town import load_town
from brlcli.sim.traffic import CORL_TRAFFIC, NOCRASH_TRAFFIC
from brlcli.sim.weather import TEST_WEATHERS, TRAIN_WEATHERS, get_weather

SUITES = ("paper", "validation", "validation_starts", "corl2017", "nocrash", "nav_validation",
          "nav_validation_traffic")
SUITE_VERSION = {"paper": 1, "validation": 1, "validation_starts": 1, "corl2017": 3, "nocrash": 3,
                 "nav_validation": 2, "nav_validation_traffic": 1}
SUITE_CHANGES = {
    ("corl2017", 2): "route commands replanned when the car leaves its route",
    ("nocrash", 2): "route commands replanned when the car leaves its route",
    ("nav_validation", 2): "route commands replanned when the car leaves its route",
    ("corl2017", 3): "traffic with junction right of way, path-based braking and pedestrians that wait for cars",
    ("nocrash", 3): "traffic with junction right of way, path-based braking and pedestrians that wait for cars",
}
"""What changed in each suite version after the first: results of an older version are readable and labelled."""
NAV_VALIDATION_ROUTES = 8
"""Planner routes per town in the navigation validation suite (`brlcli.sim.navroutes.validation_routes`)."""
NAV_VALIDATION_CONDITIONS = {"training": ("town01", (1,)), "new_town_weather": ("town02", (14,))}
"""The navigation validation suite (issue 20; what navigation models are chosen on, never CoRL2017's poses): 8
planner routes in town01 in the training weather and 8 in town02 in a test weather, no traffic."""
#: Lane-keeping suites: suite -> the town route set it drives (same towns, weathers and metrics as the paper's).
LANE_KEEPING_SUITES = {"paper": "lane_keeping", "validation": "validation", "validation_starts": "validation"}
START_VARIANTS: tuple[tuple[float, float], ...] = ((0.0, 0.0), (5.0, 0.0), (0.0, -0.6), (0.0, 0.6), (5.0, -0.6),
                                                  (5.0, 0.6))
"""`validation_starts` (issue 34): each validation route from six start poses, (metres along the route, metres to
the side of the lane centre): the route's own start, 5 m further along it (for a curve, a 10-m approach instead of
15 m), and each of these 0.6 m to either side. None of them is a start pose of the paper suite (whose curves start
20 m before the same corners)."""
PAPER_TOWNS = ("town02", "town01")
PAPER_WEATHERS = (1, 4, 14)
CORL_TASKS = ("straight", "one_curve", "navigation", "navigation_dynamic")
CORL_CONDITIONS = {
    "training": ("town01", TRAIN_WEATHERS),
    "new_weather": ("town01", TEST_WEATHERS),
    "new_town": ("town02", TRAIN_WEATHERS),
    "new_town_weather": ("town02", TEST_WEATHERS),
}
NOCRASH_TASKS = ("empty", "regular", "dense")
NOCRASH_WEATHERS_TEST = (10, 14)
"""NoCrash's new weathers: WetSunset and SoftRainSunset (CoRL2017's are 4 and 14)."""
NOCRASH_CONDITIONS = {
    "training": ("town01", TRAIN_WEATHERS),
    "new_weather": ("town01", NOCRASH_WEATHERS_TEST),
    "new_town": ("town02", TRAIN_WEATHERS),
    "new_town_weather": ("town02", NOCRASH_WEATHERS_TEST),
}
GOAL_DISTANCE_M = 2.0


def nocrash_timeout_s(length_m: float) -> float:
    """NoCrash timeout: the route at 5 km/h plus 20 s."""
    return length_m / 1000.0 / 5.0 * 3600.0 + 20.0


def _parse_list(text: str | None, allowed: tuple[str, ...], what: str) -> tuple[str, ...] | None:
    if text is None:
        return None
    items = tuple(t.strip() for t in text.split(",") if t.strip())
    for t in items:
        if t not in allowed:
            raise BrlInputError(f"unknown {what} '{t}'; choose from {', '.join(allowed)}")
    return items


def paper_suite(weathers: tuple[int, ...] | None = None, towns: tuple[str, ...] | None = None,
                suite: str = "paper") -> list[EpisodeSpec]:
    """The paper's lane-keeping test routes (straight, right and left curve) in both towns and three weathers;
    `suite="validation"` drives the towns' validation routes instead (same towns, weathers and metrics), and
    `suite="validation_starts"` each of them from the START_VARIANTS poses."""
    specs = []
    starts = START_VARIANTS if suite == "validation_starts" else ((0.0, 0.0),)
    for town_name in towns or PAPER_TOWNS:
        town = load_town(town_name)
        net = RoadNetwork(town)
        condition = "training_town" if town_name == "town01" else "unseen_town"
        routes = town.route_set(LANE_KEEPING_SUITES[suite])
        for w in weathers or PAPER_WEATHERS:
            for i, r in enumerate(routes):
                for v, (along_m, side_m) in enumerate(starts):
                    start = _start_variant(net, r.start, r.goal, along_m, side_m)
                    length = net.route(start, r.goal).length_m
                    specs.append(EpisodeSpec(suite, condition, r.kind, town.name, int(w), i * len(starts) + v, start,
                                             r.goal, round(length, 3), route_timeout_s(length)))
    return specs


def _start_variant(net: RoadNetwork, start: tuple[float, float, float], goal: tuple[float, float, float],
                   along_m: float, side_m: float) -> tuple[float, float, float]:
    """A start pose `along_m` metres along the route from `start` to `goal` and `side_m` metres to its side."""
    if along_m == 0.0 and side_m == 0.0:
        return start
    x, y, yaw = net.route(start, goal).pose_at(along_m) if along_m else start
    rad = np.radians(yaw)
    return (round(x - side_m * np.sin(rad), 3), round(y + side_m * np.cos(rad), 3), round(yaw, 3))


def corl_suite(conditions: tuple[str, ...] | None = None, tasks: tuple[str, ...] | None = None,
               weathers: tuple[int, ...] | None = None) -> list[EpisodeSpec]:
    """CoRL2017: 4 tasks x 25 pose pairs x the weathers of each condition; traffic only in the dynamic task."""
    specs = []
    cache: dict[str, tuple] = {}
    for cond in conditions or tuple(CORL_CONDITIONS):
        town_name, cond_weathers = CORL_CONDITIONS[cond]
        if town_name not in cache:
            t = load_town(town_name)
            cache[town_name] = (t, RoadNetwork(t))
        town, net = cache[town_name]
        for task in tasks or CORL_TASKS:
            poses = town.corl2017_poses["navigation" if task == "navigation_dynamic" else task]
            traffic = CORL_TRAFFIC[town_name] if task == "navigation_dynamic" else (0, 0)
            for w in cond_weathers:
                if weathers is not None and w not in weathers:
                    continue
                for i, (a, b) in enumerate(poses):
                    start = tuple(float(v) for v in town.spawn_poses[a])
                    goal = tuple(float(v) for v in town.spawn_poses[b])
                    length = net.route(start, goal).length_m
                    specs.append(EpisodeSpec("corl2017", cond, task, town.name, int(w), i, start, goal,  # type: ignore[arg-type]
                                             round(length, 3), route_timeout_s(length), *traffic))
    return specs


def nocrash_suite(conditions: tuple[str, ...] | None = None, tasks: tuple[str, ...] | None = None,
                  weathers: tuple[int, ...] | None = None) -> list[EpisodeSpec]:
    """NoCrash: 3 traffic levels x CoRL2017's 25 navigation pose pairs x the weathers of each condition."""
    specs = []
    routes: dict[str, list[tuple[tuple, tuple, float]]] = {}  # town -> (start, goal, length) of its pose pairs
    for cond in conditions or tuple(NOCRASH_CONDITIONS):
        town_name, cond_weathers = NOCRASH_CONDITIONS[cond]
        if town_name not in routes:
            town = load_town(town_name)
            net = RoadNetwork(town)
            pairs = [(tuple(float(v) for v in town.spawn_poses[a]), tuple(float(v) for v in town.spawn_poses[b]))
                     for a, b in town.corl2017_poses["navigation"]]
            routes[town_name] = [(start, goal, net.route(start, goal).length_m) for start, goal in pairs]
        for task in tasks or NOCRASH_TASKS:
            vehicles, pedestrians = NOCRASH_TRAFFIC[town_name][task]
            for w in cond_weathers:
                if weathers is not None and w not in weathers:
                    continue
                for i, (start, goal, length) in enumerate(routes[town_name]):
                    specs.append(EpisodeSpec("nocrash", cond, task, town_name, int(w), i, start, goal,  # type: ignore[arg-type]
                                             round(length, 3), nocrash_timeout_s(length), vehicles, pedestrians,
                                             end_on_collision=True))
    return specs


def nav_validation_suite(conditions: tuple[str, ...] | None = None,
                         weathers: tuple[int, ...] | None = None) -> list[EpisodeSpec]:
    """Navigation validation: seeded multi-junction planner routes (not CoRL2017's poses), CoRL2017's timeout."""
    from brlcli.sim.navroutes import validation_routes

    specs = []
    for cond in conditions or tuple(NAV_VALIDATION_CONDITIONS):
        town_name, cond_weathers = NAV_VALIDATION_CONDITIONS[cond]
        town = load_town(town_name)
        net = RoadNetwork(town)
        for w in cond_weathers:
            if weathers is not None and w not in weathers:
                continue
            for i, r in enumerate(validation_routes(net, NAV_VALIDATION_ROUTES)):
                length = net.route(r.start, r.goal).length_m
                specs.append(EpisodeSpec("nav_validation", cond, "navigation", town.name, int(w), i, r.start,
                                         r.goal, round(length, 3), route_timeout_s(length)))
    return specs


def nav_validation_traffic_suite(conditions: tuple[str, ...] | None = None, tasks: tuple[str, ...] | None = None,
                                 weathers: tuple[int, ...] | None = None) -> list[EpisodeSpec]:
    """Navigation validation in traffic (issue 35; what traffic models are chosen on, never NoCrash's poses):
    nav_validation's planner routes x NoCrash's traffic levels (tasks empty, regular, dense), NoCrash's timeout, a
    collision ends the episode."""
    specs = []
    for base in nav_validation_suite(conditions, weathers):
        for task in tasks or NOCRASH_TASKS:
            vehicles, pedestrians = NOCRASH_TRAFFIC[base.town][task]
            specs.append(replace(base, suite="nav_validation_traffic", task=task,
                                 timeout_s=nocrash_timeout_s(base.route_length_m), vehicles=vehicles,
                                 pedestrians=pedestrians, end_on_collision=True))
    return specs


def build_suite(suite: str, conditions: str | None = None, tasks: str | None = None,
                weathers: str | None = None) -> list[EpisodeSpec]:
    """Episode list of a suite, filtered by comma-separated conditions, tasks and weathers (ids or names)."""
    if suite not in SUITES:
        raise BrlInputError(f"unknown suite '{suite}'; choose from {', '.join(SUITES)}")
    wl = None if weathers is None else tuple(get_weather(w.strip()).id for w in weathers.split(",") if w.strip())
    if suite in LANE_KEEPING_SUITES:
        if conditions is not None or tasks is not None:
            kinds = _parse_list(tasks, ("straight", "right_curve", "left_curve"), "task")
            conds = _parse_list(conditions, ("unseen_town", "training_town"), "condition")
            towns = None if conds is None else tuple("town01" if c == "training_town" else "town02" for c in conds)
            specs = paper_suite(wl, towns, suite)
            return [s for s in specs if kinds is None or s.task in kinds]
        return paper_suite(wl, suite=suite)
    if suite == "nav_validation":
        _parse_list(tasks, ("navigation",), "task")
        specs = nav_validation_suite(_parse_list(conditions, tuple(NAV_VALIDATION_CONDITIONS), "condition"), wl)
    elif suite == "nav_validation_traffic":
        specs = nav_validation_traffic_suite(_parse_list(conditions, tuple(NAV_VALIDATION_CONDITIONS), "condition"),
                                             _parse_list(tasks, NOCRASH_TASKS, "task"), wl)
    elif suite == "nocrash":
        conds = _parse_list(conditions, tuple(NOCRASH_CONDITIONS), "condition")
        specs = nocrash_suite(conds, _parse_list(tasks, NOCRASH_TASKS, "task"), wl)
    else:
        conds = _parse_list(conditions, tuple(CORL_CONDITIONS), "condition")
        specs = corl_suite(conds, _parse_list(tasks, CORL_TASKS, "task"), wl)
    if not specs:
        raise BrlInputError("the chosen conditions, tasks and weathers select no episode")
    return specs


def subset(specs: list[EpisodeSpec], episodes: str | None) -> list[EpisodeSpec]:
    """A deterministic subset: '--episodes 40' (count) or '--episodes 0.1' (fraction), spread over the list."""
    if episodes is None:
        return specs
    try:
        value = float(episodes)
    except ValueError:
        raise BrlInputError(f"--episodes '{episodes}' must be a count or a fraction like 0.1") from None
    n = int(value) if value >= 1 else int(np.ceil(value * len(specs)))
    if value <= 0 or (value >= 1 and value != int(value)):
        raise BrlInputError(f"--episodes '{episodes}' must be a positive count or a fraction in (0, 1)")
    n = min(n, len(specs))
    ranked = sorted(specs, key=lambda s: hashlib.sha256(s.id.encode()).hexdigest())
    keep = {s.id for s in ranked[:n]}
    return [s for s in specs if s.id in keep]


def parse_shard(text: str | None) -> tuple[int, int]:
    """'K/N' (1 <= K <= N) -> (K, N); None -> (1, 1)."""
    if text is None:
        return 1, 1
    try:
        k, n = (int(v) for v in text.split("/"))
    except ValueError:
        raise BrlInputError(f"--shard '{text}' must look like K/N, e.g. 2/8") from None
    if not 1 <= k <= n:
        raise BrlInputError(f"--shard '{text}' needs 1 <= K <= N")
    return k, n


def shard(specs: list[EpisodeSpec], k: int, n: int) -> list[EpisodeSpec]:
    """The K-th of N deterministic slices (by position in the suite list)."""
    return [s for i, s in enumerate(specs) if i % n == k - 1]
