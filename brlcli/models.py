"""Where shipped trained models live (`models/` in a checkout, `brlcli/data/models` in an installed wheel)."""

from __future__ import annotations

import os
from pathlib import Path

DEFAULT_SEGNET = "segnet.pt"


def models_dir() -> Path:
    """Directory of the shipped models (env `BRL_MODELS_DIR` overrides)."""
    env = os.environ.get("BRL_MODELS_DIR")
    if env:
        return Path(env)
    packaged = Path(__file__).resolve().parent / "data" / "models"
    if packaged.is_dir():
        return packaged
    return Path(__file__).resolve().parents[1] / "models"


def default_segnet_path() -> Path:
    """The shipped segmentation net used for the 'estimated' input when no other is given."""
    return models_dir() / DEFAULT_SEGNET


DEFAULT_MODEL_SET = "brl_gt"


def default_model_set() -> Path | None:
    """The shipped nine-seed GT-trained BRL model set (used by `brl bench` when no model is given)."""
    path = models_dir() / DEFAULT_MODEL_SET
    return path if path.is_dir() else None
