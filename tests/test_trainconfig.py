"""Training configurations from variants, --config files and --set overrides (brl train, brl train-rl)."""

from __future__ import annotations

import json
import subprocess
import sys
from pathlib import Path

import pytest

from brlcli.baselines.deeprl import DeepRLConfig
from brlcli.config import Layer, command_layers, parse_sets, parse_value, resolve
from brlcli.errors import BrlInputError
from brlcli.trainconfig import DEFAULT_VARIANT, VARIANT_PRESETS, TrainConfig, resolve_train_config


def resolve_config(layers: list[dict], default_variant: str = "paper") -> TrainConfig:
    return resolve_train_config([Layer(f"layer {i}", d) for i, d in enumerate(layers)], default_variant)


def _brl(*args: str, cwd: Path | None = None) -> subprocess.CompletedProcess:
    return subprocess.run([sys.executable, "-m", "brlcli.cli", *args], capture_output=True, text=True, timeout=300,
                          cwd=cwd)


def test_parse_value_reads_toml_values_and_falls_back_to_text() -> None:
    assert parse_value("0.5") == 0.5 and parse_value("12") == 12 and parse_value("true") is True
    assert parse_value("visits") == "visits" and parse_value('"a b"') == "a b"
    assert parse_value('["straight"]') == ["straight"]


def test_parse_sets_nests_dotted_keys() -> None:
    layer = parse_sets(["params.step_size=visits", "params.gamma=0.8", "offroad_end=0.3"])
    assert layer == {"params": {"step_size": "visits", "gamma": 0.8}, "offroad_end": 0.3}
    for bad in ("offroad_end", "=1", "params..gamma=1"):
        with pytest.raises(BrlInputError, match="KEY=VALUE"):
            parse_sets([bad])


def test_resolve_config_layers_in_order_and_records_the_variant() -> None:
    cfg = resolve_config([{"offroad_end": 0.3}, {"params": {"gamma": 0.8}}, {"offroad_end": 0.4}])
    assert cfg.offroad_end == 0.4 and cfg.variant == "paper"
    assert cfg.params == {**TrainConfig().params, "gamma": 0.8}  # a table merges key by key
    assert cfg.agent_params().gamma == 0.8
    ref = resolve_config([{"variant": "reference-code"}])
    assert ref.variant == "reference-code" and ref.agent_params().variant == "reference-code"


@pytest.mark.parametrize("layer, message", [
    ({"variant": "nope"}, "unknown variant \"nope\"; choose one of paper, reference-code, averaging-restart, "
                          "action-averaging-restart"),
    ({"offroad_endd": 1}, "unknown training config key 'offroad_endd'; known keys: "),
    ({"steps": "many"}, "training config key 'steps' must be an integer"),
    ({"params": {"gama": 0.8}}, "unknown BRLParams key(s) (params.*): gama; known keys: T_l"),
    ({"params": {"gamma": 2.0}}, "BRLParams.gamma must lie in [0, 1]"),
    ({"offroad_end": 1.5}, "bad training configuration"),
])
def test_resolve_config_refuses_bad_layers_with_one_line(layer: dict, message: str) -> None:
    with pytest.raises(BrlInputError) as exc:
        resolve_config([layer])
    assert message in str(exc.value) and "\n" not in str(exc.value)


def test_every_variant_preset_resolves() -> None:
    assert DEFAULT_VARIANT in VARIANT_PRESETS
    for name in VARIANT_PRESETS:
        assert resolve_config([{"variant": name}]).variant == name


def test_resolve_plain_config_for_train_rl() -> None:
    cfg = resolve(DeepRLConfig, command_layers(None, {"steps": 40}, ["otherlane_end=0.4", "camera_pitch_deg=-30"]),
                  "deep RL")
    assert (cfg.steps, cfg.otherlane_end, cfg.camera().pitch_deg) == (40, 0.4, -30.0)
    with pytest.raises(BrlInputError, match="unknown deep RL config key 'params'"):
        resolve(DeepRLConfig, command_layers(None, {}, ["params.gamma=0.8"]), "deep RL")


def test_cli_print_config_shows_the_resolved_configuration(tmp_path: Path) -> None:
    toml = tmp_path / "cfg.toml"
    toml.write_text('offroad_end = 0.3\nparams = { step_size = "visits" }\n')
    r = _brl("train", "--config", str(toml), "--steps", "30", "--set", "params.gamma=0.8", "--print-config")
    assert r.returncode == 0, r.stderr
    cfg = json.loads(r.stdout)
    assert cfg["offroad_end"] == 0.3 and cfg["steps"] == 30 and cfg["variant"] == DEFAULT_VARIANT
    assert cfg["params"]["step_size"] == "visits" and cfg["params"]["gamma"] == 0.8
    r = _brl("train", "--set", "steps=7", "--steps", "30", "--print-config")  # --set is applied last
    assert json.loads(r.stdout)["steps"] == 7
    r = _brl("train-rl", "--set", "offroad_end=0.25", "--steps", "40", "--print-config")
    assert r.returncode == 0 and json.loads(r.stdout)["offroad_end"] == 0.25
    assert json.loads(r.stdout)["steps"] == 40  # an option given on the command line is kept


@pytest.mark.parametrize("args, message", [
    (["--variant", "nope"], "unknown variant"),
    (["--set", "nokey=1"], "unknown training config key 'nokey'"),
    (["--set", "steps=lots"], "'steps' must be an integer"),
    (["--set", "seed=3"], "--set cannot set seed"),
    (["--set", "params"], "must be KEY=VALUE"),
    (["--config", "missing.toml"], "--config missing.toml: cannot read it"),
])
def test_cli_bad_training_options_fail_with_one_line(tmp_path: Path, args: list[str], message: str) -> None:
    r = _brl("train", *args, "--out", str(tmp_path / "run"), cwd=tmp_path)
    assert r.returncode == 2 and message in r.stderr
    assert r.stderr.count("\n") == 1 and "Traceback" not in r.stderr
    assert not (tmp_path / "run").exists()


def test_cli_malformed_config_file(tmp_path: Path) -> None:
    bad = tmp_path / "bad.toml"
    bad.write_text("offroad_end = = 1\n")
    r = _brl("train", "--config", str(bad), "--out", str(tmp_path / "run"))
    assert r.returncode == 2 and "not valid TOML" in r.stderr and not (tmp_path / "run").exists()


def test_cli_set_with_resume_of_another_configuration_is_refused(tmp_path: Path) -> None:
    out = tmp_path / "run"
    r = _brl("train", "--steps", "12", "--no-evaluate", "--out", str(out))
    assert r.returncode == 0, r.stderr
    saved = json.loads((out / "seed_0" / "config.json").read_text())["config"]
    assert saved["variant"] == DEFAULT_VARIANT
    r = _brl("train", "--steps", "12", "--no-evaluate", "--set", "offroad_end=0.3", "--resume", "--out", str(out))
    assert r.returncode == 2 and "another configuration" in r.stderr
    r = _brl("train", "--steps", "12", "--no-evaluate", "--resume", "--out", str(out))
    assert r.returncode == 0, r.stderr


def test_models_keep_their_variant_in_bench_labels(tmp_path: Path) -> None:
    """A model trained with another variant is benched under 'TGDG (NAME)', and bench.json names its variant."""
    out = tmp_path / "ref"
    r = _brl("train", "--variant", "reference-code", "--steps", "12", "--no-evaluate", "--out", str(out))
    assert r.returncode == 0, r.stderr
    assert json.loads((out / "seed_0" / "config.json").read_text())["config"]["variant"] == "reference-code"
    bench = tmp_path / "bench"
    r = _brl("bench", "--suite", "paper", "--model", str(out / "seed_0"), "--episodes", "2", "--out", str(bench))
    assert r.returncode == 0, r.stderr
    rows = [json.loads(line) for line in (bench / "results.jsonl").read_text().splitlines()]
    assert {row["setting"] for row in rows} == {"TGDG (reference-code)"}
    policies = json.loads((bench / "bench.json").read_text())["config"]["policies"]
    assert [p["variant"] for p in policies] == ["reference-code"]


def test_cli_option_defaults_are_the_configurations_defaults() -> None:
    """The defaults `brl CMD -h` shows are the configuration's (an option left at its default is not a layer)."""
    import typer.main

    from brlcli.baselines.il import ILTrainConfig
    from brlcli.cli import app
    from brlcli.segnet.train import SegTrainConfig

    commands = typer.main.get_command(app).commands  # type: ignore[attr-defined]

    def defaults(name: str) -> dict:
        return {p.name: p.default for p in commands[name].params}

    train, cfg = defaults("train"), TrainConfig()
    for key in ("task", "town", "input", "steps", "seed", "target_speed_kmh", "evaluate", "segnet", "curve_every"):
        assert train[key] == getattr(cfg, key), key
    assert train["variant"] == DEFAULT_VARIANT and int(train["weather"]) == cfg.weather
    rl, rl_cfg = defaults("train-rl"), DeepRLConfig()
    for key in ("algo", "task", "town", "input", "steps", "eval_every", "eval_suite", "seed", "segnet"):
        assert rl[key] == getattr(rl_cfg, key), key
    assert int(rl["weather"]) == rl_cfg.weather
    il, il_cfg = defaults("train-il"), ILTrainConfig()
    assert (il["epochs"], il["batch_size"], il["seed"], il["workers"], il["val_fraction"]) == (
        il_cfg.epochs, il_cfg.batch_size, il_cfg.seed, il_cfg.threads, il_cfg.val_fraction)
    seg, seg_cfg = defaults("train-seg"), SegTrainConfig()
    assert (seg["epochs"], seg["batch_size"], seg["seed"], seg["workers"], seg["class_weights"], seg["select"],
            seg["fine_channels"]) == (seg_cfg.epochs, seg_cfg.batch_size, seg_cfg.seed, seg_cfg.threads,
                                      seg_cfg.class_weighting, seg_cfg.select, seg_cfg.net["fine"])


def test_options_left_at_their_default_do_not_override_a_config_file(tmp_path: Path) -> None:
    toml = tmp_path / "nav.toml"
    toml.write_text('task = "navigation"\nsteps = 900\n')
    r = _brl("train", "--config", str(toml), "--print-config")
    assert r.returncode == 0, r.stderr
    cfg = json.loads(r.stdout)
    assert cfg["task"] == "navigation" and cfg["steps"] == 900 and cfg["params"]["new_q"] == "nearest"
    r = _brl("train", "--task", "navigation", "--print-config")
    assert json.loads(r.stdout)["steps"] == 27000  # the task's preset, not the option's default
    r = _brl("train-seg", "--data", "x", "--config", str(tmp_path / "seg.toml"), "--print-config")
    assert r.returncode == 2 and "cannot read it" in r.stderr
    (tmp_path / "seg.toml").write_text("epochs = 3\n[net]\nfine = 16\n")
    r = _brl("train-seg", "--data", "x", "--config", str(tmp_path / "seg.toml"), "--workers", "1", "--print-config")
    seg = json.loads(r.stdout)
    assert (seg["epochs"], seg["net"]["fine"], seg["threads"]) == (3, 16, 1)
