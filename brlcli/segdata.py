"""Labelled frames for the segmentation net, read from `brl collect` bags, with a split by episode."""

from __future__ import annotations

from collections.abc import Sequence
from pathlib import Path

import numpy as np

from brlcli.bags import find_bags, iter_frames
from brlcli.errors import BrlInputError


def split_by_episode(bags: list[Path], val_fraction: float, seed: int) -> tuple[list[Path], list[Path]]:
    """Hold out whole episodes (bags): a seeded choice of `val_fraction` of them, at least one."""
    if not 0.0 < val_fraction < 1.0:
        raise BrlInputError("--val-fraction must be between 0 and 1")
    if len(bags) < 2:
        raise BrlInputError("a split by episode needs at least two bags; record more episodes or pass --val")
    rng = np.random.default_rng(seed)
    n_val = max(1, round(val_fraction * len(bags)))
    val_idx = set(rng.choice(len(bags), size=n_val, replace=False).tolist())
    return [b for i, b in enumerate(bags) if i not in val_idx], [b for i, b in enumerate(bags) if i in val_idx]


def load_frames(bags: Sequence[str | Path]) -> list[tuple[np.ndarray, np.ndarray]]:
    """(RGB, labels) of every frame of the bags, in order."""
    frames = [(f.rgb, f.labels) for f in iter_frames(list(bags), need_labels=True)]
    if not frames:
        raise BrlInputError(f"no frames in {', '.join(str(b) for b in bags)}")
    shapes = {f[0].shape for f in frames}
    if len(shapes) > 1:
        raise BrlInputError(f"frames of different sizes {sorted(shapes)}; record all data with one camera size")
    return frames


def resolve_data(data: Sequence[str], val: Sequence[str] | None, val_fraction: float,
                 seed: int) -> tuple[list[Path], dict[str, list[Path]]]:
    """Training bags and named validation bag sets (each --val is one set; none: a split by episode)."""
    train_bags = find_bags(list(data))
    if val:
        val_sets = {Path(v).name or str(v): find_bags([v]) for v in val}
        overlap = set(train_bags) & {b for bs in val_sets.values() for b in bs}
        if overlap:
            raise BrlInputError(f"validation bags are also training bags: {sorted(str(b) for b in overlap)[0]} ...")
        return train_bags, val_sets
    train_bags, held = split_by_episode(train_bags, val_fraction, seed)
    return train_bags, {"heldout": held}
