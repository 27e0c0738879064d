"""Segmentation-net files: weights plus metadata in one torch file, read back with `weights_only=True` only.

Format version 2 (this brl) carries the net's calibration: per-class logit offsets fitted on held-out frames so that
the states of its labels match the states of the ground truth (`brlcli.segnet.calibrate`). A deployable file
(`segnet.pt`) must have them; a training checkpoint (`last.pt`, `best.pt`) need not. Version 1 files (brl 0.1)
still load, as uncalibrated nets.
"""

from __future__ import annotations

from pathlib import Path
from typing import Any

import numpy as np

from brlcli.classes import CarlaClass
from brlcli.errors import BrlInputError
from brlcli.segnet.model import NUM_CLASSES, SegNet, SegNetConfig
from brlcli.torchfiles import load_torch_doc, save_torch_doc

SEGNET_FORMAT = "brl-segnet"
SEGNET_FORMAT_VERSION = 2
READABLE_VERSIONS = (1, 2)
CLASS_NAMES = [c.name.lower() for c in CarlaClass]


def save_checkpoint(path: Path, net: SegNet, extra: dict[str, Any]) -> None:
    """Write weights, architecture, classes and `extra` (plain data and tensors only) atomically."""
    weights = {k: v.cpu() for k, v in net.state_dict().items()}  # a net trained on a GPU loads anywhere
    save_torch_doc(path, SEGNET_FORMAT, SEGNET_FORMAT_VERSION, {"classes": CLASS_NAMES, "arch": net.cfg.to_dict(),
                                                               "state_dict": weights, "extra": extra})


def load_checkpoint(path: Path) -> dict[str, Any]:
    """Read a segmentation-net file (never unpickling objects) and check its format and version."""
    doc = load_torch_doc(path, SEGNET_FORMAT, READABLE_VERSIONS, "segmentation net", "brl train-seg",
                         ("classes", "arch", "state_dict", "extra"))
    if list(doc["classes"]) != CLASS_NAMES:
        raise BrlInputError(f"segmentation net {path} predicts other classes than CARLA's 13")
    return doc


def logit_offsets(doc: dict[str, Any], path: Path, deployable: bool) -> np.ndarray | None:
    """The file's per-class logit offsets (13,); None for a version-1 file or an uncalibrated checkpoint."""
    offsets = doc["extra"].get("logit_offsets")
    if offsets is None:
        if deployable and doc["format_version"] >= 2:
            raise BrlInputError(f"segmentation net {path} has no calibration (a training checkpoint?): use the run's "
                                f"segnet.pt, or calibrate it with brl calibrate-seg --segnet {path} --data BAGS")
        return None
    arr = np.asarray(offsets, dtype=np.float64)
    if arr.shape != (NUM_CLASSES,) or not np.isfinite(arr).all():
        raise BrlInputError(f"segmentation net {path} has a malformed calibration (need {NUM_CLASSES} finite offsets)")
    return arr


def load_segnet(path: Path, deployable: bool = True) -> tuple[SegNet, dict[str, Any]]:
    """The net in eval mode and its metadata (normalisation, input size, `logit_offsets`, training summary).

    `deployable` requires a version-2 file to carry its calibration (training checkpoints are loaded without).
    """
    path = Path(path)
    doc = load_checkpoint(path)
    try:
        net = SegNet(SegNetConfig.from_dict(doc["arch"]))
        net.load_state_dict(doc["state_dict"])
    except (TypeError, KeyError, RuntimeError) as exc:
        raise BrlInputError(f"segmentation net {path} does not match its architecture: {exc}".splitlines()[0]) from None
    extra = dict(doc["extra"])
    for key in ("mean", "std", "input_size"):
        if key not in extra:
            raise BrlInputError(f"segmentation net {path} lacks '{key}'")
    extra["format_version"] = doc["format_version"]
    extra["logit_offsets"] = logit_offsets(doc, path, deployable)
    return net.eval(), extra
