"""The path state option (issue 35; outside the paper): how near the nearest road user is on the path the car will
drive, from the camera alone.

The paper's 30 numbers (and the gate's six road-user shares) cannot tell a road user on the car's path from one
beside it: a logistic regression on them predicts "a road user within 8 m on the route" with a held-out ROC AUC of
about 0.90, and at Dense traffic's base rate (15 % of decisions) that error is a gate that stands or crashes
(docs/navigation-study.md, 12.9-12.10). The modular pipeline's perception and planner (`brlcli.baselines.mp`:
flat-ground bird's-eye grid of the label image, the right lane tracked row by row, a junction manoeuvre planned at
the route command's onset and dead-reckoned from the measured speed and the held control) know the path, curves
and turns included; the nearest vehicle or pedestrian cell within 1.5 m of it gives 0.96 with the planner run at
the agent's decisions. `PathView` runs that planner beside an agent, one update per decision, and gives the
nearness clip(1 - gap / NEARNESS_RANGE_M, 0, 1).

Not privileged: it reads the label image (ground truth or estimated), the measured forward speed, the route command
and the control the agent itself held since the previous decision; from the world only the camera configuration.
"""

from __future__ import annotations

import math
from types import SimpleNamespace
from typing import Any

import numpy as np

from brlcli.baselines.mp import ModularPipelinePolicy
from brlcli.features import NEARNESS_RANGE_M
from brlcli.sim.vehicle import Control
from brlcli.sim.world import FRAME_DT_S


class PathView:
    """The modular pipeline's path planner run at an agent's decisions; `update` gives the path nearness."""

    def __init__(self, frames_per_decision: int) -> None:
        self.frames_per_decision = int(frames_per_decision)
        self._mp = ModularPipelinePolicy(name="path-view")

    def reset(self, world: Any) -> None:
        """A new episode in `world` (its camera configuration is all that is read)."""
        self._mp.reset(None, world)  # type: ignore[arg-type]

    def update(self, labels: np.ndarray, speed_kmh: float, command: int, held: Control | None) -> float:
        """Path nearness at a decision: the planner advanced over the frames since the previous decision (the
        control `held` over them at the measured speed), then perception on `labels` and the path's hazard gap."""
        mp = self._mp
        speed_ms = max(float(speed_kmh), 0.0) / 3.6
        if held is not None:  # None at an episode's first decision
            mp.last_control = held
            for _ in range(self.frames_per_decision - 1):  # the decision's own frame is advanced by decide
                mp._advance_pose(speed_ms)
                if mp.entry_m is not None:
                    mp.entry_m -= speed_ms * FRAME_DT_S
        obs = SimpleNamespace(labels=labels, rgb=None, command=int(command),
                              measurements=SimpleNamespace(forward_speed_kmh=float(speed_kmh)))
        import os
        extra = os.environ.get("BRL_PATH_EXTRA")  # PROBE
        if extra == "junction":
            seen: dict = {}
            orig = mp._hazard_gap

            def rec(grid, path_car):
                seen["grid"], seen["path"] = grid, path_car
                return orig(grid, path_car)
            mp._hazard_gap = rec
            mp.decide(obs)  # type: ignore[arg-type]
            mp._hazard_gap = orig
            wide = math.inf
            if mp.manoeuvre is not None or mp.entry_m is not None:
                from brlcli.baselines import mp as mpmod
                keep = mpmod.CORRIDOR_HALF_M
                mpmod.CORRIDOR_HALF_M = 5.0
                try:
                    wide = orig(seen["grid"], seen["path"])
                finally:
                    mpmod.CORRIDOR_HALF_M = keep
            return np.array([path_nearness(mp.last_gap_m), path_nearness(wide)])
        mp.decide(obs)  # type: ignore[arg-type]
        if extra == "speed":
            return np.array([path_nearness(mp.last_gap_m), min(max(speed_kmh / 30.0, 0.0), 1.0)])
        return path_nearness(mp.last_gap_m)


def path_nearness(gap_m: float) -> float:
    """clip(1 - gap / NEARNESS_RANGE_M, 0, 1): 0 for a clear path (an infinite gap), 1 for a road user at the car."""
    if not math.isfinite(gap_m):
        return 0.0
    return float(min(max(1.0 - gap_m / NEARNESS_RANGE_M, 0.0), 1.0))
