"""`brl collect` throughput on one core: recorded frames per second at 200x88 (RGB + labels + depth +
measurements + controls, MCAP with zstd chunks), with and without CoRL2017 traffic.

    python benchmarks/bench_collect.py [--repeats 5] [--frames 600]
"""

from __future__ import annotations

import argparse
import os
import statistics
import tempfile
from pathlib import Path

os.environ.setdefault("OMP_NUM_THREADS", "1")
os.environ.setdefault("OPENBLAS_NUM_THREADS", "1")

from brlcli.collect import CollectConfig, collect


def main() -> None:
    """Run the collect benchmark and print frames/s (median of repeats)."""
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--repeats", type=int, default=5)
    ap.add_argument("--frames", type=int, default=600)
    args = ap.parse_args()
    if hasattr(os, "sched_setaffinity"):
        os.sched_setaffinity(0, {sorted(os.sched_getaffinity(0))[0]})
    for label, traffic in (("no traffic", (0, 0)), ("CoRL2017 traffic 20+50", (20, 50))):
        rates = []
        for r in range(args.repeats):
            with tempfile.TemporaryDirectory() as tmp:
                cfg = CollectConfig(town="town01", weathers=(1, 3, 6, 8), episodes=2, episode_frames=args.frames // 2,
                                    seed=r, vehicles=traffic[0], pedestrians=traffic[1])
                rates.append(collect(cfg, Path(tmp) / "bags")["frames_per_s"])
        print(f"collect town01 200x88, {label}: {statistics.median(rates):.0f} recorded frames/s")


if __name__ == "__main__":
    main()
