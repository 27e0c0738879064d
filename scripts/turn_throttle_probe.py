"""Issue 35's deployment probe: `brl bench` a `fine_stop` model with its full turns driven at another throttle.

    python scripts/turn_throttle_probe.py 0.262 bench --suite nav_validation_traffic \
        --model models/brl_nav/seed_0 --workers 1 --out runs/s47/nvt_slow04_s0

The model keeps its decisions (the state it sees carries no speed); only the controls of its `right` / `left`
primitives (steering +-0.4) change to the given throttle (0.262 settles at 12 km/h, the expert's turn speed; the
action set `fine_stop_slow` trains with them). Runs in this process, so keep `--workers 1`. Outside the paper; the
results directory's setting does not say the throttle, so keep such runs apart from real ones.
"""

from __future__ import annotations

import sys

from brlcli.cli import main
from brlcli.sim import gym_env
from brlcli.sim.vehicle import Control


def patch_full_turns(throttle: float) -> None:
    """Give `fine_stop`'s full turns (steering +-0.4) the throttle `throttle`, in this process."""
    full = {abs(a.steer) for a in gym_env.ACTIONS[1:3]}
    gym_env.ACTION_SETS["fine_stop"] = tuple(
        Control(steer=a.steer, throttle=throttle) if abs(a.steer) in full and a.throttle > 0 and not a.reverse else a
        for a in gym_env.ACTION_SETS["fine_stop"])


def _usage_error(message: str) -> None:
    print(f"error: {message}", file=sys.stderr)
    sys.exit(2)


if __name__ == "__main__":
    args = sys.argv[1:]
    if len(args) < 2 or args[1] != "bench":
        _usage_error("usage: python scripts/turn_throttle_probe.py THROTTLE bench [brl bench options]")
    if "--workers" in args and args[args.index("--workers") + 1:][:1] != ["1"]:
        _usage_error("the patch holds in this process only: give --workers 1")
    try:
        value = float(args[0])
    except ValueError:
        value = -1.0
    if not 0.0 < value <= 1.0:
        _usage_error(f"throttle must be a number in (0, 1], got {args[0]!r}")
    patch_full_turns(value)
    main([*args[1:], *([] if "--workers" in args else ["--workers", "1"])])
