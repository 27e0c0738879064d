"""Benchmark metrics: CoRL2017 infraction events and km between them, success over weathers,
the paper's test-table row (Either / Success / No collision / Score / Dist) and Jeffreys Beta posteriors.

Definitions: docs/benchmarks.md, 'Metrics'. Event counting reproduces the CARLA 0.8 benchmark loops
(`driving_benchmark/metrics.py`) except for one documented fix: the rise at frame i is measured against
``x[max(i - skip, 0)]`` rather than the wrap-around ``x[i - skip]``.
"""

from __future__ import annotations

from collections import defaultdict
from collections.abc import Iterable, Mapping, Sequence
from dataclasses import dataclass
from types import MappingProxyType
from typing import Any

import numpy as np

# --------------------------------------------------------------------------------------------------------------
# CoRL2017 infraction events


@dataclass(frozen=True)
class InfractionRule:
    """Rise detection for one per-frame measure: an event when x[i] - x[max(i - skip, 0)] > threshold."""

    measurement: str
    """Per-frame measurement key (as in `brlcli.sim.world.Measurements`)."""
    skip: int
    """Frames back to the reference frame (frames at 10 fps)."""
    recount: int
    """Frames skipped after an event before the scan may count again (the scan resumes recount + 1 later)."""
    threshold: float
    """Rise that makes an event: footprint fraction for lane measures, summed normal impulse for collisions."""


INFRACTION_RULES: Mapping[str, InfractionRule] = MappingProxyType({
    "offroad": InfractionRule("intersection_offroad", skip=10, recount=20, threshold=0.3),
    "otherlane": InfractionRule("intersection_otherlane", skip=10, recount=20, threshold=0.4),
    "collision_other": InfractionRule("collision_other", skip=10, recount=20, threshold=400.0),
    "collision_vehicles": InfractionRule("collision_vehicles", skip=10, recount=30, threshold=400.0),
    "collision_pedestrians": InfractionRule("collision_pedestrians", skip=5, recount=100, threshold=300.0),
})
"""CoRL2017 constants per infraction type (docs/benchmarks.md, 'Metrics')."""

INFRACTION_TYPES: tuple[str, ...] = tuple(INFRACTION_RULES)
"""Infraction types in report order: offroad, otherlane, collision_other, collision_vehicles, collision_pedestrians."""

COLLISION_TYPES: tuple[str, ...] = ("collision_other", "collision_vehicles", "collision_pedestrians")
"""Infraction types counted only in tasks with traffic."""


def _series(x: Any, name: str = "x") -> np.ndarray:
    arr = np.asarray(x, dtype=np.float64)
    if arr.ndim != 1:
        raise ValueError(f"{name} must be a 1-D per-frame series, got shape {arr.shape}")
    return arr


def _rises(x: np.ndarray, skip: int, threshold: float) -> np.ndarray:
    """Boolean per frame: x[i] - x[max(i - skip, 0)] > threshold (no wrap-around for i < skip)."""
    if skip < 0:
        raise ValueError(f"skip must be >= 0, got {skip}")
    ref = np.maximum(np.arange(x.size) - skip, 0)
    return (x - x[ref]) > threshold


def count_collision_events(x: np.ndarray, skip: int, recount: int, threshold: float) -> int:
    """Events of one cumulative measure with CARLA's single-measure scan (starting at frame 1)."""
    x = _series(x)
    candidates = np.flatnonzero(_rises(x, skip, threshold))
    events, i = 0, 1
    # Between events the scan only advances by one frame, so jump straight to the next rising frame >= i.
    while (k := int(np.searchsorted(candidates, i))) < candidates.size:
        events += 1
        i = int(candidates[k]) + recount + 1
    return events


def count_lane_events(offroad: np.ndarray, otherlane: np.ndarray) -> tuple[int, int]:
    """(off-road, other-lane) events with CARLA's shared scan: an off-road event moves the other-lane test."""
    off, other = _series(offroad, "offroad"), _series(otherlane, "otherlane")
    if off.shape != other.shape:
        raise ValueError(f"offroad and otherlane differ in length: {off.size} vs {other.size}")
    off_rule, other_rule = INFRACTION_RULES["offroad"], INFRACTION_RULES["otherlane"]
    off_rise = _rises(off, off_rule.skip, off_rule.threshold)
    other_rise = _rises(other, other_rule.skip, other_rule.threshold)
    candidates = np.flatnonzero(off_rise | other_rise)
    n = off.size
    n_off = n_other = 0
    i = 0
    # Frames where neither test fires only advance i by one: jump to the next frame where one fires.
    while (k := int(np.searchsorted(candidates, i))) < candidates.size:
        i = int(candidates[k])
        if off_rise[i]:
            n_off += 1
            i += off_rule.recount
            if i >= n:
                break
        if other_rise[i]:
            n_other += 1
            i += other_rule.recount
        i += 1
    return n_off, n_other


def episode_infractions(measurements: Mapping[str, np.ndarray], with_collisions: bool) -> dict[str, int]:
    """Infraction events of one episode by type; collisions only when `with_collisions` (tasks with traffic)."""
    def series(key: str) -> np.ndarray:
        if key not in measurements:
            raise KeyError(f"episode measurements lack {key!r} (have {sorted(measurements)})")
        return _series(measurements[key], key)

    n_off, n_other = count_lane_events(series(INFRACTION_RULES["offroad"].measurement),
                                       series(INFRACTION_RULES["otherlane"].measurement))
    out = {"offroad": n_off, "otherlane": n_other}
    for name in COLLISION_TYPES:
        rule = INFRACTION_RULES[name]
        out[name] = (count_collision_events(series(rule.measurement), rule.skip, rule.recount, rule.threshold)
                     if with_collisions else 0)
    return out


def km_driven(x: np.ndarray, y: np.ndarray) -> float:
    """Distance driven in km: sum of the 2-D step lengths of a position track given in metres."""
    x, y = _series(x, "x"), _series(y, "y")
    if x.shape != y.shape:
        raise ValueError(f"x and y differ in length: {x.size} vs {y.size}")
    return float(np.hypot(np.diff(x), np.diff(y)).sum() / 1000.0)


# --------------------------------------------------------------------------------------------------------------
# CoRL2017 aggregation over episodes


@dataclass(frozen=True)
class EpisodeResult:
    """One CoRL2017 episode's outcome: where and how it ran, success, km driven and infraction events by type."""

    task: int
    """0 Straight, 1 One turn, 2 Navigation, 3 Navigation with dynamic obstacles."""
    town: str
    weather: int
    """CARLA weather id."""
    success: bool
    """Within 2.0 m of the goal before the timeout."""
    km: float
    """Distance driven, km (failed episodes count too)."""
    infractions: Mapping[str, int]
    """Events per infraction type (keys of INFRACTION_TYPES), as from `episode_infractions`."""


Episode = EpisodeResult | Mapping[str, Any]
"""An episode as an `EpisodeResult` or a plain dict with the same keys."""


def _field(episode: Episode, name: str) -> Any:
    if isinstance(episode, Mapping):
        if name not in episode:
            raise KeyError(f"episode lacks {name!r} (have {sorted(episode)})")
        return episode[name]
    return getattr(episode, name)


@dataclass(frozen=True)
class KmBetweenInfractions:
    """Pooled km per infraction event; with no events `value` is the km driven and means "more than value"."""

    km: float
    events: int
    value: float
    more_than: bool

    @classmethod
    def pooled(cls, km: float, events: int) -> KmBetweenInfractions:
        """km / events, or "more than km" when there are no events."""
        if events > 0:
            return cls(km=km, events=events, value=km / events, more_than=False)
        return cls(km=km, events=0, value=km, more_than=True)

    def label(self, digits: int = 2) -> str:
        """Text as in CARLA's summary: the value, or "> km" when no event happened."""
        return f"> {self.km:.{digits}f}" if self.more_than else f"{self.value:.{digits}f}"


def km_between_infractions(episodes: Iterable[Episode]) -> dict[str, KmBetweenInfractions]:
    """Per infraction type: sum km / sum events over all given episodes (pooled, not a mean of ratios)."""
    km, events = 0.0, dict.fromkeys(INFRACTION_TYPES, 0)
    for ep in episodes:
        km += float(_field(ep, "km"))
        infractions = _field(ep, "infractions")
        for name in INFRACTION_TYPES:
            events[name] += int(infractions.get(name, 0))
    return {name: KmBetweenInfractions.pooled(km, events[name]) for name in INFRACTION_TYPES}


def success_rate_over_weathers(episodes: Iterable[Episode]) -> float:
    """Success share per weather, then the equal-weight average over the weathers present."""
    per_weather: dict[int, list[bool]] = defaultdict(list)
    for ep in episodes:
        per_weather[int(_field(ep, "weather"))].append(bool(_field(ep, "success")))
    if not per_weather:
        raise ValueError("no episodes")
    return float(np.mean([np.mean(v) for v in per_weather.values()]))


# --------------------------------------------------------------------------------------------------------------
# The paper's lane-keeping test table (section 1)

FOOTPRINT_THRESHOLD = 0.2
"""A step counts as off-road / other-lane when more than this share (20 %) of the footprint is there."""


@dataclass(frozen=True)
class LaneKeepingEpisode:
    """One test-table episode: per-step footprint fractions, outcome and distance (metres)."""

    offroad: np.ndarray
    """Per-step fraction of the footprint off road, in [0, 1]."""
    otherlane: np.ndarray
    """Per-step fraction of the footprint in the opposite lane, in [0, 1]."""
    success: bool
    collided: bool
    distance_m: float


def paper_score(either: float, success: float, no_collision: float) -> float:
    """The paper's Score = ((1 - Either) + Success + No collision) / 3, all shares in [0, 1]."""
    return ((1.0 - either) + success + no_collision) / 3.0


def paper_table_row(episodes: Iterable[LaneKeepingEpisode | Mapping[str, Any]]) -> dict[str, float]:
    """One model's test-table row; step shares pool all steps of all episodes, episode shares all episodes.

    Keys: offroad, otherlane, either (shares of steps), success, no_collision (shares of episodes), score,
    dist (total metres), episodes, steps.
    """
    episodes = list(episodes)
    if not episodes:
        raise ValueError("no episodes")
    off_parts, other_parts = [], []
    for ep in episodes:
        off, other = _series(_field(ep, "offroad"), "offroad"), _series(_field(ep, "otherlane"), "otherlane")
        if off.shape != other.shape:
            raise ValueError(f"offroad and otherlane differ in length: {off.size} vs {other.size}")
        off_parts.append(off)
        other_parts.append(other)
    off_steps = np.concatenate(off_parts) > FOOTPRINT_THRESHOLD
    other_steps = np.concatenate(other_parts) > FOOTPRINT_THRESHOLD
    if off_steps.size == 0:
        raise ValueError("episodes have no steps")
    either = float((off_steps | other_steps).mean())
    success = float(np.mean([bool(_field(ep, "success")) for ep in episodes]))
    no_collision = float(np.mean([not bool(_field(ep, "collided")) for ep in episodes]))
    return {"offroad": float(off_steps.mean()), "otherlane": float(other_steps.mean()), "either": either,
            "success": success, "no_collision": no_collision, "score": paper_score(either, success, no_collision),
            "dist": float(sum(float(_field(ep, "distance_m")) for ep in episodes)),
            "episodes": len(episodes), "steps": int(off_steps.size)}


# --------------------------------------------------------------------------------------------------------------
# Beta posteriors (paper eq. 15)

JEFFREYS_PRIOR = 0.5
"""Both parameters of the Jeffreys prior Beta(0.5, 0.5)."""


def beta_posterior(successes: int, failures: int) -> Any:
    """Posterior Beta(s + 0.5, f + 0.5) of a rate after s successes and f failures (a frozen scipy.stats.beta)."""
    if successes < 0 or failures < 0:
        raise ValueError(f"counts must be >= 0, got successes={successes}, failures={failures}")
    from scipy import stats  # imported here: scipy.stats takes about a second to import, and only reports need it

    return stats.beta(successes + JEFFREYS_PRIOR, failures + JEFFREYS_PRIOR)


def posterior_summary(successes: int, failures: int, level: float = 0.95) -> dict[str, float]:
    """Posterior mean and equal-tailed credible interval (lo, hi) at `level` (95 % by default)."""
    if not 0.0 < level < 1.0:
        raise ValueError(f"level must be in (0, 1), got {level}")
    post = beta_posterior(successes, failures)
    tail = (1.0 - level) / 2.0
    return {"mean": float(post.mean()), "lo": float(post.ppf(tail)), "hi": float(post.ppf(1.0 - tail))}


@dataclass(frozen=True)
class ModelStats:
    """One model's test-table row from its episodes (step shares pooled over all its steps)."""

    setting: str
    policy: str
    episodes: int
    steps: int
    offroad: float
    otherlane: float
    either: float
    success: float
    no_collision: float
    score: float
    dist_m: float
    successes: int
    collision_free: int


def model_stats(setting: str, policy: str, episodes: Sequence[dict[str, Any]]) -> ModelStats:
    """Offroad / Otherlane / Either from the *_steps counts pooled over the episodes; Success, No collision and
    Score (metrics.paper_score) over episodes; Dist = sum of km * 1000."""
    steps = sum(int(ep["steps"]) for ep in episodes)
    n = len(episodes)
    successes = sum(bool(ep["success"]) for ep in episodes)
    collision_free = sum(not bool(ep["collided"]) for ep in episodes)

    def share(key: str) -> float:
        return sum(int(ep[key]) for ep in episodes) / steps if steps else float("nan")

    either = share("either_steps")
    success, no_collision = successes / n, collision_free / n
    return ModelStats(setting=setting, policy=policy, episodes=n, steps=steps, offroad=share("offroad_steps"),
                      otherlane=share("otherlane_steps"), either=either, success=success, no_collision=no_collision,
                      score=paper_score(either, success, no_collision),
                      dist_m=sum(float(ep["km"]) for ep in episodes) * 1000.0, successes=successes,
                      collision_free=collision_free)
