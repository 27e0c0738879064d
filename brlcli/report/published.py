"""Published figures printed beside ours: the paper's test table, CARLA's Table 1 and the paper's Town02 table.

Sources: the seed paper (Gharaee et al., ICPR 2020) Tables II and III (labels `tab:ZGHSmall` and
`tab:carlacompTown02` in its LaTeX source; Table I is its parameter settings, `tab:settings`), and CARLA (Dosovitskiy
et al., CoRL 2017) Table 1 as transcribed in docs/benchmarks.md. Shares are percentages as printed.
"""

from __future__ import annotations

from dataclasses import dataclass

PAPER_TABLE_NAME = "Table II"
"""The paper's lane-keeping test table as its PDF numbers it (tab:ZGHSmall in the LaTeX source)."""
PAPER_TOWN02_NAME = "Table III"
"""The paper's Town02 km-between-infractions table as its PDF numbers it (tab:carlacompTown02)."""
PAPER_TABLE_SOURCE = f"Gharaee et al. 2020, {PAPER_TABLE_NAME}"
CARLA_TABLE1_SOURCE = "Dosovitskiy et al. 2017, Table 1"
PAPER_TOWN02_SOURCE = f"Gharaee et al. 2020, {PAPER_TOWN02_NAME}"


@dataclass(frozen=True)
class PublishedPaperRow:
    """One row of the paper's test table (percentages as printed; None where the paper prints nothing)."""

    setting: str
    row: str
    offroad_pct: float
    otherlane_pct: float
    either_pct: float
    success_pct: float
    no_collision_pct: float
    score: float
    score_std: float | None
    dist_m: float
    dist_std_m: float | None


PAPER_TABLE: tuple[PublishedPaperRow, ...] = (
    PublishedPaperRow("TGDG", "average", 0.0, 11.1, 11.1, 96.8, 84.1, 0.90, 0.07, 11132, 703),
    PublishedPaperRow("TGDG", "best model", 0.0, 2.4, 2.4, 100.0, 100.0, 0.99, None, 11168, None),
    PublishedPaperRow("TGDE", "average", 0.1, 11.6, 11.7, 89.0, 80.8, 0.86, 0.073, 11392, 232),
    PublishedPaperRow("TGDE", "best model", 0.0, 2.5, 2.5, 100.0, 100.0, 0.99, None, 11119, None),
    PublishedPaperRow("TEDE", "average", 11.4, 29.8, 37.9, 34.5, 73.4, 0.57, 0.3, 10209, 1950),
    PublishedPaperRow("TEDE", "best model", 0.0, 17.5, 17.5, 100.0, 100.0, 0.94, None, 11227, None),
    PublishedPaperRow("TEDG", "average", 11.5, 25.8, 36.3, 33.3, 78.3, 0.58, 0.3, 11437, 2201),
    PublishedPaperRow("TEDG", "best model", 0.0, 22.7, 22.7, 100.0, 100.0, 0.92, None, 11238, None),
    PublishedPaperRow("RL", "CARLA RL", 42.4, 21.0, 52.4, 41.7, 50.0, 0.46, None, 8787, None),
    PublishedPaperRow("IL", "CARLA IL", 8.3, 0.7, 8.4, 86.9, 90.5, 0.90, None, 11293, None),
)
"""The paper's Table II (tab:ZGHSmall), every row (the four settings' average and best model, then RL and IL)."""

PAPER_SETTINGS: tuple[str, ...] = ("TGDG", "TGDE", "TEDE", "TEDG")
"""The paper's train/deploy settings in the order of its table."""

CORL_CONDITIONS: tuple[tuple[str, str], ...] = (
    ("training", "Training"), ("new_town", "New town"), ("new_weather", "New weather"),
    ("new_town_weather", "New town & weather"),
)
"""CoRL2017 conditions (result key, column title) in the order of CARLA's Table 1."""

CORL_TASKS: tuple[tuple[str, str], ...] = (
    ("straight", "Straight"), ("one_curve", "One turn"), ("navigation", "Navigation"),
    ("navigation_dynamic", "Nav. dynamic"),
)
"""CoRL2017 tasks (result key, row title) in the order of CARLA's Table 1."""

CARLA_SUCCESS_PCT: dict[str, dict[str, dict[str, int]]] = {
    # task -> condition -> agent -> % success
    "straight": {"training": {"MP": 98, "IL": 95, "RL": 89}, "new_town": {"MP": 92, "IL": 97, "RL": 74},
                 "new_weather": {"MP": 100, "IL": 98, "RL": 86}, "new_town_weather": {"MP": 50, "IL": 80, "RL": 68}},
    "one_curve": {"training": {"MP": 82, "IL": 89, "RL": 34}, "new_town": {"MP": 61, "IL": 59, "RL": 12},
                  "new_weather": {"MP": 95, "IL": 90, "RL": 16}, "new_town_weather": {"MP": 50, "IL": 48, "RL": 20}},
    "navigation": {"training": {"MP": 80, "IL": 86, "RL": 14}, "new_town": {"MP": 24, "IL": 40, "RL": 3},
                   "new_weather": {"MP": 94, "IL": 84, "RL": 2}, "new_town_weather": {"MP": 47, "IL": 44, "RL": 6}},
    "navigation_dynamic": {"training": {"MP": 77, "IL": 83, "RL": 7}, "new_town": {"MP": 24, "IL": 38, "RL": 2},
                           "new_weather": {"MP": 89, "IL": 82, "RL": 2},
                           "new_town_weather": {"MP": 44, "IL": 42, "RL": 4}},
}
"""CARLA's Table 1, % success of the modular pipeline (MP), imitation learning (IL) and RL baselines."""

CARLA_AGENTS: tuple[str, ...] = ("MP", "IL", "RL")

PAPER_TOWN02_AGENTS: tuple[str, ...] = ("MP", "IL", "RL", "TGDG", "TEDE", "TEDG", "TGDE")
"""Columns of the paper's Town02 table, in its order."""

PAPER_TOWN02_KM: dict[str, dict[str, tuple[float, ...]]] = {
    # infraction type -> condition -> km between infractions per agent (PAPER_TOWN02_AGENTS order)
    "otherlane": {"new_town": (0.45, 1.12, 0.23, 2.14, 0.18, 0.24, 4.10),
                  "new_town_weather": (0.40, 0.78, 0.21, 2.13, 0.18, 0.25, 2.93)},
    "offroad": {"new_town": (0.46, 0.76, 0.43, 0.40, 10.24, 9.80, 0.11),
                "new_town_weather": (0.43, 0.81, 0.48, 0.39, 6.64, 9.80, 0.10)},
    "collision_other": {"new_town": (0.44, 0.40, 0.23, 2.52, 2.16, 2.18, 0.55),
                        "new_town_weather": (0.45, 0.28, 0.25, 3.55, 1.53, 3.27, 0.79)},
    "collision_vehicles": {"new_town": (0.51, 0.59, 0.41, 0.34, 0.22, 0.27, 0.38),
                           "new_town_weather": (0.47, 0.44, 0.37, 0.33, 0.26, 0.24, 0.34)},
    "collision_pedestrians": {"new_town": (1.40, 1.88, 2.55, 1.40, 1.20, 1.35, 0.53),
                              "new_town_weather": (1.46, 1.41, 2.99, 1.39, 0.69, 1.13, 1.31)},
}
"""The paper's Table III (tab:carlacompTown02): average km driven between infractions in Town02 (MP, IL, RL from
CARLA)."""

INFRACTION_TITLES: dict[str, str] = {
    "offroad": "Sidewalk (off-road)", "otherlane": "Opposite lane", "collision_other": "Collision-static",
    "collision_vehicles": "Collision-vehicle", "collision_pedestrians": "Collision-pedestrian",
}
"""Row titles of the infraction types, as in the paper's Town02 table."""
