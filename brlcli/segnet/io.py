"""Segmentation-net files: weights plus metadata in one torch file, read back with `weights_only=True` only."""

from __future__ import annotations

from pathlib import Path
from typing import Any

from brlcli.errors import BrlInputError
from brlcli.segnet.model import SegNet, SegNetConfig
from brlcli.sim.classes import CarlaClass
from brlcli.torchfiles import load_torch_doc, save_torch_doc

SEGNET_FORMAT = "brl-segnet"
SEGNET_FORMAT_VERSION = 1
CLASS_NAMES = [c.name.lower() for c in CarlaClass]


def save_checkpoint(path: Path, net: SegNet, extra: dict[str, Any]) -> None:
    """Write weights, architecture, classes and `extra` (plain data and tensors only) atomically."""
    save_torch_doc(path, SEGNET_FORMAT, SEGNET_FORMAT_VERSION, {"classes": CLASS_NAMES, "arch": net.cfg.to_dict(),
                                                               "state_dict": net.state_dict(), "extra": extra})


def load_checkpoint(path: Path) -> dict[str, Any]:
    """Read a segmentation-net file (never unpickling objects) and check its format and version."""
    doc = load_torch_doc(path, SEGNET_FORMAT, SEGNET_FORMAT_VERSION, "segmentation net", "brl train-seg",
                         ("classes", "arch", "state_dict", "extra"))
    if list(doc["classes"]) != CLASS_NAMES:
        raise BrlInputError(f"segmentation net {path} predicts other classes than CARLA's 13")
    return doc


def load_segnet(path: Path) -> tuple[SegNet, dict[str, Any]]:
    """The net in eval mode and its metadata (normalisation, input size, training summary)."""
    doc = load_checkpoint(path)
    try:
        net = SegNet(SegNetConfig.from_dict(doc["arch"]))
        net.load_state_dict(doc["state_dict"])
    except (TypeError, KeyError, RuntimeError) as exc:
        raise BrlInputError(f"segmentation net {path} does not match its architecture: {exc}".splitlines()[0]) from None
    extra = doc["extra"]
    for key in ("mean", "std", "input_size"):
        if key not in extra:
            raise BrlInputError(f"segmentation net {path} lacks '{key}'")
    return net.eval(), extra
