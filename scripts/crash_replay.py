"""How a bench's crashes happened: replay every crashed episode of a `brl bench` output with its model and print the
road users nearest the car at the crash (issue 35).

    python scripts/crash_replay.py BENCH_DIR MODEL [--timeouts] [--json FILE]

Each episode the bench ended in a crash (NoCrash or nav_validation_traffic) is driven again by the bench's own
episode function (`brlcli.bench.runner.run_episode`, the bench's seed; the same episode, frame for frame); the
world's traffic is read where the episode ended. Printed per crash: the car's speed at the crash and 1 s before,
whether it is on a junction connector or a lane, its command there (a planner started afresh from the episode's
start, so after a replan it may differ from the bench's), its share in the opposite lane, and the three nearest road
users within 10 m in the car's frame (ahead / left, m; their velocity, m/s; their heading relative to the car's,
degrees). With `--timeouts` the episodes that ran out of time instead, the road users within 15 m at the end and how
long the car had stood.
"""

from __future__ import annotations

import argparse
import json
import math
from pathlib import Path
from typing import Any

import numpy as np

from brlcli.bench.runner import run_episode, world_for
from brlcli.bench.suites import build_suite
from brlcli.classes import CarlaClass
from brlcli.policy import BRLPolicy
from brlcli.provenance import atomic_write_json
from brlcli.sim.roadnet import Navigator


def _road_users(boxes: np.ndarray, vel: np.ndarray, x: float, y: float, yaw_deg: float, within_m: float = 10.0,
                n: int = 3) -> list[dict]:
    """The `n` nearest road users within `within_m`, in the car's frame."""
    yaw = math.radians(yaw_deg)
    fwd, left = np.array([math.cos(yaw), math.sin(yaw)]), np.array([-math.sin(yaw), math.cos(yaw)])
    dist = np.hypot(boxes[:, 1] - x, boxes[:, 2] - y)
    out = []
    for k in np.argsort(dist)[:n]:
        if dist[k] > within_m:
            break
        rel = boxes[k, 1:3] - (x, y)
        out.append({"kind": "vehicle" if int(boxes[k, 0]) == CarlaClass.VEHICLES else "pedestrian",
                    "ahead_m": round(float(rel @ fwd), 1), "left_m": round(float(rel @ left), 1),
                    "v_ahead_ms": round(float(vel[k] @ fwd), 1), "v_left_ms": round(float(vel[k] @ left), 1),
                    "heading_deg": round(float((math.degrees(boxes[k, 7]) - yaw_deg + 180.0) % 360.0 - 180.0))})
    return out


def main() -> None:
    """Replay the crashed episodes and print what was near."""
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("bench", type=Path)
    ap.add_argument("model")
    ap.add_argument("--timeouts", action="store_true", help="replay the episodes that timed out instead")
    ap.add_argument("--json", type=Path, default=None)
    args = ap.parse_args()
    config = json.loads((args.bench / "bench.json").read_text())["config"]
    rows = [json.loads(line) for line in (args.bench / "results.jsonl").read_text().splitlines() if line.strip()]
    specs = {s.id: s for s in build_suite(config["suite"])}
    policy = BRLPolicy("replay", args.model)
    cache: dict[tuple, Any] = {}
    out = []
    for row in rows:
        timed_out = not row["success"] and not row.get("crashed")
        if not (timed_out if args.timeouts else row.get("crashed")):
            continue
        spec = specs[row["id"]]
        world = world_for(cache, spec, policy)
        result, log = run_episode(world, spec, policy, int(config["seed"]))  # the traffic stays at the last frame
        if (result["success"], bool(result.get("crashed"))) != (row["success"], bool(row.get("crashed"))):
            print(f"{row['id']}: the replay ended otherwise than the bench's record; skipped")
            continue
        n = len(log["x"]) - 1
        x, y, yaw = float(log["x"][n]), float(log["y"][n]), float(log["yaw_deg"][n])
        path, _, _ = world.network.locate(x, y)
        boxes, vel = world.traffic.boxes(), world.traffic.velocities()
        command = int(Navigator(world.network, spec.start, spec.goal).command(x, y, yaw))
        rec = {"id": row["id"], "speed_kmh": round(float(log["forward_speed_kmh"][n]), 1),
               "speed_1s_before_kmh": round(float(log["forward_speed_kmh"][max(n - 10, 0)]), 1),
               "on": "lane" if path in set(world.network.lane_ids) else "junction",
               "command_at_crash": command, "otherlane": round(float(log["intersection_otherlane"][n]), 2),
               "reversing_1s_before": bool(log["forward_speed_kmh"][max(n - 10, 0)] < -0.5),
               "road_users": _road_users(boxes, vel, x, y, yaw, *((15.0, 5) if args.timeouts else (10.0, 3)))}
        if args.timeouts:
            moving = np.flatnonzero(np.abs(log["forward_speed_kmh"]) >= 1.0)
            rec["standing_s"] = round((n - (int(moving[-1]) if len(moving) else 0)) * 0.1, 1)
        out.append(rec)
        print(json.dumps(rec))
    if args.json:
        atomic_write_json(args.json, {"bench": str(args.bench), "model": args.model, "crashes": out})


if __name__ == "__main__":
    main()
