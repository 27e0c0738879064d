"""The EncNet-style segmentation net behind the paper's 'estimated' input: model, training, files, inference."""

from __future__ import annotations

from collections.abc import Callable

import numpy as np

from brlcli.errors import BrlInputError

INPUT_SOURCES = ("gt", "estimated")
"""Where label images come from: the simulator's ground truth, or the segmentation net on the RGB image."""


def check_input_source(source: str, option: str = "--deploy") -> None:
    """Refuse anything but gt or estimated (one line naming the option)."""
    if source not in INPUT_SOURCES:
        raise BrlInputError(f"{option} must be gt or estimated, not '{source}'")


def labeler_for(source: str, segnet: str | None = None,
                option: str = "--deploy") -> Callable[[np.ndarray], np.ndarray] | None:
    """None for ground-truth labels; for 'estimated' the RGB -> labels function of the given (or shipped) net,
    which must take the camera's image size."""
    check_input_source(source, option)
    if source == "gt":
        return None
    from brlcli.segnet.infer import load_segmenter
    from brlcli.sim.camera import CameraConfig

    seg = load_segmenter(segnet)
    cam = CameraConfig()
    if seg.input_size != (cam.height, cam.width):
        raise BrlInputError(f"segmentation net {seg.path} takes {seg.input_size[1]}x{seg.input_size[0]} images, the "
                            f"camera gives {cam.width}x{cam.height}; train one on frames of that size")
    return seg.predict
