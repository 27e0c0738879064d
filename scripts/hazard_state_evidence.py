"""Issue 35's evidence: can the paper's 30-number state tell a near hazard from a far one, and what is the smallest
addition that can?

    python scripts/hazard_state_evidence.py [--episodes 40] [--workers 2] [--gap 2s|now] [--out FILE.json]

The privileged autopilot drives town01 in NoCrash Regular and Dense traffic (alternating), from seeded spawn-pose
pairs (routes >= 200 m), for up to 90 s; at every decision (7 frames) it records the ground-truth 30-number state,
the expert's hazard gap (free distance to the nearest road user on its route corridor, predicted 0-2 s ahead:
`Autopilot._obstacle_gap`) and candidate additions from the depth image the camera renders: the nearness
clip(1 - d / 30 m, 0, 1) of the closest vehicle or pedestrian pixel in the image's middle column (1 number) or in
each of its three columns (3 numbers). A class-balanced logistic regression (L2, scipy) fitted on the even episodes
predicts "a hazard within 8 m" (the expert stops below 7 m; `--gap now`: with road users where they are now, the
hazard reward's default) on the odd ones; the script prints its ROC AUC and balanced accuracy for each feature set.
"""

from __future__ import annotations

import argparse
import math
import os
from concurrent.futures import ProcessPoolExecutor
from pathlib import Path
from typing import Any

os.environ.setdefault("OMP_NUM_THREADS", "1")

import numpy as np
from scipy.optimize import minimize
from scipy.stats import rankdata

from brlcli.autopilot import Autopilot
from brlcli.bench.suites import NOCRASH_TRAFFIC
from brlcli.features import DYNAMIC_CATEGORY, N_CATEGORIES, N_REGIONS, depth_nearness, state_vector
from brlcli.provenance import atomic_write_json
from brlcli.sim import World
from brlcli.sim.gym_env import FRAMES_PER_DECISION
from brlcli.sim.hazard import hazard_gap_m

NEAR_M = 8.0


def expert_episode(seed: int) -> tuple[World, Any, Any, Autopilot]:
    """The seeded evidence episode: town01 in Regular (even seeds) or Dense (odd) traffic, a route of >= 200 m between
    two spawn poses, the world reset at its start and the privileged autopilot on it: (world, route, frame, pilot)."""
    task = ("regular", "dense")[seed % 2]
    n_v, n_p = NOCRASH_TRAFFIC["town01"][task]
    world = World("town01", vehicles=n_v, pedestrians=n_p, seed=seed)
    rng = np.random.default_rng(seed)
    poses = world.town.spawn_poses
    while True:
        a, b = rng.choice(len(poses), 2, replace=False)
        route = world.network.route(tuple(poses[a]), tuple(poses[b]))
        if route.cum_s[-1] >= 200.0:
            break
    frame = world.reset(tuple(poses[a]), seed=seed)
    return world, route, frame, Autopilot(world, route, np.random.default_rng(seed), noise=None)


def _episode(seed: int) -> dict[str, list]:
    world, route, frame, pilot = expert_episode(seed)
    rows: dict[str, list] = {"state": [], "gap": [], "gap_now": [], "depth": [], "speed": []}
    for i in range(900):
        m = frame.measurements
        control = pilot.expert(m)
        if i % FRAMES_PER_DECISION == 0:
            _, labels, depth = world.render(rgb=False)
            rows["state"].append(state_vector(labels).tolist())
            rows["depth"].append(depth_nearness(labels, depth).tolist())
            gap = pilot._obstacle_gap(m)
            rows["gap"].append(gap if math.isfinite(gap) else 1e3)
            gap = hazard_gap_m(world.traffic, route, m.x, m.y, m.yaw_deg, predict_s=(0.0,))
            rows["gap_now"].append(gap if math.isfinite(gap) else 1e3)
            rows["speed"].append(m.forward_speed_kmh)
        frame = world.step(control, render=False)
        if math.hypot(frame.measurements.x - route.points[-1][0], frame.measurements.y - route.points[-1][1]) < 2.0:
            break
    world.close()
    return rows


def _road_users(state: np.ndarray) -> np.ndarray:
    """The six road-user (dynamic-object) shares of 30-number states."""
    return state.reshape(-1, N_REGIONS, N_CATEGORIES)[:, :, DYNAMIC_CATEGORY]


def _fit_logistic(x: np.ndarray, y: np.ndarray, l2: float = 1e-3) -> np.ndarray:
    mu, sd = x.mean(0), x.std(0) + 1e-9
    z = np.column_stack([(x - mu) / sd, np.ones(len(x))])
    weight = np.where(y > 0, 0.5 / max(y.mean(), 1e-9), 0.5 / max(1 - y.mean(), 1e-9))  # balanced classes

    def loss(w: np.ndarray) -> tuple[float, np.ndarray]:
        p = 1.0 / (1.0 + np.exp(-np.clip(z @ w, -30, 30)))
        eps = 1e-12
        f = -np.mean(weight * (y * np.log(p + eps) + (1 - y) * np.log(1 - p + eps))) + l2 * (w[:-1] @ w[:-1])
        g = z.T @ (weight * (p - y)) / len(y) + np.append(2 * l2 * w[:-1], 0.0)
        return f, g

    w = minimize(loss, np.zeros(z.shape[1]), jac=True, method="L-BFGS-B").x
    return np.concatenate([w, mu, sd])


def _predict(params: np.ndarray, x: np.ndarray) -> np.ndarray:
    d = x.shape[1]
    w, mu, sd = params[: d + 1], params[d + 1: 2 * d + 1], params[2 * d + 1:]
    return np.column_stack([(x - mu) / sd, np.ones(len(x))]) @ w


def _auc(score: np.ndarray, y: np.ndarray) -> float:
    r = rankdata(score)
    n1, n0 = y.sum(), (1 - y).sum()
    return float((r[y == 1].sum() - n1 * (n1 + 1) / 2) / (n1 * n0))


def _balanced_accuracy(score: np.ndarray, y: np.ndarray) -> float:
    pred = score > 0
    return float(0.5 * (pred[y == 1].mean() + (~pred[y == 0]).mean()))


def main() -> None:
    """Record the episodes, fit and print the table."""
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--episodes", type=int, default=40)
    ap.add_argument("--workers", type=int, default=2)
    ap.add_argument("--gap", choices=("2s", "now"), default="2s",
                    help="the label's road users: predicted 0-2 s ahead (the expert's) or where they are now")
    ap.add_argument("--out", default=None, help="JSON file of the figures")
    args = ap.parse_args()
    with ProcessPoolExecutor(args.workers) as pool:
        episodes = list(pool.map(_episode, range(args.episodes)))
    split = {"fit": [e for i, e in enumerate(episodes) if i % 2 == 0],
             "test": [e for i, e in enumerate(episodes) if i % 2 == 1]}
    data = {}
    for part, eps in split.items():
        state = np.concatenate([np.array(e["state"]) for e in eps])
        depth = np.concatenate([np.array(e["depth"]) for e in eps])
        gap = np.concatenate([np.array(e["gap" if args.gap == "2s" else "gap_now"]) for e in eps])
        data[part] = (state, depth, (gap < NEAR_M).astype(float))
    sets = {
        "30-number state": lambda s, d: s,
        "30-number state + middle-column nearness (31)": lambda s, d: np.column_stack([s, d[:, 1]]),
        "30-number state + three column nearnesses (33)": lambda s, d: np.column_stack([s, d]),
        "middle-column nearness alone (1)": lambda s, d: d[:, 1:2],
        "the six road-user shares (6, the gate's view)": lambda s, d: _road_users(s),
    }
    out = {"gap": args.gap, "decisions_fit": len(data["fit"][2]), "decisions_test": len(data["test"][2]),
           "near_share_test": float(data["test"][2].mean()), "sets": {}}
    print(f"{out['decisions_fit']} decisions to fit, {out['decisions_test']} to test; "
          f"{out['near_share_test']:.1%} of the test decisions have a hazard within {NEAR_M:g} m")
    for name, make in sets.items():
        xf, xt = make(*data["fit"][:2]), make(*data["test"][:2])
        params = _fit_logistic(xf, data["fit"][2])
        score = _predict(params, xt)
        auc, bacc = _auc(score, data["test"][2]), _balanced_accuracy(score, data["test"][2])
        out["sets"][name] = {"auc": auc, "balanced_accuracy": bacc}
        print(f"{name:50s} AUC {auc:.3f}  balanced accuracy {bacc:.3f}")
    if args.out:
        atomic_write_json(Path(args.out), out)


if __name__ == "__main__":
    main()
