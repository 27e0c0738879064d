"""Imitation in the agent's own mixture (`--set learning=imitation`): the fit, the run's files, resume, the gate over
it, and its options' errors."""

import csv
import json
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest

from brlcli.agent.command import CommandAgent
from brlcli.errors import BrlInputError
from brlcli.imitation import fit_mixture
from brlcli.sim.gym_env import ACTION_SET_NAMES
from brlcli.train import train_many, train_run
from brlcli.trainconfig import TrainConfig

TINY = {"task": "navigation", "learning": "imitation", "actions": "fine", "traffic": ["regular"], "committee": 1,
        "imitation_iterations": 1, "imitation_episodes": 2, "evaluate": False}


def _without_seconds(path: Path) -> list[list[str]]:
    return [[v for k, v in r.items() if k != "wall_s"] for r in csv.DictReader(open(path))]


def test_the_fitted_mixture_takes_the_labelled_action_at_the_recorded_states() -> None:
    rng = np.random.default_rng(0)
    centres = rng.uniform(0.2, 0.8, size=(3, 30))
    states = np.repeat(centres, 20, axis=0) + rng.normal(0, 0.002, size=(60, 30))
    labels = np.repeat([0, 3, 6], 20)
    commands = np.full(60, 2)  # lane follow
    agent = fit_mixture(states, commands, labels, TrainConfig(**TINY), order_seed=[0])
    acted = [agent.act(c, 2, np.random.default_rng(0), greedy=True) for c in centres]
    assert acted == [0, 3, 6]
    again = fit_mixture(states, commands, labels, TrainConfig(**TINY), order_seed=[0])
    assert all(np.array_equal(agent.to_arrays()[k], v) for k, v in again.to_arrays().items())


def test_an_imitation_run_writes_its_iterations_and_resumes_bit_identical(tmp_path: Path) -> None:
    cfg = TrainConfig(**TINY)
    train_run(cfg, tmp_path / "a")
    run = tmp_path / "a"
    rows = list(csv.DictReader(open(run / "iterations.csv")))
    assert [r["driver"] for r in rows] == ["expert", "mixture"] and rows[0]["agreement"] == ""
    assert 0.0 <= float(rows[1]["agreement"]) <= 1.0 and int(rows[1]["data"]) > int(rows[0]["data"])
    with np.load(run / "iterations" / "data_1.npz", allow_pickle=False) as z:
        assert z["states"].shape[1] == 30 and set(z["traffic"]) == {"regular"} and len(z["labels"]) == len(z["actions"])
        assert set(z["labels"]) <= set(range(len(ACTION_SET_NAMES["fine"])))
    summary = json.loads((run / "summary.json").read_text())
    assert summary["summary"]["learning"] == "imitation" and summary["config"]["learning"] == "imitation"
    assert (run / "model.npz").read_bytes() == (run / "iterations" / "model_1.npz").read_bytes()
    # interrupted while the last iteration was fitted: its data is there, its model is not
    (run / "iterations" / "model_1.npz").unlink()
    (run / "summary.json").unlink()
    (run / "model.npz").unlink()
    train_run(cfg, run, resume=True)
    train_run(cfg, tmp_path / "b")
    for name in ("model.npz", "iterations.csv", "iterations/data_0.npz", "iterations/data_1.npz"):
        if name == "iterations.csv":  # seconds differ; everything else is the same
            assert _without_seconds(run / name) == _without_seconds(tmp_path / "b" / name)
        elif name.startswith("iterations/data"):
            with np.load(run / name) as x, np.load(tmp_path / "b" / name) as y:
                assert all(np.array_equal(x[k], y[k]) for k in ("states", "labels", "actions", "episode"))
        else:
            assert (run / name).read_bytes() == (tmp_path / "b" / name).read_bytes()
    other = TrainConfig(**{**TINY, "seed": 1})
    train_run(other, tmp_path / "c")
    assert (tmp_path / "c" / "model.npz").read_bytes() != (run / "model.npz").read_bytes()


def test_a_brake_gate_learns_over_an_imitating_driver_in_traffic(tmp_path: Path) -> None:
    from brlcli.agent.gate import BrakeGatedAgent

    cfg = TrainConfig(**{**TINY, "brake_gate_steps": 30, "r_hazard": 20.0, "traffic": ["dense"]})
    train_many(cfg, [0], tmp_path / "gated")
    seed = tmp_path / "gated" / "seed_0"
    driver_cfg = json.loads((seed / "driver" / "config.json").read_text())["config"]
    assert driver_cfg["learning"] == "imitation" and driver_cfg["traffic"] == ["dense"] and driver_cfg["r_hazard"] == 0
    gate_cfg = json.loads((seed / "gate" / "config.json").read_text())["config"]
    assert gate_cfg["learning"] == "td" and gate_cfg["steps"] == 30
    assert isinstance(CommandAgent.load(seed / "driver" / "model.npz"), CommandAgent)
    assert BrakeGatedAgent.load(seed / "model.npz").n_actions == 9
    summary = json.loads((seed / "summary.json").read_text())["summary"]
    assert summary["driver"]["learning"] == "imitation"
    from brlcli.cli.train import train_summary_line

    assert "one driver that imitates the expert" in train_summary_line(summary)


@pytest.mark.parametrize("overrides, message", [
    ({"learning": "dagger"}, "unknown learning 'dagger'; choose one of td, imitation"),
    ({"task": "lane-keeping", "actions": "paper", "traffic": []}, "needs --task navigation"),
    ({"imitation_episodes": 0}, "imitation_episodes must be an integer >= 1"),
    ({"imitation_iterations": 1.5}, "imitation_iterations must be an integer >= 0"),
    ({"curve_every": 100}, "drop curve_every"),
    ({"privileged_brake_m": 8.0}, "drop privileged_brake_m"),
    ({"imitation_rho": 0.0}, "imitation_rho must be a distance in"),
    ({"driver_model": "models/brl_nav/seed_0", "brake_gate_steps": 10, "r_hazard": 20.0}, "no driver_model"),
])
def test_imitation_options_are_checked_in_one_line(overrides: dict, message: str) -> None:
    with pytest.raises(BrlInputError, match=message):
        TrainConfig(**{**TINY, **overrides})


def test_brl_train_imitation_from_the_cli(tmp_path: Path) -> None:
    out = tmp_path / "run"
    cmd = [sys.executable, "-m", "brlcli", "train", "--task", "navigation", "--set", "learning=imitation",
           "--set", "committee=1", "--set", "imitation_iterations=1", "--set", "imitation_episodes=2",
           "--set", "actions=fine", "--no-evaluate", "--out", str(out)]
    done = subprocess.run(cmd, capture_output=True, text=True)
    assert done.returncode == 0, done.stderr
    assert "imitation" in done.stdout and (out / "seed_0" / "iterations.csv").exists()
    bad = subprocess.run([*cmd[:-2], "--set", "imitation_episodes=0", "--out", str(tmp_path / "bad")],
                         capture_output=True, text=True)
    assert bad.returncode == 2 and "imitation_episodes must be" in bad.stderr + bad.stdout
    assert "Traceback" not in bad.stderr and not (tmp_path / "bad").exists()


def test_a_model_trained_at_another_decision_rate_benches_at_it(tmp_path: Path) -> None:
    from brlcli.policy import BRLPolicy
    from brlcli.sim.gym_env import DrivingEnv
    from brlcli.sim.world import FRAME_DT_S

    env = DrivingEnv(routes="navigation", decision_frames=3)
    try:
        env.reset(seed=0)
        first, second = (env.step(1)[4]["measurements"]["game_time_s"] for _ in range(2))
        assert second - first == pytest.approx(3 * FRAME_DT_S, abs=1e-9)
    finally:
        env.close()
    cfg = TrainConfig(**{**TINY, "imitation_iterations": 0, "decision_frames": 3})
    train_run(cfg, tmp_path / "f3")
    policy = BRLPolicy("brl", str(tmp_path / "f3"))
    assert policy.frames_per_decision == 3 and "a decision every 3 frames" in policy.setting
    assert "imitation" in policy.setting
    with pytest.raises(BrlInputError, match=r"decision_frames must be an integer in 1\.\.20"):
        TrainConfig(decision_frames=0)
    with pytest.raises(BrlInputError, match=r"decision_frames must be an integer in 1\.\.20"):
        DrivingEnv(decision_frames=True)
