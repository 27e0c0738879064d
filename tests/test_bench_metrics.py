"""CoRL2017 infraction events, km between infractions, success over weathers, the paper's table row, Beta posteriors."""

import numpy as np
import pytest
from scipy import stats

from brlcli.bench.metrics import (
    INFRACTION_RULES,
    INFRACTION_TYPES,
    EpisodeResult,
    LaneKeepingEpisode,
    beta_posterior,
    count_collision_events,
    count_lane_events,
    episode_infractions,
    km_between_infractions,
    km_driven,
    paper_score,
    paper_table_row,
    posterior_summary,
    success_rate_over_weathers,
)

VEH = INFRACTION_RULES["collision_vehicles"]  # skip 10, recount 30, threshold 400


def _reference_collisions(x: np.ndarray, skip: int, recount: int, thr: float, wrap: bool = False) -> int:
    """Straight transcription of the loop in docs/benchmarks.md; wrap=True is CARLA's original x[i - skip]."""
    events, i = 0, 1
    while i < len(x):
        ref = x[i - skip] if wrap else x[max(i - skip, 0)]
        if x[i] - ref > thr:
            events += 1
            i += recount
        i += 1
    return events


def _reference_lanes(off: np.ndarray, other: np.ndarray, wrap: bool = False) -> tuple[int, int]:
    """Straight transcription of the shared off-road / other-lane scan."""
    def rises(x: np.ndarray, i: int, rule) -> bool:
        ref = x[i - rule.skip] if wrap else x[max(i - rule.skip, 0)]
        return x[i] - ref > rule.threshold

    ro, rl = INFRACTION_RULES["offroad"], INFRACTION_RULES["otherlane"]
    n_off = n_other = 0
    i = 0
    while i < len(off):
        if rises(off, i, ro):
            n_off += 1
            i += ro.recount
        if i >= len(off):
            break
        if rises(other, i, rl):
            n_other += 1
            i += rl.recount
        i += 1
    return n_off, n_other


def _step(n: int, at: int, height: float) -> np.ndarray:
    x = np.zeros(n)
    x[at:] = height
    return x


# ---- single-measure scan -------------------------------------------------------------------------------------


def test_constants_match_benchmark_table() -> None:
    table = {name: (r.skip, r.recount, r.threshold) for name, r in INFRACTION_RULES.items()}
    assert table == {"offroad": (10, 20, 0.3), "otherlane": (10, 20, 0.4), "collision_other": (10, 20, 400),
                     "collision_vehicles": (10, 30, 400), "collision_pedestrians": (5, 100, 300)}


@pytest.mark.parametrize(("height", "expected"), [(401.0, 1), (399.0, 0), (400.0, 0)])
def test_collision_rise_just_above_or_below_threshold(height: float, expected: int) -> None:
    assert count_collision_events(_step(100, 40, height), VEH.skip, VEH.recount, VEH.threshold) == expected


def test_collision_rises_within_recount_count_once_and_apart_twice() -> None:
    # event at frame 40, scan resumes at 40 + 30 + 1 = 71
    near = _step(200, 40, 500.0) + _step(200, 55, 500.0)  # second rise inside the recount window
    far = _step(200, 40, 500.0) + _step(200, 90, 500.0)  # second rise after it
    assert count_collision_events(near, VEH.skip, VEH.recount, VEH.threshold) == 1
    assert count_collision_events(far, VEH.skip, VEH.recount, VEH.threshold) == 2
    # a rise whose skip window still sees it at the resume frame counts again (CARLA's behaviour)
    edge = _step(200, 40, 500.0) + _step(200, 68, 500.0)  # x[71] - x[61] = 500
    assert count_collision_events(edge, VEH.skip, VEH.recount, VEH.threshold) == 2


def test_early_frames_compare_with_first_frame_not_the_end() -> None:
    # a 1 s episode with a collision at frame 3, so every frame has i < skip and the series is high at its end:
    # x[3] - x[0] counts it, while CARLA's wrap-around compares each frame with itself (x[i - 10] = x[i])
    early = _step(10, 3, 500.0)
    assert count_collision_events(early, VEH.skip, VEH.recount, VEH.threshold) == 1
    assert _reference_collisions(early, VEH.skip, VEH.recount, VEH.threshold, wrap=True) == 0
    # high only at its end: no event at i = 1 (nor anywhere before the rise), exactly one at the rise
    late = _step(60, 50, 500.0)
    assert count_collision_events(late, VEH.skip, VEH.recount, 400.0) == 1
    assert count_collision_events(late[:50], VEH.skip, VEH.recount, 400.0) == 0
    # high at the start, low at the end (lane fractions): the wrap-around would invent an event at i = 1
    start_high = np.where(np.arange(60) < 20, 1.0, 0.0)
    assert count_collision_events(start_high, 10, 20, 0.3) == 0
    assert _reference_collisions(start_high, 10, 20, 0.3, wrap=True) == 1


def test_collision_scan_matches_reference_on_random_monotone_series() -> None:
    rng = np.random.default_rng(2017)
    for _ in range(200):
        n = int(rng.integers(0, 400))
        impulses = np.where(rng.random(n) < 0.05, rng.exponential(400.0, n), 0.0)
        x = np.cumsum(impulses)
        rule = INFRACTION_RULES[INFRACTION_TYPES[int(rng.integers(2, 5))]]
        assert count_collision_events(x, rule.skip, rule.recount, rule.threshold) == \
            _reference_collisions(x, rule.skip, rule.recount, rule.threshold)


# ---- shared off-road / other-lane scan ---------------------------------------------------------------------------


def test_lane_rise_just_above_or_below_threshold() -> None:
    zeros = np.zeros(100)
    assert count_lane_events(_step(100, 30, 0.31), zeros) == (1, 0)
    assert count_lane_events(_step(100, 30, 0.29), zeros) == (0, 0)
    assert count_lane_events(zeros, _step(100, 30, 0.41)) == (0, 1)
    assert count_lane_events(zeros, _step(100, 30, 0.39)) == (0, 0)


def test_off_road_event_moves_the_other_lane_test() -> None:
    n = 100
    off = _step(n, 30, 1.0)  # off-road event at 30 -> other-lane tested at 50
    other = _step(n, 35, 1.0)  # rises at 35 and stays: other[50] - other[40] = 0
    shared = count_lane_events(off, other)
    zeros = np.zeros(n)
    independent = (count_lane_events(off, zeros)[0], count_lane_events(zeros, other)[1])
    assert independent == (1, 1)
    assert shared == (1, 0)
    # and the other-lane test does happen at the advanced index: a rise seen there is counted
    other_at_50 = _step(n, 45, 1.0)  # other[50] - other[40] = 1
    assert count_lane_events(off, other_at_50) == (1, 1)


def test_off_road_event_near_the_end_stops_the_scan() -> None:
    off = _step(40, 30, 1.0)  # event at 30 -> i = 50 >= n: break before any other-lane test
    other = _step(40, 30, 1.0)
    assert count_lane_events(off, other) == (1, 0)


def test_lane_scan_without_wrap_around() -> None:
    # starting off-road and returning to the road is not an infraction; CARLA's wrap would count one at i = 0
    off = np.where(np.arange(80) < 15, 1.0, 0.0)
    zeros = np.zeros(80)
    assert count_lane_events(off, zeros) == (0, 0)
    assert _reference_lanes(off, zeros, wrap=True) == (1, 0)


def test_lane_scan_matches_reference_on_random_series() -> None:
    rng = np.random.default_rng(7)
    for _ in range(200):
        n = int(rng.integers(0, 300))
        off = np.clip(np.cumsum(rng.normal(0.0, 0.15, n)), 0.0, 1.0)
        other = np.clip(np.cumsum(rng.normal(0.0, 0.15, n)), 0.0, 1.0)
        assert count_lane_events(off, other) == _reference_lanes(off, other)


# ---- per episode -------------------------------------------------------------------------------------------------


def _measurements(n: int = 200) -> dict[str, np.ndarray]:
    return {"intersection_offroad": _step(n, 30, 1.0), "intersection_otherlane": _step(n, 100, 1.0),
            "collision_other": _step(n, 20, 500.0), "collision_vehicles": _step(n, 60, 500.0),
            "collision_pedestrians": _step(n, 150, 350.0)}


def test_episode_infractions_with_and_without_traffic() -> None:
    m = _measurements()
    assert episode_infractions(m, with_collisions=True) == {
        "offroad": 1, "otherlane": 1, "collision_other": 1, "collision_vehicles": 1, "collision_pedestrians": 1}
    assert episode_infractions(m, with_collisions=False) == {
        "offroad": 1, "otherlane": 1, "collision_other": 0, "collision_vehicles": 0, "collision_pedestrians": 0}
    lanes_only = {k: v for k, v in m.items() if k.startswith("intersection_")}
    assert episode_infractions(lanes_only, with_collisions=False)["offroad"] == 1
    with pytest.raises(KeyError, match="collision_other"):
        episode_infractions(lanes_only, with_collisions=True)


def test_km_driven_sums_2d_steps() -> None:
    x = np.array([0.0, 3.0, 3.0, 3.0])
    y = np.array([0.0, 4.0, 4.0, 1004.0])
    assert km_driven(x, y) == pytest.approx(1.005)
    assert km_driven(np.zeros(1), np.zeros(1)) == 0.0


# ---- aggregation over episodes -----------------------------------------------------------------------------------


def _ep(weather: int, success: bool, km: float, offroad: int = 0, **kw: int) -> EpisodeResult:
    infractions = dict.fromkeys(INFRACTION_TYPES, 0) | {"offroad": offroad} | kw
    return EpisodeResult(task=0, town="town02", weather=weather, success=success, km=km, infractions=infractions)


def test_km_between_infractions_pools_over_weathers() -> None:
    # weather 4: 1 km, 1 event; weather 14: 9 km, 3 events -> 10 / 4 = 2.5 (the mean of ratios would be 2.0)
    episodes = [_ep(4, True, 1.0, offroad=1), _ep(14, True, 4.0, offroad=2), _ep(14, False, 5.0, offroad=1)]
    result = km_between_infractions(episodes)
    assert set(result) == set(INFRACTION_TYPES)
    assert result["offroad"].value == pytest.approx(2.5)
    assert (result["offroad"].km, result["offroad"].events, result["offroad"].more_than) == (10.0, 4, False)
    assert result["offroad"].label() == "2.50"


def test_km_between_infractions_more_than_when_no_events() -> None:
    episodes = [{"weather": 4, "success": True, "km": 1.5, "infractions": {"offroad": 1}},
                {"weather": 14, "success": True, "km": 2.0, "infractions": {}}]
    result = km_between_infractions(episodes)
    assert result["collision_vehicles"].more_than
    assert (result["collision_vehicles"].events, result["collision_vehicles"].value) == (0, 3.5)
    assert result["collision_vehicles"].label(1) == "> 3.5"
    assert not result["offroad"].more_than


def test_success_rate_is_mean_over_weathers_of_per_weather_means() -> None:
    # weather 4: 3 of 3; weather 14: 0 of 1 -> (1 + 0) / 2 = 0.5, while pooling would give 0.75
    episodes = [_ep(4, True, 1.0), _ep(4, True, 1.0), _ep(4, True, 1.0), _ep(14, False, 1.0)]
    assert success_rate_over_weathers(episodes) == pytest.approx(0.5)
    as_dicts = [{"weather": e.weather, "success": e.success} for e in episodes]
    assert success_rate_over_weathers(as_dicts) == pytest.approx(0.5)
    with pytest.raises(ValueError):
        success_rate_over_weathers([])


# ---- the paper's table ---------------------------------------------------------------------------------------------


@pytest.mark.parametrize(("either", "success", "no_collision", "score"),
                         [(0.024, 1.0, 1.0, 0.99), (0.524, 0.417, 0.5, 0.46)])
def test_paper_score_checks(either: float, success: float, no_collision: float, score: float) -> None:
    assert round(paper_score(either, success, no_collision), 2) == score


def test_paper_table_row_reproduces_the_paper_checks() -> None:
    # 12 episodes x 100 steps: 629 of 1200 steps with either > 20 % (52.4 %), 5 successes (41.7 %), 6 collisions
    off, other = np.full(1200, 0.1), np.full(1200, 0.2)  # 0.2 itself is not "more than 20 %"
    off[:400], other[300:629] = 0.5, 0.9  # overlapping: Either is not Offroad + Otherlane
    episodes = [LaneKeepingEpisode(off[k * 100:(k + 1) * 100], other[k * 100:(k + 1) * 100], success=k < 5,
                                   collided=k % 2 == 0, distance_m=100.0) for k in range(12)]
    row = paper_table_row(episodes)
    assert row["either"] == pytest.approx(629 / 1200)
    assert (row["success"], row["no_collision"]) == (pytest.approx(5 / 12), 0.5)
    assert round(row["score"], 2) == 0.46
    assert (row["dist"], row["episodes"], row["steps"]) == (1200.0, 12, 1200)

    # 1000 steps, 24 with either (both off-road and other-lane on some: either is not offroad + otherlane)
    off, other = np.zeros(1000), np.zeros(1000)
    off[:16], other[10:24] = 0.25, 0.6
    row = paper_table_row([{"offroad": off[:500], "otherlane": other[:500], "success": True, "collided": False,
                            "distance_m": 80.0},
                           {"offroad": off[500:], "otherlane": other[500:], "success": True, "collided": False,
                            "distance_m": 70.5}])
    assert (row["offroad"], row["otherlane"], row["either"]) == (pytest.approx(0.016), pytest.approx(0.014),
                                                                 pytest.approx(0.024))
    assert round(row["score"], 2) == 0.99
    assert row["dist"] == 150.5


def test_paper_table_row_pools_steps_over_episodes() -> None:
    # a short bad episode and a long clean one: 10 / 110 steps, not the mean of episode shares (0.5)
    bad = LaneKeepingEpisode(np.ones(10), np.zeros(10), success=False, collided=True, distance_m=5.0)
    clean = LaneKeepingEpisode(np.zeros(100), np.zeros(100), success=True, collided=False, distance_m=50.0)
    assert paper_table_row([bad, clean])["either"] == pytest.approx(10 / 110)


# ---- Beta posteriors -----------------------------------------------------------------------------------------------


@pytest.mark.parametrize(("s", "f"), [(0, 0), (9, 0), (5, 7), (120, 3)])
def test_beta_posterior_is_jeffreys(s: int, f: int) -> None:
    ref = stats.beta(s + 0.5, f + 0.5)
    post = beta_posterior(s, f)
    grid = np.linspace(0.01, 0.99, 7)
    np.testing.assert_allclose(post.pdf(grid), ref.pdf(grid))
    summary = posterior_summary(s, f)
    assert summary["mean"] == pytest.approx((s + 0.5) / (s + f + 1.0))
    assert (summary["lo"], summary["hi"]) == (pytest.approx(ref.ppf(0.025)), pytest.approx(ref.ppf(0.975)))
    assert ref.cdf(summary["hi"]) - ref.cdf(summary["lo"]) == pytest.approx(0.95)


def test_beta_posterior_rejects_negative_counts() -> None:
    with pytest.raises(ValueError):
        beta_posterior(-1, 3)
