"""The conditional imitation learning baseline: branch selection, data pairing, training, files, the bench policy."""

import dataclasses
import json
import math
from pathlib import Path

import numpy as np
import pytest
import torch

from brlcli.baselines.il import (
    IL_FORMAT,
    ILNet,
    ILNetConfig,
    ILPolicy,
    ILTrainConfig,
    command_branch,
    default_il_path,
    load_frames,
    load_il,
    save_il,
    select_branch,
    train_il,
)
from brlcli.bench.runner import run_episode
from brlcli.bench.suites import build_suite
from brlcli.collect import CollectConfig, collect
from brlcli.errors import BrlInputError
from brlcli.sim.world import World

TINY = ILNetConfig(widths=(8, 8, 16, 16), image_features=32, speed_features=8, joint_features=32, branch_hidden=16,
                   input_height=22, input_width=50).to_dict()


@pytest.fixture(scope="module")
def bags(tmp_path_factory: pytest.TempPathFactory) -> Path:
    out = tmp_path_factory.mktemp("il_bags")
    collect(CollectConfig(episodes=2, episode_frames=30, every=1, seed=3, depth=False), out)
    return out


def test_commands_map_to_branches_and_the_frames_branch_is_selected() -> None:
    assert command_branch(np.array([0, 2, 3, 4, 5])).tolist() == [0, 0, 1, 2, 3]
    outputs = torch.arange(2 * 4 * 3, dtype=torch.float32).reshape(2, 4, 3)
    got = select_branch(outputs, torch.tensor([3, 1]))
    assert got.tolist() == [outputs[0, 3].tolist(), outputs[1, 1].tolist()]


def test_each_image_is_paired_with_the_expert_control_of_its_own_measurements(bags: Path) -> None:
    from brlcli.bags import iter_frames

    data = load_frames([bags], 22, 50)
    raw = list(iter_frames([bags], need_labels=False))
    assert len(data) == 60 and data.rgb.shape == (60, 22, 50, 3)
    assert data.exact_pairs == 58 and data.lagged_pairs == 2  # --every 1: all but each bag's last frame
    e = raw[1].expert_control
    np.testing.assert_allclose(data.target[0], [e.steer, e.throttle, e.brake], rtol=1e-6)
    e = raw[29].expert_control
    np.testing.assert_allclose(data.target[29], [e.steer, e.throttle, e.brake], rtol=1e-6)


def test_training_lowers_the_loss_and_is_reproducible(bags: Path, tmp_path: Path) -> None:
    cfg = ILTrainConfig(epochs=4, batch_size=8, lr=3e-3, seed=5, threads=1, net=TINY)
    summary = train_il(cfg, [str(bags)], tmp_path / "a")
    losses = [r["train_loss"] for r in summary["history"]]
    assert losses[-1] < losses[0]
    assert summary["train_frames"] == 30 and summary["val_frames"] == 30  # one bag of two held out
    assert all("val" in r and math.isfinite(r["val"]["loss"]) for r in summary["history"])
    lines = (tmp_path / "a" / "metrics.jsonl").read_text().splitlines()
    assert [json.loads(line)["epoch"] for line in lines] == [1, 2, 3, 4]
    assert json.loads((tmp_path / "a" / "config.json").read_text())["config"]["seed"] == 5
    net, extra = load_il(tmp_path / "a" / "il.pt")
    assert extra["input_size"] == [22, 50] and net.cfg.input_width == 50
    train_il(cfg, [str(bags)], tmp_path / "b")
    a = torch.load(tmp_path / "a" / "last.pt", weights_only=True)["state_dict"]
    b = torch.load(tmp_path / "b" / "last.pt", weights_only=True)["state_dict"]
    assert all(torch.equal(a[k], b[k]) for k in a)


def test_resume_after_an_interruption_gives_the_same_weights(bags: Path, tmp_path: Path) -> None:
    cfg = ILTrainConfig(epochs=3, batch_size=8, seed=2, threads=1, net=TINY)
    full = train_il(cfg, [str(bags)], tmp_path / "full")

    def stop_after_first(record: dict) -> None:
        if record["epoch"] == 1:
            raise KeyboardInterrupt

    with pytest.raises(KeyboardInterrupt):
        train_il(cfg, [str(bags)], tmp_path / "cut", progress=stop_after_first)
    resumed = train_il(cfg, [str(bags)], tmp_path / "cut", resume=True)
    assert resumed["history"] == [dict(r, wall_s=resumed["history"][i]["wall_s"]) for i, r in
                                  enumerate(full["history"])]
    a = torch.load(tmp_path / "full" / "last.pt", weights_only=True)["state_dict"]
    b = torch.load(tmp_path / "cut" / "last.pt", weights_only=True)["state_dict"]
    assert all(torch.equal(a[k], b[k]) for k in a)
    with pytest.raises(BrlInputError):
        train_il(dataclasses.replace(cfg, lr=0.5), [str(bags)], tmp_path / "cut", resume=True)


def test_bad_files_and_options_are_input_errors(tmp_path: Path) -> None:
    with pytest.raises(BrlInputError):
        ILPolicy(model=str(tmp_path / "missing.pt"))
    with pytest.raises(BrlInputError):
        train_il(ILTrainConfig(net=TINY), [str(tmp_path / "no_bags")], tmp_path / "out")
    net = ILNet(ILNetConfig.from_dict(TINY))
    save_il(tmp_path / "ok.pt", net, {"mean": [0.5] * 3, "std": [0.25] * 3})
    ILPolicy(model=str(tmp_path / "ok.pt"), deploy="estimated")
    doc = torch.load(tmp_path / "ok.pt", weights_only=True)
    assert doc["format"] == IL_FORMAT
    torch.save({**doc, "format_version": 99}, tmp_path / "v99.pt")
    torch.save({**doc, "format": "brl-segnet"}, tmp_path / "seg.pt")
    (tmp_path / "junk.pt").write_bytes(b"not a torch file")
    for name in ("v99.pt", "seg.pt", "junk.pt"):
        with pytest.raises(BrlInputError):
            load_il(tmp_path / name)
    with pytest.raises(BrlInputError):
        ILPolicy(model=str(tmp_path / "ok.pt"), deploy="lidar")
    with pytest.raises(BrlInputError):
        ILTrainConfig(epochs=0)


@pytest.mark.skipif(not default_il_path().is_file(), reason="no shipped IL model")
def test_the_shipped_model_drives_a_short_route() -> None:
    spec = next(s for s in build_suite("paper", weathers="1") if s.town == "town01" and s.task == "straight")
    spec = dataclasses.replace(spec, timeout_s=6.0)  # 60 frames
    policy = ILPolicy()
    world = World(spec.town, seed=0)
    try:
        result, log = run_episode(world, spec, policy, bench_seed=0)
    finally:
        world.close()
    assert result["steps"] == 60 and np.isfinite(log["control"]).all()
    assert result["km"] > 0.005  # it drives off


def test_cli_trains_refuses_to_overwrite_and_benches_the_model(bags: Path, tmp_path: Path, brl_in_process) -> None:
    import subprocess
    import sys

    def brl(*args: str) -> subprocess.CompletedProcess:
        return subprocess.run([sys.executable, "-m", "brlcli.cli", *args], capture_output=True, text=True, timeout=300)

    out = tmp_path / "il"
    done = brl("train-il", "--data", str(bags), "--epochs", "1", "--batch-size", "8", "--workers", "1",
               "--out", str(out))
    assert done.returncode == 0, done.stderr
    assert done.stdout.strip().endswith("il.pt") and (out / "il.pt").is_file()
    again = brl_in_process("train-il", "--data", str(bags), "--epochs", "1", "--out", str(out))
    assert again.returncode == 2 and "--resume" in again.stderr and "Traceback" not in again.stderr
    bench = brl("bench", "--agent", "il", "--model", str(out), "--episodes", "1", "--out", str(tmp_path / "b"))
    assert bench.returncode == 0, bench.stderr
    row = json.loads((tmp_path / "b" / "results.jsonl").read_text().splitlines()[0])
    assert row["setting"] == "IL" and row["policy"] == "il/il"
