"""The paper's 30-number state: 5 category shares in 6 image regions of a semantic label image."""

from __future__ import annotations

import numpy as np

from brlcli.classes import CarlaClass

N_CATEGORIES = 5
N_REGIONS = 6
STATE_DIM = N_CATEGORIES * N_REGIONS
ROAD_LINE_WEIGHT = 20.0
TOP_ROW_SHARE = 0.4
COLUMN_SHARES = (0.3, 0.4, 0.3)

#: CARLA class id -> category: 0 road, 1 road line, 2 off-road, 3 dynamic object, 4 static object.
CLASS_TO_CATEGORY = np.zeros(256, np.int64)
CLASS_TO_CATEGORY[[CarlaClass.ROADS]] = 0
CLASS_TO_CATEGORY[[CarlaClass.ROAD_LINES]] = 1
CLASS_TO_CATEGORY[[CarlaClass.SIDEWALKS, CarlaClass.OTHER, CarlaClass.NONE]] = 2
CLASS_TO_CATEGORY[[CarlaClass.PEDESTRIANS, CarlaClass.VEHICLES]] = 3
CLASS_TO_CATEGORY[[CarlaClass.BUILDINGS, CarlaClass.FENCES, CarlaClass.POLES, CarlaClass.VEGETATION,
                   CarlaClass.WALLS, CarlaClass.TRAFFIC_SIGNS]] = 4
CATEGORY_WEIGHTS = np.array([1.0, ROAD_LINE_WEIGHT, 1.0, 1.0, 1.0])
DYNAMIC_CATEGORY = 3
"""The category of vehicles and pedestrians (road users)."""


def road_user_in_view(state: np.ndarray) -> bool:
    """Whether a state's first 30 numbers (the paper's, under every state option) show a vehicle or pedestrian."""
    return bool(np.asarray(state)[DYNAMIC_CATEGORY:STATE_DIM:N_CATEGORIES].sum() > 0.0)


def region_index(height: int, width: int) -> np.ndarray:
    """Region id (0..5, row-major: top-left, top-middle, top-right, bottom-left, ...) of every pixel."""
    top = round(TOP_ROW_SHARE * height)
    c1 = round(COLUMN_SHARES[0] * width)
    c2 = round((COLUMN_SHARES[0] + COLUMN_SHARES[1]) * width)
    rows = (np.arange(height) >= top).astype(np.int64)
    cols = np.searchsorted([c1, c2], np.arange(width), side="right")
    return rows[:, None] * 3 + cols[None, :]


def category_counts(labels: np.ndarray) -> np.ndarray:
    """Pixel count of each category in each region: (H, W) -> (6, 5), or a batch (N, H, W) -> (N, 6, 5)."""
    labels = np.asarray(labels)
    batch = labels.reshape(-1, *labels.shape[-2:])
    n, h, w = batch.shape
    bins = region_index(h, w).ravel()[None, :] * N_CATEGORIES + CLASS_TO_CATEGORY[batch.reshape(n, -1)]
    bins += (STATE_DIM * np.arange(n))[:, None]
    counts = np.bincount(bins.ravel(), minlength=n * STATE_DIM).reshape(n, N_REGIONS, N_CATEGORIES)
    return counts.reshape(*labels.shape[:-2], N_REGIONS, N_CATEGORIES)


def states_from_counts(counts: np.ndarray, weights: np.ndarray = CATEGORY_WEIGHTS) -> np.ndarray:
    """Region x category pixel counts (..., 6, 5) -> states (..., 30): categories weighted (the paper: road lines x 20),
    L1-normalised."""
    weighted = (np.asarray(counts, np.float64) * weights).reshape(*np.shape(counts)[:-2], STATE_DIM)
    return weighted / weighted.sum(-1, keepdims=True)


def state_vector(labels: np.ndarray) -> np.ndarray:
    """Label image (H, W) of CARLA ids -> 30-vector (region-major, 5 categories each), L1-normalised."""
    return states_from_counts(category_counts(labels))


NEARNESS_RANGE_M = 30.0
"""Depth (m) beyond which a road user adds nothing to the nearness state (outside the paper)."""
STATE_OPTIONS = {"paper": 0, "nearness": 3, "speed": 1, "road_users_weighted": 0}
"""Agent state options (issue 35): the paper's 30 numbers; or those and 3 nearness numbers from the camera's depth
image (`depth_nearness`), or and the measured forward speed (clip(v / SPEED_SCALE_KMH, 0, 1), so that standing still
and driving are different states), or the 30 numbers with road-user pixels weighted ROAD_USER_WEIGHT times (as the
paper weights road lines); all but the first outside the paper. Value: how many numbers the option adds."""
SPEED_SCALE_KMH = 30.0
ROAD_USER_WEIGHT = 5.0
"""`road_users_weighted`: the weight of vehicle and pedestrian pixels before the state is normalised. A pedestrian on
the car's path 5-7 m ahead is a share of 0.006-0.02 in the paper's state, under the mixture's creation distance
(0.03); five times that is above it (docs/navigation-study.md, 12.22)."""
ROAD_USER_WEIGHTS = CATEGORY_WEIGHTS * np.where(np.arange(N_CATEGORIES) == DYNAMIC_CATEGORY, ROAD_USER_WEIGHT, 1.0)


def depth_nearness(labels: np.ndarray, depth: np.ndarray) -> np.ndarray:
    """Nearness clip(1 - d / NEARNESS_RANGE_M, 0, 1) of the closest vehicle or pedestrian pixel in each image column
    (left, middle, right: COLUMN_SHARES), 0 where there is none: 3 numbers (outside the paper)."""
    w = labels.shape[1]
    c1 = round(COLUMN_SHARES[0] * w)
    c2 = round((COLUMN_SHARES[0] + COLUMN_SHARES[1]) * w)
    dynamic = (labels == CarlaClass.VEHICLES) | (labels == CarlaClass.PEDESTRIANS)
    near = np.where(dynamic, np.clip(1.0 - np.asarray(depth, np.float64) / NEARNESS_RANGE_M, 0.0, 1.0), 0.0)
    return np.array([near[:, :c1].max(initial=0.0), near[:, c1:c2].max(initial=0.0), near[:, c2:].max(initial=0.0)])


def agent_state(labels: np.ndarray, depth: np.ndarray | None, option: str = "paper",
                speed_kmh: float = 0.0) -> np.ndarray:
    """The agent's state under a state option (STATE_OPTIONS): the 30-vector, with the option's numbers appended."""
    if option == "road_users_weighted":
        return states_from_counts(category_counts(labels), ROAD_USER_WEIGHTS)
    state = state_vector(labels)
    if option == "paper":
        return state
    if option == "speed":
        return np.append(state, min(max(speed_kmh / SPEED_SCALE_KMH, 0.0), 1.0))
    if depth is None:
        raise ValueError("the nearness state needs the camera's depth image")
    return np.concatenate([state, depth_nearness(labels, depth)])


ROAD_VIEW_CATEGORIES = {"road": (0,), "road+line": (0, 1)}
"""What the reward's road view counts: Road entries only, or Road and Road-line entries (the authors' code)."""


def road_share(state: np.ndarray, categories: tuple[int, ...] = (0,)) -> float:
    """Sum of the given category entries (default Road) of a normalised state over the six regions."""
    arr = np.asarray(state).reshape(N_REGIONS, N_CATEGORIES)
    return float(arr[:, list(categories)].sum())
