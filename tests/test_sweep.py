"""`brl sweep`: grid parsing and validation, a tiny end-to-end sweep, resume and worker independence."""

from __future__ import annotations

import csv
import json
import subprocess
import sys
from pathlib import Path

import pytest

from brlcli.errors import BrlInputError
from brlcli.sweep import load_grid, plan_sweep, run_sweep, write_tables
from brlcli.trainconfig import TrainConfig

GRID = """
[base]
steps = 60

[variants.paper]            # empty = the defaults

[variants.speed6]
target_speed_kmh = 6.0

[variants.gamma8]
params = { gamma = 0.8 }
"""


def _grid(tmp_path: Path, text: str, name: str = "grid.toml") -> Path:
    p = tmp_path / name
    p.write_text(text, encoding="utf-8")
    return p


def test_grid_merges_base_and_nested_params(tmp_path: Path) -> None:
    grid = load_grid(_grid(tmp_path, GRID))
    assert list(grid) == ["paper", "speed6", "gamma8"]
    default = TrainConfig()
    assert grid["paper"] == TrainConfig(steps=60, evaluate=False)
    assert grid["speed6"].target_speed_kmh == 6.0 and grid["speed6"].steps == 60
    assert grid["gamma8"].params == {**default.params, "gamma": 0.8}
    assert grid["gamma8"].agent_params().gamma == 0.8
    assert list(load_grid(_grid(tmp_path, GRID), ["gamma8", "paper"])) == ["paper", "gamma8"]
    as_json = {"base": {"steps": 60}, "variants": {"a": {"params": {"gamma": 0.7}}, "b": {}}}
    grid = load_grid(_grid(tmp_path, json.dumps(as_json), "grid.json"))
    assert grid["a"].params == {**default.params, "gamma": 0.7} and grid["b"].steps == 60


@pytest.mark.parametrize(("text", "words"), [
    ("[variants.x]\nfoo = 1\n", "variant 'x': unknown training config key 'foo'"),
    ("[variants.end-0.2]\noffroad_end = 0.2\n", "a dot in a TOML table name nests tables"),
    ("[base]\nfoo = 1\n[variants.x]\n", "[base]: unknown training config key 'foo'"),
    ("[variants.x]\nsteps = 'many'\n", "variant 'x': training config key 'steps' must be an integer"),
    ("[variants.x]\nsteps = 0\n", "--steps must be at least 1"),
    ("[variants.x]\nparams = { gama = 0.8 }\n", "unknown BRLParams key"),
    ("[variants.x]\nseed = 3\n", "seeds come from --seeds"),
    ("[variants.x]\ntown = 'town99'\n", "unknown town 'town99'"),
    ("[variants]\n", "no variants"),
    ("steps = 60\n", "unknown top-level key 'steps'"),
    ("[variants.x\n", "not valid TOML"),
])
def test_bad_grids_are_one_line_errors(tmp_path: Path, text: str, words: str) -> None:
    with pytest.raises(BrlInputError) as info:
        load_grid(_grid(tmp_path, text))
    msg = str(info.value)
    assert msg.startswith(f"sweep grid {tmp_path / 'grid.toml'}: ") and words in msg and "\n" not in msg


def test_cli_bad_grid_exits_2_before_writing(tmp_path: Path) -> None:
    out = tmp_path / "out"
    for text, extra in (("[variants.ok]\n[variants.x]\nfoo = 1\n", []), (GRID, ["--variants", "paper,nope"]),
                        (GRID, ["--routes", "holdout"])):
        r = subprocess.run([sys.executable, "-m", "brlcli.cli", "sweep", str(_grid(tmp_path, text)), "--out", str(out),
                            *extra], capture_output=True, text=True, timeout=120)
        assert r.returncode == 2, r.stderr
        lines = r.stderr.strip().splitlines()
        assert len(lines) == 1 and lines[0].startswith("brl: error: "), r.stderr
        assert not out.exists()


def _table(out: Path) -> list[dict]:
    with open(out / "sweep.csv", newline="") as fh:
        return list(csv.DictReader(fh))


def test_tiny_sweep_tables_resume_and_workers(tmp_path: Path) -> None:
    grid = _grid(tmp_path, GRID)
    plan = plan_sweep(grid, [0, 1], routes="validation", episodes="2", variants=["paper", "speed6"])
    a, b = tmp_path / "a", tmp_path / "b"
    result = run_sweep(plan, a, workers=1)
    assert [r["variant"] for r in result["rows"]] == ["paper", "speed6"] and result["runs"] == 4
    rows = _table(a)
    assert [r["variant"] for r in rows] == ["paper", "speed6"]
    assert all(r["seeds"] == "2" and r["episodes_per_model"] == "2" for r in rows)
    for r in rows:
        assert 0.0 <= float(r["success_posterior_lo"]) <= float(r["success_posterior_mean"]) \
            <= float(r["success_posterior_hi"]) <= 1.0
    for name in ("sweep.md", "sweep.png", "sweep.json"):
        assert (a / name).stat().st_size > 0
    record = json.loads((a / "sweep.json").read_text())
    assert record["config"]["variants"]["speed6"]["target_speed_kmh"] == 6.0
    assert record["brl_version"] and record["git_commit"]
    for v in ("paper", "speed6"):
        for s in (0, 1):
            run = a / v / f"seed_{s}"
            assert json.loads((run / "config.json").read_text())["config"]["evaluate"] is False
            bench = json.loads((run / "eval_validation" / "bench.json").read_text())["config"]
            assert bench["suite"] == "validation"
    before = {n: (a / n).read_bytes() for n in ("sweep.csv", "sweep.md", "sweep.png")}

    from brlcli.report import build_report  # brl report's tables work on the validation suite too

    rep = build_report([a / v / f"seed_{s}" / "eval_validation" for v in ("paper", "speed6") for s in (0, 1)], [],
                       tmp_path / "report", "csv")
    assert "tables/validation_paper_test_table.csv" in rep["files"]
    assert {r["suite"] for r in rep["summary"]} == {"validation"}

    with pytest.raises(BrlInputError, match="already holds a sweep"):
        run_sweep(plan, a)
    seen: list[dict] = []
    run_sweep(plan, a, resume=True, progress=seen.append)
    assert not [m for m in seen if m["kind"] in ("step", "episode")]  # nothing trained or driven again
    assert {n: (a / n).read_bytes() for n in before} == before
    write_tables(a)  # --report-only
    assert {n: (a / n).read_bytes() for n in before} == before

    run_sweep(plan, b, workers=2)
    assert (b / "sweep.csv").read_bytes() == before["sweep.csv"]


def test_cli_sweep_runs_end_to_end(tmp_path: Path) -> None:
    out = tmp_path / "out"
    r = subprocess.run([sys.executable, "-m", "brlcli.cli", "sweep", str(_grid(tmp_path, GRID)), "--out", str(out),
                        "--variants", "paper", "--seeds", "0", "--episodes", "1"], capture_output=True, text=True,
                       timeout=240)
    assert r.returncode == 0, r.stderr
    assert [row["variant"] for row in _table(out)] == ["paper"]
    assert (out / "paper" / "seed_0" / "model.npz").exists()
