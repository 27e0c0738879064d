"""The brl command line: previews, provenance and one-line errors."""

import json
import subprocess
import sys
from pathlib import Path

import cv2
import pytest


def _brl(*args: str) -> subprocess.CompletedProcess:
    return subprocess.run([sys.executable, "-m", "brlcli.cli", *args], capture_output=True, text=True, timeout=300)


def test_version_and_help() -> None:
    r = _brl("--version")
    assert r.returncode == 0 and r.stdout.startswith("brl ")
    assert "preview" in _brl("--help").stdout


def test_preview_writes_pictures_and_provenance(tmp_path: Path) -> None:
    r = _brl("preview", "town02", "--out", str(tmp_path), "--weathers", "1,14")
    assert r.returncode == 0, r.stderr
    top = cv2.imread(str(tmp_path / "town02_topdown.png"))
    frames = cv2.imread(str(tmp_path / "town02_frames.png"))
    assert top is not None and top.shape[0] > 300
    assert frames is not None and frames.shape[0] > 4 * 88
    run = json.loads((tmp_path / "run.json").read_text())
    assert run["config"]["towns"] == ["town02"] and "git_commit" in run and "brl_version" in run
    assert not list(tmp_path.glob("*.tmp"))


def test_bad_input_is_one_line_exit_2(tmp_path: Path) -> None:
    for args in (["preview", "town09", "--out", str(tmp_path / "a")],
                 ["preview", "--weathers", "99", "--out", str(tmp_path / "b")]):
        r = _brl(*args)
        assert r.returncode == 2
        assert r.stderr.strip().count("\n") == 0 and r.stderr.startswith("brl: error:")
        assert "Traceback" not in r.stderr
    assert not (tmp_path / "a").exists() and not (tmp_path / "b").exists()


def test_malformed_town_file_names_the_field(tmp_path: Path) -> None:
    doc = json.loads((Path(__file__).parents[1] / "towns" / "town02.json").read_text())
    del doc["geometry"]["sidewalk_width_m"]
    bad = tmp_path / "bad.json"
    bad.write_text(json.dumps(doc))
    r = _brl("preview", str(bad), "--out", str(tmp_path / "c"))
    assert r.returncode == 2
    assert "geometry.sidewalk_width_m" in r.stderr and r.stderr.strip().count("\n") == 0


def _main(args: list[str], capsys) -> tuple[int, str]:
    """Run brl in this process; its exit code and stderr."""
    from brlcli.cli import main

    with pytest.raises(SystemExit) as exit_info:
        main(args)
    return int(exit_info.value.code or 0), capsys.readouterr().err


def test_a_negative_seed_is_refused_before_anything_is_written(tmp_path: Path, capsys) -> None:
    for command in ("preview", "collect", "train", "train-seg", "train-il", "train-rl", "bench"):
        out = tmp_path / command
        code, err = _main([command, "--seed", "-1", "--out", str(out)], capsys)
        assert code == 2 and err.startswith("brl: error:") and "--seed" in err and err.strip().count("\n") == 0
        assert not out.exists(), command


def test_a_file_that_is_no_model_gets_one_line_naming_it(tmp_path: Path, capsys) -> None:
    text = tmp_path / "notes.npz"
    text.write_text("not a model\n")
    code, err = _main(["bench", "--model", str(text), "--out", str(tmp_path / "b")], capsys)
    assert code == 2 and "is not a brl model (.npz): it is not a zip archive" in err and "pickle" not in err
    code, err = _main(["bench", "--agent", "il", "--model", str(text), "--out", str(tmp_path / "c")], capsys)
    assert code == 2 and "is not a brl IL model" in err and "Error" not in err
    assert not (tmp_path / "b").exists() and not (tmp_path / "c").exists()


def test_an_unwritable_output_file_is_refused_before_the_work(tmp_path: Path, capsys) -> None:
    from brlcli.errors import BrlInputError
    from brlcli.segnet.filetools import check_new_file

    with pytest.raises(BrlInputError, match="cannot write --out"):
        check_new_file(Path("/proc/brl-figures.json"))  # a directory even root cannot write into
    check_new_file(tmp_path / "figures.json")
    assert not list(tmp_path.iterdir())  # the probe leaves nothing behind


def test_help_names_option_values_not_python_types() -> None:
    from brlcli.cli import brl_command

    group = brl_command()
    for name in ("bench", "train", "eval-seg", "train-seg"):
        with group.make_context("brl", [name, "--help"], resilient_parsing=True) as ctx:
            text = group.commands[name].get_help(ctx)
        assert "<str>" not in text and "list[str]" not in text, name
    bench_help = group.commands["bench"].get_help(group.make_context("brl", ["bench"], resilient_parsing=True))
    assert "--model MODEL" in bench_help
