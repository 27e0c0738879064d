"""The paper's reward (eqs. 12-14) with every term by name."""

from __future__ import annotations

from dataclasses import dataclass

from brlcli.features import ROAD_VIEW_CATEGORIES, road_share


@dataclass(frozen=True)
class RewardParams:
    """Reward constants (paper Table 'Parameter Settings'); target speed in km/h (not given in the paper)."""

    r_collision: float = 50.0
    r_offroad: float = 40.0
    r_otherlane: float = 30.0
    r_reverse: float = 15.0
    r_slow: float = 10.0
    target_speed_kmh: float = 20.0
    road_view_weight: float = 20.0
    road_view_min: float = 0.5
    road_view: str = "road"
    """Which state entries the road view counts: "road" (Road) or "road+line" (Road and Road-line, authors' code)."""

    def __post_init__(self) -> None:
        if self.road_view not in ROAD_VIEW_CATEGORIES:
            raise ValueError(f"road_view must be one of {', '.join(ROAD_VIEW_CATEGORIES)}, got {self.road_view!r}")
        if not self.target_speed_kmh > 0:
            raise ValueError(f"target_speed_kmh must be > 0, got {self.target_speed_kmh}")


def reward_terms(collided: bool, offroad: float, otherlane: float, speed_kmh: float, state: object,
                 params: RewardParams = RewardParams()) -> dict[str, float]:
    """Named reward terms (only the first matching of collision / off-road / opposite lane / speed applies)."""
    terms = {"collision": 0.0, "offroad": 0.0, "otherlane": 0.0, "speed": 0.0, "road_view": 0.0}
    if collided:
        terms["collision"] = -params.r_collision
    elif offroad > 0:
        terms["offroad"] = -params.r_offroad * offroad
    elif otherlane > 0:
        terms["otherlane"] = -params.r_otherlane * otherlane
    else:
        vt = params.target_speed_kmh
        rel = ((speed_kmh - vt) / vt) ** 2
        if speed_kmh < 0:
            terms["speed"] = -params.r_reverse * rel
        elif speed_kmh < vt:
            terms["speed"] = -params.r_slow * rel
    road = road_share(state, ROAD_VIEW_CATEGORIES[params.road_view])  # type: ignore[arg-type]
    if road < params.road_view_min:
        terms["road_view"] = params.road_view_weight * (road - 1.0)
    terms["total"] = sum(terms.values())
    return terms


@dataclass(frozen=True)
class RouteRewardParams:
    """Route following (issue 20, outside the paper): the terms added to the paper's reward on navigation routes.

    `progress`: -r_progress * clip(1 - ds / (v_t * dt), 0, 2), ds the decision's advance along the planned route and
    v_t * dt the advance at the target speed, so driving along the route at the target speed costs nothing and
    standing still or driving away from it costs up to 2 r_progress. `wrong_turn`: -r_wrong_turn on the step the
    car gets farther than `wrong_turn_m` from the route (a wrong turn at a junction), which ends the episode.
    """

    r_progress: float = 5.0
    r_wrong_turn: float = 40.0
    wrong_turn_m: float = 6.0

    def __post_init__(self) -> None:
        if not (self.r_progress >= 0 and self.r_wrong_turn >= 0 and self.wrong_turn_m > 0):
            raise ValueError("r_progress and r_wrong_turn must be >= 0 and wrong_turn_m > 0, got "
                             f"{self.r_progress}, {self.r_wrong_turn}, {self.wrong_turn_m}")


def route_terms(progress_m: float, expected_m: float, lateral_m: float, params: RouteRewardParams) -> dict[str, float]:
    """The route-following terms of one decision: progress (ds vs. the target speed's; none expected, none owed) and
    the wrong-turn penalty (RouteRewardParams)."""
    shortfall = min(max(1.0 - progress_m / expected_m, 0.0), 2.0) if expected_m > 0 else 0.0
    wrong = abs(lateral_m) > params.wrong_turn_m
    return {"progress": -params.r_progress * shortfall, "wrong_turn": -params.r_wrong_turn if wrong else 0.0}


@dataclass(frozen=True)
class HazardRewardParams:
    """Traffic (issue 35, outside the paper): a target speed that falls to zero near a hazard on the route.

    With the privileged free distance g to the nearest road user on (or about to enter) the route ahead
    (`brlcli.sim.hazard.hazard_gap_m`), the target speed is v_h = v_t * clip((g - stop_m) / (slow_m - stop_m), 0, 1).
    Where v_h < v_t the paper's speed term is measured against v_h instead of v_t (no cost for standing at a hazard),
    driving faster than v_h costs -r_hazard * ((v - v_h) / v_t)^2, and the route's progress term expects the advance
    at v_h. The collision term is the paper's (-r_collision); a collision with a road user ends a training episode.
    """

    r_hazard: float = 20.0
    stop_m: float = 4.0
    slow_m: float = 15.0
    predict_s: float = 0.0
    """How far ahead (s) road users' positions are predicted for g (0.5 s steps): 0 = where they are now, which the
    camera can see; the expert's 2 s also counts users that will cross, which the camera state cannot show."""

    def __post_init__(self) -> None:
        if not (self.r_hazard >= 0 and 0 <= self.stop_m < self.slow_m and 0 <= self.predict_s <= 5):
            raise ValueError("r_hazard must be >= 0, 0 <= stop_m < slow_m and 0 <= predict_s <= 5, got "
                             f"{self.r_hazard}, {self.stop_m}, {self.slow_m}, {self.predict_s}")

    @property
    def predict_times_s(self) -> tuple[float, ...]:
        """The prediction times of g (s): 0, 0.5, ... up to predict_s."""
        return tuple(0.5 * k for k in range(round(self.predict_s / 0.5) + 1))

    def target_kmh(self, gap_m: float, target_speed_kmh: float) -> float:
        """The hazard-limited target speed v_h (km/h) for a free distance `gap_m` (inf: no hazard)."""
        share = min(max((gap_m - self.stop_m) / (self.slow_m - self.stop_m), 0.0), 1.0)
        return target_speed_kmh * share


def hazard_terms(speed_kmh: float, gap_m: float, terms: dict[str, float], reward: RewardParams,
                 params: HazardRewardParams) -> dict[str, float]:
    """The paper's terms with the speed term re-measured against the hazard target v_h, plus the `hazard` term
    (HazardRewardParams); `total` updated. Unchanged (hazard 0) where v_h is the paper's target speed."""
    vt = reward.target_speed_kmh
    vh = params.target_kmh(gap_m, vt)
    out = {**terms, "hazard": 0.0}
    if vh >= vt or terms["collision"] or terms["offroad"] or terms["otherlane"]:
        return out
    speed = 0.0
    if speed_kmh < 0:
        speed = -reward.r_reverse * ((speed_kmh - vh) / vt) ** 2
    elif speed_kmh < vh:
        speed = -reward.r_slow * ((speed_kmh - vh) / vt) ** 2
    else:
        out["hazard"] = -params.r_hazard * ((speed_kmh - vh) / vt) ** 2
    out["speed"] = speed
    out["total"] = sum(v for k, v in out.items() if k != "total")
    return out
