"""`brl report`: merge bench results (and training runs) into tables, posteriors and plots beside the published
figures; write Markdown, LaTeX, CSV and HTML plus report.json (inputs and provenance).

Everything is computed in memory first: bad input raises a one-line BrlInputError before anything is written.
Tables (md, tex, csv) depend only on the merged episodes and runs, so equal inputs give byte-identical files.
"""

from __future__ import annotations

from collections.abc import Callable, Sequence
from pathlib import Path
from typing import Any

import numpy as np

from brlcli import __version__
from brlcli.errors import BrlInputError
from brlcli.provenance import atomic_write_bytes, atomic_write_json, git_commit, provenance
from brlcli.report import tables as tb
from brlcli.report.load import Results, TrainingRun, load_frames, load_results, load_runs
from brlcli.report.published import CORL_CONDITIONS, PAPER_TOWN02_NAME

FORMATS: tuple[str, ...] = ("md", "tex", "csv", "html")
"""Output formats: report.md (+ PNGs), tables/*.tex, tables/*.csv, report.html (self-contained)."""
REPORTED_SUITES: tuple[str, ...] = ("paper", "validation", "validation_starts", "corl2017", "nocrash")
FRAME_KEYS = ("intersection_offroad", "intersection_otherlane")


def parse_formats(formats: str | Sequence[str] | None) -> tuple[str, ...]:
    """Formats from 'md,tex' or a list; refuses unknown names and an empty choice."""
    if formats is None:
        return FORMATS
    items = formats.split(",") if isinstance(formats, str) else [f for part in formats for f in str(part).split(",")]
    chosen = {f.strip().lower() for f in items if f.strip()}
    unknown = sorted(chosen - set(FORMATS))
    if unknown:
        raise BrlInputError(f"unknown report format '{unknown[0]}'; choose from {', '.join(FORMATS)}")
    if not chosen:
        raise BrlInputError(f"give at least one report format ({', '.join(FORMATS)})")
    return tuple(f for f in FORMATS if f in chosen)


def suite_size(suite: str) -> int | None:
    """Episodes of the whole suite as this brl defines it (to tell a subset, `brl bench --episodes`, from the
    suite); None for a suite it cannot build."""
    from brlcli.bench.suites import build_suite

    try:
        return len(build_suite(suite))
    except Exception:  # an unknown or unbuildable suite: its size is simply not known
        return None


def _lane_shares(data: tb.PaperData, notes: list[str]) -> list[Any]:
    from brlcli.report.plots import LaneShares

    groups = []
    missing_total = 0
    for setting, models in data.models.items():
        off_parts, other_parts, missing, n = [], [], 0, 0
        for m in models:
            for ep in data.episodes[(setting, m.policy)]:
                n += 1
                frames = load_frames(ep, FRAME_KEYS)
                if frames is None or frames[FRAME_KEYS[0]].shape != frames[FRAME_KEYS[1]].shape:
                    missing += 1
                    continue
                off_parts.append(frames["intersection_offroad"][1:])
                other_parts.append(frames["intersection_otherlane"][1:])
        missing_total += missing
        if off_parts:
            groups.append(LaneShares(setting, np.concatenate(off_parts), np.concatenate(other_parts), n - missing,
                                     missing))
    if missing_total:
        notes.append(f"The lane-position histogram leaves out {missing_total} episodes whose frames file is missing "
                     "or unreadable.")
    return groups


def _paper_section(episodes: list[dict[str, Any]], images: dict[str, Callable[[], bytes]], notes: list[str],
                   summary: list[dict[str, Any]], plots: bool, suite: str = "paper") -> tb.Section:
    if suite != "paper":  # the paper's tables on another route set: own table keys and figure files
        own_images: dict[str, Callable[[], bytes]] = {}
        own_summary: list[dict[str, Any]] = []
        section = _paper_section(episodes, own_images, notes, own_summary, plots, "paper")
        section.title = ("The paper's test suite on the validation routes (model selection)" if suite == "validation"
                         else "The paper's test suite on the validation routes from six start poses (model selection)")
        section.text += (" Validation routes (routes.validation of the towns), not the paper's test routes: published "
                         "rows are the test routes' figures, for orientation only.")
        for table in section.tables:
            table.key, table.title = f"{suite}_{table.key}", f"Validation routes: {table.title}"
        section.figures = [tb.Figure(f"{suite}_{f.file}", f"Validation routes: {f.title}", f.caption)
                           for f in section.figures]
        images.update({f"{suite}_{name}": make for name, make in own_images.items()})
        summary.extend({**row, "suite": suite} for row in own_summary)
        return section
    data = tb.paper_data(episodes, suite_size(str(episodes[0]["suite"])) if episodes else None)
    posts = tb.posteriors(data)
    conditions = sorted({(str(ep["condition"]), str(ep["town"])) for ep in episodes})
    text = (f"{len(episodes)} episodes of {sum(len(m) for m in data.models.values())} policies in the settings "
            f"{', '.join(data.settings)}; pooled over the conditions "
            f"{', '.join(f'{c} ({t})' for c, t in conditions)}.")
    subset = tb.paper_subset_phrase(data)
    if subset:
        text += (f" A subset: {subset}; the published distances are for the full suite (metres driven are not "
                 "comparable, shares are).")
    if data.missing:
        text += f" Missing settings (no results): {', '.join(data.missing)}."
    section = tb.Section("The paper's test suite (lane keeping)", text,
                         [tb.paper_table(data), tb.posterior_table(data, posts), tb.paper_models_table(data)])
    order = data.settings
    if plots:
        from brlcli.report import plots as pl

        for rate, file in (("success", "beta_success.png"), ("collision-free", "beta_collision_free.png")):
            images[file] = lambda rate=rate: pl.beta_figure(posts, rate, order)
            baselines = "; baselines dashed" if pl.has_baselines(posts, rate) else ""
            section.figures.append(tb.Figure(file, f"Beta posterior of the {rate} rate",
                                             f"Posterior PDFs (Jeffreys prior) of the {rate} rate per setting: the "
                                             "best model by Score (left) and pooled over the setting's model set "
                                             f"(right){baselines}."))
        shares = _lane_shares(data, notes)
        images["lane_histogram.png"] = lambda: pl.lane_histogram_figure(shares, order)
        section.figures.append(tb.Figure("lane_histogram.png", "Per-step lane position",
                                         "Histogram of the per-step footprint share in the other lane (left, as "
                                         "negative values) and off road (right), per setting, from the frames files; "
                                         "log scale, in % of all steps of the setting."))
    for setting, models in data.models.items():
        if data.is_model_set(setting):
            best = tb.best_model(models)
            rows = [(f"average of {len(models)} models", models), (f"best: {best.policy}", [best])]
        else:
            rows = [(m.policy, [m]) for m in models]
        for agent, ms in rows:
            summary.append({
                "suite": "paper", "setting": setting, "agent": agent, "episodes": sum(m.episodes for m in ms),
                "success": float(np.mean([m.success for m in ms])),
                "collision_free": float(np.mean([m.no_collision for m in ms])),
                "either": float(np.mean([m.either for m in ms])), "score": float(np.mean([m.score for m in ms])),
                "km": float(np.mean([m.dist_m for m in ms])) / 1000.0})
    for setting in data.missing:
        summary.append({"suite": "paper", "setting": setting, "agent": "missing", "episodes": 0})
    return section


def _corl_section(episodes: list[dict[str, Any]], summary: list[dict[str, Any]]) -> tb.Section:
    agents = tb.corl_agents(episodes)
    present = {str(ep["condition"]) for ep in episodes}
    known = [key for key, _ in CORL_CONDITIONS]
    conds = [title for key, title in CORL_CONDITIONS if key in present] + sorted(present - set(known))
    text = (f"{len(episodes)} episodes of {len(agents)} agent{'s' if len(agents) != 1 else ''} in the conditions "
            f"{', '.join(conds)}. Tables follow "
            f"CARLA's Table 1 (% success) and the paper's {PAPER_TOWN02_NAME} (Town02, km between infractions).")
    size = suite_size("corl2017")
    subset = tb.subset_phrase([sum(1 for ep in episodes if (ep["setting"], ep["policy"]) == a) for a in agents], size,
                              "agent")
    if subset:
        text += f" A subset: {subset}."
    section = tb.Section("CoRL2017 benchmark", text, [tb.corl_success_table(episodes),
                                                      tb.corl_km_table(episodes, size)])
    _agent_summaries("corl2017", episodes, agents, summary)
    return section


def _agent_summaries(suite: str, episodes: list[dict[str, Any]], agents: list[tuple[str, str]],
                     summary: list[dict[str, Any]]) -> None:
    """One terminal-summary row per (setting, policy) of a route suite (CoRL2017, NoCrash)."""
    for setting, policy in agents:
        eps = [ep for ep in episodes if ep["setting"] == setting and ep["policy"] == policy]
        steps = sum(int(ep["steps"]) for ep in eps)
        either = (sum(int(ep.get("either_steps", 0)) for ep in eps) / steps) if steps else float("nan")
        summary.append({"suite": suite, "setting": setting, "agent": policy, "episodes": len(eps),
                        "success": float(np.mean([bool(ep["success"]) for ep in eps])),
                        "collision_free": float(np.mean([not bool(ep.get("collided", False)) for ep in eps])),
                        "either": either, "km": float(sum(float(ep["km"]) for ep in eps))})


def _nocrash_section(episodes: list[dict[str, Any]], summary: list[dict[str, Any]]) -> tb.Section:
    agents = tb.corl_agents(episodes)
    text = (f"{len(episodes)} episodes of {len(agents)} agent{'s' if len(agents) != 1 else ''} (Codevilla et al., "
            "ICCV 2019: CoRL2017's navigation routes with three traffic levels; a collision ends the episode). "
            "Definitions in docs/benchmarks.md.")
    tables = [tb.nocrash_success_table(episodes), tb.nocrash_outcome_table(episodes)]
    common = tb.common_episodes(episodes)
    if common:
        n_common = len({ep["id"] for ep in common})
        text += (f" The agents drove different episode sets (a full suite beside subsets): the last two tables "
                 f"compare them on the {n_common} episodes every agent drove, episode for episode.")
        tables += [tb.nocrash_success_table(common, common=True), tb.nocrash_outcome_table(common, common=True)]
    elif common is not None:
        text += " The agents drove different episode sets with none in common: compare their rows with care."
    section = tb.Section("NoCrash benchmark", text, tables)
    _agent_summaries("nocrash", episodes, agents, summary)
    return section


def _training_section(runs: list[TrainingRun], images: dict[str, Callable[[], bytes]], plots: bool) -> tb.Section:
    marks = tb.run_marks(runs)
    inputs = sorted({r.group for r in runs})
    text = (f"{len(runs)} training runs ({', '.join(f'{sum(r.group == i for r in runs)} on {i} input' for i in inputs)}"
            "): reward and TD error per learning step from log.csv, final greedy evaluation from summary.json.")
    section = tb.Section("Training convergence", text, [tb.training_table(runs, marks)])
    if plots:
        from brlcli.report import plots as pl

        images["convergence.png"] = lambda: pl.convergence_figure(runs, marks)
        section.figures.append(tb.Figure("convergence.png", "Reward and TD-error convergence",
                                         f"Moving average over {pl.SMOOTHING_STEPS} learning steps; per training input "
                                         "the mean over runs with a ± 1 std band; the best and the worst run by final "
                                         "greedy evaluation success dashed and dotted."))
    return section


def assemble(results: Results, runs: list[TrainingRun], plots: bool, curves: list | None = None) -> dict[str, Any]:
    """Sections (tables, figure makers), notes and the terminal summary, all in memory."""
    notes = list(results.notes)
    images: dict[str, Callable[[], bytes]] = {}
    summary: list[dict[str, Any]] = []
    sections = []
    suites = results.suites()
    if "paper" in suites:
        sections.append(_paper_section(results.of_suite("paper"), images, notes, summary, plots))
    elif "validation" not in suites and "validation_starts" not in suites:
        notes.append("No results of the paper's test suite in the inputs: its table is not reported.")
    for name in ("validation", "validation_starts"):
        if name in suites:
            sections.append(_paper_section(results.of_suite(name), images, notes, summary, plots, name))
    if "corl2017" in suites:
        sections.append(_corl_section(results.of_suite("corl2017"), summary))
    else:
        notes.append("No CoRL2017 results in the inputs: its tables are not reported.")
    if "nocrash" in suites:
        sections.append(_nocrash_section(results.of_suite("nocrash"), summary))
    for suite in suites:
        if suite not in REPORTED_SUITES:
            notes.append(f"Results of suite '{suite}' are not reported (no tables for it yet).")
    if runs:
        sections.append(_training_section(runs, images, plots))
    if curves:
        from brlcli.report import curves as cv

        section = cv.curves_section(curves)
        if plots:
            images["learning_curves.png"] = lambda: cv.curve_figure(curves)
            suite_text = cv.SUITE_TEXT.get(curves[0].suite, ("", "its suite"))[1].split(" (")[0]
            section.figures.append(tb.Figure("learning_curves.png", "Sample efficiency",
                                             f"Mean greedy success on {suite_text} against environment steps (log "
                                             "scale), ± 1 std over runs; one line per learner."))
        sections.append(section)
    return {"sections": sections, "notes": notes, "images": images, "summary": summary}


def build_report(results_dirs: Sequence[str | Path], run_dirs: Sequence[str | Path] = (),
                 out: str | Path = "runs/report", formats: str | Sequence[str] | None = FORMATS,
                 curve_dirs: Sequence[str | Path] = ()) -> dict[str, Any]:
    """Merge `brl bench` results directories (and `brl train` runs) into a report in `out`.

    Returns {'out', 'files' (paths relative to out), 'episodes', 'summary' (rows for a terminal table),
    'notes'}. Raises BrlInputError (one line) on bad input, before anything is written.
    """
    fmts = parse_formats(formats)
    out = Path(out)
    if out.exists() and not out.is_dir():
        raise BrlInputError(f"--out {out} is a file, not a directory")
    results = load_results(results_dirs)
    runs = load_runs(run_dirs) if run_dirs else []
    from brlcli.report.curves import load_curves

    curves = load_curves(list(curve_dirs)) if curve_dirs else []
    plots = "md" in fmts or "html" in fmts
    parts = assemble(results, runs, plots, curves)
    sections, notes = parts["sections"], parts["notes"]
    images = {name: make() for name, make in sorted(parts["images"].items())}

    written: list[str] = []

    def write(rel: str, data: bytes) -> None:
        atomic_write_bytes(out / rel, data)
        written.append(rel)

    from brlcli.report import render

    table_files: dict[str, dict[str, str]] = {}
    for section in sections:
        for table in section.tables:
            files = table_files.setdefault(table.key, {})
            if "csv" in fmts:
                files["csv"] = f"tables/{table.key}.csv"
                write(files["csv"], render.table_csv(table).encode())
            if "tex" in fmts:
                files["tex"] = f"tables/{table.key}.tex"
                write(files["tex"], render.table_tex(table).encode())
    title = "brl report: Bayesian RL for vehicular control (Gharaee et al., ICPR 2020) reproduced"
    header = [f"Made by brl {__version__} (commit {git_commit()}) from {len(results.episodes)} episodes"
              + (f" and {len(runs)} training runs" if runs else "") + "; inputs and provenance in report.json.",
              "",
              "Rows with Source 'published' are the figures printed in the papers, beside ours (Source 'ours'). Our "
              "simulator is not CARLA: absolute numbers differ."]
    if plots:
        for name, data in images.items():
            write(f"figures/{name}", data)
        for section in sections:
            section.figures = [tb.Figure(f"figures/{f.file}", f.title, f.caption) for f in section.figures]
    if "md" in fmts:
        write("report.md", render.report_md(title, header, sections, notes, table_files, with_figures=True).encode())
    if "html" in fmts:
        embedded = {f"figures/{name}": data for name, data in images.items()}
        write("report.html", render.report_html(title, header, sections, notes, embedded).encode())
    record = provenance({"results": [str(p) for p in results_dirs], "runs": [str(p) for p in run_dirs],
                         "curves": [str(p) for p in curve_dirs], "out": str(out), "formats": list(fmts)},
                        kind="report")
    record["inputs"] = [{"path": str(d.path), "suite": d.suite, "suite_version": d.suite_version,
                         "town_versions": d.town_versions, "episodes": d.episodes,
                         "torn_last_line": d.torn_last_line, "bench_brl_version": d.bench.get("brl_version"),
                         "bench_git_commit": d.bench.get("git_commit"), "bench_config": d.bench.get("config")}
                        for d in results.dirs]
    record["training_runs"] = [{"name": r.name, "path": str(r.path), "input": r.input, "steps": int(r.step.size)}
                               for r in runs]
    record["episodes"] = len(results.episodes)
    record["duplicates_merged"] = results.duplicates
    record["notes"] = notes
    record["files"] = sorted(written)
    atomic_write_json(out / "report.json", record)
    return {"out": str(out), "files": sorted([*written, "report.json"]), "episodes": len(results.episodes),
            "summary": parts["summary"], "notes": notes}
