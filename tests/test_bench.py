"""brl bench: suites, deterministic subsets and shards, resume, worker independence, bad input."""

import signal
import subprocess
import sys
import time
from functools import partial
from pathlib import Path

import numpy as np
import pytest

from brlcli.agent import BayesianAgent
from brlcli.bench.runner import read_results, run_bench
from brlcli.bench.suites import build_suite, parse_shard, shard, subset
from brlcli.errors import BrlInputError
from brlcli.policy import PolicySpec
from brlcli.sim.town import load_town
from brlcli.train import train_run
from brlcli.trainconfig import TrainConfig


@pytest.fixture(scope="module")
def model(tmp_path_factory) -> Path:
    run = tmp_path_factory.mktemp("model") / "seed_0"
    train_run(TrainConfig(steps=200, seed=0, evaluate=False), run)
    return run / "model.npz"


def test_suite_sizes_follow_the_definitions() -> None:
    corl = build_suite("corl2017")
    assert len(corl) == 4 * 25 * 6 * 2  # tasks x poses x weathers (4 train + 2 test) x towns
    dynamic = [s for s in corl if s.task == "navigation_dynamic"]
    assert all((s.vehicles, s.pedestrians) == ((20, 50) if s.town == "town01" else (15, 50)) for s in dynamic)
    assert all(s.vehicles == 0 for s in corl if s.task != "navigation_dynamic")
    assert all(s.timeout_s == pytest.approx(s.route_length_m / 1000 / 10 * 3600 + 10, abs=1e-3) for s in corl)
    new_town = build_suite("corl2017", conditions="new_town_weather")
    assert {s.town for s in new_town} == {"town02"} and {s.weather for s in new_town} == {4, 14}
    paper = build_suite("paper")
    assert {s.town for s in paper} == {"town01", "town02"} and {s.weather for s in paper} == {1, 4, 14}
    assert len({s.id for s in corl}) == len(corl)


def test_validation_suite_is_the_paper_suite_on_validation_routes() -> None:
    paper, val = build_suite("paper"), build_suite("validation")
    n_routes = sum(len(load_town(t).validation_routes) for t in ("town01", "town02"))
    assert len(val) == 3 * n_routes and 60 <= len(val) <= 72
    assert {s.weather for s in val} == {1, 4, 14} and {s.town for s in val} == {"town01", "town02"}
    assert {(s.town, s.condition) for s in val} == {(s.town, s.condition) for s in paper}
    assert {s.task for s in val if s.town == "town02"} == {"straight", "right_curve", "left_curve"}
    assert not {(s.start, s.goal) for s in val} & {(s.start, s.goal) for s in paper}
    assert all(s.suite == "validation" and s.id.startswith("validation/") for s in val)
    assert len(build_suite("validation", conditions="unseen_town", tasks="straight", weathers="1")) == 4


def test_subsets_and_shards_are_deterministic_partitions() -> None:
    specs = build_suite("corl2017", tasks="straight")
    a, b = subset(specs, "30"), subset(specs, "30")
    assert [s.id for s in a] == [s.id for s in b] and len(a) == 30
    assert len(subset(specs, "0.1")) == 30
    parts = [shard(a, k, 4) for k in range(1, 5)]
    ids = sorted(s.id for p in parts for s in p)
    assert ids == sorted(s.id for s in a)
    for bad in ("3/2", "0/2", "x", "1/0"):
        with pytest.raises(BrlInputError):
            parse_shard(bad)
    for bad in ("0", "-1", "1.5", "abc"):
        with pytest.raises(BrlInputError):
            subset(specs, bad)


def _key(rows: list[dict]) -> list[dict]:
    return sorted(rows, key=lambda r: (r["policy"], r["id"]))


def test_sharded_and_resumed_runs_equal_one_run(tmp_path: Path, model: Path) -> None:
    specs = subset(build_suite("paper"), "6")
    pol = [PolicySpec("brl", "m", {"model": str(model)})]
    config = {"suite": "paper", "seed": 0}
    full = _key(run_bench(specs, pol, tmp_path / "full", config))
    assert len(full) == 6

    class Stop(Exception):
        pass

    seen = []

    def stop_after_two(result: dict) -> None:
        seen.append(result)
        if len(seen) == 2:
            raise Stop

    with pytest.raises(Stop):
        run_bench(shard(specs, 1, 2), pol, tmp_path / "s1", config, progress=stop_after_two)
    assert len(read_results(tmp_path / "s1")) == 2
    with pytest.raises(BrlInputError):
        run_bench(shard(specs, 1, 2), pol, tmp_path / "s1", config)  # needs resume
    run_bench(shard(specs, 1, 2), pol, tmp_path / "s1", config, resume=True)
    run_bench(shard(specs, 2, 2), pol, tmp_path / "s2", config, workers=2)
    merged = _key(read_results(tmp_path / "s1") + read_results(tmp_path / "s2"))
    assert merged == full
    for r in full:
        a = np.load(tmp_path / "full" / r["frames_file"], allow_pickle=False)
        b_dir = "s1" if (tmp_path / "s1" / r["frames_file"]).exists() else "s2"
        b = np.load(tmp_path / b_dir / r["frames_file"], allow_pickle=False)
        np.testing.assert_array_equal(a["x"], b["x"])
        assert len(a["x"]) == r["steps"] + 1


def _brl(*args: str) -> subprocess.CompletedProcess:
    return subprocess.run([sys.executable, "-m", "brlcli.cli", "bench", *args], capture_output=True, text=True,
                          timeout=300)


def test_bench_cli_runs_and_rejects_bad_input(tmp_path: Path, model: Path, brl_in_process) -> None:
    r = _brl("--model", str(model), "--episodes", "2", "--out", str(tmp_path / "ok"))
    assert r.returncode == 0, r.stderr
    assert len(read_results(tmp_path / "ok")) == 2
    wrong_state = tmp_path / "small" / "model.npz"
    wrong_state.parent.mkdir()
    BayesianAgent(state_dim=10, n_actions=4).save(wrong_state)
    junk = tmp_path / "junk.npz"
    junk.write_bytes(b"not a model")
    cases = [
        ["--suite", "corl2018", "--model", str(model)],
        ["--suite", "corl2017", "--tasks", "parking", "--model", str(model)],
        ["--suite", "corl2017", "--conditions", "night", "--model", str(model)],
        ["--suite", "nocrash", "--tasks", "heavy", "--agent", "autopilot"],
        ["--suite", "nocrash", "--conditions", "night", "--agent", "autopilot"],
        ["--weathers", "Blizzard", "--model", str(model)],
        ["--model", str(junk)],
        ["--model", str(wrong_state)],
        ["--model", str(model), "--shard", "3/2"],
        ["--suite", "corl2017", "--model", str(model), "--episodes", "1", "--out", str(tmp_path / "ok")],
        ["--agent", "mp", "--model", str(model)],
        ["--agent", "dqn", "--models", str(model)],
        ["--agent", "dqn", "--model", str(junk)],
        ["--agent", "il", "--model", str(tmp_path / "missing.pt")],
        ["--agent", "mp", "--deploy", "lidar"],
        ["--agent", "sac"],
    ]
    for i, args in enumerate(cases):
        out = [] if "--out" in args else ["--out", str(tmp_path / "bad")]
        r = (_brl if i == 0 else partial(brl_in_process, "bench"))(*args, *out)  # one in a process of its own
        assert r.returncode == 2, (args, r.stderr)
        assert r.stderr.strip().count("\n") == 0 and "Traceback" not in r.stderr, (args, r.stderr)
    assert not (tmp_path / "bad").exists()


def test_estimated_deploy_names_the_setting(tmp_path: Path, model: Path) -> None:
    specs = subset(build_suite("paper"), "1")
    rows = run_bench(specs, [PolicySpec("brl", "m", {"model": str(model), "deploy": "estimated"})],
                     tmp_path / "e", {"suite": "paper", "seed": 0})
    assert rows[0]["setting"] == "TGDE"


def test_autopilot_baseline_drives_the_routes(tmp_path: Path) -> None:
    specs = [s for s in build_suite("paper", weathers="1") if s.task != "straight"][:2]
    rows = run_bench(specs, [PolicySpec("autopilot", "autopilot", {})], tmp_path / "ap", {"suite": "paper", "seed": 0})
    assert len(rows) == 2
    assert all(r["success"] and not r["collided"] for r in rows)
    assert all(r["either_steps"] == 0 for r in rows) and rows[0]["setting"] == "autopilot"


def test_oracle_drives_a_junction_with_the_agents_primitives(tmp_path: Path) -> None:
    """The expert quantised to forward/right/left every 7 frames still takes a CoRL2017 turn (issue 20)."""
    from brlcli.policy import OraclePolicy
    from brlcli.sim.gym_env import ACTIONS

    specs = [s for s in build_suite("corl2017", conditions="training", tasks="navigation", weathers="1")][:1]
    rows = run_bench(specs, [PolicySpec("oracle", "oracle", {})], tmp_path / "o", {"suite": "corl2017", "seed": 0})
    assert rows[0]["success"] and rows[0]["setting"] == "oracle"
    oracle = OraclePolicy()
    assert oracle.frames_per_decision == 7 and set(oracle._primitives) == set(ACTIONS[:3])
    for bad in ({"decision_frames": 0}, {"turn_steer": 1.5}, {"stop": "always"}):
        with pytest.raises(BrlInputError, match="oracle"):
            OraclePolicy(**bad)


def test_oracle_quantises_the_experts_steering_and_stops_only_with_the_stop_action() -> None:
    from types import SimpleNamespace

    from brlcli.policy import STOP_ACTION, Observation, OraclePolicy
    from brlcli.sim.gym_env import ACTIONS
    from brlcli.sim.vehicle import Control

    expert = {"control": Control(steer=0.3, throttle=0.4)}
    pilot = SimpleNamespace(expert=lambda m: expert["control"])
    obs = Observation(rgb=None, labels=None, measurements=None, command=2)
    plain, stopping = OraclePolicy(), OraclePolicy(stop="braking", decision_frames=3)
    plain._pilot = stopping._pilot = pilot
    assert plain.decide(obs) == ACTIONS[1] and stopping.decide(obs) == ACTIONS[1]  # 0.3 is nearest +0.4: right
    expert["control"] = Control(steer=-0.1, throttle=0.2)
    assert plain.decide(obs) == ACTIONS[0]  # nearest 0: forward
    expert["control"] = Control(steer=-0.35, throttle=0.0, brake=1.0)
    assert plain.decide(obs) == ACTIONS[2]  # the paper's primitives cannot brake: left
    assert stopping.decide(obs) == STOP_ACTION and stopping.frames_per_decision == 3
    braking = OraclePolicy(backward_brake=True)
    braking._pilot = pilot
    rolling = Observation(rgb=None, labels=None, measurements=SimpleNamespace(forward_speed_kmh=8.0), command=2)
    standing = Observation(rgb=None, labels=None, measurements=SimpleNamespace(forward_speed_kmh=0.0), command=2)
    assert braking.decide(rolling) == ACTIONS[3] and braking.decide(standing) == ACTIONS[2]
    still = OraclePolicy(stop="standstill")
    wants = {"stop": False}
    still._pilot = SimpleNamespace(expert=pilot.expert, must_stop=lambda m: wants["stop"])
    assert still.decide(obs) == ACTIONS[2]  # braking to slow down (for a turn): keep steering
    wants["stop"] = True
    assert still.decide(obs) == STOP_ACTION
    fine = OraclePolicy(turn_steer=[0.05, 0.15, 0.4])  # issue 35: a finer steering set, +-each
    fine._pilot = pilot
    assert sorted(p.steer for p in fine._primitives) == [-0.4, -0.15, -0.05, 0.0, 0.05, 0.15, 0.4]
    expert["control"] = Control(steer=-0.1, throttle=0.2)
    assert fine.decide(obs).steer in (-0.05, -0.15) and plain.decide(obs) == ACTIONS[0]
    expert["control"] = Control(steer=0.12, throttle=0.2)
    assert fine.decide(obs).steer == 0.15
    with pytest.raises(BrlInputError, match="turn_steer"):
        OraclePolicy(turn_steer=[0.1, 2.0])


def test_nocrash_suite_definition() -> None:
    from brlcli.bench.suites import NOCRASH_TRAFFIC, nocrash_timeout_s

    specs = build_suite("nocrash")
    assert len(specs) == 25 * 3 * (4 + 2 + 4 + 2)  # navigation pose pairs x traffic levels x condition weathers
    assert {s.weather for s in specs if s.condition == "new_weather"} == {10, 14}
    assert {s.weather for s in specs if s.condition == "new_town"} == {1, 3, 6, 8}
    for s in specs:
        assert (s.vehicles, s.pedestrians) == NOCRASH_TRAFFIC[s.town][s.task] and s.end_on_collision
        assert s.timeout_s == pytest.approx(s.route_length_m / 1000 / 5 * 3600 + 20, abs=0.01)  # length rounded to mm
    assert NOCRASH_TRAFFIC["town01"]["dense"] == (100, 250) and NOCRASH_TRAFFIC["town02"]["dense"] == (70, 150)
    assert nocrash_timeout_s(1000.0) == pytest.approx(740.0)
    corl = build_suite("corl2017", conditions="training", tasks="navigation", weathers="1")
    ours = build_suite("nocrash", conditions="training", tasks="empty", weathers="1")
    assert [(c.start, c.goal) for c in corl] == [(s.start, s.goal) for s in ours]  # CoRL2017's navigation poses
    for bad in ({"tasks": "heavy"}, {"conditions": "night"}):
        with pytest.raises(BrlInputError, match=r"heavy|night"):
            build_suite("nocrash", **bad)


def test_nocrash_collision_ends_the_episode_as_a_failure(tmp_path: Path) -> None:
    """The oracle cannot brake: in Dense traffic it collides, and the episode stops there."""
    specs = build_suite("nocrash", conditions="training", tasks="dense", weathers="1")[:1]
    rows = run_bench(specs, [PolicySpec("oracle", "oracle", {})], tmp_path / "n", {"suite": "nocrash", "seed": 0})
    r = rows[0]
    assert r["crashed"] and r["collided"] and not r["success"] and r["time_s"] < r["timeout_s"] / 4
    corl = build_suite("corl2017", conditions="training", tasks="navigation_dynamic", weathers="1")[:1]
    rows = run_bench(corl, [PolicySpec("oracle", "oracle", {})], tmp_path / "c", {"suite": "corl2017", "seed": 0})
    assert "crashed" not in rows[0]  # CoRL2017 episodes go on after a collision


def test_without_a_model_the_shipped_gt_set_is_used() -> None:
    from brlcli.bench.registry import find_models

    found = find_models(None, None)
    assert [name for name, _ in found] == [f"brl_gt/seed_{k}" for k in range(9)]
    from brlcli.agent.committee import LaneKeepingCommittee, load_lane_keeping_agent

    te = sorted((Path(__file__).resolve().parents[1] / "models" / "brl_te").glob("seed_*/model.npz"))
    assert len(te) == 9
    for path in [p for _, p in found] + te:
        agent = load_lane_keeping_agent(path)
        assert isinstance(agent, LaneKeepingCommittee) and len(agent.members) == 5
        assert agent.state_dim == 30 and agent.n_actions == 4


def test_bench_stopped_by_sigterm_saves_its_episodes_and_prints_no_traceback(tmp_path: Path) -> None:
    out = tmp_path / "killed"
    proc = subprocess.Popen([sys.executable, "-m", "brlcli.cli", "bench", "--agent", "autopilot", "--suite",
                             "corl2017", "--tasks", "navigation", "--episodes", "12", "--workers", "2", "--out",
                             str(out)], stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True)
    results = out / "results.jsonl"
    try:
        deadline = time.monotonic() + 240
        while time.monotonic() < deadline and proc.poll() is None:
            if results.exists() and results.read_text().strip():
                break
            time.sleep(0.2)
        assert proc.poll() is None, "the bench finished before it could be stopped"
        proc.send_signal(signal.SIGTERM)
        stdout, stderr = proc.communicate(timeout=60)
    finally:
        if proc.poll() is None:  # a failed assertion must not leave the bench running
            proc.kill()
            proc.communicate()
    assert proc.returncode == 130, stderr
    assert "Traceback" not in stderr and "Traceback" not in stdout
    assert "--resume" in stdout + stderr
    done = read_results(out)
    assert 1 <= len(done) < 12
    assert all((out / r["frames_file"]).exists() for r in done)


def test_every_shipped_model_set_benches_as_shipped(tmp_path: Path) -> None:
    """Issue 36: models/ runs as it is; a set of committee members without a committee file votes as a committee."""
    from brlcli.agent.command import CommitteeAgent
    from brlcli.bench.registry import find_models
    from brlcli.policy import BRLPolicy

    root = Path(__file__).resolve().parents[1] / "models"
    for name in ("brl_gt", "brl_gt_paper", "brl_te", "brl_nav", "brl_nav_empty"):
        found = find_models(None, [str(root / name)])
        assert [n for n, _ in found] == [f"{name}/seed_{k}" for k in range(9)], name
        for policy_name, path in found:
            policy = BRLPolicy(policy_name, path)
            assert policy.task == ("navigation" if name.startswith("brl_nav") else "lane-keeping")
            if name == "brl_nav_empty":
                assert isinstance(policy.agent, CommitteeAgent) and len(policy.agent.members) == 7
                assert "navigation, no brake" in policy.setting
            if name == "brl_nav":  # the imitating mixtures: stop among their actions, only for road users in view
                assert policy.frames_per_decision == 3 and len(policy.actions) == 9
                assert "imitation, road_users_weighted state, stop only for road users in view" in policy.setting
    empty = root / "brl_nav_empty"
    assert find_models(str(empty / "seed_3"), None) == [("seed_3", str(empty / "seed_3"))]
    with pytest.raises(BrlInputError, match=r"committee members but no committee model\.npz"):
        find_models(str(empty), None)  # a set of member sets is --models, not --model
    (tmp_path / "empty").mkdir()
    with pytest.raises(BrlInputError, match=r"holds no model\.npz files"):
        find_models(None, [str(tmp_path / "empty")])


def test_the_traffic_validation_suite_is_nav_validation_in_nocrash_traffic() -> None:
    from brlcli.bench.suites import NOCRASH_TRAFFIC, nocrash_timeout_s

    specs = build_suite("nav_validation_traffic")
    plain = build_suite("nav_validation")
    assert len(specs) == 3 * len(plain) and len({s.id for s in specs}) == len(specs)
    assert {(s.start, s.goal) for s in specs} == {(s.start, s.goal) for s in plain}  # never NoCrash's poses
    nocrash_poses = {(s.start, s.goal) for s in build_suite("nocrash")}
    assert not nocrash_poses & {(s.start, s.goal) for s in specs}
    for s in specs:
        assert (s.vehicles, s.pedestrians) == NOCRASH_TRAFFIC[s.town][s.task] and s.end_on_collision
        assert s.timeout_s == nocrash_timeout_s(s.route_length_m)


def test_a_repeated_model_benches_every_model_under_a_readable_name() -> None:
    """Issue 36: --model A --model B runs both; two seed_0 from different sets keep their set's name."""
    from brlcli.bench.plan import plan_bench
    from brlcli.bench.registry import find_models

    root = Path(__file__).resolve().parents[1] / "models"
    found = find_models([str(root / "brl_gt" / "seed_0"), str(root / "brl_te" / "seed_0"),
                         str(root / "brl_gt" / "seed_1")], None)
    assert [n for n, _ in found] == ["brl_gt/seed_0", "brl_te/seed_0", "seed_1"]
    plan = plan_bench("paper", "brl", [str(root / "brl_gt" / "seed_0"), str(root / "brl_gt" / "seed_1")],
                      episodes="2")
    assert [p.name for p in plan.policies] == ["seed_0", "seed_1"]
    with pytest.raises(BrlInputError, match="give --agent il one --model"):
        plan_bench("paper", "il", ["a.pt", "b.pt"])


def test_the_bench_table_keeps_whole_names_in_a_log(tmp_path: Path) -> None:
    """Issue 36: with stderr not a terminal, the summary table is not cut to 80 columns (no 'brl_gt/see…')."""
    r = subprocess.run([sys.executable, "-m", "brlcli.cli", "bench", "--models", "models/brl_gt", "--episodes", "1",
                        "--out", str(tmp_path / "b")], capture_output=True, text=True, timeout=300)
    assert r.returncode == 0, r.stderr
    table = [line for line in r.stderr.splitlines() if "│" in line]
    assert any("brl_gt/seed_0" in line for line in table) and not any("…" in line for line in table)
