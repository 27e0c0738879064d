"""Output directories: what every command checks about `--out` before it writes anything.

Each command's output directory carries a marker of its kind: the `kind` field of the provenance record it writes
first (`run.json`, `bench.json`, `collect.json`, `sweep.json`, `report.json` or `config.json`). Directories written
before the field existed are recognised by the file and its content. `check_out_dir` refuses, with one line:
an empty path, a path that is a file, a place where the directory cannot be created or written, another
command's output, and (unless the command may overwrite or resume) an existing output of the same kind.
"""

from __future__ import annotations

import json
import os
import time
from datetime import UTC, datetime
from pathlib import Path
from typing import Any

from brlcli.errors import BrlInputError

MARKERS = ("run.json", "bench.json", "collect.json", "sweep.json", "report.json", "config.json")
"""Files whose provenance record names an output directory's kind, in the order they are looked at."""

KIND_NAMES = {
    "train": "a brl train model set", "train-run": "a brl train run", "preview": "brl preview pictures",
    "bench": "brl bench results", "collect": "a brl collect recording", "sweep": "a brl sweep",
    "report": "a brl report", "train-seg": "a brl train-seg run", "train-il": "a brl train-il run",
    "train-rl": "a brl train-rl run",
}


def parse_out(value: str | Path) -> Path:
    """The --out option's path; an empty string is refused (it would mean the current directory)."""
    if not str(value).strip():
        raise BrlInputError("--out is empty; give a directory, e.g. --out runs/NAME")
    return Path(value)


def default_out(command: str) -> Path:
    """A fresh output directory for a run without --out: runs/COMMAND/YYYYmmdd-HHMMSS (-2, -3, ... if taken)."""
    stamp = datetime.now(UTC).strftime("%Y%m%d-%H%M%S")
    base = Path("runs") / command / stamp
    path, k = base, 1
    while path.exists():
        k += 1
        path = base.with_name(f"{stamp}-{k}")
    return path


def _legacy_kind(name: str, record: dict[str, Any]) -> str | None:
    """The kind of a directory written before the `kind` field, from its marker file and configuration."""
    config = record.get("config") if isinstance(record.get("config"), dict) else {}
    fixed = {"bench.json": "bench", "collect.json": "collect", "sweep.json": "sweep", "report.json": "report"}
    if name in fixed:
        return fixed[name]
    if name == "run.json":
        return "train" if "seeds" in config else "preview"
    if "algo" in config:
        return "train-rl"
    if "poly_power" in config:
        return "train-seg"
    if "val_fraction" in config:
        return "train-il"
    if "params" in config or "steps" in config:
        return "train-run"
    return None


def output_kind(path: Path) -> tuple[str, str] | None:
    """(kind, marker file) of an existing output directory, or None if it holds no brl output."""
    for name in MARKERS:
        marker = Path(path) / name
        if not marker.is_file():
            continue
        try:
            record = json.loads(marker.read_text())
        except (OSError, ValueError):
            continue
        if not isinstance(record, dict):
            continue
        kind = record.get("kind") or _legacy_kind(name, record)
        if kind:
            return kind, name
    return None


def _probe_writable(out: Path) -> None:
    """Create `out` (and missing parents) and write a probe file there; undo what was created on failure."""
    created: list[Path] = []
    p = out
    while not p.exists() and p != p.parent:
        created.append(p)
        p = p.parent
    try:
        for d in reversed(created):
            d.mkdir()
        probe = out / f".brl-probe-{os.getpid()}-{time.monotonic_ns()}"
        probe.write_bytes(b"")
        probe.unlink()
    except OSError as exc:
        for d in created:
            try:
                d.rmdir()
            except OSError:
                pass
        reason = exc.strerror or type(exc).__name__
        raise BrlInputError(f"cannot write to --out {out}: {reason}; choose a writable directory") from None
    for d in created:  # leave nothing behind: the command makes the directory when it writes
        try:
            d.rmdir()
        except OSError:
            pass


def check_out_dir(out: Path, kind: str, resume: bool = False, overwrite: bool = False) -> None:
    """Refuse an --out the command cannot or must not write (see the module docstring); writes nothing.

    `overwrite`: the command rebuilds its output in place (report, preview); `resume`: the user asked to continue
    an output of the same kind. Resuming with other options is each command's own check.
    """
    out = parse_out(out)
    if out.exists() and not out.is_dir():
        raise BrlInputError(f"--out {out} is a file, not a directory; choose another --out")
    found = output_kind(out) if out.is_dir() else None
    if found and found[0] != kind:
        what = KIND_NAMES.get(found[0], found[0])
        raise BrlInputError(f"--out {out} holds {what} ({found[1]}); choose another --out")
    if found and not (resume or overwrite):
        raise BrlInputError(f"--out {out} already holds {KIND_NAMES.get(kind, kind)}; pass --resume or choose "
                            "another --out")
    if resume and not found and out.is_dir() and any(out.iterdir()) and not overwrite:
        raise BrlInputError(f"--out {out} holds no {KIND_NAMES.get(kind, kind)} to resume; choose another --out")
    _probe_writable(out)


def refuse_existing(directory: Path, what: str, resume: bool, same: bool | None = None) -> None:
    """The refusals of a directory that already holds a run (`what`: "a training run", "bench results", ...):
    without `resume`, and, when resuming, one made with another configuration (`same` False; None: not known yet)."""
    if not resume:
        raise BrlInputError(f"{directory} already holds {what}; pass --resume or choose another --out")
    if same is False:
        raise BrlInputError(f"{directory} holds {what} made with another configuration; resume it with the same "
                            "options or choose another --out")
