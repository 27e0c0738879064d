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
    """None for ground-truth labels; for 'estimated' the RGB -> labels function of the given (or shipped) net."""
    check_input_source(source, option)
    if source == "gt":
        return None
    from brlcli.segnet.infer import load_labeler

    return load_labeler(segnet)
