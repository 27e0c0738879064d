"""--out for every command: refused with one line and exit 2 before anything is written; run-time write failures
are one line and exit 1; fresh run directories when --out is not given."""

import errno
import json
import os
import subprocess
import sys
from pathlib import Path

import pytest

from brlcli import cli
from brlcli.errors import BrlInputError
from brlcli.outdir import check_out_dir, default_out, output_kind
from brlcli.provenance import atomic_write_json, provenance

ROOT = Path(__file__).resolve().parents[1]
MODEL = ROOT / "models" / "brl_gt" / "seed_0"


def _brl(*args: str, cwd: Path | None = None) -> subprocess.CompletedProcess:
    env = {**os.environ, "PYTHONPATH": str(ROOT)}
    return subprocess.run([sys.executable, "-m", "brlcli", *args], capture_output=True, text=True, timeout=300,
                          cwd=cwd, env=env)


def _refused(r: subprocess.CompletedProcess, what: str) -> None:
    assert r.returncode == 2, (what, r.stderr)
    assert r.stderr.startswith("brl: error:") and r.stderr.strip().count("\n") == 0, (what, r.stderr)


@pytest.fixture(scope="module")
def inputs(tmp_path_factory) -> dict[str, Path]:
    """Small valid inputs for every command: bags, a grid, a bench results directory."""
    base = tmp_path_factory.mktemp("inputs")
    r = _brl("collect", "--town", "town02", "--episodes", "2", "--episode-frames", "4", "--width", "64",
             "--height", "32", "--no-depth", "--out", str(base / "bags"))
    assert r.returncode == 0, r.stderr
    (base / "grid.toml").write_text("[variants.a]\n")
    r = _brl("bench", "--model", str(MODEL), "--episodes", "1", "--out", str(base / "bench"))
    assert r.returncode == 0, r.stderr
    return {"bags": base / "bags", "grid": base / "grid.toml", "bench": base / "bench"}


def _commands(inputs: dict[str, Path]) -> dict[str, list[str]]:
    bags = str(inputs["bags"])
    return {
        "preview": ["preview", "town02", "--weathers", "1"],
        "train": ["train", "--steps", "20", "--no-evaluate"],
        "sweep": ["sweep", str(inputs["grid"]), "--seeds", "0"],
        "collect": ["collect", "--town", "town02", "--episodes", "1", "--episode-frames", "2"],
        "bench": ["bench", "--model", str(MODEL), "--episodes", "1"],
        "report": ["report", str(inputs["bench"])],
        "train-seg": ["train-seg", "--data", bags, "--epochs", "1", "--batch-size", "4"],
        "train-il": ["train-il", "--data", bags, "--epochs", "1", "--batch-size", "4"],
        "train-rl": ["train-rl", "--steps", "20", "--eval-suite", "none"],
    }


def _main(args: list[str], capsys) -> tuple[int, str]:
    """Run the CLI in this process: (exit code, stderr)."""
    with pytest.raises(SystemExit) as exc:
        cli.main(args)
    return int(exc.value.code or 0), capsys.readouterr().err


def _refused_here(code: int, err: str, what: str) -> None:
    assert code == 2, (what, err)
    assert err.startswith("brl: error:") and err.strip().count("\n") == 0, (what, err)


def test_every_command_refuses_a_bad_out(inputs: dict[str, Path], tmp_path: Path, monkeypatch, capsys) -> None:
    monkeypatch.chdir(tmp_path)
    a_file = tmp_path / "a_file"
    a_file.write_text("x")
    for name, args in _commands(inputs).items():
        for label, out in (("file", str(a_file)), ("empty", ""), ("proc", "/proc/brl-out"),
                           ("other kind", str(inputs["bench"]) if name != "bench" else str(inputs["bags"]))):
            before = sorted(p.name for p in Path(out).iterdir()) if out and Path(out).is_dir() else None
            _refused_here(*_main([*args, "--out", out], capsys), f"{name} --out {label}")
            if before is not None:
                assert sorted(p.name for p in Path(out).iterdir()) == before, (name, label)
    assert a_file.read_text() == "x" and sorted(p.name for p in tmp_path.iterdir()) == ["a_file"]


def test_an_unwritable_directory_is_refused(inputs: dict[str, Path], tmp_path: Path, monkeypatch, capsys) -> None:
    locked = tmp_path / "locked"
    locked.mkdir()
    if os.geteuid() == 0:  # root writes anywhere: make creating directories there fail as it does for a user
        real_mkdir = Path.mkdir

        def no_permission(self: Path, *a, **k) -> None:
            if str(self).startswith(str(locked)):
                raise PermissionError(errno.EACCES, "Permission denied", str(self))
            real_mkdir(self, *a, **k)

        monkeypatch.setattr(Path, "mkdir", no_permission)
    else:
        locked.chmod(0o555)
    try:
        for name in ("train", "bench", "collect", "preview", "train-seg"):
            code, err = _main([*_commands(inputs)[name], "--out", str(locked / "out")], capsys)
            _refused_here(code, err, name)
            assert "cannot write" in err and "Permission denied" in err and not list(locked.iterdir())
    finally:
        locked.chmod(0o755)


def test_resume_with_other_options_is_refused_and_rewrites_nothing(tmp_path: Path) -> None:
    out = tmp_path / "t"
    assert _brl("train", "--steps", "20", "--no-evaluate", "--out", str(out)).returncode == 0
    run_json = (out / "run.json").read_bytes()
    r = _brl("train", "--steps", "30", "--no-evaluate", "--out", str(out), "--resume")
    _refused(r, "train --resume with other options")
    assert (out / "run.json").read_bytes() == run_json
    assert json.loads(run_json)["kind"] == "train"


def test_fresh_run_directories_when_out_is_not_given(tmp_path: Path) -> None:
    first = _brl("train", "--steps", "20", "--no-evaluate", cwd=tmp_path)
    second = _brl("train", "--steps", "20", "--no-evaluate", cwd=tmp_path)
    assert first.returncode == 0 and second.returncode == 0, second.stderr
    a, b = first.stdout.strip().splitlines()[-1], second.stdout.strip().splitlines()[-1]
    assert a != b and a.startswith("runs/train/") and (tmp_path / b / "seed_0" / "model.npz").is_file()
    _refused(_brl("train", "--resume", cwd=tmp_path), "train --resume without --out")


def test_check_out_dir_recognises_kinds_and_leaves_nothing(tmp_path: Path) -> None:
    bench = tmp_path / "bench"
    atomic_write_json(bench / "bench.json", {"config": {"suite": "paper"}})  # written before the kind field
    assert output_kind(bench) == ("bench", "bench.json")
    seg = tmp_path / "seg"
    atomic_write_json(seg / "config.json", provenance({"epochs": 1}, kind="train-seg"))
    assert output_kind(seg) == ("train-seg", "config.json")
    with pytest.raises(BrlInputError, match="holds brl bench results"):
        check_out_dir(bench, "train-seg")
    with pytest.raises(BrlInputError, match="--resume"):
        check_out_dir(seg, "train-seg")
    check_out_dir(seg, "train-seg", resume=True)
    check_out_dir(tmp_path / "new" / "deeper", "bench")
    assert not (tmp_path / "new").exists()  # the probe leaves nothing behind
    assert default_out("bench").parts[:2] == ("runs", "bench")


def test_a_failed_write_at_run_time_is_one_line_and_exit_1(tmp_path: Path, monkeypatch, capsys) -> None:
    def disk_full(fd: int) -> None:
        raise OSError(errno.ENOSPC, "No space left on device")

    monkeypatch.setattr(os, "fsync", disk_full)
    with pytest.raises(SystemExit) as exc:
        cli.main(["preview", "town02", "--weathers", "1", "--out", str(tmp_path / "p")])
    assert exc.value.code == 1
    err = capsys.readouterr().err
    assert err.startswith("brl: error: cannot write") and "No space left" in err and err.count("\n") == 1
    assert not list((tmp_path / "p").glob("*.tmp")) and not list((tmp_path / "p").glob(".*.tmp"))


def test_usage_errors_help_and_no_arguments(tmp_path: Path) -> None:
    r = _brl("train", "--steps", "abc")
    _refused(r, "--steps abc")
    assert "--steps" in r.stderr
    _refused(_brl("train", "--no-such-flag"), "unknown option")
    _refused(_brl("train", "--input", "gt", "--segnet", str(tmp_path / "missing.pt")), "--segnet with gt")
    bare = _brl()
    assert bare.returncode == 0 and "Commands:" in bare.stdout
    short = _brl("bench", "-h")
    assert short.returncode == 0 and "'brl[ray]'" in short.stdout and "<bool>" not in short.stdout
    assert "[base]" in _brl("sweep", "--help").stdout
    assert "--install-completion" in _brl("--help").stdout
