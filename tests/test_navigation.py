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
from brlcli.errors import BrlInputError
from brlcli.reward import RouteRewardParams, route_terms
from brlcli.sim.gym_env import DrivingEnv
from brlcli.sim.navroutes import JUNCTION_KINDS, junction_routes, validation_routes
from brlcli.sim.roadnet import Command, RoadNetwork
from brlcli.sim.town import load_town
from brlcli.train import LOG_COLUMNS, TrainConfig, train_run


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
    assert route_terms(3.9, 3.9, 0.5, p) == {"progress": 0.0, "wrong_turn": 0.0, "heading": 0.0, "lateral": 0.0}
    assert route_terms(0.0, 3.9, 0.5, p)["progress"] == -p.r_progress
    assert route_terms(-10.0, 3.9, 0.5, p)["progress"] == -2 * p.r_progress  # capped
    assert route_terms(3.9, 3.9, -6.5, p)["wrong_turn"] == -p.r_wrong_turn
    with pytest.raises(ValueError):
        RouteRewardParams(wrong_turn_m=0.0)
    with pytest.raises(ValueError):
        RouteRewardParams(r_heading=-1.0)


def test_heading_and_lateral_terms_cost_turning_away_from_the_route(net01: RoadNetwork) -> None:
    p = RouteRewardParams(r_heading=5.0, r_lateral=1.0)
    assert route_terms(3.9, 3.9, 0.0, RouteRewardParams(), heading_error_rad=0.5)["heading"] == 0.0  # off by default
    terms = route_terms(3.9, 3.9, -2.0, p, heading_error_rad=-0.4)
    assert terms["heading"] == pytest.approx(-2.0) and terms["lateral"] == pytest.approx(-2.0)
    capped = route_terms(3.9, 3.9, 9.0, p, heading_error_rad=3.0)
    assert capped["heading"] == pytest.approx(-5.0 * np.pi / 2) and capped["lateral"] == pytest.approx(-6.0)
    right = next(r for r in junction_routes(net01) if r.kind == "turn_right")
    route = net01.route(right.start, right.goal)
    start, end, _cmd = route.commands[0]
    assert route.heading_at(0.0) == pytest.approx(np.radians(right.start[2]), abs=1e-6)
    turned = np.degrees(route.heading_at(end + 5.0) - route.heading_at(start - 5.0))
    assert (turned + 180.0) % 360.0 - 180.0 == pytest.approx(-90.0, abs=5.0)  # a right turn: yaw falls by 90 degrees


def test_a_left_turn_on_go_straight_costs_heading() -> None:
    env = DrivingEnv(routes="navigation", kinds=("go_straight",), route_reward=RouteRewardParams(r_heading=5.0))
    try:
        env.reset(seed=0, options={"route": env.routes[0].name})
        costs = []
        for action in (0, 2, 0, 0):  # forward, then left: the heading cost appears after the left turn
            _obs, reward, _term, _trunc, info = env.step(action)
            costs.append(info["reward_terms"]["heading"])
        assert costs[0] > -0.2 and min(costs[2:]) < -0.5
    finally:
        env.close()


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
    agent.set_command(int(Command.TURN_LEFT))
    for _ in range(5):
        agent.learn(s, 1, -20.0, s)
    steps = [b.steps for b in agent.branches]
    assert steps == [0, 5, 0, 0] and agent.branch == 1
    agent.set_command(int(Command.REACH_GOAL))  # drives as follow lane
    assert agent.branch == 0
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
    r = _cli("train", "--task", "navigation", "--steps", "40", "--no-evaluate", "--out", str(tmp_path / "m"))
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


def test_a_command_change_bootstraps_from_the_next_branch(tmp_path: Path) -> None:
    rng = np.random.default_rng(1)
    s, s_next = rng.dirichlet(np.ones(30)), rng.dirichlet(np.ones(30))
    agent = CommandAgent()
    agent.set_command(int(Command.LANE_FOLLOW))
    for _ in range(3):  # the follow branch learns that every action is bad at s_next
        for action in range(4):
            agent.learn(s_next, action, -30.0, s_next)
    agent.save(tmp_path / "a.npz")
    own = CommandAgent.load(tmp_path / "a.npz", bootstrap="own-branch")
    nxt = CommandAgent.load(tmp_path / "a.npz", bootstrap="next-branch")
    v_follow, v_left = nxt.branches[0].value(s_next), nxt.branches[1].value(s_next)
    assert v_follow < v_left
    steps = []
    for a in (own, nxt):
        a.set_command(int(Command.TURN_LEFT))
        steps.append(a.learn(s, 2, -1.0, s_next, next_command=int(Command.LANE_FOLLOW)))
    gamma = nxt.branches[1].params.gamma
    assert steps[1].td_error - steps[0].td_error == pytest.approx(gamma * (v_follow - v_left))
    same = CommandAgent.load(tmp_path / "a.npz")
    same.set_command(int(Command.TURN_LEFT))  # no command change: the branch's own value, whatever the rule
    assert same.learn(s, 2, -1.0, s_next, next_command=int(Command.TURN_LEFT)).td_error == steps[0].td_error


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


def test_keep_best_ships_the_evaluation_with_the_best_validation_figures(tmp_path: Path,
                                                                       monkeypatch: pytest.MonkeyPatch) -> None:
    import brlcli.bench.runner

    successes = iter([0.25, 0.5, 0.25])

    class FakeEvaluator:  # the mechanics only: nav_validation itself runs in the training tests and the study
        def __init__(self, suite: str, bench_seed: int = 0) -> None:
            assert suite == "nav_validation"

        def evaluate(self, policy: object) -> dict:
            return {"episodes": 16, "success": next(successes), "collision_free": 1.0, "either": 0.1, "score": 0.5,
                    "eval_suite": "nav_validation"}

        def close(self) -> None:
            pass

    monkeypatch.setattr(brlcli.bench.runner, "SuiteEvaluator", FakeEvaluator)
    cfg = TrainConfig(task="navigation", steps=60, seed=1, curve_every=20, keep_best=True)
    summary = train_run(cfg, tmp_path / "run")["summary"]
    run = tmp_path / "run"
    assert summary["selected_step"] == 40 and summary["eval"]["success_rate"] == 0.5
    assert summary["eval_last"]["success_rate"] == 0.25 and summary["eval_last"]["step"] == 60
    assert (run / "model.npz").read_bytes() == (run / "model_best.npz").read_bytes()
    assert (run / "model.npz").read_bytes() != (run / "model_last.npz").read_bytes()
    plain = train_run(TrainConfig(task="navigation", steps=60, seed=1, evaluate=False), tmp_path / "plain")
    assert plain["summary"]["steps"] == 60  # the training itself is the same run: evaluations never touch it
    assert (tmp_path / "plain" / "model.npz").read_bytes() == (run / "model_last.npz").read_bytes()
    assert (tmp_path / "plain" / "log.csv").read_bytes() == (run / "log.csv").read_bytes()
    with pytest.raises(BrlInputError, match="keep_best needs"):
        TrainConfig(task="navigation", keep_best=True)
    with pytest.raises(BrlInputError, match="keep_best needs"):
        TrainConfig(keep_best=True, curve_every=100)


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


def test_straight_as_follow_acts_and_learns_in_the_follow_branch(tmp_path: Path) -> None:
    from brlcli.agent.command import COMMAND_FORMAT_VERSION

    rng = np.random.default_rng(0)
    agent = CommandAgent(straight_as_follow=True)
    s0, s1 = np.full(30, 0.2), np.full(30, 0.25)
    agent.set_command(Command.GO_STRAIGHT)
    assert agent.branch == 0
    before = [b.to_arrays() for b in agent.branches]
    agent.learn(s0, agent.act(s0, rng), -1.0, s1, Command.GO_STRAIGHT)
    after = [b.to_arrays() for b in agent.branches]
    changed = [any(not np.array_equal(a[k], b[k]) for k in a) for a, b in zip(before, after, strict=True)]
    assert changed == [True, False, False, False]
    agent.set_command(Command.TURN_LEFT)
    assert agent.branch == 1
    agent.save(tmp_path / "m.npz")
    again = CommandAgent.load(tmp_path / "m.npz")
    assert again.straight_as_follow and again.branch_of(Command.GO_STRAIGHT) == 0
    with np.load(tmp_path / "m.npz") as npz:
        assert int(npz["format_version"]) == COMMAND_FORMAT_VERSION + 1  # older brl refuses it
    CommandAgent().save(tmp_path / "plain.npz")
    plain = CommandAgent.load(tmp_path / "plain.npz")
    assert not plain.straight_as_follow and plain.branch_of(Command.GO_STRAIGHT) == 3


def test_warm_copy_keeps_the_knowledge_and_restarts_the_schedules() -> None:
    rng = np.random.default_rng(1)
    teacher = BayesianAgent(params=TrainConfig().agent_params())
    states = rng.uniform(0.0, 0.2, size=(60, 30))
    for t in range(59):
        teacher.learn(states[t], int(rng.integers(4)), float(rng.normal(-5.0, 8.0)), states[t + 1])
    copy = teacher.warm_copy()
    assert copy.n_components == teacher.n_components > 1
    np.testing.assert_array_equal(copy.Q, teacher.Q)
    np.testing.assert_array_equal(copy.means, teacher.means)
    for s in states[:5]:  # same densities, so the same greedy action
        assert copy.act(s, rng, greedy=True) == teacher.act(s, rng, greedy=True)
    fresh = BayesianAgent(params=teacher.params)
    assert (copy.alpha, copy.tau, copy.rho) == (fresh.alpha, fresh.tau, fresh.rho)
    assert (teacher.alpha, teacher.tau) != (fresh.alpha, fresh.tau)
    assert not copy.visits.any() and teacher.visits.any()
    copy.learn(states[0], 0, -50.0, states[1])  # learning in the copy leaves the teacher alone
    assert not np.array_equal(copy.Q, teacher.Q)


def test_warm_start_junctions_copies_the_follow_branch_once(tmp_path: Path) -> None:
    cfg = TrainConfig(task="navigation", steps=150, seed=2, evaluate=False, warm_start_junctions=60)
    summary = train_run(cfg, tmp_path / "warm")["summary"]
    at = summary["junctions_warm_started_at"]
    assert 60 <= at < 150
    plain = TrainConfig(task="navigation", steps=150, seed=2, evaluate=False)
    train_run(plain, tmp_path / "plain")
    warm_log = (tmp_path / "warm" / "log.csv").read_text().splitlines()
    plain_log = (tmp_path / "plain" / "log.csv").read_text().splitlines()
    assert warm_log[: at + 1] == plain_log[: at + 1]  # identical up to the copy, different after it
    assert warm_log != plain_log
    with pytest.raises(BrlInputError, match="warm_start_junctions"):
        TrainConfig(warm_start_junctions=60)
    with pytest.raises(BrlInputError, match="warm_start_junctions"):
        TrainConfig(task="navigation", warm_start_junctions=-1)


def test_no_backward_trains_and_deploys_three_primitives(tmp_path: Path) -> None:
    from brlcli.policy import BRLPolicy

    cfg = TrainConfig(task="navigation", steps=150, seed=2, evaluate=False, no_backward=True,
                      branch_restart_below=[10.0] * 4)  # the restarted branches keep three actions too
    summary = train_run(cfg, tmp_path / "run")["summary"]
    assert summary["branch_restarts"]
    lines = (tmp_path / "run" / "log.csv").read_text().splitlines()
    actions = {line.split(",")[LOG_COLUMNS.index("action")] for line in lines[1:]}
    assert actions == {"forward", "right", "left"}
    agent = CommandAgent.load(tmp_path / "run" / "model.npz")
    assert agent.n_actions == 3 and {b.n_actions for b in agent.branches} == {3}
    policy = BRLPolicy("brl", str(tmp_path / "run" / "model.npz"))
    rng = np.random.default_rng(0)
    picks = {int(policy.act(s, int(c))) for s, c in zip(rng.dirichlet(np.ones(30), size=40),
                                                           rng.choice([2, 3, 4, 5], size=40), strict=True)}
    assert picks <= {0, 1, 2}
    plain = TrainConfig(task="navigation", steps=150, seed=2, evaluate=False)
    assert plain.n_actions == 4 and cfg.n_actions == 3


def test_teams_learn_apart_and_ship_the_best_team_per_command(tmp_path: Path) -> None:
    from brlcli.agent.command import TeamAgent
    from brlcli.train import _deployable, _team_means

    cfg = TrainConfig(task="navigation", steps=240, seed=2, evaluate=False, teams=3)
    summary = train_run(cfg, tmp_path / "run")["summary"]
    teams = TeamAgent.load(tmp_path / "run" / "checkpoint" / "agent.npz")
    assert len(teams.teams) == 3
    follow = [t.branches[0].Q for t in teams.teams]
    assert not np.array_equal(follow[0], follow[1]) and not np.array_equal(follow[1], follow[2])
    stats = json.loads((tmp_path / "run" / "checkpoint" / "state.json").read_text())["stats"]
    means = _team_means(cfg, stats)
    choice = summary["team_choice"]
    for b, name in enumerate(("follow", "left", "right", "straight")):
        if not np.isnan(means[:, b]).all():
            assert means[choice[name], b] == np.nanmax(means[:, b])
    shipped = CommandAgent.load(tmp_path / "run" / "model.npz")  # a plain command-conditioned model
    composed = _deployable(teams, cfg, stats)
    for b in range(4):
        np.testing.assert_array_equal(shipped.branches[b].Q, composed.branches[b].Q)
        np.testing.assert_array_equal(shipped.branches[b].Q, teams.teams[list(choice.values())[b]].branches[b].Q)
    with pytest.raises(BrlInputError, match="teams"):
        TrainConfig(teams=2)
    with pytest.raises(BrlInputError, match="teams"):
        TrainConfig(task="navigation", teams=2, team_share=0.0)
    with pytest.raises(BrlInputError, match="not a team checkpoint"):
        TeamAgent.load(tmp_path / "run" / "model.npz")


def test_shared_mixture_blocks_share_components_and_keep_their_own_values() -> None:
    rng = np.random.default_rng(4)
    states = rng.dirichlet(np.ones(30), size=40)
    agent = BayesianAgent(n_blocks=2)
    agent.select_block(1)
    for i in range(39):
        agent.learn(states[i], int(rng.integers(4)), -20.0, states[i + 1])
    assert agent.n_components > 1 and agent.steps == 39
    block1_alpha, block1_tau = agent.alpha, agent.tau
    agent.select_block(0)  # block 0 never learned: its schedules are the initial ones, its values untouched or
    fresh = BayesianAgent()  # copied into new components, never updated
    assert (agent.alpha, agent.tau, agent.steps) == (fresh.alpha, fresh.tau, 0)
    assert not agent.visits.any()
    q0 = agent.Q
    agent.learn(states[0], 2, -30.0, states[1])
    assert not np.array_equal(agent.Q, q0)
    agent.select_block(1)
    assert (agent.alpha, agent.tau, agent.steps) == (block1_alpha, block1_tau, 39)
    q1 = agent.Q
    agent.reset_block(0)  # forgetting a block leaves the other one and the components alone
    assert np.array_equal(agent.Q, q1) and agent.n_components > 1
    agent.select_block(0)
    assert np.all(agent.Q == agent.params.init_q) and agent.steps == 0
    with pytest.raises(ValueError, match="block"):
        agent.select_block(2)


def test_shared_mixture_command_agent_trains_saves_and_loads(tmp_path: Path) -> None:
    cfg = TrainConfig(task="navigation", steps=150, seed=2, evaluate=False, shared_mixture=True,
                      branch_restart_below=[10.0] * 4)  # every branch restarts: its block is forgotten
    summary = train_run(cfg, tmp_path / "run")["summary"]
    assert summary["branch_restarts"]
    agent = CommandAgent.load(tmp_path / "run" / "model.npz")
    assert agent.shared is not None and summary["components"] == agent.shared.n_components
    assert len(set(summary["components_per_branch"].values())) == 1
    steps = [b.steps for b in agent.branches]
    assert 0 < sum(steps) <= 150 and steps[0] > 0
    again = CommandAgent.load(tmp_path / "run" / "model.npz")
    rng = np.random.default_rng(0)
    for s in rng.dirichlet(np.ones(30), size=10):
        for command in (2, 3, 4, 5):
            agent.set_command(command)
            again.set_command(command)
            assert agent.act(s, rng, greedy=True) == again.act(s, rng, greedy=True)
    with pytest.raises(BrlInputError, match="shared_mixture"):
        TrainConfig(shared_mixture=True)
    with pytest.raises(BrlInputError, match="shared_mixture"):
        TrainConfig(task="navigation", shared_mixture=True, teams=2)


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
        for m in members:
            m.set_command(int(c))
        probs = np.array([m.current.action_probabilities(s) for m in members])
        expected = probs.argmax(1)[0] if probs.argmax(1)[0] == probs.argmax(1)[1] else int(probs.mean(0).argmax())
        assert policy.act(s, int(c)) == expected
    with pytest.raises(ValueError, match="greedily"):
        agent.act(np.full(30, 1 / 30), rng)
    with pytest.raises(BrlInputError, match="committee"):
        TrainConfig(committee=2)
    with pytest.raises(BrlInputError, match="committee"):
        TrainConfig(task="navigation", committee=0)
    with pytest.raises(BrlInputError, match="not a command-conditioned one"):  # a single agent's loader refuses it
        CommandAgent.load(tmp_path / "com" / "model.npz")
