"""Deep RL baseline (SB3 DQN): env checks, resumable bit-identical training, the bench policy, learning curves."""

from __future__ import annotations

import csv
import io
import tempfile
from pathlib import Path

import numpy as np
import pytest
import torch

import brlcli.baselines.deeprl as drl
from brlcli.baselines.deeprl import DeepRLConfig, load_model, train_deep_rl
from brlcli.bench.runner import run_bench
from brlcli.bench.suites import build_suite
from brlcli.curve import CURVE_FILE, read_curve, steps_to_reach, write_curve
from brlcli.errors import BrlInputError
from brlcli.policy import PolicySpec
from brlcli.report import build_report
from brlcli.sim.gym_env import DrivingEnv

TINY = {"steps": 240, "eval_every": 120, "eval_suite": "none", "learning_starts": 40, "target_update_interval": 40,
        "batch_size": 16}


def test_env_passes_the_sb3_checker() -> None:
    from stable_baselines3.common.env_checker import check_env

    env = DrivingEnv()
    try:
        check_env(env, warn=True)
    finally:
        env.close()


def test_dqn_trains_on_brl_trains_reward_and_episode_rule() -> None:
    env = drl._make_env(DeepRLConfig())
    try:
        assert env.reward_params.road_view == "road+line" and env.offroad_end == 0.5
    finally:
        env.close()
    old = DeepRLConfig().to_dict()
    del old["road_view"], old["offroad_end"]  # a config.json written before these options
    cfg = DeepRLConfig.from_dict(old)
    assert (cfg.road_view, cfg.offroad_end) == ("road", None)
    with pytest.raises(BrlInputError, match="road_view"):
        DeepRLConfig(road_view="lines")
    with pytest.raises(BrlInputError, match="offroad_end"):
        DeepRLConfig(offroad_end=1.5)


class _Stop(Exception):
    pass


@pytest.fixture(scope="module")
def trained(tmp_path_factory: pytest.TempPathFactory) -> Path:
    out = tmp_path_factory.mktemp("dqn") / "run"
    tmp = tmp_path_factory.mktemp("tmpdir")
    old = tempfile.tempdir
    tempfile.tempdir = str(tmp)  # where SB3's default logger would make its SB3-<date> directory
    try:
        train_deep_rl(DeepRLConfig(**TINY), out)
    finally:
        tempfile.tempdir = old
    assert not list(tmp.glob("SB3-*")), "training left SB3 logger directories in the temporary directory"
    return out


def test_interrupted_training_resumes_bit_identically(trained: Path, tmp_path: Path, monkeypatch) -> None:
    original = drl._save_checkpoint

    def stop_after_first_chunk(run_dir, model, chunk, *args):
        original(run_dir, model, chunk, *args)
        raise _Stop

    monkeypatch.setattr(drl, "_save_checkpoint", stop_after_first_chunk)
    with pytest.raises(_Stop):
        train_deep_rl(DeepRLConfig(**TINY), tmp_path / "b")
    monkeypatch.setattr(drl, "_save_checkpoint", original)
    assert sorted(p.name for p in (tmp_path / "b" / "checkpoint").iterdir()) == [
        "networks_00001.pt", "replay_00001.npz", "state.json"]
    with pytest.raises(BrlInputError, match="--resume"):
        train_deep_rl(DeepRLConfig(**TINY), tmp_path / "b")
    summary = train_deep_rl(DeepRLConfig(**TINY), tmp_path / "b", resume=True)["summary"]
    assert summary["env_steps"] == TINY["steps"]
    assert sorted(p.name for p in (tmp_path / "b" / "checkpoint").iterdir()) == [
        "networks_00002.pt", "replay_00002.npz", "state.json"]  # older chunks' files are gone
    a, meta_a = load_model(trained)
    b, meta_b = load_model(tmp_path / "b" / "drl.pt")
    assert meta_a == meta_b and meta_a["env_steps"] == TINY["steps"]
    for (ka, va), (kb, vb) in zip(a.state_dict().items(), b.state_dict().items(), strict=True):
        assert ka == kb and torch.equal(va, vb)
    with pytest.raises(BrlInputError, match="another configuration"):
        train_deep_rl(DeepRLConfig(**{**TINY, "seed": 3}), tmp_path / "b", resume=True)


def test_training_moves_the_network_away_from_its_initialisation(trained: Path) -> None:
    from stable_baselines3 import DQN

    env = DrivingEnv()
    init = DQN("MlpPolicy", env, policy_kwargs={"net_arch": [64, 64]}, seed=0, device="cpu").q_net.q_net
    env.close()
    net, _ = load_model(trained)
    diffs = [float((p - q).detach().abs().max()) for p, q in zip(net.parameters(), init.parameters(), strict=True)]
    assert max(diffs) > 1e-4


def test_dqn_policy_drives_a_short_route_in_the_bench(trained: Path, tmp_path: Path) -> None:
    specs = build_suite("paper", weathers="1")[:1]
    rows = run_bench(specs, [PolicySpec("dqn", "dqn/tiny", {"model": str(trained), "deploy": "gt"})],
                     tmp_path / "b", {"suite": "paper", "seed": 0})
    assert len(rows) == 1 and rows[0]["setting"] == "DQN-TGDG" and rows[0]["steps"] > 0


def test_bad_model_files_are_refused(tmp_path: Path, trained: Path) -> None:
    with pytest.raises(BrlInputError, match="does not exist"):
        load_model(tmp_path / "nothing.pt")
    junk = tmp_path / "junk.pt"
    junk.write_bytes(b"not a torch file")
    with pytest.raises(BrlInputError, match="not a brl deep RL model"):
        load_model(junk)
    doc = torch.load(trained / "drl.pt", weights_only=True)
    doc["format_version"] = 99
    buf = io.BytesIO()
    torch.save(doc, buf)
    (tmp_path / "v99.pt").write_bytes(buf.getvalue())
    with pytest.raises(BrlInputError, match="format version 99"):
        load_model(tmp_path / "v99.pt")
    with pytest.raises(BrlInputError, match="unknown deep RL algorithm"):
        DeepRLConfig(algo="a2c")
    with pytest.raises(BrlInputError, match="multiple of the train frequency"):
        DeepRLConfig(eval_every=10)


def test_learning_curve_written_during_training(tmp_path: Path, monkeypatch) -> None:
    import brlcli.bench.runner as curve

    two = build_suite("paper", weathers="1")[:2]
    monkeypatch.setattr(curve, "build_suite", lambda suite, weathers=None: two)
    out = tmp_path / "c"
    train_deep_rl(DeepRLConfig(**{**TINY, "eval_suite": "paper"}), out, evaluator=curve.SuiteEvaluator("paper"))
    rows = read_curve(out / CURVE_FILE)
    assert [r["env_steps"] for r in rows] == [120, 240]
    assert all(r["episodes"] == 2 and 0.0 <= r["success"] <= 1.0 for r in rows)


def _curve_dir(path: Path, algo: str | None, successes: list[float], every: int) -> Path:
    import json

    path.mkdir(parents=True)
    cfg = {"input": "gt", **({"algo": algo} if algo else {})}
    (path / "config.json").write_text(json.dumps({"config": cfg}))
    write_curve(path / CURVE_FILE, [{"env_steps": every * (k + 1), "episodes": 66, "success": s,
                                     "collision_free": 1.0, "either": 0.1, "score": 0.5, "eval_suite": "paper"}
                                    for k, s in enumerate(successes)])
    return path


def test_steps_to_reach_and_the_sample_efficiency_table(tmp_path: Path) -> None:
    rows = [{"env_steps": 100, "success": 0.2}, {"env_steps": 200, "success": 0.5}, {"env_steps": 300,
                                                                                    "success": 0.4}]
    assert steps_to_reach(rows, 0.45) == 200
    assert steps_to_reach(rows, 0.6) is None
    brl = tmp_path / "brl"
    _curve_dir(brl / "seed_0", None, [0.2, 0.4], 500)
    _curve_dir(brl / "seed_1", None, [0.4, 0.6], 500)
    dqn = _curve_dir(tmp_path / "dqn", "dqn", [0.1, 0.3, 0.5, 0.45], 5000)
    results = tmp_path / "res"
    from tests.test_report import model_set, write_results

    write_results(results, model_set("TGDG"))
    out = tmp_path / "rep"
    build_report([results], out=out, formats="csv", curve_dirs=[brl, dqn])
    with open(out / "tables" / "sample_efficiency.csv", newline="") as fh:
        table = {r["Learner"]: r for r in csv.DictReader(fh)}
    assert table["BRL (TG)"]["Final success [%]"] == "50.0000"  # mean of 0.4 and 0.6
    assert table["BRL (TG)"]["Runs"] == "2"
    assert table["DQN (TG)"]["Env steps to BRL (TG) final success"] == "15000"
    assert np.isclose(float(table["DQN (TG)"]["Best mean success [%]"]), 50.0)


def test_cli_trains_refuses_to_overwrite_and_rejects_bad_options(tmp_path: Path, brl_in_process) -> None:
    import subprocess
    import sys

    def brl(*args: str) -> subprocess.CompletedProcess:
        return subprocess.run([sys.executable, "-m", "brlcli.cli", *args], capture_output=True, text=True, timeout=300)

    out = tmp_path / "dqn"
    args = ("train-rl", "--steps", "40", "--eval-every", "20", "--eval-suite", "none", "--out", str(out))
    done = brl(*args)
    assert done.returncode == 0, done.stderr
    assert done.stdout.strip().endswith("drl.pt") and load_model(out)[1]["env_steps"] == 40
    for bad in (args, ("train-rl", "--algo", "ppo", "--out", str(tmp_path / "x")),
                ("train-rl", "--eval-every", "10", "--out", str(tmp_path / "x")),
                ("train-rl", "--weather", "Blizzard", "--out", str(tmp_path / "x"))):
        r = brl_in_process(*bad)
        assert r.returncode == 2 and r.stderr.strip().count("\n") == 0 and "Traceback" not in r.stderr, r.stderr
    assert not (tmp_path / "x").exists()


def test_navigation_dqn_sees_the_command_and_curves_on_nav_validation(tmp_path: Path, monkeypatch) -> None:
    import brlcli.bench.runner as curve

    cfg = DeepRLConfig(**{**TINY, "task": "navigation", "eval_suite": "auto"})
    assert cfg.evaluation_suite == "nav_validation" and cfg.state_dim == 34
    with pytest.raises(BrlInputError, match="does not fit"):
        DeepRLConfig(task="navigation", eval_suite="paper")
    env = drl._make_env(cfg)
    try:
        obs, info = env.reset(seed=0)
        assert obs.shape == (34,) and obs[30:].sum() == 1.0 and env.unwrapped.route_reward is not None
        assert obs[30 + int(drl.command_branch(info["command"]))] == 1.0
    finally:
        env.close()
    one = build_suite("nav_validation")[:1]
    monkeypatch.setattr(curve, "build_suite", lambda suite, weathers=None: one)
    train_deep_rl(cfg, tmp_path / "nav", evaluator=curve.SuiteEvaluator(cfg.evaluation_suite))
    rows = read_curve(tmp_path / "nav" / CURVE_FILE)
    assert [r["eval_suite"] for r in rows] == ["nav_validation", "nav_validation"]
    net, meta = load_model(tmp_path / "nav")
    assert net[0].in_features == 34 and meta["train"]["task"] == "navigation"
    policy = drl.DeepRLPolicy("dqn/nav", str(tmp_path / "nav" / "drl.pt"))
    assert policy.uses_command and policy.task == "navigation" and "navigation" in policy.setting


def test_navigation_dqn_with_the_brake_trains_in_traffic_on_the_hazard_reward(tmp_path: Path) -> None:
    traffic = {"task": "navigation", "actions": "stop", "traffic": ("regular",), "r_hazard": 20.0}
    cfg = DeepRLConfig(**{**TINY, **traffic})
    assert DeepRLConfig(**{**traffic, "eval_suite": "auto"}).evaluation_suite == "nav_validation_traffic"
    assert DeepRLConfig.from_dict(cfg.to_dict()) == cfg  # traffic round-trips through config.json's list
    env = drl._make_env(cfg)
    try:
        assert env.action_space.n == 5 and env.unwrapped.hazard is not None
        assert env.unwrapped.traffic_levels == ("regular",)
    finally:
        env.close()
    train_deep_rl(cfg, tmp_path / "stop")
    net, meta = load_model(tmp_path / "stop")
    assert net[-1].out_features == 5 and meta["train"]["actions"] == "stop"
    policy = drl.DeepRLPolicy("dqn/stop", str(tmp_path / "stop" / "drl.pt"))
    assert len(policy.actions) == 5 and "stop primitive" in policy.setting
    with pytest.raises(BrlInputError, match="needs traffic"):
        DeepRLConfig(r_hazard=20.0)
    with pytest.raises(BrlInputError, match="action set"):
        DeepRLConfig(actions="brake")
    with pytest.raises(BrlInputError, match="nav_validation_traffic does not fit"):
        DeepRLConfig(eval_suite="nav_validation_traffic")
