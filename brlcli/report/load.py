"""Read and merge `brl bench` results directories and `brl train` run directories, refusing what cannot be merged.

A results directory holds `bench.json` (provenance and the bench configuration) and `results.jsonl` (one JSON
object per finished episode); see `brlcli.bench.runner`. Every problem is a one-line `BrlInputError`.
"""

from __future__ import annotations

import csv
import gzip
import io
import json
import math
import zipfile
from collections.abc import Iterable, Sequence
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np

from brlcli.bench.suites import SUITE_CHANGES, SUITE_VERSION
from brlcli.errors import BrlInputError

COMMON_KEYS: tuple[str, ...] = ("suite", "condition", "task", "town", "weather", "id", "policy", "setting",
                                "success", "km", "steps")
"""Keys every episode record must have."""

SUITE_KEYS: dict[str, tuple[str, ...]] = {
    "paper": ("collided", "offroad_steps", "otherlane_steps", "either_steps"),
    "corl2017": ("infractions",),
    "nocrash": ("collided",),
}
SUITE_KEYS["validation"] = SUITE_KEYS["paper"]  # the paper's suite on other routes
SUITE_KEYS["validation_starts"] = SUITE_KEYS["paper"]  # and from several start poses
"""Further keys the tables of a suite need."""

CONFLICT_KEYS: tuple[str, ...] = ("seed", "success", "steps", "collided")
"""Two records of one episode that differ in any of these come from different runs and are refused."""

ARCHIVED_RESULTS = "results.jsonl.gz"
"""A results directory archived without its frames (`scripts/archive_bench.py`) holds its results.jsonl gzipped."""

ROOT_KEY = "_results_dir"
"""Key added to each loaded episode: the results directory its `frames_file` is relative to."""


@dataclass(frozen=True)
class ResultsDir:
    """One results directory as read: where it is, what bench wrote about it and how many episodes it held."""

    path: Path
    suite: str
    suite_version: int
    town_versions: dict[str, str]
    bench: dict[str, Any]
    episodes: int
    torn_last_line: bool


@dataclass
class Results:
    """Merged episodes of one or more results directories (deduplicated, in a fixed order)."""

    dirs: list[ResultsDir]
    episodes: list[dict[str, Any]]
    duplicates: int = 0
    notes: list[str] = field(default_factory=list)

    def suites(self) -> list[str]:
        """Suites present, sorted."""
        return sorted({ep["suite"] for ep in self.episodes})

    def of_suite(self, suite: str) -> list[dict[str, Any]]:
        """Episodes of one suite (in the merged order)."""
        return [ep for ep in self.episodes if ep["suite"] == suite]


def _one_line(text: str) -> str:
    return " ".join(str(text).split())


def _read_bench(path: Path) -> dict[str, Any]:
    meta = path / "bench.json"
    if not meta.is_file():
        raise BrlInputError(f"{path} is not a brl bench results directory (no bench.json)")
    try:
        doc = json.loads(meta.read_text(encoding="utf-8"))
    except (OSError, UnicodeDecodeError, json.JSONDecodeError) as exc:
        raise BrlInputError(f"{meta} is not readable JSON ({_one_line(exc)})") from None
    config = doc.get("config") if isinstance(doc, dict) else None
    if not isinstance(config, dict):
        raise BrlInputError(f"{meta} is not a brl bench record (no 'config' object)")
    for key, kind in (("suite", str), ("suite_version", int), ("town_versions", dict)):
        if not isinstance(config.get(key), kind) or isinstance(config.get(key), bool):
            raise BrlInputError(f"{meta} lacks config.{key} ({kind.__name__})")
    return doc


def _read_episodes(path: Path, suite: str) -> tuple[list[dict[str, Any]], bool]:
    """Episode records of results.jsonl; a torn (unparsable) last line is dropped, any other bad line refused."""
    file = path / "results.jsonl"
    if not file.is_file() and (path / ARCHIVED_RESULTS).is_file():
        file = path / ARCHIVED_RESULTS
    if not file.is_file():
        raise BrlInputError(f"{path} holds no results.jsonl (no finished episodes)")
    try:
        data = file.read_bytes()
        text = (gzip.decompress(data) if file.name == ARCHIVED_RESULTS else data).decode("utf-8")
    except (OSError, EOFError, UnicodeDecodeError) as exc:
        raise BrlInputError(f"{file} is not readable UTF-8 text ({_one_line(exc)})") from None
    lines = [(n, line) for n, line in enumerate(text.splitlines(), start=1) if line.strip()]
    rows: list[dict[str, Any]] = []
    torn = False
    required = COMMON_KEYS + SUITE_KEYS.get(suite, ())
    for pos, (n, line) in enumerate(lines):
        try:
            row = json.loads(line)
        except json.JSONDecodeError:
            if pos == len(lines) - 1:
                torn = True  # the write of the last episode was cut off (a crash); bench re-runs it on --resume
                continue
            raise BrlInputError(f"{file} line {n} is not JSON: the results file is corrupt") from None
        if not isinstance(row, dict):
            raise BrlInputError(f"{file} line {n} is not a JSON object: the results file is corrupt")
        missing = [k for k in required if k not in row]
        if missing:
            raise BrlInputError(f"{file} line {n} lacks {', '.join(repr(k) for k in missing)}")
        if row["suite"] != suite:
            raise BrlInputError(f"{file} line {n} is a '{row['suite']}' episode but bench.json says '{suite}'")
        if not isinstance(row["km"], int | float) or not math.isfinite(row["km"]) or row["km"] < 0:
            raise BrlInputError(f"{file} line {n} has an invalid km {row['km']!r}")
        if not isinstance(row["steps"], int) or row["steps"] < 0:
            raise BrlInputError(f"{file} line {n} has an invalid steps {row['steps']!r}")
        if suite == "corl2017" and not isinstance(row["infractions"], dict):
            raise BrlInputError(f"{file} line {n} has no infractions object")
        rows.append(row)
    if not rows:
        raise BrlInputError(f"{file} is empty: no finished episodes")
    return rows, torn


def load_results(results_dirs: Sequence[str | Path]) -> Results:
    """Read, check and merge results directories.

    Refuses (one-line BrlInputError): no directories, a directory without bench.json or with an empty or corrupt
    results.jsonl, results of one suite with different suite versions, a town with different town versions, and
    two different records of the same episode. Duplicate identical episodes (policy, setting, id) are merged.
    The merged order does not depend on the order or sharding of the inputs.
    """
    if not results_dirs:
        raise BrlInputError("no results: give at least one `brl bench` results directory")
    paths: list[Path] = []
    for item in results_dirs:
        p = Path(item)
        if not p.is_dir():
            raise BrlInputError(f"results directory {p} does not exist")
        if p.resolve() not in [q.resolve() for q in paths]:
            paths.append(p)
    paths.sort(key=lambda q: str(q.resolve()))
    dirs: list[ResultsDir] = []
    loaded: list[tuple[ResultsDir, list[dict[str, Any]]]] = []
    for p in paths:
        doc = _read_bench(p)
        config = doc["config"]
        rows, torn = _read_episodes(p, config["suite"])
        d = ResultsDir(path=p, suite=config["suite"], suite_version=config["suite_version"],
                       town_versions={str(k): str(v) for k, v in config["town_versions"].items()}, bench=doc,
                       episodes=len(rows), torn_last_line=torn)
        dirs.append(d)
        loaded.append((d, rows))
    _check_versions(dirs)
    return _merge(dirs, loaded)


def _check_versions(dirs: list[ResultsDir]) -> None:
    suite_seen: dict[str, ResultsDir] = {}
    town_seen: dict[str, tuple[str, ResultsDir]] = {}
    for d in dirs:
        first = suite_seen.setdefault(d.suite, d)
        if first.suite_version != d.suite_version:
            raise BrlInputError(f"cannot merge {d.suite} results of suite version {first.suite_version} ({first.path}) "
                                f"and {d.suite_version} ({d.path}); re-run one of them with this brl")
        for town, version in sorted(d.town_versions.items()):
            seen_version, seen_dir = town_seen.setdefault(town, (version, d))
            if seen_version != version:
                raise BrlInputError(f"cannot merge results of {town} version {seen_version} ({seen_dir.path}) and "
                                    f"version {version} ({d.path}); re-run one of them with the same towns")


def _merge(dirs: list[ResultsDir], loaded: list[tuple[ResultsDir, list[dict[str, Any]]]]) -> Results:
    merged: dict[tuple[str, str, str], dict[str, Any]] = {}
    duplicates = 0
    for d, rows in loaded:
        for row in rows:
            key = (str(row["policy"]), str(row["setting"]), str(row["id"]))
            if key in merged:
                first = merged[key]
                diff = [k for k in CONFLICT_KEYS if first.get(k) != row.get(k)]
                if diff:
                    raise BrlInputError(f"episode {key[2]} of {key[0]} ({key[1]}) differs between "
                                        f"{first[ROOT_KEY]} and {d.path} ({', '.join(diff)}): results of different "
                                        "runs (bench seed or model) cannot be merged")
                duplicates += 1
                continue
            merged[key] = {**row, ROOT_KEY: str(d.path)}
    episodes = [merged[k] for k in sorted(merged)]
    notes = []
    if duplicates:
        notes.append(f"{duplicates} duplicate episode records (same policy, setting and episode id) were merged.")
    for d in dirs:
        current = SUITE_VERSION.get(d.suite, d.suite_version)
        if d.suite_version < current:
            changes = "; ".join(SUITE_CHANGES[(d.suite, v)] for v in range(d.suite_version + 1, current + 1)
                                if (d.suite, v) in SUITE_CHANGES)
            notes.append(f"{d.path}: {d.suite} results of suite version {d.suite_version}, older than this brl's "
                         f"{current} (since then: {changes}); they are not comparable with version {current}'s.")
    torn = sum(d.torn_last_line for d in dirs)
    if torn:
        notes.append(f"{torn} results file(s) ended in a torn line (an interrupted write), which was ignored.")
    return Results(dirs=dirs, episodes=episodes, duplicates=duplicates, notes=notes)


def load_frames(episode: dict[str, Any], keys: Iterable[str]) -> dict[str, np.ndarray] | None:
    """Per-frame arrays of an episode from its frames file, or None when the file is missing or unreadable."""
    rel = episode.get("frames_file")
    if not isinstance(rel, str) or not rel:
        return None
    path = Path(episode[ROOT_KEY]) / rel
    try:
        with np.load(path, allow_pickle=False) as npz:
            return {k: np.asarray(npz[k], dtype=np.float64) for k in keys}
    except (OSError, KeyError, ValueError, zipfile.BadZipFile):
        return None


# --------------------------------------------------------------------------------------------------------------
# Training runs


@dataclass(frozen=True)
class TrainingRun:
    """One `brl train` run: its learning curve (reward, TD error per step) and the final greedy evaluation."""

    name: str
    path: Path
    input: str
    """State source it was trained on: gt or estimated."""
    step: np.ndarray
    reward: np.ndarray
    td_error: np.ndarray
    evaluation: dict[str, Any] | None
    """summary.json's greedy evaluation (success_rate, either_share, collision_free_rate), None if absent."""
    variant: str = "paper"
    """The method variant it was trained with (config.json)."""

    @property
    def group(self) -> str:
        """Runs compared together: the training input, and the method variant when it is not the paper's."""
        return self.input if self.variant == "paper" else f"{self.input} ({self.variant})"


def _log_dir(run: Path) -> Path:
    """Where a run's learning curve is: the run itself, or for a committee's seed directory its member 0 (the seed's
    own run; the committee's config.json and summary.json stay the seed directory's)."""
    return run / "member_0" if not (run / "log.csv").is_file() and (run / "member_0" / "log.csv").is_file() else run


def _run_paths(item: Path) -> list[Path]:
    if not item.exists():
        raise BrlInputError(f"training run directory {item} does not exist")
    if (_log_dir(item) / "log.csv").is_file():
        return [item]
    found = sorted(p for p in item.iterdir() if p.is_dir() and (_log_dir(p) / "log.csv").is_file()) \
        if item.is_dir() else []
    if not found:
        if (item / "iterations.csv").is_file() or any(item.glob("*/iterations.csv")):
            raise BrlInputError(f"{item} holds imitation runs (learning=imitation: iterations.csv, no log.csv); --runs "
                                "reads TD runs' learning curves: drop it (each run's iterations.csv has its DAgger "
                                "iterations)")
        raise BrlInputError(f"{item} holds no training runs (no log.csv in it or its subdirectories)")
    return found


def _read_log(path: Path) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    file = path / "log.csv"
    try:
        text = file.read_text(encoding="utf-8")
    except (OSError, UnicodeDecodeError) as exc:
        raise BrlInputError(f"{file} is not readable ({_one_line(exc)})") from None
    reader = csv.reader(io.StringIO(text))
    header = next(reader, None)
    if not header or not {"step", "reward", "td_error"} <= set(header):
        raise BrlInputError(f"{file} is not a brl training log (needs columns step, reward, td_error)")
    cols = [header.index(c) for c in ("step", "reward", "td_error")]
    lines = [row for row in reader if row]
    values = []
    for n, row in enumerate(lines, start=2):
        try:
            if len(row) != len(header):
                raise ValueError("field count")
            values.append([float(row[c]) for c in cols])
        except ValueError:
            if n == len(lines) + 1:
                continue  # a torn last line of a run that is still being written
            raise BrlInputError(f"{file} line {n} is malformed") from None
    arr = np.asarray(values, dtype=np.float64).reshape(-1, 3)
    return arr[:, 0], arr[:, 1], arr[:, 2]


def _read_json(file: Path) -> dict[str, Any] | None:
    if not file.is_file():
        return None
    try:
        doc = json.loads(file.read_text(encoding="utf-8"))
    except (OSError, UnicodeDecodeError, json.JSONDecodeError) as exc:
        raise BrlInputError(f"{file} is not readable JSON ({_one_line(exc)})") from None
    return doc if isinstance(doc, dict) else None


def load_runs(run_dirs: Sequence[str | Path]) -> list[TrainingRun]:
    """Training runs from run directories or directories of runs (e.g. runs/nine with seed_0..seed_8), by name."""
    runs: dict[str, TrainingRun] = {}
    for item in run_dirs:
        for path in _run_paths(Path(item)):
            step, reward, td = _read_log(_log_dir(path))
            if step.size == 0:
                raise BrlInputError(f"{_log_dir(path) / 'log.csv'} holds no learning steps yet")
            config = _read_json(path / "config.json") or {}
            train_input = str((config.get("config") or {}).get("input", "gt"))
            variant = str((config.get("config") or {}).get("variant", "paper"))
            summary = _read_json(path / "summary.json") or {}
            evaluation = (summary.get("summary") or {}).get("eval")
            name = f"{path.resolve().parent.name}/{path.resolve().name}"
            if name in runs and runs[name].path.resolve() != path.resolve():
                raise BrlInputError(f"two training runs are named {name} ({runs[name].path} and {path})")
            runs[name] = TrainingRun(name=name, path=path, input=train_input, step=step, reward=reward,
                                     td_error=td, evaluation=evaluation if isinstance(evaluation, dict) else None,
                                     variant=variant)
    return [runs[k] for k in sorted(runs)]
