"""The report's tables: the paper's test table, Beta posteriors, CoRL2017 success and km between infractions, and
the training runs; each beside the published figures. Cells are formatted once here with fixed precision so that
every output format is deterministic.
"""

from __future__ import annotations

from collections import defaultdict
from collections.abc import Callable, Sequence
from dataclasses import dataclass, field
from typing import Any

import numpy as np

from brlcli.bench.metrics import (
    INFRACTION_TYPES,
    ModelStats,
    km_between_infractions,
    model_stats,
    posterior_summary,
    success_rate_over_weathers,
)
from brlcli.report import published as pub
from brlcli.report.load import TrainingRun
from brlcli.settings import base_setting

# --------------------------------------------------------------------------------------------------------------
# Cells and tables

DASH = "–"
"""Shown where there is no value (no episodes, or the paper prints none)."""


@dataclass(frozen=True)
class Cell:
    """A table cell: `text` as shown in md/tex/html, `value` as written to CSV (plain number or text)."""

    text: str
    value: str

    @classmethod
    def of(cls, text: Any) -> Cell:
        """A text cell (the same in every format)."""
        return cls(str(text), str(text))


EMPTY = Cell(DASH, "")


def pct(share: float | None) -> Cell:
    """A share in [0, 1] as percent: 1 decimal shown, 4 in CSV."""
    if share is None or not np.isfinite(share):
        return EMPTY
    return Cell(f"{100.0 * share:.1f}", f"{100.0 * share:.4f}")


def published_pct(percent: float | None) -> Cell:
    """A percentage as the paper prints it (1 decimal)."""
    return EMPTY if percent is None else Cell(f"{percent:.1f}", f"{percent:.1f}")


def num(x: float | None, digits: int, csv_digits: int = 6) -> Cell:
    """A number with `digits` decimals shown and `csv_digits` in CSV."""
    if x is None or not np.isfinite(x):
        return EMPTY
    return Cell(f"{x:.{digits}f}", f"{x:.{csv_digits}f}")


def count(n: int) -> Cell:
    """An integer."""
    return Cell(str(int(n)), str(int(n)))


@dataclass
class Table:
    """A report table: title, column names, rows of cells, notes printed under it; `breaks` are row indices
    before which a rule separates groups; the first `label_columns` columns are text (left-aligned)."""

    key: str
    title: str
    columns: list[str]
    rows: list[list[Cell]] = field(default_factory=list)
    notes: list[str] = field(default_factory=list)
    breaks: list[int] = field(default_factory=list)
    label_columns: int = 1

    def add(self, cells: Sequence[Cell]) -> None:
        """Append a row (must have one cell per column)."""
        if len(cells) != len(self.columns):
            raise ValueError(f"table {self.key}: row has {len(cells)} cells for {len(self.columns)} columns")
        self.rows.append(list(cells))

    def group(self) -> None:
        """Start a new group of rows (a rule before the next row)."""
        if self.rows and (not self.breaks or self.breaks[-1] != len(self.rows)):
            self.breaks.append(len(self.rows))


@dataclass(frozen=True)
class Figure:
    """A plot of the report: PNG file name, title and caption."""

    file: str
    title: str
    caption: str


@dataclass
class Section:
    """A part of the report: a heading, a paragraph, tables and figures."""

    title: str
    text: str
    tables: list[Table] = field(default_factory=list)
    figures: list[Figure] = field(default_factory=list)


def setting_order(settings: Sequence[str]) -> list[str]:
    """The paper's settings in its order (each followed by its other method variants, 'TGDG (NAME)', by name), then
    any other setting (baselines) sorted by name."""
    present = set(settings)
    ordered = [s for p in pub.PAPER_SETTINGS for s in sorted(present, key=lambda x: (x != p, x))
               if base_setting(s) == p]
    return ordered + sorted(present - set(ordered))


# --------------------------------------------------------------------------------------------------------------
# The paper's test suite


def best_model(models: Sequence[ModelStats]) -> ModelStats:
    """The model with the highest Score (ties: the first by name; a model without steps, Score NaN, comes last)."""
    return sorted(models, key=lambda m: (-m.score if np.isfinite(m.score) else np.inf, m.policy))[0]


@dataclass
class PaperData:
    """What the paper-suite tables and plots are made from."""

    models: dict[str, list[ModelStats]]
    """Setting -> its models (sorted by name); settings in setting_order."""
    episodes: dict[tuple[str, str], list[dict[str, Any]]]
    """(setting, policy) -> episodes."""
    missing: list[str]
    """Paper settings without any results, under any method variant's label ('TGDG (NAME)' counts as TGDG)."""
    suite_size: int | None = None
    """Episodes of the whole suite the results were drawn from (None: not known)."""

    @property
    def settings(self) -> list[str]:
        """Settings present."""
        return list(self.models)

    def is_model_set(self, setting: str) -> bool:
        """A paper setting of any method variant (average and best model) rather than a baseline (one row per
        policy)."""
        return base_setting(setting) in pub.PAPER_SETTINGS


def paper_data(episodes: Sequence[dict[str, Any]], suite_size: int | None = None) -> PaperData:
    """Group the paper-suite episodes by setting and model; `suite_size`: episodes of the whole suite (to say when
    the results are a subset of it)."""
    groups: dict[tuple[str, str], list[dict[str, Any]]] = defaultdict(list)
    for ep in episodes:
        groups[(str(ep["setting"]), str(ep["policy"]))].append(ep)
    models: dict[str, list[ModelStats]] = {}
    for setting in setting_order([s for s, _ in groups]):
        models[setting] = [model_stats(setting, p, groups[(s, p)]) for s, p in sorted(groups) if s == setting]
    present = {base_setting(s) for s in models}
    missing = [s for s in pub.PAPER_SETTINGS if s not in present]
    return PaperData(models=models, episodes=dict(groups), missing=missing, suite_size=suite_size)


def subset_phrase(counts: Sequence[int], suite_size: int | None, per: str) -> str | None:
    """'7 of the suite's 66 episodes per model' (or 'from 7 to 20 of ...') when any count is below the suite's size;
    None when every one ran the whole suite, or the size is not known."""
    if suite_size is None or not counts or min(counts) >= suite_size:
        return None
    lo, hi = min(counts), max(counts)
    ran = str(lo) if lo == hi else f"from {lo} to {hi}"
    return f"{ran} of the suite's {suite_size} episodes per {per}"


def paper_subset_phrase(data: PaperData) -> str | None:
    """subset_phrase of the paper-suite models (and baselines)."""
    return subset_phrase([m.episodes for ms in data.models.values() for m in ms], data.suite_size, "model")


PAPER_COLUMNS = ["Setting", "Row", "Source", "Models", "Episodes", "Offroad [%]", "Otherlane [%]", "Either [%]",
                 "Success [%]", "No collision [%]", "Score", "Score std", "Dist [m]", "Dist std [m]"]


def _stats_cells(m: ModelStats) -> list[Cell]:
    return [pct(m.offroad), pct(m.otherlane), pct(m.either), pct(m.success), pct(m.no_collision)]


def _published_cells(r: pub.PublishedPaperRow) -> list[Cell]:
    return [published_pct(r.offroad_pct), published_pct(r.otherlane_pct), published_pct(r.either_pct),
            published_pct(r.success_pct), published_pct(r.no_collision_pct), num(r.score, 2, 3),
            EMPTY if r.score_std is None else Cell.of(f"{r.score_std:g}"), num(r.dist_m, 0, 0),
            EMPTY if r.dist_std_m is None else num(r.dist_std_m, 0, 0)]


def _our_rows(t: Table, setting: str, models: list[ModelStats] | None) -> None:
    """Our average and best-model rows of one setting label (or a 'missing' row)."""
    if models:
        scores = np.array([m.score for m in models])
        dists = np.array([m.dist_m for m in models])
        mean = {k: float(np.mean([getattr(m, k) for m in models]))
                for k in ("offroad", "otherlane", "either", "success", "no_collision")}
        t.add([Cell.of(setting), Cell.of("average"), Cell.of("ours"), count(len(models)),
               count(sum(m.episodes for m in models)),
               *(pct(mean[k]) for k in ("offroad", "otherlane", "either", "success", "no_collision")),
               num(float(scores.mean()), 2, 6), num(float(scores.std()), 2, 6), num(float(dists.mean()), 0, 3),
               num(float(dists.std()), 0, 3)])
        b = best_model(models)
        t.add([Cell.of(setting), Cell.of(f"best model: {b.policy}"), Cell.of("ours"), count(1), count(b.episodes),
               *_stats_cells(b), num(b.score, 2, 6), EMPTY, num(b.dist_m, 0, 3), EMPTY])
    else:
        t.add([Cell.of(setting), Cell.of("missing: no results for this setting"), Cell.of("ours"), count(0),
               count(0), *([EMPTY] * 9)])


def paper_table(data: PaperData) -> Table:
    """The paper's test table: per setting our average (± std over models) and best model, then the published
    rows; baselines (other settings) one row per policy; the published RL and IL rows last."""
    t = Table("paper_test_table", f"Lane-keeping test table (the paper's {pub.PAPER_TABLE_NAME})", list(PAPER_COLUMNS),
              label_columns=3)
    published_rows = {(r.setting, r.row): r for r in pub.PAPER_TABLE}
    for paper_setting in pub.PAPER_SETTINGS:
        t.group()
        labels = [s for s in data.settings if base_setting(s) == paper_setting] or [paper_setting]
        for setting in labels:
            _our_rows(t, setting, data.models.get(setting))
        for row in ("average", "best model"):
            r = published_rows[(paper_setting, row)]
            t.add([Cell.of(paper_setting), Cell.of(row), Cell.of("published"), EMPTY, EMPTY, *_published_cells(r)])
    baselines = [s for s in data.settings if not data.is_model_set(s)]
    for setting in baselines:
        t.group()
        for m in data.models[setting]:
            t.add([Cell.of(setting), Cell.of(m.policy), Cell.of("ours"), count(1), count(m.episodes),
                   *_stats_cells(m), num(m.score, 2, 6), EMPTY, num(m.dist_m, 0, 3), EMPTY])
    t.group()
    for setting in ("RL", "IL"):
        r = published_rows[(setting, f"CARLA {setting}")]
        t.add([Cell.of(setting), Cell.of(r.row), Cell.of("published"), EMPTY, EMPTY, *_published_cells(r)])
    t.notes = [
        "Offroad / Otherlane / Either: share of time steps with more than 20 % of the car's footprint off road / in "
        "the opposite lane / either, pooled over all steps of a model's episodes. Success / No collision: share of "
        "episodes. Score = ((1 - Either) + Success + No collision) / 3. Dist: metres driven by a model in all its "
        "episodes.",
        "Average rows: mean over the setting's models; Score std and Dist std are the standard deviations over the "
        "models (population, ddof = 0). Best model: highest Score (ties: first by name).",
        f"Rows marked published come from {pub.PAPER_TABLE_SOURCE} (CARLA 0.8, nine models per setting); RL and IL are "
        "CARLA's baselines there. Our simulator is not CARLA: compare trends, not absolute values.",
    ]
    subset = paper_subset_phrase(data)
    if subset:
        t.notes.insert(1, f"Dist is not comparable with the published rows in absolute terms: those are for the "
                          f"paper's full test suite, ours for {subset} (a subset of it). The shares (per step or "
                          "per episode) and the Score are comparable; metres driven scale with the episodes run.")
    for setting in data.missing:
        t.notes.append(f"Setting {setting} is missing: the inputs hold no {setting} results.")
    for setting, models in data.models.items():
        sizes = sorted({m.episodes for m in models})
        if len(sizes) > 1:
            t.notes.append(f"{setting}: models ran different numbers of episodes ({sizes[0]} to {sizes[-1]}); "
                           "the results are incomplete.")
    if baselines:
        t.notes.append(f"Other policies (baselines) as extra rows: {', '.join(baselines)}.")
    return t


def paper_models_table(data: PaperData) -> Table:
    """Every model's row of the test table (the best model of each setting marked)."""
    t = Table("paper_models", "Lane-keeping test table: every model", ["Setting", "Policy", "Best", "Episodes",
              "Steps", "Offroad [%]", "Otherlane [%]", "Either [%]", "Success [%]", "No collision [%]", "Score",
              "Dist [m]"], label_columns=3)
    for setting, models in data.models.items():
        t.group()
        best = best_model(models).policy if data.is_model_set(setting) else None
        for m in models:
            t.add([Cell.of(setting), Cell.of(m.policy), Cell.of("best" if m.policy == best else ""),
                   count(m.episodes), count(m.steps), *_stats_cells(m), num(m.score, 3, 6), num(m.dist_m, 0, 3)])
    t.notes = ["Step shares pool all steps of a model's episodes; Score = ((1 - Either) + Success + No collision) / 3."]
    return t


@dataclass(frozen=True)
class Posterior:
    """A Beta posterior (Jeffreys prior) of one rate for one scope of one setting."""

    setting: str
    scope: str
    """'best' or 'pooled' (or 'policy' for a baseline)."""
    label: str
    rate: str
    """'success' or 'collision-free'."""
    successes: int
    failures: int
    models: int


def posteriors(data: PaperData) -> list[Posterior]:
    """Success and collision-free posteriors per setting: best model and pooled over the model set; baselines
    per policy."""
    out: list[Posterior] = []
    for setting, models in data.models.items():
        if data.is_model_set(setting):
            b = best_model(models)
            scopes = [("best", f"best model: {b.policy}", [b]),
                      ("pooled", f"pooled over {len(models)} model{'s' if len(models) != 1 else ''}", models)]
        else:
            scopes = [("policy", m.policy, [m]) for m in models]
        for scope, label, ms in scopes:
            n = sum(m.episodes for m in ms)
            s_ok, s_cf = sum(m.successes for m in ms), sum(m.collision_free for m in ms)
            out.append(Posterior(setting, scope, label, "success", s_ok, n - s_ok, len(ms)))
            out.append(Posterior(setting, scope, label, "collision-free", s_cf, n - s_cf, len(ms)))
    return out


def posterior_table(data: PaperData, posts: Sequence[Posterior]) -> Table:
    """Posterior mean and 95 % equal-tailed credible interval of each rate (metrics.posterior_summary)."""
    t = Table("paper_posteriors", "Beta posteriors of the success and collision-free rates (Jeffreys prior)",
              ["Setting", "Scope", "Rate", "Models", "Successes", "Failures", "Mean", "95 % lo", "95 % hi"],
              label_columns=3)
    last = None
    for p in posts:
        if p.setting != last:
            t.group()
            last = p.setting
        s = posterior_summary(p.successes, p.failures)
        t.add([Cell.of(p.setting), Cell.of(p.label), Cell.of(p.rate), count(p.models), count(p.successes),
               count(p.failures), num(s["mean"], 3), num(s["lo"], 3), num(s["hi"], 3)])
    for setting in data.missing:
        t.group()
        t.add([Cell.of(setting), Cell.of("missing: no results for this setting"), Cell.of(DASH), count(0), EMPTY,
               EMPTY, EMPTY, EMPTY, EMPTY])
    t.notes = ["Posterior Beta(s + 0.5, f + 0.5) after s successes and f failures with the Jeffreys prior "
               "Beta(0.5, 0.5) (paper eq. 15); 95 % equal-tailed credible interval. Success: reached the goal in "
               "time; collision-free: no collision in the episode."]
    return t


# --------------------------------------------------------------------------------------------------------------
# CoRL2017


def _agent_label(policy: str, setting: str) -> str:
    return f"{policy} ({setting})"


SHORT_SETTING_CHARS = 40
"""A setting label longer than this is shown in a table as its paper setting and a key, spelled out in a note."""


class AgentLabels:
    """The agent cells of one table. A long setting label ('TGDG (action-averaging-committee, navigation, ...)')
    shows as its paper setting and a key ('TGDG [a]'), each key spelled out once in the table's notes; the CSV
    keeps the full label."""

    def __init__(self) -> None:
        self._keys: dict[str, str] = {}

    def _short(self, setting: str) -> str:
        if len(setting) <= SHORT_SETTING_CHARS:
            return setting
        if setting not in self._keys:
            i = len(self._keys)
            self._keys[setting] = chr(ord("a") + i) if i < 26 else f"s{i + 1}"
        return f"{base_setting(setting)} [{self._keys[setting]}]"

    def agent(self, policy: str, setting: str) -> Cell:
        """One policy's cell: 'seed_0 (TGDG)', or 'brl_nav/seed_0 (TGDG [a])' for a long setting."""
        return Cell(f"{policy} ({self._short(setting)})", _agent_label(policy, setting))

    def model_set(self, policies: Sequence[str], setting: str) -> Cell:
        """A model set's mean row: 'brl_nav: mean of 9 models (TGDG [a])'."""
        name = f"{policies[0].split('/')[0]}: mean of {len(policies)} models"
        return Cell(f"{name} ({self._short(setting)})", f"{name} ({setting})")

    def notes(self) -> list[str]:
        """The keys spelled out (a note), or none when every setting is shown whole."""
        if not self._keys:
            return []
        return ["Settings: " + "; ".join(f"[{k}] {s}" for s, k in self._keys.items()) + "."]


def corl_agents(episodes: Sequence[dict[str, Any]]) -> list[tuple[str, str]]:
    """(setting, policy) pairs, the paper's settings first."""
    pairs = {(str(ep["setting"]), str(ep["policy"])) for ep in episodes}
    order = setting_order([s for s, _ in pairs])
    return sorted(pairs, key=lambda sp: (order.index(sp[0]), sp[1]))


def model_set_ends(agents: Sequence[tuple[str, str]]) -> dict[tuple[str, str], list[str]]:
    """Model sets among the agents: {(setting, last member's policy): member policies} for every group of two or
    more policies named `<set>/<model>` (e.g. nav/seed_0 .. nav/seed_8) with the same setting."""
    sets: dict[tuple[str, str], list[str]] = defaultdict(list)
    for setting, policy in agents:
        if "/" in policy:
            sets[(setting, policy.split("/")[0])].append(policy)
    return {(setting, members[-1]): members for (setting, _), members in sets.items() if len(members) > 1}


def model_set_cell(rates: Sequence[float]) -> Cell:
    """A model set's cell: mean ± sample std (ddof 1) [worst, best] of its models' success shares, in %."""
    v = 100.0 * np.asarray(rates, dtype=float)
    std = float(np.std(v, ddof=1)) if len(v) > 1 else 0.0
    return Cell(f"{v.mean():.1f} ± {std:.1f} [{v.min():.1f}, {v.max():.1f}]", f"{v.mean():.4f}")


def pooled_success(episodes: Sequence[dict[str, Any]]) -> float:
    """Share of the episodes that succeeded (pooled, whatever their weather)."""
    return sum(bool(ep["success"]) for ep in episodes) / len(episodes)


def _model_set_cells(groups: dict[tuple[str, str, str, str], list[dict[str, Any]]], setting: str,
                     members: Sequence[str], task: str, cond_keys: Sequence[str],
                     rate: Callable[[Sequence[dict[str, Any]]], float]) -> list[Cell]:
    """A model set's cells, one per condition: its members' `rate` in the (task, condition) cell."""
    cells = []
    for cond in cond_keys:
        rates = [rate(groups[(setting, m, task, cond)]) for m in members if groups.get((setting, m, task, cond))]
        cells.append(model_set_cell(rates) if rates else EMPTY)
    return cells


MODEL_SET_NOTE = ("Rows 'mean of N models': a model set (policies named set/model with one setting), the mean ± "
                  "sample std over its models of their success in the cell, [worst, best] model.")


def corl_success_table(episodes: Sequence[dict[str, Any]]) -> Table:
    """% success per task x condition per agent (mean over weathers), with CARLA's Table 1 MP / IL / RL."""
    cond_keys = [c for c, _ in pub.CORL_CONDITIONS]
    t = Table("corl_success", "CoRL2017: % success per task and condition",
              ["Task", "Agent", "Source", *(title for _, title in pub.CORL_CONDITIONS)], label_columns=3)
    groups: dict[tuple[str, str, str, str], list[dict[str, Any]]] = defaultdict(list)
    for ep in episodes:
        groups[(str(ep["setting"]), str(ep["policy"]), str(ep["task"]), str(ep["condition"]))].append(ep)
    agents = corl_agents(episodes)
    sets = model_set_ends(agents)
    labels = AgentLabels()
    empty = 0
    for task, task_title in pub.CORL_TASKS:
        t.group()
        for setting, policy in agents:
            cells = []
            for cond in cond_keys:
                eps = groups.get((setting, policy, task, cond), [])
                if eps:
                    rate = success_rate_over_weathers(eps)
                    cells.append(Cell(f"{100.0 * rate:.1f} (n={len(eps)})", f"{100.0 * rate:.4f}"))
                else:
                    empty += 1
                    cells.append(EMPTY)
            t.add([Cell.of(task_title), labels.agent(policy, setting), Cell.of("ours"), *cells])
            if (setting, policy) in sets:
                members = sets[(setting, policy)]
                t.add([Cell.of(task_title), labels.model_set(members, setting), Cell.of("ours"),
                       *_model_set_cells(groups, setting, members, task, cond_keys, success_rate_over_weathers)])
        for agent in pub.CARLA_AGENTS:
            t.add([Cell.of(task_title), Cell.of(agent), Cell.of("published"),
                   *(count(pub.CARLA_SUCCESS_PCT[task][c][agent]) for c in cond_keys)])
    unknown = sorted({str(ep["task"]) for ep in episodes} - {k for k, _ in pub.CORL_TASKS}
                     | {str(ep["condition"]) for ep in episodes} - set(cond_keys))
    t.notes = [
        "% success: the share of episodes that reached the goal in time, per weather, then the equal-weight mean "
        "over the weathers of the condition; n = episodes.",
        f"Rows marked published come from {pub.CARLA_TABLE1_SOURCE} (MP modular pipeline, IL imitation learning, RL "
        "reinforcement learning; 25 routes x every weather of the condition in CARLA 0.8).",
    ]
    if sets:
        t.notes.append(MODEL_SET_NOTE)
    t.notes.extend(labels.notes())
    if empty:
        t.notes.append(f"{DASH}: no episodes of ours in {empty} agent x task x condition cells (a subset of the suite "
                       "was run).")
    if unknown:
        t.notes.append(f"Episodes of tasks or conditions outside CoRL2017 are left out: {', '.join(unknown)}.")
    return t


def corl_km_table(episodes: Sequence[dict[str, Any]], suite_size: int | None = None) -> Table:
    """Average km between infractions per type x condition (pooled over tasks and weathers) per agent, with the
    paper's Town02 table (its Table III: MP, IL, RL and its four settings) beside ours; `suite_size`: episodes of
    the whole CoRL2017 suite (to say when ours are a subset of it)."""
    cond_keys = [c for c, _ in pub.CORL_CONDITIONS]
    t = Table("corl_km_between_infractions", "CoRL2017: average km driven between infractions",
              ["Infraction", "Agent", "Source", *(title for _, title in pub.CORL_CONDITIONS)], label_columns=3)
    groups: dict[tuple[str, str, str], list[dict[str, Any]]] = defaultdict(list)
    for ep in episodes:
        groups[(str(ep["setting"]), str(ep["policy"]), str(ep["condition"]))].append(ep)
    agents = corl_agents(episodes)
    labels = AgentLabels()
    pooled = {(s, p, c): km_between_infractions(groups[(s, p, c)]) for s, p in agents for c in cond_keys
              if groups.get((s, p, c))}
    t.group()
    for setting, policy in agents:
        t.add([Cell.of("km driven"), labels.agent(policy, setting), Cell.of("ours"),
               *(num(pooled[(setting, policy, c)][INFRACTION_TYPES[0]].km, 2) if (setting, policy, c) in pooled
                 else EMPTY for c in cond_keys)])
    for kind in INFRACTION_TYPES:
        t.group()
        title = pub.INFRACTION_TITLES[kind]
        for setting, policy in agents:
            cells = []
            for c in cond_keys:
                if (setting, policy, c) not in pooled:
                    cells.append(EMPTY)
                    continue
                k = pooled[(setting, policy, c)][kind]
                cells.append(Cell(k.label(2), f">{k.km:.6f}" if k.more_than else f"{k.value:.6f}"))
            t.add([Cell.of(title), labels.agent(policy, setting), Cell.of("ours"), *cells])
        for i, agent in enumerate(pub.PAPER_TOWN02_AGENTS):
            cells = [num(pub.PAPER_TOWN02_KM[kind][c][i], 2, 2) if c in pub.PAPER_TOWN02_KM[kind] else EMPTY
                     for c in cond_keys]
            t.add([Cell.of(title), Cell.of(agent), Cell.of("published"), *cells])
    t.notes = [
        "km between infractions: km driven / infraction events, pooled over all tasks and weathers of a condition; "
        "'> X': no event in the X km driven. Collisions are counted only in the task with traffic "
        "(navigation with dynamic obstacles).",
        f"Rows marked published come from {pub.PAPER_TOWN02_SOURCE} (Town02 only: New town and New town & "
        "weather; MP, IL and RL from CARLA).",
    ]
    subset = subset_phrase([sum(len(groups.get((s, p, c), [])) for c in cond_keys) for s, p in agents], suite_size,
                           "agent")
    if subset:
        t.notes.append(f"The published figures are for the full CoRL2017 suite (25 routes x every weather of a "
                       f"condition); ours are for {subset} (a subset of it), so the km driven are not comparable in "
                       "absolute terms. The km between infractions (per-km rates) are, with the wider uncertainty of "
                       "fewer km ('> X' bounds are weaker).")
    t.notes.extend(labels.notes())
    return t


# --------------------------------------------------------------------------------------------------------------
# Training runs


@dataclass(frozen=True)
class RunMarks:
    """Best and worst run (by final greedy evaluation) of each training input."""

    best: dict[str, str]
    worst: dict[str, str]


def _eval_key(run: TrainingRun) -> tuple[float, float, float]:
    ev = run.evaluation or {}
    return (float(ev.get("success_rate", float("nan"))), -float(ev.get("either_share", float("nan"))),
            float(ev.get("collision_free_rate", float("nan"))))


def run_marks(runs: Sequence[TrainingRun]) -> RunMarks:
    """Best / worst per input by final evaluation success (ties: lower Either share, then higher collision-free
    rate, then name)."""
    best: dict[str, str] = {}
    worst: dict[str, str] = {}
    for train_input in sorted({r.group for r in runs}):
        rated = [r for r in runs if r.group == train_input and r.evaluation is not None
                 and all(np.isfinite(_eval_key(r)))]
        if not rated:
            continue
        best[train_input] = sorted(rated, key=lambda r: (*(-v for v in _eval_key(r)), r.name))[0].name
        worst[train_input] = sorted(rated, key=lambda r: (*_eval_key(r), r.name))[0].name
    return RunMarks(best, worst)


def _part_mean(values: np.ndarray, first: bool) -> float:
    n = max(1, values.size // 10)
    return float(values[:n].mean() if first else values[-n:].mean())


def training_table(runs: Sequence[TrainingRun], marks: RunMarks) -> Table:
    """One row per training run: learning-curve summary and the final greedy evaluation."""
    t = Table("training_runs", "Training runs: learning curves and final greedy evaluation",
              ["Run", "Input", "Mark", "Steps", "Reward first 10 %", "Reward last 10 %", "TD error first 10 %",
               "TD error last 10 %", "Eval success [%]", "Eval either [%]", "Eval collision-free [%]"],
              label_columns=3)
    last = None
    for r in sorted(runs, key=lambda r: (r.group, r.name)):
        if r.group != last:
            t.group()
            last = r.group
        mark = [m for m, d in (("best", marks.best), ("worst", marks.worst)) if d.get(r.group) == r.name]
        ev = r.evaluation or {}
        t.add([Cell.of(r.name), Cell.of(r.group), Cell.of(" / ".join(mark)), count(int(r.step.size)),
               num(_part_mean(r.reward, True), 2), num(_part_mean(r.reward, False), 2),
               num(_part_mean(r.td_error, True), 2), num(_part_mean(r.td_error, False), 2),
               pct(ev.get("success_rate")), pct(ev.get("either_share")), pct(ev.get("collision_free_rate"))])
    t.notes = ["Best / worst: by the final greedy evaluation's success rate on the lane-keeping routes "
               "(summary.json; ties: lower Either share, then higher collision-free rate, then name), per training "
               "input (gt: TG models, estimated: TE models) and method variant (named when it is not the paper's)."]
    if any(r.evaluation is None for r in runs):
        t.notes.append(f"{DASH}: the run has no final evaluation (summary.json) yet.")
    return t


# --------------------------------------------------------------------------------------------------------------
# NoCrash

NOCRASH_TASKS: tuple[tuple[str, str], ...] = (("empty", "Empty"), ("regular", "Regular"), ("dense", "Dense"))
"""NoCrash traffic levels (result key, row title)."""


def common_episodes(episodes: Sequence[dict[str, Any]]) -> list[dict[str, Any]] | None:
    """The episodes whose identifier every agent drove, when the agents drove different episode sets (a full run
    beside fixed subsets, `brl bench --episodes`); None when every agent drove the same episodes."""
    ids: dict[tuple[str, str], set[str]] = defaultdict(set)
    for ep in episodes:
        ids[(str(ep["setting"]), str(ep["policy"]))].add(str(ep["id"]))
    sets = list(ids.values())
    if len(sets) < 2 or all(s == sets[0] for s in sets[1:]):
        return None
    common = set.intersection(*sets)
    return [ep for ep in episodes if str(ep["id"]) in common]


COMMON_SUFFIX = ("_common", ", on the episodes every agent drove")
"""Key and title suffix of a table restricted to `common_episodes`."""


def nocrash_success_table(episodes: Sequence[dict[str, Any]], common: bool = False) -> Table:
    """% success per traffic level x condition per agent, pooled over weathers, with its Beta posterior; `common`:
    the episodes are `common_episodes` (the table's key and title say so)."""
    cond_keys = [c for c, _ in pub.CORL_CONDITIONS]
    key_end, title_end = COMMON_SUFFIX if common else ("", "")
    t = Table(f"nocrash_success{key_end}",
              f"NoCrash: % success per traffic level and condition (Beta posterior, 95 %){title_end}",
              ["Traffic", "Agent", *(title for _, title in pub.CORL_CONDITIONS)], label_columns=2)
    groups: dict[tuple[str, str, str, str], list[dict[str, Any]]] = defaultdict(list)
    for ep in episodes:
        groups[(str(ep["setting"]), str(ep["policy"]), str(ep["task"]), str(ep["condition"]))].append(ep)
    agents = corl_agents(episodes)
    sets = model_set_ends(agents)
    labels = AgentLabels()
    for task, task_title in NOCRASH_TASKS:
        t.group()
        for setting, policy in agents:
            cells = []
            for cond in cond_keys:
                eps = groups.get((setting, policy, task, cond), [])
                if not eps:
                    cells.append(EMPTY)
                    continue
                ok = sum(bool(ep["success"]) for ep in eps)
                s = posterior_summary(ok, len(eps) - ok)
                cells.append(Cell(f"{100.0 * ok / len(eps):.1f} [{100.0 * s['lo']:.1f}, {100.0 * s['hi']:.1f}] "
                                  f"(n={len(eps)})", f"{100.0 * ok / len(eps):.4f}"))
            t.add([Cell.of(task_title), labels.agent(policy, setting), *cells])
            if (setting, policy) in sets:
                members = sets[(setting, policy)]
                t.add([Cell.of(task_title), labels.model_set(members, setting),
                       *_model_set_cells(groups, setting, members, task, cond_keys, pooled_success)])
    t.notes = ["% success: episodes that reached the goal within 2 m before the timeout (the route at 5 km/h + 20 s) "
               "without a collision, pooled over the weathers of the condition; a collision above CoRL2017's "
               "intensity threshold ends the episode as a failure. In brackets: the 95 % equal-tailed interval of "
               "the Beta posterior with the Jeffreys prior; n = episodes. " + DASH + ": not run."]
    if sets:
        t.notes.append(MODEL_SET_NOTE)
    t.notes.extend(labels.notes())
    return t


def nocrash_outcome_table(episodes: Sequence[dict[str, Any]], common: bool = False) -> Table:
    """Per agent and traffic level: the shares of episodes that succeeded, crashed and timed out (`common`: as in
    `nocrash_success_table`)."""
    key_end, title_end = COMMON_SUFFIX if common else ("", "")
    t = Table(f"nocrash_outcomes{key_end}", f"NoCrash: how episodes ended, pooled over conditions{title_end}",
              ["Traffic", "Agent", "Episodes", "Success [%]", "Collision [%]", "Timeout [%]"], label_columns=2)
    agents = corl_agents(episodes)
    labels = AgentLabels()
    for task, task_title in NOCRASH_TASKS:
        t.group()
        for setting, policy in agents:
            eps = [ep for ep in episodes if ep["setting"] == setting and ep["policy"] == policy
                   and ep["task"] == task]
            if not eps:
                continue
            n = len(eps)
            ok = sum(bool(ep["success"]) for ep in eps)
            crashed = sum(bool(ep.get("crashed", False)) for ep in eps)
            t.add([Cell.of(task_title), labels.agent(policy, setting), count(n), pct(ok / n),
                   pct(crashed / n), pct((n - ok - crashed) / n)])
    t.notes = ["Collision: the episode ended at a collision; timeout: it neither reached the goal nor collided."]
    t.notes.extend(labels.notes())
    return t
