"""Segmentation-net inference speed: batch 1, one CPU thread, 200x88 (the default camera); old vs new in one run.

    python benchmarks/bench_segnet.py [--model models/segnet.pt] [--repeats 5] [--frames 300]

Rows, timed in turn (interleaved repeats, median frames/s):
- brl 0.1: the brl 0.1 net's architecture through brl 0.1's inference path (torch eager: normalise, net, argmax).
  Speed does not depend on the weights, so this needs no old file.
- MODEL, torch: the given (default: shipped) net's full RGB -> labels function in torch eager mode.
- MODEL, onnxruntime: the same function as deployed (`brlcli.segnet.infer.Segmenter`).
The ratios are to the brl 0.1 row of the same run.
"""

from __future__ import annotations

import argparse
import os
import statistics
import time
from collections.abc import Callable

os.environ.setdefault("OMP_NUM_THREADS", "1")

import numpy as np
import torch

from brlcli.segnet.infer import Segmenter
from brlcli.segnet.model import SegNet, SegNetConfig


def brl01_predictor(size: tuple[int, int]) -> Callable[[np.ndarray], np.ndarray]:
    """brl 0.1's Segmenter.predict on a net of brl 0.1's architecture (random weights, eval mode)."""
    torch.manual_seed(0)
    net = SegNet(SegNetConfig()).eval()
    mean = torch.full((1, 3, 1, 1), 0.45 * 255.0)
    inv_std = 1.0 / torch.full((1, 3, 1, 1), 0.25 * 255.0)

    def predict(rgb: np.ndarray) -> np.ndarray:
        with torch.inference_mode():
            x = torch.from_numpy(np.ascontiguousarray(rgb)).permute(2, 0, 1)[None].float()
            return net((x - mean) * inv_std)[0][0].argmax(0).to(torch.uint8).numpy()

    return predict


def main() -> None:
    """Time the three predictors on a rendered-size random image (median over interleaved repeats)."""
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--model", default=None)
    ap.add_argument("--repeats", type=int, default=5)
    ap.add_argument("--frames", type=int, default=300)
    args = ap.parse_args()
    if hasattr(os, "sched_setaffinity"):
        os.sched_setaffinity(0, {sorted(os.sched_getaffinity(0))[0]})
    torch.set_num_threads(1)
    fast = Segmenter(args.model, threads=1)
    ref = Segmenter(args.model, threads=1, backend="torch")
    h, w = fast.input_size
    rgb = np.random.default_rng(0).integers(0, 255, (h, w, 3), dtype=np.uint8)
    np.testing.assert_array_equal(fast.predict(rgb), ref.predict(rgb))
    rows = {"brl 0.1 net, torch eager (brl 0.1's path)": brl01_predictor((h, w)),
            f"{fast.path.name}, torch eager": ref.predict, f"{fast.path.name}, onnxruntime (deployed)": fast.predict}
    rates: dict[str, list[float]] = {name: [] for name in rows}
    for fn in rows.values():
        for _ in range(20):
            fn(rgb)
    for _ in range(args.repeats):
        for name, fn in rows.items():
            t0 = time.perf_counter()
            for _ in range(args.frames):
                fn(rgb)
            rates[name].append(args.frames / (time.perf_counter() - t0))
    base = statistics.median(rates[next(iter(rows))])
    print(f"segmentation at {w}x{h}, batch 1, 1 thread ({args.repeats} x {args.frames} frames, median):")
    for name, values in rates.items():
        med = statistics.median(values)
        print(f"  {name:48s} {med:7.0f} frames/s  {med / base:5.2f}x")


if __name__ == "__main__":
    main()
