"""The state error where it matters: GT-trained BRL models driving on a segmentation net's labels.

At every decision of each model (greedy, on the estimated state) this records the L1 distance between the states
of the ground-truth and the estimated labels, the per-category bias, and whether the greedy action on the estimated
state equals the one on the GT state, on the road and off it (more than 20 % of the footprint off the road):

    python scripts/deploy_state_error.py --segnet models/segnet.pt --suite validation \\
        models/brl_gt/seed_0 models/brl_gt/seed_3

One line per model. Runs the bench's episodes in this process (no results directory is written).
"""

from __future__ import annotations

import argparse
from pathlib import Path

import numpy as np

from brlcli.bench.runner import run_episode, world_for
from brlcli.bench.suites import build_suite
from brlcli.features import state_vector
from brlcli.policy import BRLPolicy, Observation
from brlcli.segnet.infer import load_segmenter
from brlcli.sim.gym_env import ACTIONS
from brlcli.sim.vehicle import Control


def main() -> None:
    """Drive each model through the suite on estimated labels and print its state-error line."""
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("models", nargs="+", help="BRL run directories or model.npz files (GT-trained)")
    ap.add_argument("--segnet", default=None)
    ap.add_argument("--suite", default="validation", help="validation (for choosing) or paper")
    args = ap.parse_args()
    seg = load_segmenter(args.segnet)
    specs = build_suite(args.suite)
    worlds: dict = {}
    for model in args.models:
        path = Path(model) / "model.npz" if Path(model).is_dir() else Path(model)
        pol = BRLPolicy(path.parent.name, str(path), deploy="gt")
        l1: list = []
        bias: list = []
        agree: list = []
        off: list = []

        def decide(obs: Observation, pol: BRLPolicy = pol, l1: list = l1, bias: list = bias,
                   agree: list = agree, off: list = off) -> Control:
            gt, est = state_vector(obs.labels), state_vector(seg.predict(obs.rgb))
            action_gt, action_est = int(pol.act(gt)), int(pol.act(est))
            l1.append(np.abs(gt - est).sum())
            bias.append((est - gt).reshape(6, 5).sum(0))
            agree.append(action_gt == action_est)
            off.append(obs.measurements.intersection_offroad > 0.2)
            return ACTIONS[action_est]

        pol.decide = decide  # type: ignore[method-assign]
        success = [run_episode(world_for(worlds, spec, pol), spec, pol, 0)[0]["success"] for spec in specs]
        a, o = np.array(agree), np.array(off)
        print(f"{model}: success {np.mean(success):.3f}, {len(a)} decisions, state L1 {np.mean(l1):.4f} "
              f"(p95 {np.quantile(l1, 0.95):.3f}), bias road/line/off/dyn/static {np.round(np.mean(bias, 0), 4)}, "
              f"same action {a.mean():.3f} (on the road {a[~o].mean():.3f}, off it "
              f"{a[o].mean() if o.any() else float('nan'):.3f}; off the road {o.mean():.2f})", flush=True)
    for world in worlds.values():
        world.close()


if __name__ == "__main__":
    main()
