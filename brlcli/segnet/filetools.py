"""What `brl eval-seg` and `brl calibrate-seg` do with a segmentation-net file and recorded bags."""

from __future__ import annotations

import json
from collections.abc import Callable, Sequence
from pathlib import Path
from typing import Any

import numpy as np

from brlcli.segnet.calibrate import calibrate
from brlcli.segnet.io import load_segnet, save_checkpoint
from brlcli.segnet.train import evaluate

Frames = Sequence[tuple[np.ndarray, np.ndarray]]


def evaluate_file(path: Path, sets: dict[str, Frames], calibrated: bool = True) -> dict[str, Any]:
    """IoU and state error of a net file on named sets of labelled frames (its calibration applied, or not)."""
    net, meta = load_segnet(path)
    _check_size(path, meta, sets)
    offsets = meta["logit_offsets"] if calibrated else None
    mean, std = np.asarray(meta["mean"], np.float32), np.asarray(meta["std"], np.float32)
    return {"segnet": str(path), "format_version": meta["format_version"],
            "calibration": "applied" if offsets is not None else ("none in file" if calibrated else "ignored"),
            "sets": {name: evaluate(net, frames, mean, std, offsets) for name, frames in sets.items()}}


def calibrate_file(path: Path, frames: Frames, out: Path, fitted_on: str,
                   progress: Callable[[str], None] | None = None) -> dict[str, Any]:
    """Fit a net file's logit offsets on labelled frames and write the calibrated net to `out` (format 2)."""
    net, meta = load_segnet(path, deployable=False)
    _check_size(path, meta, {fitted_on: frames})
    mean, std = np.asarray(meta["mean"], np.float32), np.asarray(meta["std"], np.float32)
    offsets, used = calibrate(net, mean, std, frames, progress)
    record = {"fitted_on": fitted_on, "frames": used, "objective": "mean state L1", "source": str(path),
              "logit_offsets": [round(float(v), 6) for v in offsets],
              "sets": {fitted_on: {"uncalibrated": evaluate(net, frames, mean, std),
                                   "calibrated": evaluate(net, frames, mean, std, offsets)}}}
    extra = {k: v for k, v in meta.items() if k not in ("format_version", "logit_offsets", "calibration")}
    save_checkpoint(out, net, {**extra, "logit_offsets": [float(v) for v in offsets],
                               "calibration": json.dumps(record)})
    return record


def _check_size(path: Path, meta: dict[str, Any], sets: dict[str, Frames]) -> None:
    from brlcli.errors import BrlInputError

    size = tuple(meta["input_size"])
    for name, frames in sets.items():
        if frames and frames[0][1].shape != size:
            got = frames[0][1].shape
            raise BrlInputError(f"segmentation net {path} takes {size[1]}x{size[0]} images, the frames of {name} are "
                                f"{got[1]}x{got[0]}; record them with brl collect --width {size[1]} --height {size[0]}")
