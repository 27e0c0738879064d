"""Traffic alone (no ego car) in NoCrash Dense: contacts between road users, and whether traffic keeps moving.

    python scripts/traffic_check.py [--episodes 500] [--seconds 60] [--workers 2] [--json out.json]

Per town (town01: 100 vehicles, 250 pedestrians; town02: 70, 150) runs `--episodes` episodes of `--seconds`
simulated seconds, episode e seeded with numpy's default_rng(e), and counts the episodes with a vehicle-vehicle
contact (overlapping bodies, `Traffic.vehicle_contacts`), the episodes with a pedestrian inside or touching a
vehicle's body, and the share of vehicles standing (< 0.1 m/s) over the episode's last 10 s.
"""

from __future__ import annotations

import argparse
import os
from concurrent.futures import ProcessPoolExecutor
from pathlib import Path

os.environ.setdefault("OMP_NUM_THREADS", "1")

import numpy as np

from brlcli.bench.suites import NOCRASH_TRAFFIC
from brlcli.provenance import atomic_write_json
from brlcli.sim import RoadNetwork, load_town
from brlcli.sim.traffic import Traffic
from brlcli.sim.vehicle import LENGTH_M, WIDTH_M


def _episode(args: tuple[str, int, int]) -> tuple[bool, bool, float]:
    town, seed, frames = args
    n_v, n_p = NOCRASH_TRAFFIC[town]["dense"]
    t = Traffic(RoadNetwork(load_town(town)), n_v, n_p)
    t.reset(np.random.default_rng(seed))
    vv, pv, standing = False, False, []
    for k in range(frames):
        t.step(0.1, -1e4, -1e4)
        vv = vv or len(t.vehicle_contacts()) > 0
        rel = t.p_pose[:, None, :2] - t.v_pose[None, :, :2]
        c, s = np.cos(t.v_pose[:, 2]), np.sin(t.v_pose[:, 2])
        fwd, lat = rel[..., 0] * c + rel[..., 1] * s, -rel[..., 0] * s + rel[..., 1] * c
        pv = pv or bool(((np.abs(fwd) < LENGTH_M / 2 + 0.25) & (np.abs(lat) < WIDTH_M / 2 + 0.25)).any())
        if k >= frames - 100:
            standing.append(float((t.v_speed < 0.1).mean()))
    return vv, pv, float(np.mean(standing))


def main() -> None:
    """Run the check and print one line per town."""
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--episodes", type=int, default=500)
    ap.add_argument("--seconds", type=float, default=60.0)
    ap.add_argument("--workers", type=int, default=2)
    ap.add_argument("--json", default=None)
    args = ap.parse_args()
    frames = round(args.seconds * 10)
    out = {}
    with ProcessPoolExecutor(args.workers) as pool:
        for town in ("town01", "town02"):
            rows = list(pool.map(_episode, [(town, e, frames) for e in range(args.episodes)], chunksize=4))
            vv = sum(r[0] for r in rows)
            pv = sum(r[1] for r in rows)
            standing = [r[2] for r in rows]
            out[town] = {"episodes": len(rows), "vehicle_vehicle_contact_episodes": vv,
                         "pedestrian_vehicle_contact_episodes": pv, "standing_share_last_10s_mean": np.mean(standing),
                         "standing_share_last_10s_max": max(standing)}
            print(f"{town}: {len(rows)} Dense episodes of {args.seconds:g} s: vehicle-vehicle contact in {vv}, "
                  f"pedestrian-vehicle contact in {pv}; vehicles standing over the last 10 s: mean "
                  f"{np.mean(standing):.0%}, worst episode {max(standing):.0%}", flush=True)
    if args.json:
        atomic_write_json(Path(args.json), out)


if __name__ == "__main__":
    main()
