"""CARLA 0.8 semantic classes (label image ids) and the paper's five state categories."""

from enum import IntEnum

import numpy as np


class CarlaClass(IntEnum):
    """CARLA 0.8 semantic segmentation ids; brl label images use the same ids."""

    NONE = 0
    BUILDINGS = 1
    FENCES = 2
    OTHER = 3
    PEDESTRIANS = 4
    POLES = 5
    ROAD_LINES = 6
    ROADS = 7
    SIDEWALKS = 8
    VEGETATION = 9
    VEHICLES = 10
    WALLS = 11
    TRAFFIC_SIGNS = 12


NUM_CLASSES = 13

#: A readable colour per class for label visualisations (CARLA's palette), RGB uint8.
LABEL_PALETTE = np.array(
    [
        [0, 0, 0], [70, 70, 70], [190, 153, 153], [250, 170, 160], [220, 20, 60], [153, 153, 153],
        [157, 234, 50], [128, 64, 128], [244, 35, 232], [107, 142, 35], [0, 0, 142], [102, 102, 156],
        [220, 220, 0],
    ],
    dtype=np.uint8,
)


def colorize_labels(labels: np.ndarray) -> np.ndarray:
    """Label image (H, W) of CARLA ids -> RGB image with CARLA's palette."""
    return LABEL_PALETTE[labels]
