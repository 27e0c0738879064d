"""Simulator benchmarks (issue 2 targets), pinned to one CPU core.

    python benchmarks/bench_sim.py [--repeats 5] [--steps 300] [--json out.json]

Figures: town build time; decision steps/s (7 frames of physics + measurements, then 1 rendered frame of RGB
and labels at 200x88) in town01 without traffic (also with labels only, no RGB image, as in ground-truth runs),
with CoRL2017 traffic (20 vehicles, 50 pedestrians) and with
NoCrash's Dense traffic (100 vehicles, 250 pedestrians; issue 20's target: >= 60 steps/s);
measurement-only frames/s; resident memory growth over 1,000 episode resets. Each figure is the median of
`--repeats` runs.
"""

from __future__ import annotations

import argparse
import json
import os
import platform
import statistics
import time

os.environ.setdefault("OMP_NUM_THREADS", "1")
os.environ.setdefault("OPENBLAS_NUM_THREADS", "1")

from brlcli.sim import Control, World


def _rss_mb() -> float:
    with open("/proc/self/statm") as fh:
        return int(fh.read().split()[1]) * os.sysconf("SC_PAGE_SIZE") / 2**20


def _decision_steps(world: World, steps: int) -> float:
    spec = world.town.training_routes[0]
    world.reset(spec.start, seed=1)
    controls = [Control(throttle=0.5), Control(steer=0.4, throttle=0.35), Control(steer=-0.4, throttle=0.35)]
    t0 = time.perf_counter()
    for i in range(steps):
        c = controls[i % 3]
        for _ in range(6):
            world.step(c, render=False)
        world.step(c, render=True)
        if i % 40 == 39:
            world.reset(spec.start)
    return steps / (time.perf_counter() - t0)


def main() -> None:
    """Run every benchmark and print a table (and JSON with --json)."""
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--repeats", type=int, default=5)
    ap.add_argument("--steps", type=int, default=300)
    ap.add_argument("--resets", type=int, default=1000)
    ap.add_argument("--json", default=None)
    args = ap.parse_args()
    if hasattr(os, "sched_setaffinity"):
        os.sched_setaffinity(0, {sorted(os.sched_getaffinity(0))[0]})
    results: dict[str, float] = {}
    for town in ("town01", "town02"):
        times = []
        for _ in range(args.repeats):
            t0 = time.perf_counter()
            World(town).close()
            times.append(time.perf_counter() - t0)
        results[f"build_{town}_s"] = statistics.median(times)
    world = World("town01")
    results["decision_steps_per_s_no_traffic"] = statistics.median(
        _decision_steps(world, args.steps) for _ in range(args.repeats))
    world.rgb_frames = False  # ground-truth runs (GT training and bench): labels and depth, no RGB image
    results["decision_steps_per_s_no_traffic_labels_only"] = statistics.median(
        _decision_steps(world, args.steps) for _ in range(args.repeats))
    world.rgb_frames = True
    frames = []
    for _ in range(args.repeats):
        world.reset(world.town.training_routes[0].start, seed=2)
        t0 = time.perf_counter()
        for i in range(args.steps * 7):
            world.step(Control(throttle=0.5, steer=0.05 * ((i // 50) % 3 - 1)), render=False)
            if i % 280 == 279:
                world.reset(world.town.training_routes[0].start)
        frames.append(args.steps * 7 / (time.perf_counter() - t0))
    results["measurement_frames_per_s"] = statistics.median(frames)
    world.close()
    busy = World("town01", vehicles=20, pedestrians=50)
    results["decision_steps_per_s_corl_traffic"] = statistics.median(
        _decision_steps(busy, args.steps) for _ in range(args.repeats))
    dense = World("town01", vehicles=100, pedestrians=250)
    results["decision_steps_per_s_nocrash_dense"] = statistics.median(
        _decision_steps(dense, args.steps) for _ in range(args.repeats))
    dense.close()
    for _ in range(50):
        busy.reset()
    rss0 = _rss_mb()
    for _ in range(args.resets):
        busy.reset()
        busy.step(Control(throttle=0.5), render=False)
    results["rss_growth_over_resets_mb"] = _rss_mb() - rss0
    results["resets"] = args.resets
    busy.close()
    meta = {"python": platform.python_version(), "machine": platform.machine(), "cpu_count": os.cpu_count(),
            "repeats": args.repeats, "steps": args.steps}
    for k, v in results.items():
        print(f"{k:40s} {v:10.3f}")
    if args.json:
        with open(args.json, "w") as fh:
            json.dump({"results": results, "meta": meta}, fh, indent=2)


if __name__ == "__main__":
    main()
