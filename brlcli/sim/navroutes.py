"""Navigation routes from the route planner (issue 20; outside the paper): junction routes to train a
command-conditioned agent on, and longer multi-junction routes to choose on. Neither uses CoRL2017's poses.

Junction routes: for every connector of a town's lane graph (every left, right and straight turn at every junction),
a route that starts `approach_m` before the junction on the incoming lane and ends `JUNCTION_EXIT_M` into the
outgoing lane, for each approach in `JUNCTION_APPROACHES_M` (a lane shorter than the approach starts at its first
metre). Validation routes: shortest routes between lane points drawn with a fixed seed, 150-500 m long and through
at least two junctions.
"""

from __future__ import annotations

import numpy as np

from brlcli.sim.roadnet import Command, RoadNetwork, command_branch
from brlcli.sim.town import RouteSpec

TASKS = ("lane-keeping", "navigation")
"""What an agent is trained for: `lane-keeping`, the paper's task (lane-keeping routes); `navigation` (issue 20,
outside the paper): the planner's junction routes, the route command as an input, and the paper's reward plus
route following (`brlcli.reward.RouteRewardParams`)."""
JUNCTION_KINDS = ("turn_left", "turn_right", "go_straight")
"""Kinds of junction routes: the turn they take."""
TASK_ROUTE_KINDS = {"lane-keeping": ("straight", "right_curve", "left_curve"),
                    "navigation": ("straight", "right_curve", "left_curve", *JUNCTION_KINDS)}
"""The kinds of training routes of each task: navigation drives the town's lane-keeping training routes (command
follow lane throughout) and the junction routes, a kind drawn per episode with `KIND_WEIGHTS`."""
KIND_WEIGHTS = {"turn_left": 2.0, "turn_right": 2.0, "go_straight": 2.0}
"""Relative probability of a kind when a navigation episode draws its route (others: 1): junction routes are two
thirds of the episodes, so each turn's branch sees about as many decisions as lane following."""
JUNCTION_APPROACHES_M = (25.0, 60.0)
"""Distances before the junction at which the junction routes start (m)."""
JUNCTION_EXIT_M = 30.0
"""Distance into the outgoing lane at which a junction route ends (m)."""
VALIDATION_SEED = 2020
VALIDATION_LENGTH_M = (150.0, 500.0)


def _kind(command: Command) -> str:
    return JUNCTION_KINDS[int(command_branch(int(command))) - 1]


def junction_routes(network: RoadNetwork, approaches_m: tuple[float, ...] = JUNCTION_APPROACHES_M) -> list[RouteSpec]:
    """One route per (connector, approach): through exactly one junction turn, named nav_<connector>_<approach>."""
    routes = []
    for lane_in in network.lanes:
        for c in network.successors[lane_in.index]:
            conn = network.paths[c]
            lane_out = network.paths[network.successors[c][0]]
            for approach in approaches_m:
                s0 = max(lane_in.length_m - approach, 1.0)
                goal = lane_out.pose_at(min(JUNCTION_EXIT_M, lane_out.length_m - 1.0))
                routes.append(RouteSpec(f"nav_{c:03d}_{int(approach)}", _kind(conn.command), lane_in.pose_at(s0),
                                        goal))
    return sorted(routes, key=lambda r: r.name)


def validation_routes(network: RoadNetwork, count: int = 24, seed: int = VALIDATION_SEED) -> list[RouteSpec]:
    """`count` multi-junction routes between seeded random lane points (kind: 'navigation')."""
    rng = np.random.default_rng(seed)
    lanes = network.lanes
    routes: list[RouteSpec] = []
    while len(routes) < count:
        a, b = (lanes[int(i)] for i in rng.integers(len(lanes), size=2))
        start = a.pose_at(float(rng.uniform(5.0, a.length_m - 5.0)))
        goal = b.pose_at(float(rng.uniform(5.0, b.length_m - 5.0)))
        route = network.route(start, goal)
        turns = sum(1 for _s0, _s1, cmd in route.commands)
        if VALIDATION_LENGTH_M[0] <= route.length_m <= VALIDATION_LENGTH_M[1] and turns >= 2:
            routes.append(RouteSpec(f"navval_{len(routes):02d}", "navigation", start, goal))
    return routes
