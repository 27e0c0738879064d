"""Whether a bench's vehicle crashes and deadlocks start with a traffic vehicle that took its junction turn while the
ego car was approaching that junction (issue 35; navigation-study 12.25).

    python scripts/junction_grant_replay.py BENCH_DIR MODEL [--traffic regular] [--limit 40] [--timeouts] [--json F]

Each crashed episode of a `brl bench` results directory (plain or archived by `scripts/archive_bench.py`) is driven
again by the bench's own episode function with the model (the bench's seed: the same episode, frame for frame), with
a probe on the traffic's junction rule (`Traffic._junction_stop_gap`) that notes every turn granted: the vehicle, the
junction, the time, and the ego car's distance to that junction's centre and whether it was closing in. At the end the
vehicle nearest the ego car (the one it hit, or for `--timeouts` the one it stands beside) is reported with its last
grant: a grant while the ego car was within `APPROACH_M` of the same junction and closing in is one that a rule
reserving the approaching ego car's movement would have withheld. Prints one JSON line per episode and a summary.
Outside the paper; a probe, not part of brl.
"""

from __future__ import annotations

import argparse
import json
import math
import sys
from pathlib import Path
from typing import Any

import numpy as np

from brlcli.bench.runner import run_episode, world_for
from brlcli.bench.suites import build_suite
from brlcli.errors import BrlInputError
from brlcli.policy import BRLPolicy
from brlcli.provenance import atomic_write_json
from brlcli.report.load import load_results
from brlcli.sim.traffic import JUNCTION_APPROACH_M

APPROACH_M = JUNCTION_APPROACH_M + 10.0
"""The ego car counts as approaching a junction within this distance of its centre (the vehicles ask for their turn
15 m before their lane's end, which lies up to about 10 m from the centre)."""


class GrantProbe:
    """Wraps a Traffic's junction rule and records each turn it grants with the ego car's distance to the junction."""

    def __init__(self, traffic: Any) -> None:
        self.traffic = traffic
        self.original = traffic._junction_stop_gap
        self.frame = 0
        self.last_grant: dict[int, dict[str, float]] = {}
        self.ego_dist_before = np.full(len(traffic._node_xy), np.inf)  # per junction, at the previous frame
        traffic._junction_stop_gap = self._wrapped

    def _wrapped(self, dt_s: float, ego_x: float, ego_y: float) -> np.ndarray:
        t = self.traffic
        before = t.v_go.copy()
        out = self.original(dt_s, ego_x, ego_y)
        self.frame += 1
        nodes = t._node_xy
        dist = np.hypot(nodes[:, 0] - ego_x, nodes[:, 1] - ego_y)
        for i in np.flatnonzero(t.v_go & ~before):
            node = int(t._path_to[int(t.v_path[i])])
            self.last_grant[int(i)] = {"frame": self.frame, "node": node, "ego_dist_m": float(dist[node]),
                                       "ego_closing": bool(dist[node] < self.ego_dist_before[node] - 0.05),
                                       "ego_speed_ms": float(t._ego_speed)}
        self.ego_dist_before = dist
        return out

    def restore(self) -> None:
        """Put the traffic's own junction rule back."""
        self.traffic._junction_stop_gap = self.original


def main() -> None:
    """Replay the crashed (or timed-out) episodes with the probe and print what the hit vehicle's last grant was."""
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("bench", type=Path)
    ap.add_argument("model")
    ap.add_argument("--traffic", default=None, help="only this traffic level (NoCrash task), e.g. regular")
    ap.add_argument("--limit", type=int, default=40)
    ap.add_argument("--timeouts", action="store_true")
    ap.add_argument("--json", type=Path, default=None)
    args = ap.parse_args()
    try:
        results = load_results([args.bench])
        policy = BRLPolicy("replay", args.model)
    except BrlInputError as exc:
        print(f"junction_grant_replay: {exc}", file=sys.stderr)
        raise SystemExit(2) from None
    bench_seed = int(json.loads((args.bench / "bench.json").read_text())["config"]["seed"])

    def wanted(r: dict[str, Any]) -> bool:
        """A vehicle crash (or with --timeouts a timeout) of the chosen traffic level."""
        if args.traffic is not None and r["task"] != args.traffic:
            return False
        if args.timeouts:
            return not r["success"] and not r.get("crashed")
        return bool(r.get("crashed")) and r["infractions"].get("collision_vehicles", 0) > 0

    rows = [r for r in results.episodes if wanted(r)][:args.limit]
    specs = {s.id: s for s in build_suite(rows[0]["suite"])} if rows else {}
    cache: dict[tuple, Any] = {}
    out = []
    for row in rows:
        spec = specs[row["id"]]
        world = world_for(cache, spec, policy)
        probe = GrantProbe(world.traffic)
        try:
            result, log = run_episode(world, spec, policy, bench_seed)
        finally:
            probe.restore()
        if (result["success"], bool(result.get("crashed"))) != (row["success"], bool(row.get("crashed"))):
            print(json.dumps({"id": row["id"], "skipped": "the replay ended otherwise than the bench's record"}))
            continue
        t = world.traffic
        n = len(log["x"]) - 1
        x, y = float(log["x"][n]), float(log["y"][n])
        d = np.hypot(t.v_pose[:, 0] - x, t.v_pose[:, 1] - y)
        hit = int(np.argmin(d))
        grant = probe.last_grant.get(hit)
        path, _, _ = world.network.locate(x, y)
        yaw = math.radians(float(log["yaw_deg"][n]))
        fwd, left = np.array([math.cos(yaw), math.sin(yaw)]), np.array([-math.sin(yaw), math.cos(yaw)])
        rel = t.v_pose[hit, :2] - (x, y)
        heading = (math.degrees(t.v_pose[hit, 2] - yaw) + 180.0) % 360.0 - 180.0
        kind = ("same way" if abs(heading) < 60 else "oncoming" if abs(heading) > 120 else "crossing")
        kind = ("ahead, " if rel @ fwd > 1.0 else "behind, " if rel @ fwd < -1.0 else "beside, ") + kind
        rec: dict[str, Any] = {"id": row["id"], "ego_on": "lane" if path in set(world.network.lane_ids) else "junction",
                               "ego_speed_kmh": round(float(log["forward_speed_kmh"][n]), 1),
                               "ego_speed_1s_before_kmh": round(float(log["forward_speed_kmh"][max(n - 10, 0)]), 1),
                               "other_dist_m": round(float(d[hit]), 1), "other": kind,
                               "other_ahead_left_m": [round(float(rel @ fwd), 1), round(float(rel @ left), 1)],
                               "other_speed_kmh": round(float(t.v_speed[hit]) * 3.6, 1),
                               "other_in_junction": bool(t._is_connector[t.v_path[hit]]),
                               "other_grant": None if grant is None else {
                                   "s_before_end": round((probe.frame - grant["frame"]) * 0.1, 1),
                                   "ego_dist_m": round(grant["ego_dist_m"], 1), "ego_closing": grant["ego_closing"],
                                   "ego_speed_kmh": round(grant["ego_speed_ms"] * 3.6, 1)}}
        rec["withheld_by_an_ego_reservation"] = bool(grant is not None and grant["ego_dist_m"] < APPROACH_M
                                                     and grant["ego_closing"] and grant["ego_speed_ms"] > 0.5)
        out.append(rec)
        print(json.dumps(rec), flush=True)
    kinds: dict[str, int] = {}
    for r in out:
        key = f'ego on {r["ego_on"]}, other {r["other"]}' + (", granted as the ego approached"
                                                            if r["withheld_by_an_ego_reservation"] else "")
        kinds[key] = kinds.get(key, 0) + 1
    for key, count in sorted(kinds.items(), key=lambda kv: -kv[1]):
        print(f"{count:4d}  {key}")
    n_with = sum(r["withheld_by_an_ego_reservation"] for r in out)
    in_j = sum(r["other_in_junction"] for r in out)
    print(f"{len(out)} episodes: the other vehicle in a junction in {in_j}; its turn granted while the ego car was "
          f"within {APPROACH_M:.0f} m of that junction and closing in: {n_with}")
    if args.json:
        atomic_write_json(args.json, {"bench": str(args.bench), "model": args.model, "episodes": out})


if __name__ == "__main__":
    main()
