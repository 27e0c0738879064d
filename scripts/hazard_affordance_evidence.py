"""Issue 35's evidence, continued: does a small net on the camera's label and depth images (a learned hazard
affordance, as in conditional affordance learning) tell a hazard on the car's route from road users beside it better
than the views tried so far (section 12.9, 12.10 of docs/navigation-study.md)?

    python scripts/hazard_affordance_evidence.py [--episodes 80] [--workers 2] [--data FILE.npz] [--out FILE.json]

The privileged autopilot drives town01 in NoCrash Regular and Dense traffic, as in `hazard_state_evidence.py` (the
same seeded episodes). At every decision (7 frames) it records a 4 x 22 x 50 image (the label and depth images
pooled 4 x 4: the nearness clip(1 - d / 30 m, 0, 1) of road-user pixels, max-pooled; the road and road-line shares;
the road-user nearness of the previous decision), the route command, the 30-number state and two labels: the
privileged hazard gap along the route with road users where they are now and predicted 0-2 s ahead (the expert's).
A class-balanced logistic regression on the 30 numbers (the reference, as in section 12.9) and a two-layer CNN with
the command (torch, seeded) are fitted on the even episodes and scored on the odd ones: ROC AUC and balanced accuracy
for "a hazard within 8 m", over all decisions and over those under a junction command. Outside the paper.
"""

from __future__ import annotations

import argparse
import math
import os
from concurrent.futures import ProcessPoolExecutor
from pathlib import Path

os.environ.setdefault("OMP_NUM_THREADS", "1")

import numpy as np
from hazard_state_evidence import _auc, _balanced_accuracy, _fit_logistic, _predict, expert_episode

from brlcli.classes import CarlaClass
from brlcli.features import NEARNESS_RANGE_M, state_vector
from brlcli.npzio import save_npz
from brlcli.provenance import atomic_write_json
from brlcli.sim.gym_env import FRAMES_PER_DECISION
from brlcli.sim.hazard import PREDICT_S, hazard_gap_and_user, hazard_gap_m

NEAR_M = 8.0
POOL = 4
FOLLOW = 2  # the route command "follow lane" (Command.LANE_FOLLOW)


def _image(labels: np.ndarray, depth: np.ndarray) -> np.ndarray:
    """(3, H/4, W/4): max-pooled road-user nearness, road share, road-line share."""
    h, w = (labels.shape[0] // POOL) * POOL, (labels.shape[1] // POOL) * POOL
    lab, dep = labels[:h, :w], np.asarray(depth[:h, :w], np.float64)
    users = (lab == CarlaClass.VEHICLES) | (lab == CarlaClass.PEDESTRIANS)
    near = np.where(users, np.clip(1.0 - dep / NEARNESS_RANGE_M, 0.0, 1.0), 0.0)
    blocks = (h // POOL, POOL, w // POOL, POOL)
    return np.stack([near.reshape(blocks).max((1, 3)),
                     (lab == CarlaClass.ROADS).reshape(blocks).mean((1, 3)),
                     (lab == CarlaClass.ROAD_LINES).reshape(blocks).mean((1, 3))]).astype(np.float32)


def _hazard_bearing_deg(traffic: object, route: object, x_m: float, y_m: float, yaw_deg: float,
                        predict_s: tuple[float, ...]) -> float:
    """The bearing (degrees from the car's heading, left positive) of the road user, where it is now, that sets the
    hazard gap (`hazard_gap_and_user`); nan when the route is clear."""
    _, who = hazard_gap_and_user(traffic, route, x_m, y_m, yaw_deg, predict_s)  # type: ignore[arg-type]
    if who < 0:
        return math.nan
    box = traffic.boxes()[who]  # type: ignore[attr-defined]
    return float(np.degrees(np.arctan2(box[2] - y_m, box[1] - x_m) - math.radians(yaw_deg) + np.pi) % 360.0 - 180.0)


def _episode(seed: int) -> dict[str, np.ndarray]:
    world, route, frame, pilot = expert_episode(seed)  # the same episodes as hazard_state_evidence.py
    rows: dict[str, list] = {"image": [], "command": [], "state": [], "gap": [], "gap_now": [], "bearing_deg": [],
                           "bearing_now_deg": []}
    previous = None
    for i in range(900):
        m = frame.measurements
        control = pilot.expert(m)
        if i % FRAMES_PER_DECISION == 0:
            _, labels, depth = world.render(rgb=False)
            img = _image(labels, depth)
            rows["image"].append(np.concatenate([img, (img[:1] if previous is None else previous)]))
            previous = img[:1]
            s, _ = route.project(m.x, m.y)
            rows["command"].append(int(route.command_at(s)))
            rows["state"].append(state_vector(labels))
            gap = pilot._obstacle_gap(m)
            rows["gap"].append(gap if math.isfinite(gap) else 1e3)
            gap = hazard_gap_m(world.traffic, route, m.x, m.y, m.yaw_deg, predict_s=(0.0,))
            rows["gap_now"].append(gap if math.isfinite(gap) else 1e3)
            rows["bearing_deg"].append(_hazard_bearing_deg(world.traffic, route, m.x, m.y, m.yaw_deg, PREDICT_S))
            rows["bearing_now_deg"].append(_hazard_bearing_deg(world.traffic, route, m.x, m.y, m.yaw_deg, (0.0,)))
        frame = world.step(control, render=False)
        if math.hypot(frame.measurements.x - route.points[-1][0], frame.measurements.y - route.points[-1][1]) < 2.0:
            break
    world.close()
    out = {k: np.asarray(v) for k, v in rows.items()}
    out["episode"] = np.full(len(rows["gap"]), seed)
    return out


def _record(episodes: int, workers: int) -> dict[str, np.ndarray]:
    with ProcessPoolExecutor(workers) as pool:
        parts = list(pool.map(_episode, range(episodes)))
    return {k: np.concatenate([p[k] for p in parts]) for k in parts[0]}


def _cnn_scores(data: dict[str, np.ndarray], y: np.ndarray, fit: np.ndarray, epochs: int = 25) -> np.ndarray:
    """Held-out logits of a small CNN (image + command one-hot) fitted on the `fit` rows with balanced BCE."""
    import torch

    torch.manual_seed(0)
    torch.set_num_threads(1)
    x = torch.from_numpy(data["image"].astype(np.float32))
    cmd = torch.nn.functional.one_hot(torch.from_numpy(data["command"] - FOLLOW).clamp(0, 3), 4).float()
    target = torch.from_numpy(y.astype(np.float32))

    class Net(torch.nn.Module):
        def __init__(self) -> None:
            super().__init__()
            self.conv = torch.nn.Sequential(
                torch.nn.Conv2d(4, 16, 3, padding=1), torch.nn.ReLU(), torch.nn.MaxPool2d(2),
                torch.nn.Conv2d(16, 32, 3, padding=1), torch.nn.ReLU(), torch.nn.MaxPool2d(2),
                torch.nn.Flatten())
            n = self.conv(torch.zeros(1, *x.shape[1:])).shape[1]
            self.head = torch.nn.Sequential(torch.nn.Linear(n + 4, 64), torch.nn.ReLU(), torch.nn.Linear(64, 1))

        def forward(self, img: torch.Tensor, c: torch.Tensor) -> torch.Tensor:
            return self.head(torch.cat([self.conv(img), c], 1)).squeeze(1)

    net = Net()
    opt = torch.optim.Adam(net.parameters(), lr=1e-3, weight_decay=1e-4)
    idx = np.flatnonzero(fit)
    pos = float(y[fit].mean())
    loss_fn = torch.nn.BCEWithLogitsLoss(pos_weight=torch.tensor((1 - pos) / max(pos, 1e-9)))
    gen = np.random.default_rng(0)
    for _ in range(epochs):
        gen.shuffle(idx)
        for b in range(0, len(idx), 64):
            j = torch.from_numpy(idx[b:b + 64])
            opt.zero_grad()
            loss_fn(net(x[j], cmd[j]), target[j]).backward()
            opt.step()
    with torch.no_grad():
        test = torch.from_numpy(np.flatnonzero(~fit))
        return net(x[test], cmd[test]).numpy()


def main() -> None:
    """Record (or read) the decisions, fit both models per label and print the table."""
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--episodes", type=int, default=80)
    ap.add_argument("--workers", type=int, default=2)
    ap.add_argument("--data", default=None, help="npz of the recorded decisions: read if it exists, else written")
    ap.add_argument("--out", default=None, help="JSON file of the figures")
    args = ap.parse_args()
    if args.data and Path(args.data).exists():
        with np.load(args.data, allow_pickle=False) as npz:
            data = {k: npz[k] for k in npz.files}
    else:
        data = _record(args.episodes, args.workers)
        if args.data:
            save_npz(args.data, data, compress=True)
    fit = data["episode"] % 2 == 0
    junction = np.isin(data["command"][~fit], (3, 4, 5))  # turn left, turn right, go straight
    out: dict = {"decisions_fit": int(fit.sum()), "decisions_test": int((~fit).sum()),
                 "junction_test": int(junction.sum()), "labels": {}}
    print(f"{out['decisions_fit']} decisions to fit, {out['decisions_test']} to test ({out['junction_test']} under a "
          "junction command)")
    for label in ("gap_now", "gap"):
        y = (data[label] < NEAR_M).astype(float)
        yt = y[~fit]
        logistic = _predict(_fit_logistic(data["state"][fit], y[fit]), data["state"][~fit])
        scores = {"30-number state, logistic": logistic,
                  "label and depth image + command, CNN": _cnn_scores(data, y, fit)}
        rows = {}
        for name, score in scores.items():
            rows[name] = {"auc": _auc(score, yt), "balanced_accuracy": _balanced_accuracy(score, yt),
                          "auc_junction": _auc(score[junction], yt[junction]),
                          "balanced_accuracy_junction": _balanced_accuracy(score[junction], yt[junction])}
            r = rows[name]
            print(f"{label:8s} {name:40s} AUC {r['auc']:.3f} bal. acc. {r['balanced_accuracy']:.3f} | junction "
                  f"commands AUC {r['auc_junction']:.3f} bal. acc. {r['balanced_accuracy_junction']:.3f}")
        out["labels"][label] = {"near_share_test": float(yt.mean()), "near_share_junction": float(yt[junction].mean()),
                                "models": rows}
    if args.out:
        atomic_write_json(Path(args.out), out)


if __name__ == "__main__":
    main()
