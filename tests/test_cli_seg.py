"""brl eval-seg, brl calibrate-seg and brl train-seg from the command line: figures, files, one-line errors."""

import json
import subprocess
import sys
from pathlib import Path

import pytest
import torch

from brlcli.segnet.io import load_segnet, save_checkpoint
from brlcli.segnet.model import SegNet, SegNetConfig

TINY = SegNetConfig(stem=8, widths=(8, 16, 16, 16), enc_channels=16, codewords=4)


def _brl(*args: str) -> subprocess.CompletedProcess:
    return subprocess.run([sys.executable, "-m", "brlcli.cli", *args], capture_output=True, text=True, timeout=300)


def _one_line_error(r: subprocess.CompletedProcess) -> None:
    assert r.returncode == 2, r.stderr
    assert r.stderr.startswith("brl: error:") and r.stderr.strip().count("\n") == 0 and "Traceback" not in r.stderr


@pytest.fixture(scope="module")
def bags(tmp_path_factory) -> Path:
    """Two small episodes at 64x32 recorded by brl collect."""
    out = tmp_path_factory.mktemp("seg") / "bags"
    r = _brl("collect", "--town", "town02", "--episodes", "2", "--episode-frames", "8", "--every", "2",
             "--width", "64", "--height", "32", "--no-depth", "--out", str(out))
    assert r.returncode == 0, r.stderr
    return out


def _net_file(path: Path, size: tuple[int, int], offsets: list[float] | None) -> Path:
    torch.manual_seed(0)
    meta = {"mean": [0.5] * 3, "std": [0.25] * 3, "input_size": list(size)}
    if offsets is not None:
        meta["logit_offsets"] = offsets
    save_checkpoint(path, SegNet(TINY).eval(), meta)
    return path


def test_eval_and_calibrate_write_the_state_error(bags: Path, tmp_path: Path, brl_in_process) -> None:
    raw = _net_file(tmp_path / "raw.pt", (32, 64), None)
    cal = tmp_path / "cal.pt"
    r = _brl("calibrate-seg", "--segnet", str(raw), "--data", str(bags), "--out", str(cal))
    assert r.returncode == 0, r.stderr
    assert "state L1" in r.stdout and r.stdout.strip().endswith(str(cal))
    _, meta = load_segnet(cal)
    assert meta["logit_offsets"] is not None and meta["format_version"] == 2
    report = tmp_path / "eval.json"
    r = brl_in_process("eval-seg", "--segnet", str(cal), "--data", str(bags), "--out", str(report))
    assert r.returncode == 0, r.stderr
    doc = json.loads(report.read_text())
    figures = doc["results"]["sets"]["bags"]
    assert doc["results"]["calibration"] == "applied" and figures["frames"] == 16
    assert {"state_l1", "state_bias", "area_ratio", "iou_categories"} <= set(figures)
    assert "git_commit" in doc and doc["config"]["segnet"] == str(cal)
    r = brl_in_process("eval-seg", "--segnet", str(cal), "--data", str(bags), "--uncalibrated", "--out",
             str(tmp_path / "raw.json"))
    before = json.loads((tmp_path / "raw.json").read_text())["results"]["sets"]["bags"]["state_l1"]
    assert r.returncode == 0 and figures["state_l1"] <= before + 1e-9


def test_bad_segmentation_input_is_one_line_exit_2(bags: Path, tmp_path: Path, brl_in_process) -> None:
    raw = _net_file(tmp_path / "raw.pt", (32, 64), None)
    wide = _net_file(tmp_path / "wide.pt", (88, 200), [0.0] * 13)
    (tmp_path / "junk.pt").write_bytes(b"junk")
    corrupt = tmp_path / "corrupt"
    corrupt.mkdir()
    (corrupt / "metadata.yaml").write_text("not: [a bag")
    cases = [
        ["eval-seg", "--data", str(tmp_path / "missing")],
        ["eval-seg", "--data", str(corrupt), "--segnet", str(wide)],
        ["eval-seg", "--data", str(bags), "--segnet", str(tmp_path / "junk.pt")],
        ["eval-seg", "--data", str(bags), "--segnet", str(raw)],  # format 2 without calibration
        ["eval-seg", "--data", str(bags), "--segnet", str(wide)],  # another input size
        ["calibrate-seg", "--data", str(bags), "--segnet", str(raw), "--out", str(raw)],  # exists
        ["train-seg", "--data", str(bags), "--class-weights", "sqrt", "--out", str(tmp_path / "t")],
        ["train-seg", "--data", str(bags), "--select", "loss", "--out", str(tmp_path / "t")],
        ["bench", "--deploy", "estimated", "--segnet", str(raw), "--out", str(tmp_path / "b")],
    ]
    for i, args in enumerate(cases):
        _one_line_error((_brl if i == 0 else brl_in_process)(*args))  # one in a process of its own
    assert not (tmp_path / "t").exists() and not (tmp_path / "b").exists()


def test_train_seg_ends_with_a_calibrated_net(bags: Path, tmp_path: Path) -> None:
    out = tmp_path / "run"
    r = _brl("train-seg", "--data", str(bags), "--val-fraction", "0.5", "--epochs", "1", "--batch-size", "4",
             "--workers", "1", "--fine-channels", "8", "--select", "state", "--out", str(out))
    assert r.returncode == 0, r.stderr
    assert "calibrated" in r.stdout and r.stdout.strip().endswith(str(out / "segnet.pt"))
    _, meta = load_segnet(out / "segnet.pt")
    assert meta["logit_offsets"] is not None
    cfg = json.loads((out / "config.json").read_text())["config"]
    assert cfg["select"] == "state" and cfg["net"]["fine"] == 8
