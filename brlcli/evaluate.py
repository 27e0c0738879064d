"""Greedy evaluation of a policy on a town's lane-keeping routes (the paper's test table metrics per episode)."""

from __future__ import annotations

from collections.abc import Callable
from typing import Any

import numpy as np

from brlcli.bench.metrics import FOOTPRINT_THRESHOLD as EITHER_THRESHOLD
from brlcli.sim.camera import CameraConfig
from brlcli.sim.gym_env import DrivingEnv


def run_episode(env: DrivingEnv, policy: Callable[[np.ndarray], int], route: str, seed: int) -> dict[str, Any]:
    """Drive one route greedily; per-episode success, collision and per-step off-road / other-lane shares."""
    obs, info = env.reset(seed=seed, options={"route": route})
    offroad, otherlane, collided, dist = [], [], False, 0.0
    last = None
    while True:
        obs, _r, terminated, truncated, info = env.step(policy(obs))
        m = info["measurements"]
        offroad.append(m["intersection_offroad"])
        otherlane.append(m["intersection_otherlane"])
        collided |= info["collided"]
        if last is not None:
            dist += float(np.hypot(m["x"] - last[0], m["y"] - last[1]))
        last = (m["x"], m["y"])
        if terminated or truncated:
            break
    off = np.asarray(offroad) > EITHER_THRESHOLD
    other = np.asarray(otherlane) > EITHER_THRESHOLD
    return {"route": route, "success": bool(terminated), "collision_free": not collided, "steps": len(offroad),
            "offroad_share": float(off.mean()), "otherlane_share": float(other.mean()),
            "either_share": float((off | other).mean()), "distance_m": dist,
            "offroad": offroad, "otherlane": otherlane}


def evaluate_lane_keeping(agent: Any, town: str = "town01", weather: int | str = 1, seed: int = 0,
                          labeler: Callable[[np.ndarray], np.ndarray] | None = None,
                          camera: CameraConfig | None = None, routes: str = "lane_keeping") -> dict[str, Any]:
    """Greedy policy of `agent` (anything with `act(state, rng, greedy=True)`) on every lane-keeping route.

    With a `labeler` (the segmentation net) the agent sees estimated labels, as in deployment on estimated input;
    `camera` is the state camera the agent was trained with (default: CoRL2017's); `routes` the town's route set
    (`lane_keeping`: the paper's test routes; `validation`: the routes choices are made on).
    """
    env = DrivingEnv(town=town, weather=weather, routes=routes, labeler=labeler, camera=camera)
    rng = np.random.default_rng(seed)

    def policy(obs: np.ndarray) -> int:
        return int(agent.act(obs.astype(np.float64), rng, greedy=True))

    from brlcli.bench.metrics import LaneKeepingEpisode, paper_table_row

    episodes = [run_episode(env, policy, r.name, seed) for r in env.routes]
    env.close()
    row = paper_table_row([LaneKeepingEpisode(np.asarray(e["offroad"]), np.asarray(e["otherlane"]), e["success"],
                                              not e["collision_free"], e["distance_m"]) for e in episodes])
    for e in episodes:  # per-step series are summarised above; keep the JSON small
        del e["offroad"], e["otherlane"]
    return {"town": town, "weather": weather, "routes": routes, "episodes": episodes,
            "success_rate": row["success"], "collision_free_rate": row["no_collision"],
            "either_share": row["either"], "score": row["score"], "distance_m": row["dist"]}
