"""`brl report`: the paper's tables, Beta posteriors, CoRL2017 tables and plots from `brl bench` results.

Library entry point: `build_report(results_dirs, run_dirs, out, formats) -> dict` (see `brlcli.report.build`).
Modules: load (read and merge results and training runs), tables (the tables as formatted cells), published (the
papers' figures), plots (PNG figures), render (Markdown, LaTeX, CSV, HTML).
"""

from brlcli.report.build import FORMATS, build_report, parse_formats

__all__ = ["FORMATS", "build_report", "parse_formats"]
