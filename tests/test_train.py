"""Training: determinism, resume after an interruption, model sets, CLI errors, and that the agent learns."""

import json
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest

from brlcli.agent import BayesianAgent
from brlcli.errors import BrlInputError
from brlcli.evaluate import evaluate_lane_keeping
from brlcli.train import LOG_COLUMNS, parse_seeds, train_many, train_run
from brlcli.trainconfig import TrainConfig


def _files(run: Path) -> tuple[bytes, bytes]:
    return (run / "log.csv").read_bytes(), (run / "model.npz").read_bytes()


def test_same_seed_gives_identical_log_and_model(tmp_path: Path) -> None:
    cfg = TrainConfig(steps=80, seed=4, evaluate=False)
    train_run(cfg, tmp_path / "a")
    train_run(cfg, tmp_path / "b")
    assert _files(tmp_path / "a") == _files(tmp_path / "b")
    other = TrainConfig(steps=80, seed=5, evaluate=False)
    train_run(other, tmp_path / "c")
    assert _files(tmp_path / "c")[0] != _files(tmp_path / "a")[0]
    header = (tmp_path / "a" / "log.csv").read_text().splitlines()
    assert header[0].split(",") == list(LOG_COLUMNS) and len(header) == 81
    cfg_saved = json.loads((tmp_path / "a" / "config.json").read_text())
    assert cfg_saved["config"]["seed"] == 4 and "git_commit" in cfg_saved and "brl_version" in cfg_saved


@pytest.mark.parametrize("params, extra", [({}, {}),
                                           ({"step_size": "action-visits"}, {}),
                                           ({}, {"task": "navigation"}),
                                           ({}, {"task": "navigation", "branch_restart_below": [10.0] * 4})])
def test_interrupted_run_resumes_bit_identical(tmp_path: Path, params: dict, extra: dict) -> None:
    """Also with the per-action step size, for the command-conditioned agent of the navigation task, and with its
    per-branch restarts (every branch restarts at both checks when every threshold is above every reward)."""
    cfg = TrainConfig(steps=150, seed=1, evaluate=False, params={**TrainConfig().params, **params}, **extra)
    train_run(cfg, tmp_path / "full")

    class Stop(Exception):
        pass

    def kill_at_100(p) -> None:
        if p.step >= 100:
            raise Stop

    with pytest.raises(Stop):
        train_run(cfg, tmp_path / "cut", progress=kill_at_100)
    assert not (tmp_path / "cut" / "model.npz").exists()
    with pytest.raises(BrlInputError):
        train_run(cfg, tmp_path / "cut")  # refuses to overwrite without resume
    summary = train_run(cfg, tmp_path / "cut", resume=True)["summary"]
    assert _files(tmp_path / "cut") == _files(tmp_path / "full")
    if "branch_restart_below" in extra:
        restarts = summary["branch_restarts"]
        assert {r["step"] >= 50 for r in restarts} == {True} and len({r["step"] for r in restarts}) == 2
        assert restarts and all(r["mean_reward"] < 10.0 for r in restarts)


def test_log_rows_are_written_by_column_name() -> None:
    from brlcli.agent import LearnStep
    from brlcli.train import TRAFFIC_LOG_COLUMNS, Run, log_columns, log_row

    learned = LearnStep(-1.5, 2, False, 0.25, "neutral", 3, 0.9, 0.6, 0.1)
    info = {"reward_terms": {"collision": 0.0, "offroad": 0.0, "otherlane": -2.0, "speed": -1.0, "road_view": 0.0},
            "measurements": {"forward_speed_kmh": 12.0, "intersection_offroad": 0.0, "intersection_otherlane": 0.1,
                             "x": 1.0, "y": 2.0}}
    run = Run(TrainConfig(steps=10), None, np.random.default_rng(0), step=7, episode=2)  # type: ignore[arg-type]
    row = log_row(run, 3, 1, -3.0, learned, info, 2)
    assert list(row) == list(LOG_COLUMNS + TRAFFIC_LOG_COLUMNS)
    assert log_columns(TrainConfig()) == LOG_COLUMNS  # the paper's runs keep their log format
    assert log_columns(TrainConfig(traffic=["regular"])) == LOG_COLUMNS + TRAFFIC_LOG_COLUMNS
    assert row["action"] == "right" and row["components"] == 3 and row["tau"] == 0.6 and row["r_progress"] == 0.0


def test_retired_knobs_are_refused_with_the_commit_that_reruns_them(tmp_path: Path) -> None:
    from brlcli.config import Layer
    from brlcli.retired import RETIRED_AT
    from brlcli.trainconfig import resolve_train_config

    for layer in ({"teams": 3}, {"keep_best": True}, {"params": {"exploration": "posterior"}}, {"no_backward": False}):
        with pytest.raises(BrlInputError, match=f"retired.*git checkout {RETIRED_AT}"):
            resolve_train_config([Layer("--set", layer)])
    saved = {**TrainConfig().to_dict(), "teams": 1, "shared_mixture": False, "r_heading": 0.0,
             "params": {"init_scatter": 1e-3, "td_error": "component"}}
    assert TrainConfig.from_saved(saved, "x/config.json") == TrainConfig()  # an older brl's run without the knobs
    with pytest.raises(BrlInputError, match=r"x/config.json was made with teams = 3.*git checkout"):
        TrainConfig.from_saved({**saved, "teams": 3}, "x/config.json")


def test_model_set_does_not_depend_on_worker_count(tmp_path: Path) -> None:
    cfg = TrainConfig(steps=40, evaluate=False)
    train_many(cfg, [0, 1], tmp_path / "w1", workers=1)
    train_many(cfg, [0, 1], tmp_path / "w2", workers=2)
    for s in (0, 1):
        assert _files(tmp_path / "w1" / f"seed_{s}") == _files(tmp_path / "w2" / f"seed_{s}")


def test_parse_seeds() -> None:
    assert parse_seeds("0-8") == list(range(9))
    assert parse_seeds("3,1,1") == [1, 3]
    for bad in ("3-1", "x", "", "-2"):
        with pytest.raises(BrlInputError):
            parse_seeds(bad)


@pytest.mark.parametrize("args", [["--input", "estimated", "--segnet", "missing.pt"], ["--input", "depth"],
                                  ["--seeds", "5-2"], ["--steps", "0"],
                                  ["--weather", "Foggy"], ["--town", "town77"], ["--workers", "0"]])
def test_cli_bad_input_is_one_line_exit_2(tmp_path: Path, args: list[str]) -> None:
    r = subprocess.run([sys.executable, "-m", "brlcli.cli", "train", "--out", str(tmp_path / "o"), *args],
                       capture_output=True, text=True, timeout=120)
    assert r.returncode == 2, r.stderr
    assert r.stderr.strip().count("\n") == 0 and "Traceback" not in r.stderr
    assert not (tmp_path / "o" / "seed_0" / "model.npz").exists()


def test_cli_trains_and_refuses_to_overwrite(tmp_path: Path) -> None:
    cmd = [sys.executable, "-m", "brlcli.cli", "train", "--steps", "30", "--no-evaluate", "--out", str(tmp_path)]
    r = subprocess.run(cmd, capture_output=True, text=True, timeout=120)
    assert r.returncode == 0, r.stderr
    summary = json.loads((tmp_path / "seed_0" / "summary.json").read_text())["summary"]
    assert summary["committee"] == 5 and len(summary["members"]) == 5  # the default: a committee of five
    member = json.loads((tmp_path / "seed_0" / "member_0" / "summary.json").read_text())["summary"]
    assert member["final_attempt_steps"] == 30  # each member restarts when trapped: 30 steps in its last attempt
    assert member["steps"] == 30 + sum(r["attempt_steps"] for r in member["restarts"])
    again = subprocess.run(cmd, capture_output=True, text=True, timeout=120)
    assert again.returncode == 2 and "--resume" in again.stderr


class _Uniform:
    def act(self, state: np.ndarray, rng: np.random.Generator, greedy: bool = True) -> int:
        return int(rng.integers(4))


def test_agent_beats_a_uniform_random_policy(tmp_path: Path) -> None:
    """A small budget (1000 learning steps, seeds 0-2) already drives the lane-keeping routes better than chance."""
    random_rate = evaluate_lane_keeping(_Uniform())["success_rate"]
    rates = []
    for seed in (0, 1, 2):
        train_run(TrainConfig(steps=1000, seed=seed, evaluate=False), tmp_path / str(seed))
        agent = BayesianAgent.load(tmp_path / str(seed) / "model.npz")
        rates.append(evaluate_lane_keeping(agent)["success_rate"])
    assert np.mean(rates) >= random_rate + 0.2, (rates, random_rate)


def test_estimated_input_trains_on_the_shipped_segmentation_net(tmp_path: Path) -> None:
    from brlcli.models import default_segnet_path

    cfg = TrainConfig(steps=30, seed=0, input="estimated", segnet=str(default_segnet_path()), evaluate=False)
    train_run(cfg, tmp_path / "te")
    gt = TrainConfig(steps=30, seed=0, evaluate=False)
    train_run(gt, tmp_path / "tg")
    log_te = (tmp_path / "te" / "log.csv").read_text()
    assert len(log_te.splitlines()) == 31
    assert log_te != (tmp_path / "tg" / "log.csv").read_text()  # the estimated states differ from GT ones


def test_learning_curve_evaluations_do_not_change_training(tmp_path: Path, monkeypatch) -> None:
    import brlcli.bench.runner as curve
    from brlcli.bench.suites import build_suite
    from brlcli.curve import read_curve

    two = build_suite("paper", weathers="1")[:2]
    monkeypatch.setattr(curve, "build_suite", lambda suite, weathers=None: two)
    train_run(TrainConfig(steps=60, seed=2, evaluate=False), tmp_path / "plain")
    train_run(TrainConfig(steps=60, seed=2, evaluate=False, curve_every=30), tmp_path / "curve")
    assert _files(tmp_path / "plain") == _files(tmp_path / "curve")
    rows = read_curve(tmp_path / "curve" / "learning_curve.csv")
    assert [r["env_steps"] for r in rows] == [30, 60] and all(r["episodes"] == 2 for r in rows)
    assert all(0.0 <= r["success"] <= 1.0 and 0.0 <= r["either"] <= 1.0 for r in rows)


def test_train_summary_line_reports_either_and_score_beside_success() -> None:
    """A model that drives on the sidewalk must not read as just 'success 100 %'."""
    from brlcli.cli import train_summary_line

    s = {"seed": 3, "steps": 4500, "episodes": 40, "components": 12, "steps_per_s": 150.0,
         "eval": {"town": "town01", "routes": "validation", "success_rate": 1.0, "either_share": 0.627,
                  "score": 0.79}}
    line = train_summary_line(s)
    assert "lane-keeping success 100%  Either 62.7%  Score 0.79 (town01 validation routes)" in line
    assert "Either" not in train_summary_line({**s, "eval": None})
    restarts = [{"step": 1502, "mean_reward": -9.41}, {"step": 3010, "mean_reward": -7.5}]
    assert ("(2 restarts, trapped: -9.4 per step over the window at step 1,502; -7.5 per step over the window at "
            "step 3,010)") in train_summary_line({**s, "restarts": restarts}) and "restart" not in line
    committee = {**s, "committee": 5, "members": [{"restarts": []}, {"restarts": [{}]}], "eval": {
        "suite": "validation_starts", "success_rate": 0.99, "either_share": 0.01, "score": 0.99}}
    assert ("(a committee of 5 members, majority vote; 1 member restarted when trapped), lane-keeping success 99%  "
            "Either 1.0%  Score 0.99 (validation_starts suite)") in train_summary_line(committee)


def test_restarts_on_a_trap_and_resumes_bit_identical(tmp_path: Path) -> None:
    """restart_below above every reward restarts at each check until max_restarts; a cut run resumes exactly."""
    cfg = TrainConfig(steps=90, seed=2, evaluate=False, restart_below=1.0, max_restarts=2)
    summary = train_run(cfg, tmp_path / "full")["summary"]
    n = len(summary["restarts"])
    assert summary["attempts"] == n + 1 and n >= 1  # every check restarts, until the cap
    assert all(r["attempt_steps"] >= 30 for r in summary["restarts"])  # first check at a third of the steps
    assert all(r["step"] <= 90 for r in summary["restarts"]) and summary["steps"] <= 180  # never past 2 x steps
    assert summary["final_attempt_steps"] == 90
    assert summary["steps"] == 90 + sum(r["attempt_steps"] for r in summary["restarts"])
    rows = (tmp_path / "full" / "log.csv").read_text().splitlines()[1:]
    attempts = [int(r.split(",")[LOG_COLUMNS.index("attempt")]) for r in rows]
    assert attempts == sorted(attempts) and set(attempts) == set(range(n + 1)) and attempts.count(n) == 90
    agent = BayesianAgent.load(tmp_path / "full" / "model.npz")
    assert agent.steps == 90  # the model is the last attempt's, trained from scratch

    class Stop(Exception):
        pass

    def kill(p) -> None:
        if p.step >= summary["restarts"][0]["step"] + 20:
            raise Stop

    with pytest.raises(Stop):
        train_run(cfg, tmp_path / "cut", progress=kill)
    train_run(cfg, tmp_path / "cut", resume=True)
    assert _files(tmp_path / "cut") == _files(tmp_path / "full")
    never = TrainConfig(steps=90, seed=2, evaluate=False, restart_below=-1e9)
    assert train_run(never, tmp_path / "never")["summary"]["attempts"] == 1


def test_trap_test_reads_the_reward_at_its_checks_only() -> None:
    """The trap test fires at its checks only, on a low mean reward over its window, at most max_restarts times."""
    from brlcli.train import Run, RunStats, TrapRestart

    cfg = TrainConfig(steps=90, restart_below=-7.0)
    hook = TrapRestart(cfg)

    def run(step: int, rewards: list[float], attempt: int = 0) -> Run:
        return Run(cfg, None, np.random.default_rng(0), step=step,  # type: ignore[arg-type]
                   stats=RunStats(attempt=attempt, window=rewards, window_offroad=[0] * len(rewards)))

    assert not hook.trapped(run(29, [-9.0] * 15))  # before the first check (a third)
    assert hook.trapped(run(30, [-9.0] * 15))
    assert not hook.trapped(run(30, [-4.0] * 15))  # edge hugging: the reward test misses it
    assert not hook.trapped(run(30, [-9.0] * 15, attempt=2))  # max_restarts reached
    r = run(30, [-4.0] * 15)
    assert not hook.trapped(r) and r.stats.checks_done == 1 and not hook.trapped(r)  # one test per check


def test_a_lane_keeping_committee_votes_and_benches(tmp_path: Path) -> None:
    """committee=K for lane keeping: K paper agents trained apart (member 0 the seed's own run), one model that drives
    by majority vote, read by the bench like any lane-keeping model."""
    from brlcli.agent.committee import LaneKeepingCommittee, load_lane_keeping_agent
    from brlcli.policy import BRLPolicy

    cfg = TrainConfig(steps=60, seed=2, evaluate=False, committee=3)
    summary = train_run(cfg, tmp_path / "com")["summary"]
    assert summary["committee"] == 3 and summary["steps"] == 180 and len(summary["members"]) == 3
    train_run(TrainConfig(steps=60, seed=2, evaluate=False), tmp_path / "plain")
    assert (tmp_path / "com" / "member_0" / "log.csv").read_bytes() == (tmp_path / "plain" / "log.csv").read_bytes()
    agent = load_lane_keeping_agent(tmp_path / "com" / "model.npz")
    assert isinstance(agent, LaneKeepingCommittee) and len(agent.members) == 3
    members = [BayesianAgent.load(tmp_path / "com" / f"member_{k}" / "model.npz") for k in range(3)]
    policy = BRLPolicy("c", str(tmp_path / "com" / "model.npz"))
    rng = np.random.default_rng(0)
    for s in rng.dirichlet(np.ones(30), size=20):
        probs = np.array([m.action_probabilities(s) for m in members])
        votes = np.bincount(probs.argmax(1), minlength=4)
        assert policy.act(s) == int(np.argmax(np.where(votes == votes.max(), probs.mean(0), -np.inf)))
    with pytest.raises(ValueError, match="greedily"):
        agent.act(np.full(30, 1 / 30), rng)
    from brlcli.agent.command import CommandAgent

    CommandAgent().save(tmp_path / "nav.npz")
    with pytest.raises(BrlInputError, match="not a lane-keeping one"):
        load_lane_keeping_agent(tmp_path / "nav.npz")


def test_validation_starts_drive_each_validation_route_from_six_poses_none_of_the_paper_suite() -> None:
    from brlcli.bench.suites import START_VARIANTS, build_suite

    starts = build_suite("validation_starts", weathers="1")
    plain = build_suite("validation", weathers="1")
    assert len(starts) == len(START_VARIANTS) * len(plain) and len({s.id for s in starts}) == len(starts)
    assert {s.start for s in plain} <= {s.start for s in starts}
    paper = {tuple(round(v, 1) for v in s.start) for s in build_suite("paper")}
    assert not paper & {tuple(round(v, 1) for v in s.start) for s in starts}
