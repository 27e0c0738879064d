"""The executor seam: local and Ray give the same bench results and models, retries, resume, bad input, imports."""

import functools
import json
import logging
import os
import subprocess
import sys
from pathlib import Path

import pytest

from brlcli.bench.runner import read_results, run_bench
from brlcli.bench.suites import build_suite, subset
from brlcli.errors import BrlInputError
from brlcli.executor import Executor, report, run_tasks
from brlcli.policy import PolicySpec
from brlcli.train import train_many, train_run
from brlcli.trainconfig import TrainConfig


@pytest.fixture(scope="module")
def ray_instance():
    """One local Ray instance with 2 CPUs for the whole module (shut down at the end)."""
    ray = pytest.importorskip("ray")
    ray.init(address="local", num_cpus=2, include_dashboard=False, logging_level=logging.ERROR, log_to_driver=False)
    ray.cloudpickle.register_pickle_by_value(sys.modules[__name__])  # Ray workers cannot import test modules
    yield ray
    ray.shutdown()


@pytest.fixture(scope="module")
def model(tmp_path_factory) -> Path:
    run = tmp_path_factory.mktemp("model") / "seed_0"
    train_run(TrainConfig(steps=200, seed=0, evaluate=False), run)
    return run / "model.npz"


class _Scale:
    def __init__(self, k: int) -> None:
        self.k = k


def _scaled(state: _Scale, x: int) -> int:
    report(("seen", x))
    return state.k * x


def test_run_tasks_locally_and_on_ray_give_the_same_results(ray_instance) -> None:
    setup = functools.partial(_Scale, 3)
    for kind, workers in (("local", 1), ("local", 2), ("ray", 1)):
        messages: list = []
        out = dict(run_tasks(_scaled, range(5), executor=kind, workers=workers, setup=setup,
                             on_report=messages.append))
        assert out == {i: 3 * i for i in range(5)}, kind
        assert sorted(messages) == [("seen", i) for i in range(5)], kind
    assert list(run_tasks(_scaled, [], executor="ray")) == []


def _lines(out: Path) -> list[str]:
    return sorted((out / "results.jsonl").read_text().splitlines())


def _frames(out: Path) -> dict[str, bytes]:
    return {str(p.relative_to(out)): p.read_bytes() for p in sorted((out / "frames").rglob("*.npz"))}


def test_bench_on_ray_equals_local_and_survives_a_killed_worker(tmp_path: Path, model: Path, ray_instance,
                                                                monkeypatch) -> None:
    specs = subset(build_suite("paper"), "3")
    pols = [PolicySpec("brl", "m", {"model": str(model)})]
    config = {"suite": "paper", "seed": 0}
    run_bench(specs, pols, tmp_path / "local", config)
    run_bench(specs, pols, tmp_path / "ray", config, executor="ray")
    assert _lines(tmp_path / "ray") == _lines(tmp_path / "local") and len(_lines(tmp_path / "local")) == 3
    assert _frames(tmp_path / "ray") == _frames(tmp_path / "local")

    marker_dir = tmp_path / "kill"
    marker_dir.mkdir()
    monkeypatch.setenv("BRL_TEST_KILL_FIRST_TRY", str(marker_dir))
    run_bench(specs, pols, tmp_path / "killed", config, executor="ray")
    assert (marker_dir / "killed").exists()  # one worker died mid-run; Ray ran its task again
    assert _lines(tmp_path / "killed") == _lines(tmp_path / "local")
    assert _frames(tmp_path / "killed") == _frames(tmp_path / "local")


def test_interrupted_ray_bench_resumes_to_the_same_results(tmp_path: Path, model: Path, ray_instance) -> None:
    specs = subset(build_suite("paper"), "3")
    pols = [PolicySpec("brl", "m", {"model": str(model)})]
    config = {"suite": "paper", "seed": 0}
    run_bench(specs, pols, tmp_path / "full", config)

    class Stop(Exception):
        pass

    def stop(_result: dict) -> None:
        raise Stop  # the caller stops after the first episode: outstanding tasks are cancelled

    with pytest.raises(Stop):
        run_bench(specs, pols, tmp_path / "cut", config, executor="ray", progress=stop)
    assert len(read_results(tmp_path / "cut")) == 1
    run_bench(specs, pols, tmp_path / "cut", config, executor="ray", resume=True)
    assert _lines(tmp_path / "cut") == _lines(tmp_path / "full")


def test_seeds_trained_on_ray_equal_local_ones_and_resume(tmp_path: Path, ray_instance) -> None:
    cfg = TrainConfig(steps=200, evaluate=False)
    train_many(cfg, [0, 1], tmp_path / "local")

    class Stop(Exception):
        pass

    def stop_at_100(p) -> None:
        if p.step >= 100:
            raise Stop

    with pytest.raises(Stop):  # an interrupted seed 1 ...
        train_run(TrainConfig(steps=200, seed=1, evaluate=False), tmp_path / "ray" / "seed_1", progress=stop_at_100)
    seen: set = set()
    results = train_many(cfg, [0, 1], tmp_path / "ray", resume=True, executor="ray",
                         progress=lambda p: seen.add(p.seed))  # ... resumed on Ray
    assert [r["summary"]["seed"] for r in results] == [0, 1] and seen == {0, 1}
    for s in (0, 1):
        for name in ("model.npz", "log.csv"):
            a = (tmp_path / "local" / f"seed_{s}" / name).read_bytes()
            assert (tmp_path / "ray" / f"seed_{s}" / name).read_bytes() == a, (s, name)


def test_sweep_on_ray_equals_local(tmp_path: Path, ray_instance) -> None:
    from brlcli.sweep import plan_sweep, run_sweep

    grid = tmp_path / "grid.toml"
    grid.write_text("[base]\nsteps = 60\n[variants.a]\n[variants.b]\nparams = { gamma = 0.8 }\n")
    plan = plan_sweep(grid, [0], routes="validation", episodes="1")  # 2 variants x 1 seed: 2 tasks
    run_sweep(plan, tmp_path / "local", workers=1)
    seen: list = []
    run_sweep(plan, tmp_path / "ray", executor=Executor("ray"), progress=seen.append)
    assert (tmp_path / "ray" / "sweep.csv").read_bytes() == (tmp_path / "local" / "sweep.csv").read_bytes()
    assert {m["kind"] for m in seen} >= {"step", "trained", "evaluated"}
    for v in ("a", "b"):
        for s in (0,):
            name = f"{v}/seed_{s}/model.npz"
            assert (tmp_path / "ray" / name).read_bytes() == (tmp_path / "local" / name).read_bytes(), name


def test_bad_executor_options_fail_before_anything_runs() -> None:
    for kwargs in ({"kind": "spark"}, {"kind": "local", "ray_address": "10.0.0.1:6379"}, {"workers": 0}):
        with pytest.raises(BrlInputError):
            Executor(**kwargs)


def _cli(*args: str, env: dict | None = None) -> subprocess.CompletedProcess:
    return subprocess.run([sys.executable, "-m", "brlcli", *args], capture_output=True, text=True, timeout=120,
                          env={**os.environ, **(env or {})})


def test_cli_rejects_unreachable_clusters_and_missing_ray(tmp_path: Path, model: Path) -> None:
    shim = tmp_path / "noray"
    (shim / "ray").mkdir(parents=True)
    (shim / "ray" / "__init__.py").write_text("raise ImportError('no ray here')\n")
    no_ray = {"PYTHONPATH": os.pathsep.join(p for p in (str(shim), os.environ.get("PYTHONPATH")) if p)}
    out = tmp_path / "out"
    cases = [
        (["bench", "--model", str(model), "--executor", "ray", "--ray-address", "127.0.0.1:1"], None),
        (["bench", "--model", str(model), "--executor", "ray"], no_ray),
        (["train", "--seeds", "0-1", "--steps", "10", "--executor", "ray", "--ray-address", "127.0.0.1:1"], None),
        (["train", "--steps", "10", "--ray-address", "127.0.0.1:1"], None),  # needs --executor ray
    ]
    for args, env in cases:
        r = _cli(*args, "--out", str(out), env=env)
        assert r.returncode == 2, (args, r.stderr)
        assert r.stderr.startswith("brl: error: ") and r.stderr.strip().count("\n") == 0, (args, r.stderr)
        assert not out.exists(), args


def test_cli_bench_joins_a_running_cluster(tmp_path: Path, model: Path, ray_instance) -> None:
    address = ray_instance.get_runtime_context().gcs_address
    r = _cli("bench", "--model", str(model), "--episodes", "2", "--executor", "ray", "--ray-address", address,
             "--out", str(tmp_path / "b"))
    assert r.returncode == 0, r.stderr
    rows = read_results(tmp_path / "b")
    assert len(rows) == 2 and all((tmp_path / "b" / row["frames_file"]).exists() for row in rows)
    assert "ray, 2 CPUs on 1 node" in r.stderr
    assert json.loads((tmp_path / "b" / "bench.json").read_text())["config"]["suite"] == "paper"


def test_policy_interface_sits_below_bench_and_baselines() -> None:
    code = ("import sys, brlcli.policy, brlcli.baselines.deeprl, brlcli.train\n"
            "bad = [m for m in ('brlcli.bench.runner', 'brlcli.bench.registry', 'ray') if m in sys.modules]\n"
            "assert not bad, bad\n"
            "import brlcli.bench.runner, brlcli.cli\n"
            "assert 'ray' not in sys.modules\n")
    r = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, timeout=60)
    assert r.returncode == 0, r.stderr
