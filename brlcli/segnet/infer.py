"""Batch-1 CPU inference of the segmentation net inside the simulation loop."""

from __future__ import annotations

from collections.abc import Callable
from pathlib import Path

import numpy as np
import torch

from brlcli.errors import BrlInputError
from brlcli.models import default_segnet_path
from brlcli.segnet.io import load_segnet


class Segmenter:
    """RGB uint8 (H, W, 3) -> estimated label image uint8 (H, W) in CARLA ids."""

    def __init__(self, path: str | Path | None = None, threads: int | None = 1) -> None:
        self.path = Path(path) if path else default_segnet_path()
        self.net, meta = load_segnet(self.path)
        self.input_size = tuple(meta["input_size"])
        self._mean = torch.tensor(meta["mean"], dtype=torch.float32).view(1, 3, 1, 1) * 255.0
        self._inv_std = 1.0 / (torch.tensor(meta["std"], dtype=torch.float32).view(1, 3, 1, 1) * 255.0)
        if threads:
            torch.set_num_threads(threads)

    def predict(self, rgb: np.ndarray) -> np.ndarray:
        """Estimated labels of one image (must have the net's input size)."""
        if rgb.shape[:2] != self.input_size:
            raise BrlInputError(f"the segmentation net {self.path} expects {self.input_size[1]}x{self.input_size[0]} "
                                f"images, the camera gives {rgb.shape[1]}x{rgb.shape[0]}")
        with torch.inference_mode():
            x = torch.from_numpy(np.ascontiguousarray(rgb)).permute(2, 0, 1)[None].float()
            logits = self.net((x - self._mean) * self._inv_std)[0]
            return logits[0].argmax(0).to(torch.uint8).numpy()


def load_labeler(path: str | Path | None = None) -> Callable[[np.ndarray], np.ndarray]:
    """A function RGB -> estimated labels using the given (or the shipped) segmentation net."""
    return Segmenter(path).predict
