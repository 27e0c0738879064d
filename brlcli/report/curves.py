"""Sample efficiency: learning curves (greedy success vs. environment steps) of BRL and deep RL runs.

Inputs are run directories holding `learning_curve.csv` (from `brl train --curve-every N` or `brl train-rl`), or
directories of such runs (seed_0, seed_1, ...). Runs are grouped by learner: the deep RL algorithm named in the
run's config.json (e.g. DQN), else BRL; by training input (TG / TE) and task (navigation runs are marked). Every
curve of a report must come from the same evaluation suite (the paper suite for lane keeping, nav_validation for
navigation).
"""

from __future__ import annotations

import io
import json
from dataclasses import dataclass
from pathlib import Path

import numpy as np
from matplotlib.backends.backend_agg import FigureCanvasAgg
from matplotlib.figure import Figure

from brlcli.curve import CURVE_FILE, read_curve, steps_to_reach
from brlcli.errors import BrlInputError
from brlcli.report.tables import Cell, Section, Table, count, pct


@dataclass(frozen=True)
class CurveRun:
    """One run's learning curve."""

    learner: str
    name: str
    suite: str
    env_steps: np.ndarray
    success: np.ndarray
    collision_free: np.ndarray
    score: np.ndarray


def _learner(run: Path) -> str:
    cfg_path = run / "config.json"
    try:
        cfg = json.loads(cfg_path.read_text()).get("config", {}) if cfg_path.exists() else {}
    except json.JSONDecodeError:
        raise BrlInputError(f"{cfg_path} is not a brl run configuration") from None
    tag = {"gt": "TG", "estimated": "TE"}.get(str(cfg.get("input", "gt")), "T?")
    if cfg.get("task", "lane-keeping") != "lane-keeping":
        tag += f", {cfg['task']}"
    algo = cfg.get("algo")
    if algo:
        return f"{str(algo).upper()} ({tag})"
    variant = str(cfg.get("variant", "paper"))
    return f"BRL ({tag})" if variant == "paper" else f"BRL {variant} ({tag})"


def load_curves(dirs: list[str | Path]) -> list[CurveRun]:
    """Learning curves of run directories (or directories of runs), sorted by learner and name."""
    runs: dict[str, CurveRun] = {}
    for item in dirs:
        path = Path(item)
        if (path / CURVE_FILE).is_file():
            paths = [path]
        elif path.is_dir():
            paths = sorted(p.parent for p in path.glob(f"*/{CURVE_FILE}"))
        else:
            raise BrlInputError(f"{path} does not exist")
        if not paths:
            raise BrlInputError(f"{path} holds no {CURVE_FILE}; train with brl train --curve-every N or brl train-rl")
        for p in paths:
            rows = read_curve(p / CURVE_FILE)
            if not rows:
                raise BrlInputError(f"{p / CURVE_FILE} holds no evaluations yet")
            rows.sort(key=lambda r: r["env_steps"])
            name = f"{p.resolve().parent.name}/{p.resolve().name}"
            if name in runs:
                raise BrlInputError(f"two learning curves are named {name}; give them distinct directories")
            suites = {r["eval_suite"] for r in rows}
            if len(suites) != 1:
                raise BrlInputError(f"{p / CURVE_FILE} mixes evaluation suites ({', '.join(sorted(suites))})")
            runs[name] = CurveRun(_learner(p), name, suites.pop(), np.array([r["env_steps"] for r in rows]),
                                  *(np.array([r[k] for r in rows]) for k in ("success", "collision_free", "score")))
    found = {r.suite for r in runs.values()}
    if len(found) > 1:
        raise BrlInputError(f"the learning curves come from different suites ({', '.join(sorted(found))}); report "
                            "them separately")
    return sorted(runs.values(), key=lambda r: (r.learner, r.name))


SUITE_TEXT = {"paper": ("paper-suite", "the paper suite's 66 lane-keeping episodes"),
              "nav_validation": ("nav_validation", "the nav_validation suite's 16 navigation episodes (planner routes "
                                                   "through junctions in town01 and town02, route commands)")}
"""How the tables and plots name a curve's evaluation suite: (short, long)."""


def _suite(runs: list[CurveRun]) -> tuple[str, str]:
    suite = runs[0].suite if runs else "paper"
    return SUITE_TEXT.get(suite, (suite, f"the {suite} suite's episodes"))


def mean_curve(runs: list[CurveRun]) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """(env steps evaluated by every run, mean success, std success) of a learner's runs."""
    common = sorted(set.intersection(*(set(r.env_steps.tolist()) for r in runs)))
    vals = np.array([[r.success[list(r.env_steps).index(s)] for s in common] for r in runs])
    return np.array(common), vals.mean(axis=0), vals.std(axis=0)


def _groups(runs: list[CurveRun]) -> dict[str, list[CurveRun]]:
    out: dict[str, list[CurveRun]] = {}
    for r in runs:
        out.setdefault(r.learner, []).append(r)
    return out


def _reference(groups: dict[str, list[CurveRun]]) -> tuple[str, float] | None:
    """The BRL learner (GT input first) and its final mean success: the level the others must reach."""
    brl = [k for k in groups if k.startswith("BRL")]
    for learner in sorted(brl, key=lambda k: ("(TG" not in k, k)):
            steps, mean, _ = mean_curve(groups[learner])
            if steps.size:
                return learner, float(mean[-1])
    return None


def sample_efficiency_table(runs: list[CurveRun]) -> Table:
    """Per learner: runs, budget, final and best mean success, env steps to reach BRL's final mean success."""
    groups = _groups(runs)
    ref = _reference(groups)
    target_col = f"Env steps to {ref[0]} final success" if ref else "Env steps to BRL's final success"
    short, long = _suite(runs)
    t = Table("sample_efficiency", f"Sample efficiency: {short} success against environment steps",
              ["Learner", "Runs", "Env steps (last eval)", "Final success [%]", "Final success std [%]",
               "Best mean success [%]", "At env steps", target_col], label_columns=1)
    for learner, group in groups.items():
        steps, mean, std = mean_curve(group)
        if steps.size == 0:
            t.add([Cell.of(learner), count(len(group)), *([Cell.of("no common evaluation steps")] * 6)])
            continue
        best = int(np.argmax(mean))
        reach = None
        if ref is not None:
            reach = steps_to_reach([{"env_steps": int(s), "success": float(m)} for s, m in zip(steps, mean,
                                                                                             strict=True)], ref[1])
        t.add([Cell.of(learner), count(len(group)), count(int(steps[-1])), pct(float(mean[-1])), pct(float(std[-1])),
               pct(float(mean[best])), count(int(steps[best])),
               count(reach) if reach is not None else Cell.of("not reached" if ref else "–")])
    t.notes = ["An environment step is one decision (an action held for 7 simulator frames, 0.7 s). Success: share of "
               f"{long} reaching the goal, greedy policy, mean over the learner's runs at each evaluated step."]
    if ref is not None:
        t.notes.append(f"Target: the final mean success of {ref[0]}, {100 * ref[1]:.1f} %; 'not reached' means no "
                       "evaluated step's mean success reached it within the run's budget.")
    return t


def curve_figure(runs: list[CurveRun]) -> bytes:
    """Mean paper-suite success (± 1 std over runs) against env steps per learner, log x axis."""
    fig = Figure(figsize=(10.0, 5.0), dpi=100, layout="constrained")
    ax = fig.subplots()
    colors = ("tab:blue", "tab:red", "tab:green", "tab:purple", "tab:brown", "tab:gray")
    for k, (learner, group) in enumerate(_groups(runs).items()):
        steps, mean, std = mean_curve(group)
        if not steps.size:
            continue
        c = colors[k % len(colors)]
        ax.plot(steps, 100 * mean, color=c, lw=2, marker="o", ms=3, label=f"{learner}: mean of {len(group)} runs")
        if len(group) > 1:
            ax.fill_between(steps, 100 * (mean - std), 100 * (mean + std), color=c, alpha=0.2, lw=0)
    ref = _reference(_groups(runs))
    if ref is not None:
        ax.axhline(100 * ref[1], color="black", ls="--", lw=1, label=f"{ref[0]} final mean success")
    ax.set_xscale("log")
    ax.set_xlabel("environment steps (decisions), log scale")
    short, long = _suite(runs)
    ax.set_ylabel(f"{short} success [%]")
    ax.set_ylim(-2, 102)
    ax.grid(alpha=0.3, which="both")
    ax.legend(loc="lower right", fontsize=9)
    ax.set_title(f"Sample efficiency: greedy success on {long.split(' (')[0]}", fontsize=12)
    FigureCanvasAgg(fig)
    buf = io.BytesIO()
    fig.savefig(buf, format="png", dpi=100, metadata={"Software": None})
    return buf.getvalue()


def curves_section(runs: list[CurveRun]) -> Section:
    """The report section (the figure is added by the caller when plots are made)."""
    learners = ", ".join(f"{k} ({len(v)} runs)" for k, v in _groups(runs).items())
    return Section("Sample efficiency (learning curves)",
                   f"Greedy success on {_suite(runs)[1]} during training, per learner: {learners}.",
                   [sample_efficiency_table(runs)])
