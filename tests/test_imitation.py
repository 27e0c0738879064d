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


def test_a_lone_imitation_run_drives_on_every_worker_with_the_same_records(tmp_path: Path) -> None:
    cfg = TrainConfig(**{**TINY, "imitation_episodes": 3, "traffic": ["regular", "dense"]})
    train_run(cfg, tmp_path / "one")
    train_many(cfg, [0], tmp_path / "two", workers=2)  # one seed: its drives go to two processes
    two = tmp_path / "two" / "seed_0"
    assert (two / "model.npz").read_bytes() == (tmp_path / "one" / "model.npz").read_bytes()
    for it in (0, 1):
        name = f"iterations/data_{it}.npz"
        with np.load(tmp_path / "one" / name) as x, np.load(two / name) as y:
            assert all(np.array_equal(x[k], y[k]) for k in ("states", "commands", "labels", "actions", "traffic",
                                                             "episode", "goals", "crashes"))
    assert _without_seconds(two / "iterations.csv") == _without_seconds(tmp_path / "one" / "iterations.csv")


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
    ({"imitation_stop_weight": 0.5}, r"imitation_stop_weight must be a number in \[1, 100\]"),
    ({"driver_model": "models/brl_nav_empty/seed_0", "brake_gate_steps": 10, "r_hazard": 20.0}, "no driver_model"),
])
def test_imitation_options_are_checked_in_one_line(overrides: dict, message: str) -> None:
    with pytest.raises(BrlInputError, match=message):
        TrainConfig(**{**TINY, **overrides})


def test_brl_train_imitation_from_the_cli(tmp_path: Path) -> None:
    out = tmp_path / "run"  # the navigation preset is the imitation recipe: only its budget is cut here
    cmd = [sys.executable, "-m", "brlcli", "train", "--task", "navigation", "--set", "imitation_iterations=1",
           "--set", "imitation_episodes=2", "--no-evaluate", "--out", str(out)]
    done = subprocess.run(cmd, capture_output=True, text=True)
    assert done.returncode == 0, done.stderr
    assert "imitation" in done.stdout and (out / "seed_0" / "iterations.csv").exists()
    saved = json.loads((out / "seed_0" / "config.json").read_text())["config"]
    assert (saved["learning"], saved["actions"], saved["stop_rule"], saved["decision_frames"]) == \
        ("imitation", "fine_stop", "road_user", 3)
    fine = subprocess.run([*cmd[:-2], "--set", "actions=fine", "--out", str(tmp_path / "fine")],
                          capture_output=True, text=True)  # the preset's rule needs stop: say how to drop it
    assert fine.returncode == 2 and "add --set stop_rule=any" in fine.stderr and "Traceback" not in fine.stderr
    assert not (tmp_path / "fine").exists()
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


def _stop_agent(stop_at_empty_road: bool) -> CommandAgent:
    """A mixture fitted to stop at one state (with or without a road user in view) and drive on at another."""
    rng = np.random.default_rng(1)
    road = np.zeros(30)
    road[0::5] = 1.0 / 6  # only road in every region
    seen = road.copy()
    seen[3], seen[0] = 0.05, 1.0 / 6 - 0.05  # a road user in the top-left region
    stop_state = road if stop_at_empty_road else seen
    go_state = seen if stop_at_empty_road else road
    states = np.vstack([np.repeat([stop_state], 20, 0), np.repeat([go_state], 20, 0)]) + rng.normal(0, 1e-4, (40, 30))
    labels = np.repeat([8, 0], 20)  # fine_stop: 8 is stop, 0 forward
    cfg = TrainConfig(**{**TINY, "actions": "fine_stop"})
    return fit_mixture(states, np.full(40, 2), labels, cfg, order_seed=[0])


def test_the_road_user_stop_rule_drives_on_where_nothing_is_in_view() -> None:
    from brlcli.agent.command import CommitteeAgent, RoadUserStop
    from brlcli.features import road_user_in_view

    road = np.zeros(30)
    road[0::5] = 1.0 / 6
    seen = road.copy()
    seen[3], seen[0] = 0.05, 1.0 / 6 - 0.05
    assert not road_user_in_view(road) and road_user_in_view(seen) and road_user_in_view(np.append(seen, 0.0))
    rng = np.random.default_rng(0)
    stopper = _stop_agent(stop_at_empty_road=True)
    assert stopper.act(road, 2, rng, greedy=True) == 8  # the learned values stop on an empty road ...
    ruled = RoadUserStop(stopper, 8)
    assert ruled.act(road, 2, rng, greedy=True) != 8  # ... the rule drives on
    probs = stopper.branch(2).action_probabilities(road)
    assert ruled.act(road, 2, rng, greedy=True) == int(np.argmax(probs[:8]))  # the best of the others
    braker = _stop_agent(stop_at_empty_road=False)
    assert RoadUserStop(braker, 8).act(seen, 2, rng, greedy=True) == 8  # a road user in view: it stops
    committee = RoadUserStop(CommitteeAgent([stopper, stopper]), 8)
    assert committee.act(road, 2, rng, greedy=True) != 8 and committee.n_actions == 9
    with pytest.raises(ValueError, match="greedily"):
        ruled.act(road, 2, rng)


def test_a_run_with_the_road_user_stop_rule_labels_and_benches_by_it(tmp_path: Path,
                                                                     monkeypatch: pytest.MonkeyPatch) -> None:
    from brlcli.autopilot import Autopilot
    from brlcli.policy import BRLPolicy
    from brlcli.sim.gym_env import DrivingEnv

    monkeypatch.setattr(Autopilot, "must_stop", lambda self, m: True)  # the expert wants to stand ...
    labels = {}
    for rule in ("any", "road_user"):
        env = DrivingEnv(routes="navigation", actions="fine_stop", stop_rule=rule)  # ... on an empty road
        try:
            env.reset(seed=0)
            labels[rule] = env.expert_action()
        finally:
            env.close()
    assert labels["any"] == 8 and labels["road_user"] != 8  # the rule's teacher asks for no stop it cannot see
    monkeypatch.undo()
    cfg = TrainConfig(**{**TINY, "actions": "fine_stop", "traffic": ["dense"], "stop_rule": "road_user",
                         "imitation_iterations": 0, "imitation_episodes": 2})
    train_run(cfg, tmp_path / "rule")
    policy = BRLPolicy("brl", str(tmp_path / "rule"))
    assert "stop only for road users in view" in policy.setting
    assert type(policy.agent).__name__ == "RoadUserStop"
    for overrides in ({"actions": "fine"}, {"learning": "td", "imitation_iterations": 8}, {"stop_rule": "never"}):
        with pytest.raises(BrlInputError, match="stop_rule"):
            TrainConfig(**{**TINY, "actions": "fine_stop", "stop_rule": "road_user", **overrides})


def test_a_stop_weight_makes_the_fit_stop_where_the_expert_mostly_drives() -> None:
    from brlcli.imitation import teacher_distances
    from brlcli.sim.gym_env import ACTION_SETS

    distances = teacher_distances(ACTION_SETS["fine_stop"], 3.0)
    assert list(distances[:8, 8]) == [3.0] * 8 and list(distances[8, :8]) == [1.0] * 8 and distances[8, 8] == 0
    assert np.array_equal(teacher_distances(ACTION_SETS["fine"], 3.0), teacher_distances(ACTION_SETS["fine"]))
    rng = np.random.default_rng(0)
    state = np.full(30, 1.0 / 30)
    states = state + rng.normal(0, 1e-4, size=(40, 30))
    labels = np.where(np.arange(40) % 10 < 3, 8, 0)  # the expert stands at 30 % of these visits
    acted = {}
    averaging = {"variant": "action-averaging-committee",  # the navigation preset's: Q[a, m] averages its targets
                 "params": {"init_scatter": 0.001, "new_q": "nearest", "step_size": "action-visits"}}
    for weight in (1.0, 3.0):
        cfg = TrainConfig(**{**TINY, **averaging, "actions": "fine_stop", "imitation_stop_weight": weight})
        agent = fit_mixture(states, np.full(40, 2), labels, cfg, order_seed=[0])
        acted[weight] = agent.act(state, 2, rng, greedy=True)
    assert acted == {1.0: 0, 3.0: 8}  # drives on at weight 1, stands at 3 (0.3 > 1 / (1 + 3))
