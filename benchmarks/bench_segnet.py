"""Segmentation-net inference speed: batch 1, one CPU thread, 200x88 (the default camera).

    python benchmarks/bench_segnet.py [--model models/segnet.pt] [--repeats 5] [--frames 300]
"""

from __future__ import annotations

import argparse
import os
import statistics
import time

os.environ.setdefault("OMP_NUM_THREADS", "1")

import numpy as np

from brlcli.segnet.infer import Segmenter


def main() -> None:
    """Time `Segmenter.predict` on rendered-size random images (median of repeats)."""
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--model", default=None)
    ap.add_argument("--repeats", type=int, default=5)
    ap.add_argument("--frames", type=int, default=300)
    args = ap.parse_args()
    if hasattr(os, "sched_setaffinity"):
        os.sched_setaffinity(0, {sorted(os.sched_getaffinity(0))[0]})
    seg = Segmenter(args.model, threads=1)
    h, w = seg.input_size
    rgb = np.random.default_rng(0).integers(0, 255, (h, w, 3), dtype=np.uint8)
    for _ in range(10):
        seg.predict(rgb)
    rates = []
    for _ in range(args.repeats):
        t0 = time.perf_counter()
        for _ in range(args.frames):
            seg.predict(rgb)
        rates.append(args.frames / (time.perf_counter() - t0))
    print(f"segmentation net {seg.path} at {w}x{h}, batch 1, 1 thread: {statistics.median(rates):.0f} frames/s")


if __name__ == "__main__":
    main()
