"""Calibrating a segmentation net for the state: per-class logit offsets fitted on held-out labelled frames.

A net trained with class-weighted cross-entropy buys recall of thin classes with their area (the shipped brl 0.1
net predicted 1.36x the road-line area), and the 30-number state weighs road lines by 20. Adding a constant
offset b_c to each class's logit before the argmax (post-hoc logit adjustment; Menon et al., ICLR 2021) moves
every class boundary without retraining. The offsets are fitted in two stages on frames the net was not trained
on: first the pixel area of every class is matched to the ground truth (kept if that beats no offsets), then a
coordinate descent over the classes minimises the mean L1 distance between the states of the estimated and the
GT labels, the figure that matters to the agent. Deterministic (plain numpy, fixed grids).
"""

from __future__ import annotations

from collections.abc import Callable, Sequence

import numpy as np

from brlcli.errors import BrlInputError
from brlcli.features import (
    CLASS_TO_CATEGORY,
    N_CATEGORIES,
    N_REGIONS,
    STATE_DIM,
    category_counts,
    region_index,
    states_from_counts,
)
from brlcli.segnet.infer import batch_logits
from brlcli.segnet.metrics import NUM_CLASSES
from brlcli.segnet.model import SegNet

AREA_ITERATIONS = 8
SWEEP_STEPS = (1.0, 0.5, 0.25)
GRID = np.linspace(-1.0, 1.0, 11)


def _area_offsets(logits: np.ndarray, labels: np.ndarray, buf: np.ndarray) -> np.ndarray:
    offsets = np.zeros(NUM_CLASSES)
    gt_area = np.bincount(labels.ravel(), minlength=NUM_CLASSES)[:NUM_CLASSES].astype(np.float64)
    for _ in range(AREA_ITERATIONS):
        np.add(logits, offsets[None, :, None, None].astype(np.float32), out=buf)
        est_area = np.bincount(buf.argmax(1).ravel(), minlength=NUM_CLASSES)[:NUM_CLASSES].astype(np.float64)
        offsets += 0.8 * np.log((gt_area + 1.0) / (est_area + 1.0))
    return offsets


def fit_logit_offsets(logits: np.ndarray, labels: np.ndarray,
                      progress: Callable[[str], None] | None = None) -> np.ndarray:
    """Per-class logit offsets (13,) for logits (N, 13, H, W) float32 and GT labels (N, H, W): area matching, then
    coordinate descent on the mean state L1 (offset steps 1, 0.5, 0.25 on an 11-point grid per class). Never worse
    on these frames than no offsets."""
    logits = np.asarray(logits, np.float32)
    n, _, h, w = logits.shape
    gt_states = states_from_counts(category_counts(labels))
    # the state bin (frame, region) of every pixel; a label adds its category
    cell = ((np.arange(n)[:, None] * N_REGIONS + region_index(h, w).ravel()[None, :]) * N_CATEGORIES).ravel()
    category = CLASS_TO_CATEGORY[:NUM_CLASSES]

    def state_l1(counts: np.ndarray) -> float:
        return float(np.abs(states_from_counts(counts.reshape(n, N_REGIONS, N_CATEGORIES)) - gt_states).sum(1).mean())

    def counts_of(bins: np.ndarray) -> np.ndarray:
        return np.bincount(bins, minlength=n * STATE_DIM)

    buf = np.empty_like(logits)
    offsets = np.zeros(NUM_CLASSES)
    best = state_l1(counts_of(cell + category[logits.argmax(1).ravel()]))
    area = _area_offsets(logits, labels, buf)
    np.add(logits, area[None, :, None, None].astype(np.float32), out=buf)
    matched = state_l1(counts_of(cell + category[buf.argmax(1).ravel()]))
    if progress:
        progress(f"state L1 {best:.4f} uncalibrated, {matched:.4f} with matched areas")
    if matched < best:  # start from the better of no offsets and matched areas
        offsets, best = area, matched
    for step in SWEEP_STEPS:
        for c in range(NUM_CLASSES):
            np.add(logits, offsets[None, :, None, None].astype(np.float32), out=buf)
            own = buf[:, c].ravel().copy()
            buf[:, c] = -np.inf
            other = buf.argmax(1).ravel()
            margin = own - np.take_along_axis(buf, other.reshape(n, 1, h, w), 1).ravel()
            # only pixels within one step of the boundary can change class; the rest are counted once
            near = np.abs(margin) <= step
            keep = ~near
            fixed = np.where(margin[keep] > 0, category[c], category[other[keep]])
            fixed_counts = counts_of(cell[keep] + fixed)
            m, o, cells = margin[near], other[near], cell[near]
            best_d = 0.0
            for d in GRID[GRID != 0] * step:
                # a pixel takes class c when its shifted logit beats the best other class (argmax keeps the first
                # of equal logits: c wins a tie only against a later class)
                wins = (m + d > 0) | ((m + d == 0) & (o > c))
                value = state_l1(fixed_counts + counts_of(cells + np.where(wins, category[c], category[o])))
                if value < best - 1e-9:
                    best, best_d = value, d
            offsets[c] += best_d
        if progress:
            progress(f"step {step}: state L1 {best:.4f}")
    return offsets - offsets.mean()


MAX_FRAMES = 600
"""Calibration uses at most this many frames (evenly spaced) of the set it is fitted on (logits held in memory)."""


def calibrate(net: SegNet, mean: np.ndarray, std: np.ndarray, frames: Sequence[tuple[np.ndarray, np.ndarray]],
              progress: Callable[[str], None] | None = None, device: str = "cpu") -> tuple[np.ndarray, int]:
    """Fit a net's per-class logit offsets on labelled (RGB, labels) frames (the net's logits on `device`); returns
    them and the frames used."""
    if not frames:
        raise BrlInputError("no frames to calibrate the segmentation net on")
    pick = np.unique(np.linspace(0, len(frames) - 1, min(len(frames), MAX_FRAMES)).round().astype(int))
    rgb = np.stack([frames[i][0] for i in pick])
    labels = np.stack([frames[i][1] for i in pick])
    return fit_logit_offsets(batch_logits(net, rgb, mean, std, device=device), labels, progress), len(pick)
