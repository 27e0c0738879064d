"""The brl command line: previews, provenance and one-line errors."""

import json
import subprocess
import sys
from pathlib import Path

import cv2


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
