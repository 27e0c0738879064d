"""The 30-number state and the paper's reward."""

import numpy as np
import pytest

from brlcli.classes import CarlaClass
from brlcli.features import STATE_DIM, region_index, road_share, state_vector
from brlcli.reward import RewardParams, reward_terms


def _naive_state(labels: np.ndarray) -> np.ndarray:
    """Direct loop implementation of perception.md, as an oracle."""
    cat = {7: 0, 6: 1, 8: 2, 3: 2, 0: 2, 4: 3, 10: 3, 1: 4, 2: 4, 5: 4, 9: 4, 11: 4, 12: 4}
    h, w = labels.shape
    top = round(0.4 * h)
    cols = [0, round(0.3 * w), round(0.7 * w), w]
    out = np.zeros(30)
    for r, (r0, r1) in enumerate([(0, top), (top, h)]):
        for c in range(3):
            region = labels[r0:r1, cols[c] : cols[c + 1]]
            for v in region.ravel():
                k = cat[int(v)]
                out[(r * 3 + c) * 5 + k] += 20.0 if k == 1 else 1.0
    return out / out.sum()


def test_state_vector_matches_naive_oracle() -> None:
    rng = np.random.default_rng(0)
    labels = rng.integers(0, 13, size=(88, 200)).astype(np.uint8)
    s = state_vector(labels)
    assert s.shape == (STATE_DIM,)
    np.testing.assert_allclose(s, _naive_state(labels), rtol=1e-12)
    assert s.sum() == pytest.approx(1.0)
    assert (s >= 0).all()


def test_regions_split_rows_40_60_and_columns_30_40_30() -> None:
    r = region_index(10, 10)
    assert (r[:4] < 3).all() and (r[4:] >= 3).all()
    assert list(r[0, :]) == [0, 0, 0, 1, 1, 1, 1, 2, 2, 2]


def test_road_line_weight_and_road_share() -> None:
    labels = np.full((10, 10), CarlaClass.ROADS, np.uint8)
    labels[9, 5] = CarlaClass.ROAD_LINES
    s = state_vector(labels)
    # one line pixel counts as 20 road pixels
    assert s[4 * 5 + 1] == pytest.approx(20.0 / (99 + 20))
    assert road_share(s) == pytest.approx(99.0 / 119.0)


def test_reward_first_matching_term_only() -> None:
    state = np.zeros(30)
    state[0::5] = 1 / 6  # all road: no road-view penalty
    p = RewardParams(target_speed_kmh=20.0)
    t = reward_terms(True, 0.5, 0.5, 10.0, state, p)
    assert t["collision"] == -50 and t["offroad"] == 0 and t["total"] == -50
    t = reward_terms(False, 0.5, 0.5, 10.0, state, p)
    assert t["offroad"] == -20 and t["otherlane"] == 0
    t = reward_terms(False, 0.0, 0.5, 10.0, state, p)
    assert t["otherlane"] == -15
    assert reward_terms(False, 0, 0, 10.0, state, p)["speed"] == pytest.approx(-10 * 0.25)
    assert reward_terms(False, 0, 0, -10.0, state, p)["speed"] == pytest.approx(-15 * 2.25)
    assert reward_terms(False, 0, 0, 25.0, state, p)["total"] == 0.0


def test_road_view_penalty_below_half_road() -> None:
    state = np.zeros(30)
    state[0::5] = 0.3 / 6
    state[2::5] = 0.7 / 6
    t = reward_terms(False, 0, 0, 25.0, state)
    assert t["road_view"] == pytest.approx(20 * (0.3 - 1))


def test_road_users_weighted_multiplies_road_user_pixels_before_normalising() -> None:
    from brlcli.features import ROAD_USER_WEIGHT, agent_state

    labels = np.full((88, 200), CarlaClass.ROADS, np.uint8)
    labels[10:20, 95:105] = CarlaClass.PEDESTRIANS  # 100 pixels in the top-middle region
    paper, weighted = agent_state(labels, None, "paper"), agent_state(labels, None, "road_users_weighted")
    assert weighted.shape == (STATE_DIM,) and weighted.sum() == pytest.approx(1.0)
    n = labels.size
    assert paper[1 * 5 + 3] == pytest.approx(100 / n)
    assert weighted[1 * 5 + 3] == pytest.approx(ROAD_USER_WEIGHT * 100 / (n - 100 + ROAD_USER_WEIGHT * 100))
    np.testing.assert_allclose(weighted[0::5] / paper[0::5], (n / (n - 100 + ROAD_USER_WEIGHT * 100)))
