"""`brl sweep`: train every variant of a grid of training configurations for several seeds, evaluate each model
greedily on a route set with the bench, and tabulate the variants side by side.

A grid file (TOML or JSON) names variants; each is a (flat or nested) table of overrides merged onto
`TrainConfig().to_dict()` after an optional `[base]` table, and validated by `TrainConfig.from_dict`:

    [base]
    steps = 4500
    [variants.paper]            # empty = the defaults
    [variants.speed6]
    target_speed_kmh = 6.0
    [variants.gamma8]
    params = { gamma = 0.8 }

Layout of a sweep directory:
    sweep.json                     resolved grid (every variant's full TrainConfig), seeds, route set, episodes,
                                   brl version, git commit; the table rows
    sweep.md, sweep.csv, sweep.png per variant: success, Either, Score (mean and std over seeds), best model,
                                   pooled Beta posterior of success, collision-free, components, training time
    VARIANT/seed_N/                a `brl train` run (config.json, log.csv, model.npz, summary.json, checkpoint/)
    VARIANT/seed_N/eval_ROUTES/    a `brl bench` results directory of that model on the route set

Training and evaluation tasks are plain functions of plain dicts (`train_task`, `eval_task`), run through the
executor seam (`brlcli.executor`: `workers` local processes or Ray tasks); every result depends only on the variant,
the seed and the bench seed, never on the executor or the workers.
"""

from __future__ import annotations

import csv
import io
import json
import math
import re
from collections.abc import Callable, Sequence
from dataclasses import dataclass, replace
from pathlib import Path
from typing import Any

import numpy as np

from brlcli import __version__
from brlcli.config import Layer, merge_layer, read_config_file
from brlcli.errors import BrlInputError
from brlcli.outdir import refuse_existing
from brlcli.provenance import atomic_write_bytes, atomic_write_json, git_commit, provenance
from brlcli.retired import RETIRED_CONFIG, refuse_retired
from brlcli.train import check_run_dir, run_dir_for
from brlcli.trainconfig import OPEN, TrainConfig, resolve_train_config

SWEEP_FILE = "sweep.json"
ROUTE_SETS = ("validation_starts", "validation", "paper")
"""Route sets a sweep evaluates on: `brl bench` suites (validation: model selection; paper: the test routes)."""
RESERVED_KEYS = {"seed": "seeds come from --seeds", "evaluate": "a sweep evaluates every model with the bench"}
"""Training config keys a variant may not set."""
VARIANT_NAME = re.compile(r"^[A-Za-z0-9][A-Za-z0-9_.-]*$")
SWEEP_COLUMNS = ("variant", "seeds", "success_mean", "success_std", "either_mean", "either_std", "score_mean",
                 "score_std", "best_seed", "best_score", "success_posterior_mean", "success_posterior_lo",
                 "success_posterior_hi", "collision_free_mean", "components_mean", "episodes_per_model")
"""Columns of sweep.csv (shares in [0, 1]); training wall time is left out (it varies between runs) and shown in
sweep.md and sweep.json."""


# --------------------------------------------------------------------------------------------------------------
# The grid


def resolve_variant(base: dict[str, Any], overrides: dict[str, Any], name: str = "") -> TrainConfig:
    """`base` then `overrides` merged onto the default training configuration, validated (one-line errors).

    A grid that names no method variant (`variant = ...`) gets the paper's, whatever `brl train`'s default is, so
    that a grid means the same configurations in every brl version.
    """
    for layer in (base, overrides):
        for key, why in RESERVED_KEYS.items():
            if key in layer:
                raise BrlInputError(f"training config key '{key}' cannot be set in a sweep ({why})")
    cfg = resolve_train_config([Layer("[base]", base), Layer(f"[variants.{name}]", overrides)],
                               default_variant="paper")
    return replace(cfg, evaluate=False)


def read_grid_file(path: Path) -> dict[str, Any]:
    """The decoded grid document (TOML, or JSON for a .json file)."""
    return read_config_file(path, what="sweep grid")


def load_grid(path: Path, only: Sequence[str] | None = None) -> dict[str, TrainConfig]:
    """Variant name -> resolved training configuration, every variant validated up front."""
    doc = read_grid_file(path)
    extra = sorted(set(doc) - {"base", "variants"})
    if extra:
        raise BrlInputError(f"sweep grid {path}: unknown top-level key '{extra[0]}' (use [base] and [variants.NAME])")
    base = doc.get("base", {})
    variants = doc.get("variants")
    if not isinstance(base, dict):
        raise BrlInputError(f"sweep grid {path}: 'base' must be a table")
    if not isinstance(variants, dict) or not variants:
        raise BrlInputError(f"sweep grid {path}: no variants (add tables [variants.NAME])")
    try:
        refuse_retired(base, RETIRED_CONFIG)
        merge_layer(TrainConfig().to_dict(), base, "", TrainConfig().to_dict(), open_tables=OPEN)
    except BrlInputError as exc:
        raise BrlInputError(f"sweep grid {path}: [base]: {exc}") from None
    names = list(variants)
    if only:
        unknown = [v for v in only if v not in variants]
        if unknown:
            raise BrlInputError(f"sweep grid {path}: unknown variant '{unknown[0]}'; the grid has {', '.join(names)}")
        names = [v for v in names if v in set(only)]
    resolved: dict[str, TrainConfig] = {}
    for name in names:
        overrides = variants[name]
        if not VARIANT_NAME.match(name):
            raise BrlInputError(f"sweep grid {path}: variant name '{name}' must be letters, digits, '_', '-', '.'")
        if not isinstance(overrides, dict):
            raise BrlInputError(f"sweep grid {path}: variant '{name}' must be a table")
        try:
            resolved[name] = resolve_variant(base, overrides, name)
        except BrlInputError as exc:
            raise BrlInputError(f"sweep grid {path}: variant '{name}': {exc}") from None
    return resolved


# --------------------------------------------------------------------------------------------------------------
# Tasks (plain functions, for any executor)


def variant_dir(out: Path, variant: str) -> Path:
    """A variant's model set in a sweep (seed_N/ runs, as `brl train --seeds` writes them)."""
    return Path(out) / variant


def eval_dir_for(run_dir: Path, routes: str) -> Path:
    """A run's bench results directory for a route set."""
    return Path(run_dir) / f"eval_{routes}"


def train_task(item: tuple[str, TrainConfig, str]) -> dict[str, Any]:
    """Train one (variant, seed) run, or return its summary when finished; resumes from its checkpoint."""
    from brlcli.executor import report
    from brlcli.train import Progress, train_run

    variant, cfg, run_dir = item

    def progress(p: Progress) -> None:
        report({"kind": "step", "variant": variant, "seed": p.seed, "step": p.step, "steps": p.steps,
                "components": p.components})

    result = train_run(cfg, Path(run_dir), resume=True, progress=progress)
    return {"variant": variant, "seed": cfg.seed, **result["summary"]}


def bench_config(cfg: TrainConfig, model: str, policy: str, routes: str, episodes: str | None,
                 bench_seed: int) -> tuple[list[Any], list[Any], dict[str, Any]]:
    """(episode specs, policy specs, bench.json config) of one model's evaluation, as `brl bench` makes them."""
    from brlcli.bench.plan import bench_record
    from brlcli.bench.suites import build_suite, subset
    from brlcli.policy import PolicySpec

    specs = subset(build_suite(routes), episodes)
    pol = PolicySpec("brl", policy, {"model": model, "deploy": cfg.input, "segnet": cfg.segnet})
    selection = {"conditions": None, "tasks": None, "weathers": None, "episodes": episodes}
    config = bench_record(routes, specs, [pol], cfg.input, bench_seed, selection, variants={policy: cfg.variant})
    return specs, [pol], config


def eval_task(item: tuple[str, TrainConfig, str, str, str | None, int]) -> dict[str, Any]:
    """Evaluate one trained model greedily on a route set with the bench (finished episodes are kept)."""
    from brlcli.bench.runner import run_bench
    from brlcli.executor import report

    variant, cfg, run_dir, routes, episodes, bench_seed = item
    run = Path(run_dir)
    specs, pols, config = bench_config(cfg, str(run / "model.npz"), f"{variant}/seed_{cfg.seed}", routes, episodes,
                                       bench_seed)

    def progress(result: dict) -> None:
        report({"kind": "episode", "variant": variant, "seed": cfg.seed, "success": result["success"]})

    results = run_bench(specs, pols, eval_dir_for(run, routes), config, workers=1, resume=True, progress=progress)
    return {"variant": variant, "seed": cfg.seed, "episodes": len(results)}


# --------------------------------------------------------------------------------------------------------------
# The sweep


@dataclass
class SweepPlan:
    """What a sweep runs: resolved variants, seeds, the route set and its episode subset, the bench seed."""

    grid: str
    variants: dict[str, TrainConfig]
    seeds: list[int]
    routes: str = "validation"
    episodes: str | None = None
    bench_seed: int = 0

    def config(self) -> dict[str, Any]:
        """The resolved sweep configuration saved in sweep.json (resume must match it)."""
        return {"grid": self.grid, "variants": {k: v.to_dict() for k, v in self.variants.items()},
                "seeds": list(self.seeds), "routes": self.routes, "episodes": self.episodes,
                "bench_seed": self.bench_seed}

    def runs(self) -> list[tuple[str, TrainConfig, Path]]:
        """(variant, training config, run directory under a sweep's `out`, relative) of every run, variants in grid
        order, seeds ascending."""
        return [(v, cfg.for_seed(s), run_dir_for(Path(v), s)) for v, cfg in self.variants.items()
                for s in self.seeds]


def plan_sweep(grid: Path, seeds: list[int], routes: str = "validation", episodes: str | None = None,
               variants: Sequence[str] | None = None, bench_seed: int = 0) -> SweepPlan:
    """Validate the grid, the route set and the episode subset; nothing is written."""
    if routes not in ROUTE_SETS:
        raise BrlInputError(f"--routes must be one of {', '.join(ROUTE_SETS)}, not '{routes}'")
    resolved = load_grid(grid, variants)
    from brlcli.bench.suites import build_suite, subset

    subset(build_suite(routes), episodes)  # a bad --episodes or a town without the route set fails here
    return SweepPlan(str(grid), resolved, sorted(seeds), routes, episodes, bench_seed)


def _saved_plan_config(saved: dict[str, Any], where: str) -> dict[str, Any]:
    """A saved sweep configuration with its variants read as this brl reads them (retired keys at their off values
    dropped)."""
    variants = {k: TrainConfig.from_saved(v, f"{where} (variant {k})").to_dict()
                for k, v in saved.get("variants", {}).items()}
    return {**{k: v for k, v in saved.items() if k != "grid"}, "variants": variants}


def prepare_sweep(plan: SweepPlan, out: Path, resume: bool, write: bool = True) -> None:
    """Refuse an existing sweep without --resume or with another configuration; check every run; write sweep.json
    (unless `write` is false: a check only)."""
    out = Path(out)
    meta = out / SWEEP_FILE
    if meta.exists():
        refuse_existing(out, "a sweep", resume)
        saved = _saved_plan_config(_read_sweep(out)["config"], str(meta))
        if saved != {k: v for k, v in plan.config().items() if k != "grid"}:
            raise BrlInputError(f"{out} holds a sweep of another grid, seeds, route set or episodes; resume it with "
                                "the same ones or choose another --out")
    elif out.exists() and out.is_dir() and any(out.iterdir()):
        raise BrlInputError(f"{out} is not empty and holds no sweep (no {SWEEP_FILE}); choose another --out")
    elif out.exists() and not out.is_dir():
        raise BrlInputError(f"--out {out} is a file, not a directory")
    for variant, cfg, rel in plan.runs():
        try:
            check_run_dir(cfg, out / rel, resume=True)
        except BrlInputError:
            raise BrlInputError(f"{out / rel} holds a run with another configuration than variant '{variant}'; "
                                "choose another --out") from None
    if write and not meta.exists():
        atomic_write_json(meta, provenance(plan.config(), kind="sweep"))


def _read_sweep(out: Path) -> dict[str, Any]:
    meta = Path(out) / SWEEP_FILE
    try:
        doc = json.loads(meta.read_text(encoding="utf-8"))
        if not all(k in doc["config"] for k in ("variants", "seeds", "routes")):
            raise KeyError("config")
    except (OSError, UnicodeDecodeError, json.JSONDecodeError, KeyError, TypeError):
        raise BrlInputError(f"{meta} is missing or not a brl sweep record") from None
    return doc


def run_sweep(plan: SweepPlan, out: Path, workers: int = 1, resume: bool = False,
              progress: Callable[[Any], None] | None = None, executor: Any = None) -> dict[str, Any]:
    """Train every (variant, seed), evaluate every model on the route set, write the tables; returns the table.

    `progress` receives plain dicts with 'kind', 'variant' and 'seed': 'step' (with step, steps, components) while
    training, 'episode' (with success) while evaluating, 'trained' and 'evaluated' when a run finishes a phase.
    """
    from brlcli.executor import Executor, run_tasks

    out = Path(out)
    prepare_sweep(plan, out, resume)
    runs = plan.runs()
    ex = executor if executor is not None else Executor("local", workers)
    try:
        phases = ((train_task, "trained", [(v, cfg, str(out / rel)) for v, cfg, rel in runs]),
                  (eval_task, "evaluated", [(v, cfg, str(out / rel), plan.routes, plan.episodes, plan.bench_seed)
                                            for v, cfg, rel in runs]))
        for fn, kind, items in phases:
            for _, result in run_tasks(fn, items, executor=ex, on_report=progress):
                if progress:
                    progress({"kind": kind, "variant": result["variant"], "seed": result["seed"]})
    finally:
        if executor is None:
            ex.close()
    return write_tables(out)


# --------------------------------------------------------------------------------------------------------------
# Tables


@dataclass(frozen=True)
class RunResult:
    """One finished run of a sweep: its training summary and its model's row of the test table."""

    variant: str
    seed: int
    stats: Any  # brlcli.report.tables.ModelStats
    components: int
    wall_s: float


def collect_runs(out: Path) -> tuple[dict[str, Any], list[RunResult], list[str]]:
    """(sweep.json record, finished runs, notes on unfinished ones) of a sweep directory."""
    from brlcli.bench.metrics import model_stats
    from brlcli.bench.runner import read_results

    out = Path(out)
    doc = _read_sweep(out)
    cfg = doc["config"]
    from brlcli.bench.suites import build_suite, subset

    expected = len(subset(build_suite(cfg["routes"]), cfg.get("episodes")))
    runs, notes = [], []
    for variant, seed in ((v, s) for v in cfg["variants"] for s in cfg["seeds"]):
        run = run_dir_for(variant_dir(out, variant), seed)
        summary_path = run / "summary.json"
        episodes = read_results(eval_dir_for(run, cfg["routes"]))
        if not summary_path.exists() or len(episodes) < expected:
            notes.append(f"{variant}/seed_{seed}: unfinished ({'trained' if summary_path.exists() else 'training'}, "
                         f"{len(episodes)}/{expected} evaluation episodes)")
            continue
        summary = json.loads(summary_path.read_text())["summary"]
        episodes = sorted(episodes, key=lambda e: e["id"])
        stats = model_stats(episodes[0]["setting"], f"seed_{seed}", episodes)
        runs.append(RunResult(variant, seed, stats, int(summary["components"]), float(summary["wall_s"])))
    return doc, runs, notes


def _mean_std(xs: Sequence[float]) -> tuple[float, float]:
    arr = np.asarray(xs, dtype=np.float64)
    return (float(arr.mean()), float(arr.std())) if arr.size else (math.nan, math.nan)


def sweep_rows(doc: dict[str, Any], runs: Sequence[RunResult]) -> list[dict[str, Any]]:
    """One row per variant (grid order): means and std over seeds (ddof 0), best model, pooled success posterior."""
    from brlcli.bench.metrics import posterior_summary

    rows = []
    for variant in doc["config"]["variants"]:
        rs = sorted((r for r in runs if r.variant == variant), key=lambda r: r.seed)
        row: dict[str, Any] = {"variant": variant, "seeds": len(rs)}
        if rs:
            best = sorted(rs, key=lambda r: (-r.stats.score if np.isfinite(r.stats.score) else math.inf, r.seed))[0]
            successes = sum(r.stats.successes for r in rs)
            episodes = sum(r.stats.episodes for r in rs)
            post = posterior_summary(successes, episodes - successes)
            for key in ("success", "either", "score"):
                row[f"{key}_mean"], row[f"{key}_std"] = _mean_std([getattr(r.stats, key) for r in rs])
            row.update({"best_seed": best.seed, "best_score": best.stats.score,
                        "success_posterior_mean": post["mean"], "success_posterior_lo": post["lo"],
                        "success_posterior_hi": post["hi"],
                        "collision_free_mean": _mean_std([r.stats.no_collision for r in rs])[0],
                        "components_mean": _mean_std([r.components for r in rs])[0],
                        "episodes_per_model": rs[0].stats.episodes,
                        "wall_s_mean": _mean_std([r.wall_s for r in rs])[0],
                        "score_per_seed": {str(r.seed): r.stats.score for r in rs},
                        "success_per_seed": {str(r.seed): r.stats.success for r in rs},
                        "either_per_seed": {str(r.seed): r.stats.either for r in rs}})
        rows.append(row)
    return rows


def _csv(rows: Sequence[dict[str, Any]]) -> str:
    buf = io.StringIO()
    w = csv.writer(buf, lineterminator="\n")
    w.writerow(SWEEP_COLUMNS)
    for row in rows:
        cells = []
        for col in SWEEP_COLUMNS:
            v = row.get(col)
            cells.append("" if v is None else f"{v:.6f}" if isinstance(v, float) else str(v))
        w.writerow(cells)
    return buf.getvalue()


def _pct(x: float | None) -> str:
    return "–" if x is None or not math.isfinite(x) else f"{100 * x:.1f}"


def _md(doc: dict[str, Any], rows: Sequence[dict[str, Any]], notes: Sequence[str]) -> str:
    cfg = doc["config"]
    lines = [f"# brl sweep: {len(cfg['variants'])} variants x {len(cfg['seeds'])} seeds on the {cfg['routes']} routes",
             "",
             f"Made by brl {__version__} (commit {git_commit()}); grid `{cfg.get('grid', '')}`, seeds "
             f"{', '.join(map(str, cfg['seeds']))}, route set `{cfg['routes']}`"
             + (f" (episodes {cfg['episodes']})" if cfg.get("episodes") else "")
             + f", bench seed {cfg.get('bench_seed', 0)}. Resolved configurations in {SWEEP_FILE}.",
             "",
             "| Variant | Seeds | Success [%] | Either [%] | Score | Best model (Score) | Success posterior [%] "
             "| No collision [%] | Components | Training [s] |",
             "|---|---:|---:|---:|---:|---|---:|---:|---:|---:|"]
    for r in rows:
        if not r["seeds"]:
            lines.append(f"| {r['variant']} | 0 | – | – | – | – | – | – | – | – |")
            continue
        lines.append(
            f"| {r['variant']} | {r['seeds']} | {_pct(r['success_mean'])} ± {_pct(r['success_std'])} "
            f"| {_pct(r['either_mean'])} ± {_pct(r['either_std'])} | {r['score_mean']:.3f} ± {r['score_std']:.3f} "
            f"| seed_{r['best_seed']} ({r['best_score']:.3f}) | {_pct(r['success_posterior_mean'])} "
            f"[{_pct(r['success_posterior_lo'])}, {_pct(r['success_posterior_hi'])}] "
            f"| {_pct(r['collision_free_mean'])} | {r['components_mean']:.1f} | {r['wall_s_mean']:.0f} |")
    lines += ["",
              "Success, Either, Score: mean ± std over the seeds (population std) of each model's row of the paper's "
              "test table on the route set (Either: share of steps with more than 20 % of the footprint off road or in "
              "the other lane; Score = ((1 - Either) + Success + No collision) / 3). Best model: highest Score (ties: "
              "lowest seed). Success posterior: Beta posterior (Jeffreys prior) of the success rate pooled over the "
              "variant's models, mean [95 % credible interval]. Components: mixture components at the end of "
              "training; Training: learning wall time per model.",
              "", "![sweep](sweep.png)", ""]
    if any(r["seeds"] for r in rows):
        lines += ["## Score per seed", "", "| Variant | " + " | ".join(f"seed_{s}" for s in cfg["seeds"]) + " |",
                  "|---|" + "---:|" * len(cfg["seeds"])]
        for r in rows:
            per = r.get("score_per_seed", {})
            lines.append(f"| {r['variant']} | " + " | ".join(f"{per[str(s)]:.3f}" if str(s) in per else "–"
                                                             for s in cfg["seeds"]) + " |")
        lines.append("")
    if notes:
        lines += ["## Unfinished runs", "", *[f"- {n}" for n in notes], ""]
    return "\n".join(lines)


def _png(rows: Sequence[dict[str, Any]]) -> bytes:
    from matplotlib.backends.backend_agg import FigureCanvasAgg
    from matplotlib.figure import Figure

    names = [r["variant"] for r in rows]
    x = np.arange(len(rows))
    fig = Figure(figsize=(10.0, 4.2), dpi=100, layout="constrained")
    ax_score, ax_rates = fig.subplots(1, 2)
    for i, r in enumerate(rows):
        per = list(r.get("score_per_seed", {}).values())
        if per:
            ax_score.scatter(np.full(len(per), i), per, s=22, color="tab:blue", alpha=0.6, zorder=2,
                             label="a seed" if i == 0 else None)
            ax_score.scatter([i], [r["score_mean"]], s=160, marker="_", linewidths=2.5, color="black", zorder=3,
                             label="mean" if i == 0 else None)
    ax_score.set_xticks(x, names, rotation=30, ha="right")
    ax_score.set_xlim(-0.6, len(rows) - 0.4)
    ax_score.set_ylim(0.0, 1.02)
    ax_score.set_ylabel("Score")
    ax_score.set_title("Score per seed")
    ax_score.grid(axis="y", alpha=0.3)
    ax_score.legend(loc="lower right", fontsize=8)
    width = 0.38
    for off, key, color, label in ((-width / 2, "success", "tab:green", "success"),
                                   (width / 2, "either", "tab:red", "Either (off road / other lane)")):
        means = [100 * r.get(f"{key}_mean", math.nan) for r in rows]
        stds = [100 * r.get(f"{key}_std", math.nan) for r in rows]
        ax_rates.bar(x + off, means, width, yerr=stds, capsize=3, color=color, alpha=0.75, label=label)
    ax_rates.set_xticks(x, names, rotation=30, ha="right")
    ax_rates.set_ylim(0.0, 105.0)
    ax_rates.set_ylabel("% (mean ± std over seeds)")
    ax_rates.set_title("Success and Either")
    ax_rates.grid(axis="y", alpha=0.3)
    ax_rates.legend(loc="upper right", fontsize=8)
    FigureCanvasAgg(fig)
    buf = io.BytesIO()
    fig.savefig(buf, format="png", metadata={"Software": None})
    return buf.getvalue()


def write_tables(out: Path) -> dict[str, Any]:
    """Rebuild sweep.md, sweep.csv, sweep.png and the rows in sweep.json from the finished runs of a sweep."""
    out = Path(out)
    doc, runs, notes = collect_runs(out)
    rows = sweep_rows(doc, runs)
    atomic_write_bytes(out / "sweep.csv", _csv(rows).encode())
    atomic_write_bytes(out / "sweep.md", _md(doc, rows, notes).encode())
    atomic_write_bytes(out / "sweep.png", _png(rows))
    record = provenance(doc["config"], kind="sweep")
    record["rows"] = rows
    record["unfinished"] = list(notes)
    atomic_write_json(out / SWEEP_FILE, record)
    return {"out": str(out), "rows": rows, "notes": notes, "runs": len(runs),
            "total": len(doc["config"]["variants"]) * len(doc["config"]["seeds"])}
