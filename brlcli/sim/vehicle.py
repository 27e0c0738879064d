"""The ego car's vehicle model: a kinematic bicycle with first-order longitudinal dynamics.

Longitudinal (forward speed v, m/s, negative when reversing; `g` = +1 forward gear, -1 reverse):
    a = g * ACCEL_MAX * throttle - DRAG_LINEAR * v - DRAG_QUAD * v|v| - ROLLING * sign(v) - BRAKE_MAX * brake * sign(v)
Rolling resistance and brake never reverse the direction of motion within a sub-step.
Calibration (steady state, measured with `advance` at 0.05 s steps): throttle 0.5 settles at 23.1 km/h, throttle
0.35 (the paper's turn primitive) at 16.2 km/h, throttle 0.4 in reverse at -18.6 km/h.

Lateral: the steering angle follows the command with a first-order lag `STEER_TAU_S` up to `MAX_STEER_DEG`
(steer 0.4 -> 18 degrees -> turning radius WHEELBASE_M / tan(18 deg) = 8.9 m, tighter than the inner lane of
a town corner, 18 m); yaw rate = v tan(delta) / WHEELBASE_M.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

LENGTH_M = 4.5
WIDTH_M = 2.0
HEIGHT_M = 1.5
WHEELBASE_M = 2.9
MASS_KG = 1500.0
MAX_STEER_DEG = 45.0
STEER_TAU_S = 0.15
ACCEL_MAX = 4.0  # m/s^2 at full throttle
DRAG_LINEAR = 0.25  # 1/s
DRAG_QUAD = 0.006  # 1/m
ROLLING = 0.15  # m/s^2
BRAKE_MAX = 8.0  # m/s^2 at full brake


@dataclass(frozen=True)
class Control:
    """Driver controls: steer [-1, 1] (+ right), throttle [0, 1], brake [0, 1], reverse gear."""

    steer: float = 0.0
    throttle: float = 0.0
    brake: float = 0.0
    reverse: bool = False

    def clipped(self) -> Control:
        """The same control with every value clipped to its range (NaN counts as 0)."""

        def clip(v: float, lo: float, hi: float) -> float:
            return 0.0 if not math.isfinite(v) else min(max(float(v), lo), hi)

        return Control(clip(self.steer, -1, 1), clip(self.throttle, 0, 1), clip(self.brake, 0, 1), bool(self.reverse))


@dataclass
class VehicleState:
    """Planar state of a car: position (m), yaw (rad, counter-clockwise from +x), speed (m/s), steering (rad)."""

    x_m: float = 0.0
    y_m: float = 0.0
    yaw_rad: float = 0.0
    speed_ms: float = 0.0
    steer_rad: float = 0.0


def longitudinal_accel(speed_ms: float, control: Control) -> float:
    """Acceleration (m/s^2) from the throttle, drag and rolling resistance (brake handled in `advance`)."""
    gear = -1.0 if control.reverse else 1.0
    a = gear * ACCEL_MAX * control.throttle - DRAG_LINEAR * speed_ms - DRAG_QUAD * speed_ms * abs(speed_ms)
    return a


def advance(state: VehicleState, control: Control, dt_s: float) -> tuple[float, float]:
    """Integrate speed and steering over `dt_s`; returns the commanded (speed m/s, yaw rate rad/s)."""
    target = -control.steer * math.radians(MAX_STEER_DEG)  # + steer is to the right (clockwise)
    state.steer_rad += (target - state.steer_rad) * min(1.0, dt_s / STEER_TAU_S)
    v = state.speed_ms + longitudinal_accel(state.speed_ms, control) * dt_s
    # rolling resistance and brake only slow the car down, never push it backwards
    slow = (ROLLING + BRAKE_MAX * control.brake) * dt_s
    if abs(v) <= slow and (control.throttle == 0.0 or control.brake > 0.0):
        v = 0.0
    elif abs(v) > slow:
        v -= math.copysign(slow, v)
    state.speed_ms = v
    yaw_rate = v * math.tan(state.steer_rad) / WHEELBASE_M
    return v, yaw_rate
