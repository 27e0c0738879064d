"""Check that what brl computes is bit-identical to another commit's (issue 33's invariant).

    python scripts/check_invariant.py BASE [--work DIR] [--quick]

Checks BASE out into a git worktree, runs the same plan of brl commands with BASE's code and with this working tree's
code (same Python, same machine), and compares the outputs array for array and record for record: trained arrays
(`model.npz`), training logs (`log.csv`), summaries, learning curves, bench records (`results.jsonl` and the per-frame
`frames/*.npz`) of the shipped lane-keeping models, a navigation committee on CoRL2017 and NoCrash, the baselines, a
sweep, the deep RL baseline, imitation learning and the segmentation net (training, evaluation). Provenance (version,
commit, Python) and wall times are left out; so are the keys of training knobs retired at their default values (the
configs and models of the newer code no longer carry them). Prints one line per output and exits 1 on any difference.

Bit-identical holds on one machine and environment (numpy, OpenBLAS and numba choose kernels by CPU): run both sides
here, never against figures from another machine.
"""

from __future__ import annotations

import argparse
import csv
import hashlib
import io
import json
import os
import shutil
import subprocess
import sys
import tempfile
from pathlib import Path
from typing import Any

import numpy as np

ROOT = Path(__file__).resolve().parents[1]

RETIRED_DEFAULTS: dict[str, Any] = {
    "teams": 1, "team_share": 0.5, "shared_mixture": False, "warm_start_junctions": 0, "straight_as_follow": False,
    "no_backward": False, "r_heading": 0.0, "r_lateral": 0.0, "restart_offroad_above": None, "keep_best": False,
    "command_bootstrap": "next-branch", "exploration": "tau", "posterior_scale": 5.0, "td_error": "component",
}
"""Config and parameter keys that issue 33 retired, at the value every retired knob had when it was off."""
ADDED_DEFAULTS: dict[str, Any] = {"privileged_brake_m": 0.0, "learning": "td", "imitation_iterations": 8,
                                  "imitation_episodes": 300, "imitation_rho": 0.03,
                                  "decision_frames": 7, "stop_rule": "any",
                                  "imitation_stop_weight": 1.0}
"""Config keys added since issue 33 (issue 35's training options), at their defaults (which change nothing)."""
RETIRED_COLUMNS = ("r_heading", "r_lateral")
"""log.csv columns of retired knobs (always 0.0 when the knob was off)."""
RETIRED_STATS = ("warm_started", "best")
VOLATILE = {"git_commit", "brl_version", "python", "steps_per_s", "frames_per_s", "fps"}
"""Record keys that differ between two runs of the same code (provenance, time; and every key naming a wall time)."""


def _volatile(key: str) -> bool:
    return key in VOLATILE or "wall" in key

GRID = """[base]
steps = 300
[variants.paper]
[variants.speed6]
target_speed_kmh = 6.0
variant = "action-averaging-restart"
"""


def plan(quick: bool) -> list[tuple[str, list[str]]]:
    """(name, brl arguments) of every step, in order; paths are relative to the side's output directory."""
    lk_steps = "800" if quick else "1500"
    steps: list[tuple[str, list[str]]] = [
        ("collect", ["collect", "--town", "town01", "--episodes", "2", "--episode-frames", "30", "--seed", "3",
                     "--traffic", "--out", "bags"]),
        ("eval-seg", ["eval-seg", "--data", "bags", "--out", "evalseg.json"]),
        ("train-seg", ["train-seg", "--data", "bags", "--val-fraction", "0.5", "--epochs", "1", "--batch-size", "8",
                       "--workers", "2", "--out", "seg"]),
        ("train lane keeping (default)", ["train", "--steps", lk_steps, "--seed", "0", "--out", "lk"]),
        ("train lane keeping (paper, 2 seeds, 2 workers)",
         ["train", "--variant", "paper", "--steps", "600", "--seeds", "1-2", "--workers", "2", "--no-evaluate",
          "--out", "lk_paper"]),
        ("train lane keeping (trap restart)", ["train", "--steps", "900", "--seed", "4", "--set", "restart_below=-3.0",
                                               "--no-evaluate", "--out", "lk_restart"]),
        ("train lane keeping (estimated input)", ["train", "--input", "estimated", "--steps", "300", "--seed", "5",
                                                  "--no-evaluate", "--out", "lk_te"]),
        ("train navigation (committee of 2)", ["train", "--task", "navigation", "{nav_td}", "--steps", "1500",
                                               "--seed", "0", "--set", "committee=2", "--out", "nav"]),
        ("train navigation (curve)", ["train", "--task", "navigation", "{nav_td}", "--steps", "1000", "--curve-every",
                                      "500", "--set", "committee=1", "--seed", "1", "--no-evaluate",
                                      "--out", "nav_curve"]),
        ("assemble the shipped committee", ["train", "--task", "navigation", "{nav_td}", "--variant",
                                            "action-averaging-restart", "--seeds", "0", "--set", "committee=7",
                                            "--out", "nav_shipped",
                                            "--resume"]),  # the shipped members' variant (before issue 34's default)
        ("train-rl", ["train-rl", "--steps", "1200", "--eval-every", "600", "--eval-suite", "none", "--seed", "0",
                      "--out", "drl"]),
        ("train-il", ["train-il", "--data", "bags", "--epochs", "1", "--batch-size", "16", "--out", "il"]),
        ("sweep", ["sweep", "grid.toml", "--seeds", "0", "--episodes", "3", "--out", "sweep"]),
        ("bench paper (shipped GT models)", ["bench", "--suite", "paper", "--models", "{models}/brl_gt",
                                             "--episodes", "4" if quick else "8", "--workers", "2",
                                             "--out", "bench_paper"]),
        ("bench paper (estimated deploy)", ["bench", "--suite", "paper", "--model", "{models}/brl_gt/seed_3",
                                            "--deploy", "estimated", "--episodes", "2", "--out", "bench_tgde"]),
        ("bench corl2017 (shipped committee)", ["bench", "--suite", "corl2017", "--model", "nav_shipped/seed_0",
                                                "--episodes", "4" if quick else "12", "--workers", "2",
                                                "--out", "bench_corl"]),
        ("bench nocrash (shipped committee)", ["bench", "--suite", "nocrash", "--model", "nav_shipped/seed_0",
                                               "--episodes", "3" if quick else "9", "--workers", "2",
                                               "--out", "bench_nocrash"]),
        ("bench corl2017 mp", ["bench", "--agent", "mp", "--suite", "corl2017", "--episodes", "3", "--out",
                               "bench_mp"]),
        ("bench corl2017 il", ["bench", "--agent", "il", "--suite", "corl2017", "--episodes", "3", "--out",
                               "bench_il"]),
        ("bench corl2017 dqn", ["bench", "--agent", "dqn", "--model", "{models}/dqn_nav", "--suite", "corl2017",
                                "--episodes", "3", "--out", "bench_dqn"]),
        ("bench nocrash autopilot", ["bench", "--agent", "autopilot", "--suite", "nocrash", "--episodes", "3",
                                     "--out", "bench_autopilot"]),
        ("report", ["report", "bench_paper", "bench_corl", "bench_nocrash", "--runs", "lk_paper", "--format", "csv",
                    "--out", "report"]),
    ]
    return steps


def _nav_td_options() -> list[str]:
    """What `{nav_td}` stands for where the navigation preset learns by imitation (since issue 35's recipe became it):
    the TD-learning empty-road recipe that the preset was before (`NAVIGATION_TD_RECIPE`), less its committee size,
    which each step sets itself."""
    sys.path.insert(0, str(ROOT))
    from brlcli.trainconfig import NAVIGATION_TD_RECIPE, set_options

    return set_options({k: v for k, v in NAVIGATION_TD_RECIPE.items() if k != "committee"})


def _nav_td(src: Path) -> list[str]:
    """The options that make `src`'s navigation preset the TD-learning empty-road recipe."""
    probe = "from brlcli.trainconfig import TASK_PRESETS; print(TASK_PRESETS['navigation'].get('learning', 'td'))"
    learning = subprocess.run([sys.executable, "-c", probe], env={**os.environ, "PYTHONPATH": str(src)},
                              capture_output=True, text=True, check=True).stdout.strip()
    return _nav_td_options() if learning != "td" else []


def run_side(src: Path, out: Path, models: Path, quick: bool) -> None:
    """Run every step of the plan with the brl of `src` in `out`, the shipped models read from `models`."""
    out.mkdir(parents=True, exist_ok=True)
    (out / "grid.toml").write_text(GRID)
    shutil.copytree(models / "brl_nav_empty" / "seed_0", out / "nav_shipped" / "seed_0")
    env = {**os.environ, "PYTHONPATH": str(src), "BRL_MODELS_DIR": str(models), "BRL_GIT_COMMIT": "check"}
    nav_td = _nav_td(src)
    for name, args in plan(quick):
        args = [b for a in args for b in (nav_td if a == "{nav_td}" else [a.replace("{models}", str(models))])]
        print(f"  [{src.name}] {name}: brl {' '.join(args)}", flush=True)
        done = subprocess.run([sys.executable, "-m", "brlcli", *args], cwd=out, env=env, capture_output=True,
                              text=True, check=False)
        if done.returncode != 0:
            raise SystemExit(f"{src}: brl {' '.join(args)} failed ({done.returncode}):\n{done.stderr[-2000:]}")


def _clean(obj: Any) -> Any:
    """A JSON value without volatile keys and without retired keys at their off values."""
    if isinstance(obj, dict):
        return {k: _clean(v) for k, v in obj.items()
                if not _volatile(k) and not (k in RETIRED_DEFAULTS and v == RETIRED_DEFAULTS[k])
                and not (k in ADDED_DEFAULTS and v == ADDED_DEFAULTS[k]) and k not in RETIRED_STATS}
    if isinstance(obj, list):
        return [_clean(v) for v in obj]
    if isinstance(obj, str) and obj.startswith(("{", "[")):
        try:
            return _clean(json.loads(obj))
        except json.JSONDecodeError:
            return obj
    return obj


def _json_digest(obj: Any) -> str:
    return hashlib.sha256(json.dumps(_clean(obj), sort_keys=True).encode()).hexdigest()


def digest_file(path: Path) -> str | None:
    """A digest of what a file holds (None: a file the check does not compare)."""
    suffix = path.suffix
    if suffix == ".json":
        return _json_digest(json.loads(path.read_text()))
    if suffix == ".jsonl":
        rows = [_clean(json.loads(line)) for line in path.read_text().splitlines() if line.strip()]
        return _json_digest(sorted(rows, key=lambda r: json.dumps(r, sort_keys=True)))
    if suffix == ".csv":
        with open(path, newline="") as fh:
            rows = list(csv.DictReader(fh))
        for r in rows:
            for col in RETIRED_COLUMNS:
                if col in r and float(r.pop(col)) != 0.0:
                    return f"retired column {col} is not zero"
            for col in [c for c in r if _volatile(c)]:
                r.pop(col)
        return _json_digest(rows)
    if suffix == ".npz":
        h = hashlib.sha256()
        with np.load(path, allow_pickle=False) as npz:
            for key in sorted(npz.files):
                arr = npz[key]
                if key.endswith("params_json"):
                    arr = np.array(json.dumps(_clean(json.loads(str(arr))), sort_keys=True))
                h.update(key.encode() + str(arr.dtype).encode() + str(arr.shape).encode() + arr.tobytes())
        return h.hexdigest()
    if suffix == ".pt":
        import torch

        doc = torch.load(path, weights_only=True, map_location="cpu")
        h = hashlib.sha256()

        def walk(obj: Any, where: str) -> None:
            if isinstance(obj, torch.Tensor):
                h.update(where.encode() + obj.numpy().tobytes())
            elif isinstance(obj, dict):
                for k in sorted(obj, key=str):
                    if not _volatile(str(k)):
                        walk(obj[k], f"{where}.{k}")
            elif isinstance(obj, list | tuple):
                for i, v in enumerate(obj):
                    walk(v, f"{where}[{i}]")
            else:
                h.update(f"{where}={_clean(obj)!r}".encode())

        walk(doc, "")
        return h.hexdigest()
    if suffix in (".mcap", ".db3"):
        return hashlib.sha256(path.read_bytes()).hexdigest()
    return None


def digest_tree(out: Path) -> dict[str, str]:
    """Relative path -> digest of every compared output file (checkpoints left out: resume has its own tests)."""
    found: dict[str, str] = {}
    for path in sorted(out.rglob("*")):
        rel = path.relative_to(out)
        if not path.is_file() or "checkpoint" in rel.parts or rel.name == "grid.toml":
            continue
        digest = digest_file(path)
        if digest is not None:
            found[str(rel)] = digest
    return found


def digest_models(models: Path) -> str:
    """One digest of every model file under a models/ directory (its READMEs aside)."""
    h = hashlib.sha256()
    for path in sorted(p for p in models.rglob("*") if p.is_file() and p.suffix != ".md"):
        h.update(str(path.relative_to(models)).encode() + path.read_bytes())
    return h.hexdigest()


def main() -> None:
    """Run the plan on both sides and compare."""
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("base", help="the commit to compare with (e.g. the commit before a redesign)")
    parser.add_argument("--work", type=Path, default=None, help="working directory (default: a temporary one)")
    parser.add_argument("--quick", action="store_true", help="fewer steps and episodes")
    args = parser.parse_args()
    work = args.work or Path(tempfile.mkdtemp(prefix="brl-invariant-"))
    base_src = work / "base"
    if not base_src.exists():
        subprocess.run(["git", "-C", str(ROOT), "worktree", "add", "--detach", str(base_src), args.base], check=True,
                       capture_output=True)
    try:
        if digest_models(base_src / "models") != digest_models(ROOT / "models"):
            raise SystemExit(f"models/ differ between {args.base} and this tree: the check reads one set of shipped "
                             "models, so compare trees with the same models/")
        models = work / "models"  # both sides read the same files at the same paths, and write to the same path
        if not models.exists():
            shutil.copytree(ROOT / "models", models)
        sides = {}
        for name, src in (("base", base_src), ("head", ROOT)):
            out, kept = work / "out", work / f"out_{name}"
            for d in (out, kept):
                if d.exists():
                    shutil.rmtree(d)
            run_side(src, out, models, args.quick)
            sides[name] = digest_tree(out)
            out.rename(kept)
    finally:
        subprocess.run(["git", "-C", str(ROOT), "worktree", "remove", "--force", str(base_src)], check=False,
                       capture_output=True)
    paths = sorted(set(sides["base"]) | set(sides["head"]))
    bad = 0
    buf = io.StringIO()
    for p in paths:
        a, b = sides["base"].get(p), sides["head"].get(p)
        state = "same" if a == b else "only in base" if b is None else "only in head" if a is None else "DIFFERENT"
        bad += state != "same"
        buf.write(f"{state:12s} {p}\n")
    print(buf.getvalue(), end="")
    print(f"{len(paths) - bad} of {len(paths)} outputs identical to {args.base} (outputs in {work})")
    sys.exit(1 if bad else 0)


if __name__ == "__main__":
    main()
