"""Navigation (issue 20): planner routes, route commands and the route-following reward, the command-conditioned
agent, its training, its model file and the bench's task checks."""

import json
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest

from brlcli.agent import BayesianAgent
from brlcli.agent.command import CommandAgent, is_command_model
from brlcli.bench.suites import build_suite
from brlcli.config import Layer
from brlcli.errors import BrlInputError
from brlcli.reward import RouteRewardParams, route_terms
from brlcli.sim.gym_env import DrivingEnv
from brlcli.sim.navroutes import JUNCTION_KINDS, junction_routes, validation_routes
from brlcli.sim.roadnet import Command, RoadNetwork
from brlcli.sim.town import load_town
from brlcli.train import LOG_COLUMNS, train_run
from brlcli.trainconfig import NAVIGATION_TD_RECIPE, TrainConfig, resolve_train_config, set_options

TD_NAVIGATION = {**NAVIGATION_TD_RECIPE, "committee": 1}
"""The empty-road TD recipe of models/brl_nav_empty, one agent per seed (a committee costs 7x the test's time)."""
TD_NAVIGATION_SETS = set_options(TD_NAVIGATION)


@pytest.fixture(scope="module")
def net01() -> RoadNetwork:
    return RoadNetwork(load_town("town01"))


def test_junction_routes_take_exactly_their_turn(net01: RoadNetwork) -> None:
    routes = junction_routes(net01)
    connectors = [p for p in net01.paths if p.kind == "connector"]
    assert len(routes) == 2 * len(connectors) and {r.kind for r in routes} == set(JUNCTION_KINDS)
    expected = {"turn_left": Command.TURN_LEFT, "turn_right": Command.TURN_RIGHT, "go_straight": Command.GO_STRAIGHT}
    for r in routes[::7]:
        route = net01.route(r.start, r.goal)
        assert [cmd for _a, _b, cmd in route.commands] == [expected[r.kind]], r.name


def test_validation_routes_are_seeded_multi_junction_routes(net01: RoadNetwork) -> None:
    a, b = validation_routes(net01, 5), validation_routes(net01, 5)
    assert a == b and len(a) == 5
    assert validation_routes(net01, 5, seed=1) != a
    for r in a:
        route = net01.route(r.start, r.goal)
        assert 150 <= route.length_m <= 500 and len(route.commands) >= 2
    specs = build_suite("nav_validation")
    assert len(specs) == 16 and {s.town for s in specs} == {"town01", "town02"}
    with pytest.raises(BrlInputError, match="unknown task"):
        build_suite("nav_validation", tasks="straight")


def test_route_terms() -> None:
    p = RouteRewardParams()
    assert route_terms(3.9, 3.9, 0.5, p) == {"progress": 0.0, "wrong_turn": 0.0}
    assert route_terms(0.0, 3.9, 0.5, p)["progress"] == -p.r_progress
    assert route_terms(-10.0, 3.9, 0.5, p)["progress"] == -2 * p.r_progress  # capped
    assert route_terms(3.9, 3.9, -6.5, p)["wrong_turn"] == -p.r_wrong_turn
    with pytest.raises(ValueError):
        RouteRewardParams(wrong_turn_m=0.0)
    with pytest.raises(ValueError):
        RouteRewardParams(r_progress=-1.0)


def test_going_straight_on_a_right_turn_is_a_wrong_turn_that_ends_the_episode() -> None:
    env = DrivingEnv(routes="navigation", kinds=("turn_right",), route_reward=RouteRewardParams())
    try:
        _obs, info = env.reset(seed=0, options={"route": env.routes[0].name})
        commands = [info["command"]]
        for _ in range(60):
            _obs, reward, terminated, truncated, info = env.step(0)  # forward only
            commands.append(info["command"])
            if terminated or truncated:
                break
        assert truncated and not terminated and info["wrong_turn"]
        assert info["reward_terms"]["wrong_turn"] == -RouteRewardParams().r_wrong_turn
        assert reward <= -RouteRewardParams().r_wrong_turn
        assert commands[0] == Command.LANE_FOLLOW and Command.TURN_RIGHT in commands
    finally:
        env.close()


def test_command_agent_learns_only_in_the_commanded_branch(tmp_path: Path) -> None:
    agent = CommandAgent()
    rng = np.random.default_rng(0)
    s = rng.dirichlet(np.ones(30))
    left = int(Command.TURN_LEFT)
    for _ in range(5):
        agent.learn(s, 1, -20.0, s, left, left)
    steps = [b.steps for b in agent.branches]
    assert steps == [0, 5, 0, 0] and agent.branch(left) is agent.branches[1]
    assert agent.branch_of(int(Command.REACH_GOAL)) == 0  # drives as follow lane
    assert agent.act(s, left, rng, greedy=True) == agent.branches[1].act(s, rng, greedy=True)
    path = tmp_path / "model.npz"
    agent.save(path)
    back = CommandAgent.load(path)
    assert is_command_model(path)
    for mine, theirs in zip(agent.branches, back.branches, strict=True):
        assert np.array_equal(mine.Q, theirs.Q) and np.array_equal(mine.means, theirs.means)
        assert mine.steps == theirs.steps and mine.tau == theirs.tau
    with pytest.raises(BrlInputError, match="lacks the entry"):
        BayesianAgent.load(path)
    lane = tmp_path / "lane.npz"
    BayesianAgent().save(lane)
    assert not is_command_model(lane)
    with pytest.raises(BrlInputError, match="lane-keeping model"):
        CommandAgent.load(lane)


def test_navigation_training_is_reproducible_and_logs_commands(tmp_path: Path) -> None:
    """(Resume after a kill: tests/test_train.py's resume test, navigation case.)"""
    cfg = TrainConfig(task="navigation", steps=150, seed=2, evaluate=False)
    assert cfg.route_kinds == ("straight", "right_curve", "left_curve", *JUNCTION_KINDS)
    train_run(cfg, tmp_path / "full")
    train_run(cfg, tmp_path / "again")
    never = TrainConfig(task="navigation", steps=150, seed=2, evaluate=False, branch_restart_below=[-1e9] * 4)
    train_run(never, tmp_path / "never")  # a per-branch trap test that never fires changes nothing
    for name in ("log.csv", "model.npz"):
        assert (tmp_path / "again" / name).read_bytes() == (tmp_path / "full" / name).read_bytes()
        assert (tmp_path / "never" / name).read_bytes() == (tmp_path / "full" / name).read_bytes()
    saved = json.loads((tmp_path / "full" / "config.json").read_text())["config"]
    assert saved["task"] == "navigation"
    lines = (tmp_path / "full" / "log.csv").read_text().splitlines()
    header = lines[0].split(",")
    assert header == list(LOG_COLUMNS)
    commands = {int(line.split(",")[header.index("command")]) for line in lines[1:]}
    assert commands <= {0, 2, 3, 4, 5} and commands & {3, 4, 5}
    summary = json.loads((tmp_path / "full" / "summary.json").read_text())["summary"]
    assert sum(summary["components_per_branch"].values()) == summary["components"]
    assert is_command_model(tmp_path / "full" / "model.npz")


def test_task_choices_are_checked() -> None:
    with pytest.raises(BrlInputError, match="unknown task"):
        TrainConfig(task="racing")
    with pytest.raises(BrlInputError, match="not navigation routes"):
        TrainConfig(task="navigation", route_kinds=("roundabout",))
    with pytest.raises(BrlInputError, match="not lane-keeping routes"):
        TrainConfig(route_kinds=("turn_left",))
    with pytest.raises(BrlInputError, match="four thresholds"):
        TrainConfig(branch_restart_below=[-5.0] * 4)
    with pytest.raises(BrlInputError, match="four thresholds"):
        TrainConfig(task="navigation", branch_restart_below=[-5.0])


def _cli(*args: str) -> subprocess.CompletedProcess:
    return subprocess.run([sys.executable, "-m", "brlcli.cli", *args], capture_output=True, text=True, timeout=300)


def test_bench_refuses_a_navigation_model_on_a_suite_without_commands(tmp_path: Path, brl_in_process) -> None:
    r = _cli("train", "--task", "navigation", *TD_NAVIGATION_SETS, "--steps", "40", "--no-evaluate",
             "--out", str(tmp_path / "m"))
    assert r.returncode == 0, r.stderr
    model = tmp_path / "m" / "seed_0"
    for suite in ("paper", "validation"):
        r = brl_in_process("bench", "--suite", suite, "--model", str(model), "--out", str(tmp_path / suite))
        assert r.returncode == 2 and r.stderr.strip().count("\n") == 0 and "navigation" in r.stderr, r.stderr
        assert not (tmp_path / suite).exists()
    r = _cli("bench", "--suite", "nav_validation", "--model", str(model), "--episodes", "2",
             "--out", str(tmp_path / "nv"))
    assert r.returncode == 0, r.stderr
    rows = [json.loads(line) for line in (tmp_path / "nv" / "results.jsonl").read_text().splitlines()]
    assert len(rows) == 2 and all("navigation" in row["setting"] for row in rows)


def test_a_command_change_bootstraps_from_the_next_branch() -> None:
    rng = np.random.default_rng(1)
    s, s_next = rng.dirichlet(np.ones(30)), rng.dirichlet(np.ones(30))
    follow, left = int(Command.LANE_FOLLOW), int(Command.TURN_LEFT)
    agent = CommandAgent()
    for _ in range(3):  # the follow branch learns that every action is bad at s_next
        for action in range(4):
            agent.learn(s_next, action, -30.0, s_next, follow, follow)
    v_follow, v_left = agent.branches[0].value(s_next), agent.branches[1].value(s_next)
    assert v_follow < v_left
    import copy

    same = copy.deepcopy(agent)
    changed = agent.learn(s, 2, -1.0, s_next, left, follow)  # the next decision is the follow branch's
    kept = same.learn(s, 2, -1.0, s_next, left, left)  # no command change: the branch's own value
    gamma = agent.branches[1].params.gamma
    assert changed.td_error - kept.td_error == pytest.approx(gamma * (v_follow - v_left))


def test_suite_task_check_applies_to_any_policy_with_a_task() -> None:
    from brlcli.bench.registry import check_suite_task

    class NavPolicy:
        name = "dqn/nav"
        task = "navigation"

    with pytest.raises(BrlInputError, match="without commands"):
        check_suite_task("validation", NavPolicy())
    check_suite_task("corl2017", NavPolicy())
    check_suite_task("paper", object())  # a policy without a task drives lanes


def test_the_bench_replans_a_route_the_car_has_left_as_carlas_planner_does(net01: RoadNetwork) -> None:
    from brlcli.sim.roadnet import Navigator

    routes = junction_routes(net01)
    right = next(r for r in routes if r.kind == "turn_right")
    straight = next(r for r in routes if r.kind == "go_straight" and r.start == right.start)
    nav = Navigator(net01, right.start, right.goal)
    assert nav.command(*right.start) == Command.LANE_FOLLOW and nav.replans == 0  # on its route: no new plan
    inside = next(p for p in net01.paths if p.kind == "connector" and p.command == Command.GO_STRAIGHT)
    assert nav.command(*inside.pose_at(inside.length_m / 2)) is not None and nav.replans == 0  # in a junction: keep
    missed = straight.goal  # went straight where the route turns right: 30 m into the wrong road
    assert abs(nav.route.project(*missed[:2])[1]) > 6.0
    nav.command(*missed)
    assert nav.replans == 1
    assert abs(nav.route.project(*missed[:2])[1]) < 0.5  # the new route starts where the car is ...
    assert np.hypot(*(np.array(nav.route.goal) - right.goal[:2])) < 1.0  # ... and still ends at the goal
    assert len(nav.route.commands) >= 1  # and it has to turn somewhere to get back


def test_the_junction_route_mix_is_configurable() -> None:
    env = DrivingEnv(routes="navigation", kinds=("straight", "turn_left"), junction_weight=4.0,
                     junction_approaches_m=(25.0,))
    try:
        assert {r.name.rsplit("_", 1)[1] for r in env.routes if r.kind == "turn_left"} == {"25"}
        assert np.allclose(np.diff(np.concatenate([[0.0], env._kind_cdf])), [0.2, 0.8])
    finally:
        env.close()
    with pytest.raises(BrlInputError, match="junction_weight must be > 0"):
        TrainConfig(task="navigation", junction_weight=0.0)


def test_majority_vote_takes_the_most_chosen_action_and_breaks_ties_by_mean_probability() -> None:
    from brlcli.agent.command import majority_vote

    probs = np.array([[0.1, 0.6, 0.2, 0.1], [0.2, 0.5, 0.2, 0.1], [0.9, 0.0, 0.05, 0.05]])
    assert majority_vote(probs) == 1  # two of three choose right, though forward has the largest single p
    tie = np.array([[0.7, 0.1, 0.1, 0.1], [0.1, 0.2, 0.6, 0.1], [0.1, 0.1, 0.1, 0.7]])
    assert majority_vote(tie) == 0  # one vote each: the highest mean p(a|s) among the tied actions
    assert majority_vote(np.array([[0.25] * 4] * 2)) == 0


def test_a_committee_trains_its_members_apart_and_drives_by_vote(tmp_path: Path) -> None:
    from brlcli.agent.command import CommitteeAgent, load_navigation_agent
    from brlcli.policy import BRLPolicy

    cfg = TrainConfig(task="navigation", steps=120, seed=2, evaluate=False, committee=2)
    summary = train_run(cfg, tmp_path / "com")["summary"]
    assert summary["committee"] == 2 and summary["steps"] == 240 and len(summary["members"]) == 2
    train_run(TrainConfig(task="navigation", steps=120, seed=2, evaluate=False), tmp_path / "plain")
    logs = [(tmp_path / d / "log.csv").read_bytes() for d in ("com/member_0", "plain", "com/member_1")]
    assert logs[0] == logs[1] and logs[2] != logs[0]  # member 0 is the seed's own run, member 1 another
    agent = load_navigation_agent(tmp_path / "com" / "model.npz")
    assert isinstance(agent, CommitteeAgent) and len(agent.members) == 2
    members = [CommandAgent.load(tmp_path / "com" / f"member_{k}" / "model.npz") for k in range(2)]
    rng = np.random.default_rng(0)
    policy = BRLPolicy("brl", str(tmp_path / "com" / "model.npz"))
    for s, c in zip(rng.dirichlet(np.ones(30), size=30), rng.choice([2, 3, 4, 5], size=30), strict=True):
        probs = np.array([m.branch(int(c)).action_probabilities(s) for m in members])
        expected = probs.argmax(1)[0] if probs.argmax(1)[0] == probs.argmax(1)[1] else int(probs.mean(0).argmax())
        assert policy.act(s, int(c)) == expected
    with pytest.raises(ValueError, match="greedily"):
        agent.act(np.full(30, 1 / 30), 2, rng)
    with pytest.raises(BrlInputError, match="committee"):
        TrainConfig(committee=2, curve_every=100)
    with pytest.raises(BrlInputError, match="committee"):
        TrainConfig(task="navigation", committee=0)
    with pytest.raises(BrlInputError, match="not a command-conditioned one"):  # a single agent's loader refuses it
        CommandAgent.load(tmp_path / "com" / "model.npz")


def test_a_braking_model_trains_in_traffic_and_its_options_are_checked_at_bench(tmp_path: Path) -> None:
    import csv
    import json

    from brlcli.policy import BRLPolicy

    cfg = TrainConfig(task="navigation", steps=150, seed=0, evaluate=False, actions="stop", traffic=["regular"],
                      r_hazard=20.0, state="nearness")
    train_run(cfg, tmp_path / "stop")
    rows = list(csv.DictReader(open(tmp_path / "stop" / "log.csv")))
    assert {"r_hazard", "hazard_gap_m", "crashed", "traffic"} <= set(rows[0]) and rows[0]["traffic"] == "regular"
    assert "stop" in {r["action"] for r in rows}
    model = str(tmp_path / "stop" / "model.npz")
    policy = BRLPolicy("brl", model)
    assert len(policy.actions) == 5 and "stop primitive" in policy.setting and policy.needs_depth
    config_file = tmp_path / "stop" / "config.json"
    saved = json.loads(config_file.read_text())
    saved["config"]["state"] = "paper"  # a state option the model was not trained with
    config_file.write_text(json.dumps(saved))
    with pytest.raises(BrlInputError, match="state size 33 and 5 actions"):
        BRLPolicy("brl", model)
    train_run(TrainConfig(task="navigation", steps=60, seed=0, evaluate=False), tmp_path / "plain")
    assert "no brake" in BRLPolicy("brl", str(tmp_path / "plain" / "model.npz")).setting


def test_a_brake_gate_learns_over_a_frozen_committee_and_benches(tmp_path: Path) -> None:
    import csv

    from brlcli.agent.bayes import save_model_arrays
    from brlcli.agent.gate import BrakeGatedAgent, gate_features
    from brlcli.policy import BRLPolicy
    from brlcli.train import train_many

    cfg = TrainConfig(task="navigation", steps=80, seed=0, evaluate=False, committee=2, actions="fine",
                      brake_gate_steps=60, traffic=["regular"], r_hazard=20.0)
    train_many(cfg, [0], tmp_path / "gated")
    seed = tmp_path / "gated" / "seed_0"
    driver = seed / "driver"
    assert (driver / "member_1" / "model.npz").exists() and (seed / "gate" / "log.csv").exists()
    driver_cfg = json.loads((driver / "config.json").read_text())["config"]
    assert driver_cfg["traffic"] == [] and driver_cfg["r_hazard"] == 0.0  # the driver learns on empty roads
    rows = list(csv.DictReader(open(seed / "gate" / "log.csv")))
    assert len(rows) == 60 and rows[0]["traffic"] == "regular"
    assert "stop" in {r["action"] for r in rows}
    agent = load_navigation_agent_checked(seed / "model.npz")
    assert agent.n_actions == 9 and agent.stop_action == 8 and agent.state_dim == 30
    summary = json.loads((seed / "summary.json").read_text())["summary"]
    assert summary["steps"] == 2 * 80 + 60 and summary["gate"]["steps"] == 60 and summary["driver"]["committee"] == 2
    # the gated model drives: stop where the gate says so, else the frozen committee's vote
    rng = np.random.default_rng(1)
    policy = BRLPolicy("brl", str(seed / "model.npz"))
    assert len(policy.actions) == 9 and "fine steering, brake gate" in policy.setting
    for s, c in zip(rng.dirichlet(np.ones(30), size=20), rng.choice([2, 3, 4, 5], size=20), strict=True):
        stops = agent.gate.act(gate_features(s), rng, greedy=True) == 1
        expected = 8 if stops else agent.driver.act(s, int(c), rng, greedy=True)
        assert policy.act(s, int(c)) == expected
    loaded = BrakeGatedAgent.load(seed / "model.npz")
    assert all(np.array_equal(v, loaded.to_arrays()[k]) for k, v in agent.to_arrays().items())
    assert agent.gate.state_dim == 6  # the gate sees the six road-user shares
    old = {**agent.to_arrays(), "gate_state": np.array("full")}  # a gate of the retired gate_state option
    save_model_arrays(tmp_path / "old.npz", old)
    with pytest.raises(BrlInputError, match=r"gate_state' was retired.*5b48387"):
        BrakeGatedAgent.load(tmp_path / "old.npz")
    with pytest.raises(BrlInputError, match="retired"):
        resolve_train_config([Layer("--set", {"gate_state": "full"})])
    # a gate over an existing driver only: the same gate as the seed's own (same seed, same driver)
    again = TrainConfig(task="navigation", steps=60, seed=0, evaluate=False, actions="fine", traffic=["regular"],
                        r_hazard=20.0, driver_model=str((driver / "model.npz").resolve()),
                        branch_restart_below=None)
    train_run(again, tmp_path / "gate_only")
    assert (tmp_path / "gate_only" / "log.csv").read_bytes() == (seed / "gate" / "log.csv").read_bytes()


def test_a_ghost_traffic_driver_trains_among_road_users_and_its_gate_in_real_traffic(tmp_path: Path) -> None:
    import csv

    from brlcli.agent.gate import BrakeGatedAgent
    from brlcli.policy import BRLPolicy
    from brlcli.train import train_many

    cfg = TrainConfig(task="navigation", steps=80, seed=0, evaluate=False, committee=1, actions="fine",
                      brake_gate_steps=40, traffic=["dense"], r_hazard=20.0, ghost_traffic=True)
    train_many(cfg, [0], tmp_path / "ghost")
    seed = tmp_path / "ghost" / "seed_0"
    driver_cfg = json.loads((seed / "driver" / "config.json").read_text())["config"]
    assert driver_cfg["traffic"] == ["dense"] and driver_cfg["ghost_traffic"] and driver_cfg["r_hazard"] == 0.0
    rows = list(csv.DictReader(open(seed / "driver" / "log.csv")))
    assert {r["traffic"] for r in rows} == {"dense"} and not any(float(r["r_collision"]) for r in rows)
    gate_cfg = json.loads((seed / "gate" / "config.json").read_text())["config"]
    assert not gate_cfg["ghost_traffic"]  # the gate learns in real traffic
    agent = BrakeGatedAgent.load(seed / "model.npz")
    assert agent.n_actions == 9 and "brake gate" in BRLPolicy("brl", str(seed / "model.npz")).setting
    # the driver given as its run directory (its own model.npz) trains a gate alone
    again = TrainConfig(task="navigation", steps=40, seed=0, evaluate=False, actions="fine", traffic=["dense"],
                        r_hazard=20.0, driver_model=str(seed / "driver"), branch_restart_below=None)
    train_run(again, tmp_path / "gate_only")
    assert (tmp_path / "gate_only" / "log.csv").read_bytes() == (seed / "gate" / "log.csv").read_bytes()
    with pytest.raises(BrlInputError, match="ghost_traffic"):
        TrainConfig(task="navigation", ghost_traffic=True)


def load_navigation_agent_checked(path: Path):
    from brlcli.agent.command import load_navigation_agent
    from brlcli.agent.gate import BrakeGatedAgent

    agent = load_navigation_agent(path)
    assert isinstance(agent, BrakeGatedAgent) and is_command_model(path)
    return agent


@pytest.mark.parametrize("overrides, message", [
    ({"traffic": []}, "traffic levels and the hazard reward"),
    ({"r_hazard": 0.0}, "traffic levels and the hazard reward"),
    ({"actions": "stop"}, "set actions to one of paper, fine"),
    ({"task": "lane-keeping"}, "--task navigation"),
    ({"brake_gate_steps": -5}, "brake_gate_steps must be an integer >= 0"),
    ({"driver_model": "README.md"}, "is not a navigation model"),
    ({"driver_model": "models/brl_gt/seed_0"}, "is not a navigation model"),
    ({"driver_model": "models/brl_nav_empty/seed_0/member_0/model.npz", "committee": 3}, "drop committee"),
    ({"driver_model": "models/brl_nav_empty/seed_0", "ghost_traffic": True}, "drop ghost_traffic"),
])
def test_brake_gate_options_are_checked_in_one_line(overrides: dict, message: str) -> None:
    base = {"task": "navigation", "brake_gate_steps": 100, "traffic": ["regular"], "r_hazard": 20.0}
    with pytest.raises(BrlInputError, match=message):
        TrainConfig(**{**base, **overrides})


@pytest.mark.parametrize("overrides, message", [
    ({"privileged_brake_m": -1.0}, "privileged_brake_m must be a distance >= 0"),
    ({"traffic": []}, "needs --task navigation and traffic levels"),
    ({"ghost_traffic": True}, "without ghost_traffic or driver_model"),
])
def test_privileged_brake_options_are_checked_in_one_line(overrides: dict, message: str) -> None:
    base = {"task": "navigation", "traffic": ["regular"], "privileged_brake_m": 8.0}
    with pytest.raises(BrlInputError, match=message):
        TrainConfig(**{**base, **overrides})


def test_a_privileged_brake_drivers_gate_learns_without_it() -> None:
    cfg = TrainConfig(task="navigation", traffic=["regular"], privileged_brake_m=8.0, brake_gate_steps=50,
                      r_hazard=20.0, actions="fine")
    assert cfg.driver_config().traffic == ["regular"] and cfg.driver_config().privileged_brake_m == 8.0
    assert cfg.gate_config("models/brl_nav_empty/seed_0").privileged_brake_m == 0.0


def test_a_fine_braking_model_says_it_has_the_stop_primitive(tmp_path: Path) -> None:
    from brlcli.policy import BRLPolicy

    cfg = TrainConfig(task="navigation", steps=60, seed=0, evaluate=False, actions="fine_stop", traffic=["regular"],
                      r_hazard=20.0, committee=1)
    train_run(cfg, tmp_path / "fine_stop")
    policy = BRLPolicy("brl", str(tmp_path / "fine_stop" / "model.npz"))
    assert len(policy.actions) == 9 and "fine steering, stop primitive" in policy.setting
    # a model of a retired action set (its config.json says so): one line naming the study and the commit
    config_file = tmp_path / "fine_stop" / "config.json"
    config = json.loads(config_file.read_text())
    config["config"]["actions"] = "fine_stop_slow"
    config_file.write_text(json.dumps(config))
    with pytest.raises(BrlInputError, match=r"action set 'fine_stop_slow' was retired .*section 12\.27.*4e10806"):
        BRLPolicy("brl", str(tmp_path / "fine_stop" / "model.npz"))
    with pytest.raises(BrlInputError, match="action set 'fine_stop_slow' was retired"):
        TrainConfig(task="navigation", actions="fine_stop_slow")
    with pytest.raises(BrlInputError, match="unknown action set 'fine_stop_fast'; choose one of paper, stop"):
        TrainConfig(task="navigation", actions="fine_stop_fast")


def test_a_brake_gate_drives_over_a_shipped_member_set() -> None:
    from brlcli.agent.command import CommitteeAgent
    from brlcli.train import new_learner

    cfg = TrainConfig(task="navigation", driver_model="models/brl_nav_empty/seed_0", traffic=["dense"], r_hazard=20.0)
    learner = new_learner(cfg)
    assert isinstance(learner.driver, CommitteeAgent) and len(learner.driver.members) == 7  # type: ignore[attr-defined]
    assert cfg.env_actions == "stop" and not cfg.trains_driver_then_gate


def test_the_navigation_preset_trains_what_is_shipped() -> None:
    from brlcli.config import Layer

    preset = resolve_train_config([Layer("--task", {"task": "navigation"})]).to_dict()
    for seed_dir in sorted(Path("models/brl_nav").glob("seed_*")):
        shipped = json.loads((seed_dir / "config.json").read_text())["config"]
        assert not list(seed_dir.glob("member_*")) and (seed_dir / "model.npz").exists()
        # the shipped runs were trained without the end-of-run evaluation, before imitation_stop_weight (1) existed
        assert {**preset, "seed": shipped["seed"], "evaluate": False, "imitation_stop_weight": 1.0} == \
            {**shipped, "imitation_stop_weight": 1.0}, seed_dir
    empty = json.loads(Path("models/brl_nav_empty/seed_0/member_0/config.json").read_text())["config"]
    td = resolve_train_config([Layer("--set", {"task": "navigation", **NAVIGATION_TD_RECIPE})])
    assert td.committee == len(list(Path("models/brl_nav_empty/seed_0").glob("member_*"))) == 7
    assert (td.steps, td.branch_restart_below, td.params) == (empty["steps"], empty["branch_restart_below"],
                                                              empty["params"])
    over_driver = resolve_train_config([Layer("--set", {"task": "navigation", **TD_NAVIGATION,
                                                        "driver_model": "models/brl_nav_empty/seed_0",
                                                        "traffic": ["dense"], "r_hazard": 20.0})])
    assert over_driver.committee == 1  # the preset's one agent: a gate over a given driver is one agent
    with pytest.raises(BrlInputError, match="drop committee"):
        resolve_train_config([Layer("--set", {"task": "navigation", **NAVIGATION_TD_RECIPE, "r_hazard": 20.0,
                                              "driver_model": "models/brl_nav_empty/seed_0", "traffic": ["dense"]})])


def test_gate_files_of_retired_knobs_are_refused_in_one_line(tmp_path: Path) -> None:
    from brlcli.agent.bayes import save_model_arrays
    from brlcli.agent.gate import BrakeGatedAgent

    gated = BrakeGatedAgent(CommandAgent.load("models/brl_nav_empty/seed_0/member_0/model.npz"))
    arrays = gated.to_arrays()
    save_model_arrays(tmp_path / "scaled.npz", {**arrays, "gate_scale": np.array(10.0)})
    with pytest.raises(BrlInputError, match=r"'gate_scale' was retired.*618b968"):
        BrakeGatedAgent.load(tmp_path / "scaled.npz")
    per_command = {k: v for k, v in arrays.items() if not k.startswith("gate.")}
    per_command.update({f"gate.{k}": v for k, v in CommandAgent(6, 2).to_arrays().items()})
    save_model_arrays(tmp_path / "branches.npz", per_command)
    with pytest.raises(BrlInputError, match=r"'gate_branches' was retired.*e082171"):
        BrakeGatedAgent.load(tmp_path / "branches.npz")
    save_model_arrays(tmp_path / "plain.npz", {**arrays, "gate_scale": np.array(1.0)})
    assert BrakeGatedAgent.load(tmp_path / "plain.npz").gate.state_dim == 6


def test_a_driver_of_another_state_is_refused_before_anything_is_written(tmp_path: Path) -> None:
    train_run(TrainConfig(task="navigation", steps=20, seed=0, evaluate=False, actions="fine", state="speed"),
              tmp_path / "speed_driver")
    with pytest.raises(BrlInputError, match=r"state size 31 .* state 'nearness' .* need 33"):
        train_run(TrainConfig(task="navigation", steps=40, seed=0, evaluate=False, actions="fine",
                              traffic=["dense"], r_hazard=20.0, state="nearness",
                              driver_model=str(tmp_path / "speed_driver")), tmp_path / "bad")
    assert not (tmp_path / "bad").exists()
    result = subprocess.run([sys.executable, "-m", "brlcli", "train", "--task", "navigation", "--seeds", "0",
                             *TD_NAVIGATION_SETS, "--set", f"driver_model={tmp_path / 'speed_driver'}",
                             "--set", "state=nearness",
                             "--set", 'traffic=["dense"]', "--set", "r_hazard=20", "--steps", "10", "--no-evaluate",
                             "--out", str(tmp_path / "bad_cli")], capture_output=True, text=True)
    assert result.returncode == 2 and "need 33" in result.stderr and "Traceback" not in result.stderr
    assert not (tmp_path / "bad_cli").exists()
