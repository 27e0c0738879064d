"""The report's figures as PNG bytes (matplotlib's Agg canvas, fixed sizes and dpi, no pyplot state).

- Beta posterior PDFs of the success and the collision-free rate per setting (best model; pooled over the set),
- the histogram of per-step other-lane (left, negative) and off-road (right, positive) footprint shares,
- reward and TD-error convergence over training steps (mean and spread over seeds, best and worst run marked).
"""

from __future__ import annotations

import io
import textwrap
from collections.abc import Sequence
from dataclasses import dataclass

import numpy as np
from matplotlib.backends.backend_agg import FigureCanvasAgg
from matplotlib.figure import Figure

from brlcli.bench.metrics import FOOTPRINT_THRESHOLD, beta_posterior
from brlcli.report.load import TrainingRun
from brlcli.report.tables import Posterior, RunMarks
from brlcli.settings import base_setting

DPI = 100
"""Dots per inch of every PNG."""
WIDTH_IN = 10.0
"""Width of every figure, inches."""
SMOOTHING_STEPS = 200
"""Window of the moving average of the learning curves, learning steps."""

SETTING_COLORS = {"TGDG": "tab:blue", "TGDE": "tab:orange", "TEDE": "tab:green", "TEDG": "tab:red"}
OTHER_COLORS = ("tab:purple", "tab:brown", "tab:pink", "tab:gray", "tab:olive", "tab:cyan", "goldenrod", "navy",
                "teal", "darkred")
INPUT_COLORS = {"gt": ("tab:blue", "navy", "tab:orange"), "estimated": ("tab:green", "darkgreen", "tab:red")}
"""Per training input: mean color, best-run color, worst-run color."""
EXTRA_INPUT_COLORS = (("tab:purple", "indigo", "tab:brown"), ("tab:cyan", "teal", "tab:pink"),
                      ("tab:olive", "darkolivegreen", "tab:gray"))
"""Mean, best-run and worst-run colors of further training groups (a second method variant on the same input)."""


def group_colors(groups: Sequence[str]) -> dict[str, tuple[str, str, str]]:
    """Colors per training group ('gt', 'estimated (action-averaging-restart)', ...): each input's own colors for
    its first group whatever the variant label, further groups of that input in turn from EXTRA_INPUT_COLORS."""
    out: dict[str, tuple[str, str, str]] = {}
    used: set[str] = set()
    extra = 0
    for group in sorted(groups, key=lambda g: (" " in g, g)):  # a paper group (no variant label) first
        base = group.partition(" ")[0]
        if base in INPUT_COLORS and base not in used:
            out[group] = INPUT_COLORS[base]
            used.add(base)
        else:
            out[group] = EXTRA_INPUT_COLORS[extra % len(EXTRA_INPUT_COLORS)]
            extra += 1
    return out


def _own_color(setting: str, order: Sequence[str]) -> str | None:
    """The paper setting's color of a label: its own, or its base setting's for a method variant ('TGDG (NAME)')
    when the base setting itself is not shown and no other variant of it comes before."""
    if setting in SETTING_COLORS:
        return SETTING_COLORS[setting]
    base = base_setting(setting)
    if base in SETTING_COLORS and base not in order:
        first = next((s for s in order if base_setting(s) == base), setting)
        return SETTING_COLORS[base] if first == setting else None
    return None


def color_of(setting: str, order: Sequence[str]) -> str:
    """A fixed color per paper setting (a method variant's label takes its setting's color when that setting is not
    shown); other settings in turn."""
    own = _own_color(setting, order)
    if own is not None:
        return own
    others = [s for s in order if _own_color(s, order) is None]
    return OTHER_COLORS[others.index(setting) % len(OTHER_COLORS)] if setting in others else "black"


def _png(fig: Figure) -> bytes:
    FigureCanvasAgg(fig)
    buf = io.BytesIO()
    fig.savefig(buf, format="png", dpi=DPI, metadata={"Software": None})
    return buf.getvalue()


def has_baselines(posts: Sequence[Posterior], rate: str) -> bool:
    """Whether the posteriors of `rate` hold a baseline's (one policy, not a model set)."""
    return any(p.rate == rate and p.scope == "policy" for p in posts)


def beta_panel_titles(posts: Sequence[Posterior], rate: str) -> tuple[str, str]:
    """Titles of the left (best model) and right (pooled) panels; '(and baselines)' only where there are some."""
    left = "Best model per setting" + (" (and baselines)" if has_baselines(posts, rate) else "")
    return left, "Pooled over each setting's model set"


def beta_label(p: Posterior) -> str:
    """A posterior's legend entry: setting, which model(s), successes of episodes and the posterior mean (the panel's
    title says best or pooled)."""
    mean = (p.successes + 0.5) / (p.successes + p.failures + 1.0)
    n = p.successes + p.failures
    if p.scope == "best":
        who = f" {p.label.removeprefix('best model: ')}"
    elif p.scope == "pooled":
        who = f", {p.models} model{'s' if p.models != 1 else ''}"
    else:
        who = "" if p.label == p.setting else f" ({p.label})"
    label = f"{p.setting}{who}: {p.successes}/{n}, mean {mean:.2f}"
    return "\n".join(textwrap.wrap(label, LEGEND_WRAP, subsequent_indent="    ", break_on_hyphens=False))


LEGEND_WRAP = 62
"""Characters per line of a Beta legend entry (at font size 8 a line this long fills most of a panel's width)."""
LEGEND_ROW_IN = 0.16
"""Height of one legend line at font size 8, inches (the Beta figure grows by it per line below the axes)."""


def beta_figure(posts: Sequence[Posterior], rate: str, order: Sequence[str]) -> bytes:
    """PDFs of one rate's posteriors: best model per setting (left), pooled over the model set (right); each panel's
    legend below it (the figure grows with the entries, so nothing is cut at its edge)."""
    panels = (("best", "policy"), ("pooled",))
    shown_of = [[p for p in posts if p.rate == rate and p.scope in scopes] for scopes in panels]
    lines = max(sum(beta_label(p).count("\n") + 1 for p in shown) for shown in shown_of)
    fig = Figure(figsize=(WIDTH_IN, 4.4 + LEGEND_ROW_IN * lines), dpi=DPI, layout="constrained")
    axes = fig.subplots(1, 2, sharey=False)
    x = np.linspace(0.0005, 0.9995, 2000)
    inner = (x > 0.01) & (x < 0.99)
    titles = beta_panel_titles(posts, rate)
    for ax, shown, title in zip(axes, shown_of, titles, strict=True):
        top = 0.0
        for p in shown:
            pdf = beta_posterior(p.successes, p.failures).pdf(x)
            ax.plot(x, pdf, color=color_of(p.setting, order), lw=2, ls="-" if p.scope != "policy" else "--",
                    label=beta_label(p))
            top = max(top, float(np.max(pdf[inner])))
        ax.set_xlim(0.0, 1.0)
        ax.set_ylim(0.0, top * 1.1 if top > 0 else 1.0)
        if any(p.successes == 0 or p.failures == 0 for p in shown):
            ax.text(0.02, 0.06, "with 0 failures (or 0 successes) the density\n"
                    "rises without bound at 1 (or 0): clipped",
                    ha="left", va="bottom", fontsize=8, color="dimgray", transform=ax.transAxes)
        ax.set_xlabel(f"{rate} rate (share of episodes)")
        ax.set_ylabel("posterior probability density")
        ax.set_title(title, fontsize=11)
        ax.grid(alpha=0.3)
        if shown:  # below the axes, inside the figure: constrained layout makes room for it
            ax.legend(fontsize=8, loc="upper center", bbox_to_anchor=(0.5, -0.14), ncols=1, frameon=False,
                      handlelength=2.2)
        else:
            ax.text(0.5, 0.5, "no results", ha="center", va="center", transform=ax.transAxes)
    fig.suptitle(f"Beta posterior of the {rate} rate (Jeffreys prior Beta(0.5, 0.5))", fontsize=13)
    return _png(fig)


@dataclass(frozen=True)
class LaneShares:
    """Per-step footprint shares of one setting's episodes (from the frames files)."""

    setting: str
    offroad: np.ndarray
    otherlane: np.ndarray
    episodes: int
    missing_frames: int


def lane_histogram_figure(groups: Sequence[LaneShares], order: Sequence[str]) -> bytes:
    """Histogram of the per-step other-lane share (left, as negative values) and off-road share (right)."""
    n = max(1, len(groups))
    fig = Figure(figsize=(WIDTH_IN, 1.0 + 2.3 * n), dpi=DPI, layout="constrained")
    axes = np.atleast_1d(fig.subplots(n, 1, sharex=True, squeeze=False)[:, 0])
    bins = np.linspace(-1.0, 1.0, 41)
    for ax, g in zip(axes, groups, strict=False):
        steps = max(1, g.offroad.size)
        other = g.otherlane[g.otherlane > 0]
        off = g.offroad[g.offroad > 0]
        weight = 100.0 / steps
        ax.hist(-other, bins=bins[bins <= 0], weights=np.full(other.size, weight), color="tab:orange",
                edgecolor="black", lw=0.3, label="in the other lane (share < 0)")
        ax.hist(off, bins=bins[bins >= 0], weights=np.full(off.size, weight), color="tab:red", edgecolor="black",
                lw=0.3, label="off road (share > 0)")
        for edge in (-FOOTPRINT_THRESHOLD, FOOTPRINT_THRESHOLD):
            ax.axvline(edge, color="black", ls="--", lw=1,
                       label=f"{100 * FOOTPRINT_THRESHOLD:.0f} % threshold" if edge > 0 else None)
        ax.axvline(0.0, color="gray", lw=0.8)
        in_lane = float(np.mean((g.offroad <= 0) & (g.otherlane <= 0))) * 100.0 if g.offroad.size else 0.0
        if other.size or off.size:  # a log axis needs positive data (a policy may never leave its lane)
            ax.set_yscale("log")
        ax.set_ylim(0.01, 100.0)
        ax.set_ylabel("share of steps [%]")
        ax.set_title(f"{g.setting}: {g.episodes} episodes, {g.offroad.size} steps; "
                     f"{in_lane:.1f} % of steps fully in the own lane (not shown)", fontsize=10,
                     color=color_of(g.setting, order))
        ax.grid(alpha=0.3, which="major")
        if ax is axes[0]:
            ax.legend(fontsize=8, loc="upper center", ncols=3)
    if not groups:
        axes[0].text(0.5, 0.5, "no frames files", ha="center", va="center", transform=axes[0].transAxes)
    axes[-1].set_xlim(-1.0, 1.0)
    axes[-1].set_xlabel("share of the car's footprint per step: in the other lane (left, negative) | off road "
                        "(right, positive)")
    fig.suptitle("Per-step lane position: other lane (left) and off road (right)", fontsize=13)
    return _png(fig)


def _moving_average(values: np.ndarray, window: int) -> np.ndarray:
    window = max(1, min(window, values.size))
    c = np.cumsum(np.insert(values, 0, 0.0))
    return (c[window:] - c[:-window]) / window


def convergence_figure(runs: Sequence[TrainingRun], marks: RunMarks) -> bytes:
    """Reward (top) and TD error (bottom) over training steps: per training input the mean over seeds with a
    ± 1 std band, the best and the worst run (final greedy evaluation) as thin lines."""
    fig = Figure(figsize=(WIDTH_IN, 7.5), dpi=DPI, layout="constrained")
    ax_r, ax_td = fig.subplots(2, 1, sharex=True)
    colors = group_colors(sorted({r.group for r in runs}))
    for train_input in sorted({r.group for r in runs}):
        group = [r for r in runs if r.group == train_input]
        color, best_color, worst_color = colors[train_input]
        base, _, variant = train_input.partition(" ")
        tag = {"gt": "TG", "estimated": "TE"}.get(base, base) + (f" {variant}" if variant else "")
        length = min(r.step.size for r in group)
        window = min(SMOOTHING_STEPS, length)
        for ax, attr in ((ax_r, "reward"), (ax_td, "td_error")):
            curves = np.stack([_moving_average(getattr(r, attr)[:length], window) for r in group])
            steps = group[0].step[window - 1:length]
            mean, std = curves.mean(axis=0), curves.std(axis=0)
            ax.plot(steps, mean, color=color, lw=2, label=f"{tag}: mean of {len(group)} runs")
            ax.fill_between(steps, mean - std, mean + std, color=color, alpha=0.2, lw=0,
                            label=f"{tag}: ± 1 std over runs")
            for mark, style, line_color in (("best", "--", best_color), ("worst", ":", worst_color)):
                name = getattr(marks, mark).get(train_input)
                run = next((r for r in group if r.name == name), None)
                if run is None:
                    continue
                success = (run.evaluation or {}).get("success_rate", float("nan"))
                ax.plot(steps, _moving_average(getattr(run, attr)[:length], window), color=line_color, lw=1.3, ls=style,
                        label=f"{tag} {mark}: {run.name} (eval success {100 * success:.0f} %)")
    ax_r.set_ylabel(f"reward (moving average, {SMOOTHING_STEPS} steps)")
    ax_td.set_ylabel(f"TD error (moving average, {SMOOTHING_STEPS} steps)")
    ax_td.set_xlabel("training step (learning steps)")
    ax_r.set_title("Reward", fontsize=11)
    ax_td.set_title("TD error", fontsize=11)
    for ax in (ax_r, ax_td):
        ax.grid(alpha=0.3)
    handles, labels = ax_r.get_legend_handles_labels()
    if handles:
        fig.legend(handles, labels, loc="outside lower center", ncols=2, fontsize=8)
    fig.suptitle("Convergence of the training runs", fontsize=13)
    return _png(fig)
