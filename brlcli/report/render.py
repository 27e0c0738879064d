"""Render report tables and sections as Markdown, LaTeX (booktabs), CSV and a self-contained HTML page."""

from __future__ import annotations

import base64
import csv
import html
import io
from collections.abc import Mapping, Sequence

from brlcli.report.tables import Section, Table

TEX_ESCAPES = {
    "\\": r"\textbackslash{}", "&": r"\&", "%": r"\%", "$": r"\$", "#": r"\#", "_": r"\_", "{": r"\{", "}": r"\}",
    "~": r"\textasciitilde{}", "^": r"\textasciicircum{}", "±": r"$\pm$", ">": r"$>$", "<": r"$<$", "–": "--",
    "≥": r"$\geq$", "≤": r"$\leq$",
}


def tex_escape(text: str) -> str:
    """Text safe inside a LaTeX table cell or caption."""
    return "".join(TEX_ESCAPES.get(ch, ch) for ch in text)


def table_csv(table: Table) -> str:
    """The table as CSV: a header, then one line per row (CSV values: plain numbers, '' where there is none)."""
    buf = io.StringIO()
    writer = csv.writer(buf, lineterminator="\n")
    writer.writerow(table.columns)
    for row in table.rows:
        writer.writerow([c.value for c in row])
    return buf.getvalue()


def table_tex(table: Table) -> str:
    """The table as a LaTeX table environment with booktabs rules (needs the booktabs and graphicx packages)."""
    align = "l" * table.label_columns + "r" * (len(table.columns) - table.label_columns)
    lines = [f"% brl report table {table.key}: {table.title}", "% needs \\usepackage{booktabs,graphicx}",
             "\\begin{table}[ht]", "\\centering", "\\small",
             f"\\caption{{{tex_escape(table.title)}}}", f"\\label{{tab:brl-{table.key.replace('_', '-')}}}",
             "\\resizebox{\\linewidth}{!}{%", f"\\begin{{tabular}}{{{align}}}", "\\toprule",
             " & ".join(tex_escape(c) for c in table.columns) + " \\\\", "\\midrule"]
    for i, row in enumerate(table.rows):
        if i in table.breaks and i > 0:
            lines.append("\\midrule")
        lines.append(" & ".join(tex_escape(c.text) for c in row) + " \\\\")
    lines += ["\\bottomrule", "\\end{tabular}}", "\\end{table}", ""]
    return "\n".join(lines)


def _md_cell(text: str) -> str:
    return text.replace("|", "\\|") if text else " "


def table_md(table: Table, csv_file: str | None = None, tex_file: str | None = None) -> str:
    """The table as a Markdown pipe table with its notes as a list."""
    lines = [f"### {table.title}", ""]
    lines.append("| " + " | ".join(_md_cell(c) for c in table.columns) + " |")
    lines.append("|" + "|".join(":---" if i < table.label_columns else "---:" for i in range(len(table.columns)))
                 + "|")
    for row in table.rows:
        lines.append("| " + " | ".join(_md_cell(c.text) for c in row) + " |")
    lines.append("")
    for note in table.notes:
        lines.append(f"- {note}")
    links = [f"[{kind}]({f})" for kind, f in (("CSV", csv_file), ("LaTeX", tex_file)) if f]
    if links:
        lines.append(f"- Files: {', '.join(links)}.")
    lines.append("")
    return "\n".join(lines)


def report_md(title: str, header: Sequence[str], sections: Sequence[Section], notes: Sequence[str],
              files: Mapping[str, Mapping[str, str]], with_figures: bool) -> str:
    """The whole report as Markdown; `files` maps table key -> {'csv': path, 'tex': path} when written."""
    out = [f"# {title}", ""]
    out += [*header, ""]
    for s in sections:
        out += [f"## {s.title}", "", s.text, ""]
        for t in s.tables:
            f = files.get(t.key, {})
            out.append(table_md(t, f.get("csv"), f.get("tex")))
        if with_figures:
            for fig in s.figures:
                out += [f"### {fig.title}", "", f"![{fig.title}]({fig.file})", "", fig.caption, ""]
    if notes:
        out += ["## Notes", ""] + [f"- {n}" for n in notes] + [""]
    return "\n".join(out)


HTML_STYLE = """
body { font-family: sans-serif; max-width: 1200px; margin: 2em auto; padding: 0 1em; color: #222; }
table { border-collapse: collapse; margin: 0.5em 0 0.5em 0; font-size: 0.85em; }
th, td { padding: 0.2em 0.6em; border-bottom: 1px solid #ddd; }
th { border-bottom: 2px solid #444; text-align: center; }
td.num { text-align: right; font-variant-numeric: tabular-nums; }
tr.break td { border-top: 1.5px solid #444; }
tr.published td { color: #555; font-style: italic; }
ul.notes { font-size: 0.85em; color: #444; }
img { max-width: 100%; border: 1px solid #ccc; }
""".strip()


NUM_CLASS = ' class="num"'


def table_html(table: Table) -> str:
    """The table as an HTML table (published rows in italics) with its notes."""
    parts = [f"<h3>{html.escape(table.title)}</h3>", "<table>", "<thead><tr>"]
    parts += [f"<th>{html.escape(c)}</th>" for c in table.columns]
    parts.append("</tr></thead><tbody>")
    source = table.columns.index("Source") if "Source" in table.columns else None
    for i, row in enumerate(table.rows):
        classes = []
        if i in table.breaks and i > 0:
            classes.append("break")
        if source is not None and row[source].text == "published":
            classes.append("published")
        cls = f' class="{" ".join(classes)}"' if classes else ""
        cells = "".join(f"<td{NUM_CLASS if j >= table.label_columns else ''}>{html.escape(c.text)}</td>"
                        for j, c in enumerate(row))
        parts.append(f"<tr{cls}>{cells}</tr>")
    parts.append("</tbody></table>")
    if table.notes:
        parts.append('<ul class="notes">' + "".join(f"<li>{html.escape(n)}</li>" for n in table.notes) + "</ul>")
    return "\n".join(parts)


def report_html(title: str, header: Sequence[str], sections: Sequence[Section], notes: Sequence[str],
                images: Mapping[str, bytes]) -> str:
    """A self-contained HTML page: the tables and the PNGs embedded as data URIs."""
    parts = ["<!DOCTYPE html>", '<html lang="en">', "<head>", '<meta charset="utf-8">',
             f"<title>{html.escape(title)}</title>", f"<style>\n{HTML_STYLE}\n</style>", "</head>", "<body>",
             f"<h1>{html.escape(title)}</h1>"]
    parts += [f"<p>{html.escape(line)}</p>" for line in header if line.strip()]
    for s in sections:
        parts += [f"<h2>{html.escape(s.title)}</h2>", f"<p>{html.escape(s.text)}</p>"]
        parts += [table_html(t) for t in s.tables]
        for fig in s.figures:
            if fig.file not in images:
                continue
            data = base64.b64encode(images[fig.file]).decode("ascii")
            parts += [f"<h3>{html.escape(fig.title)}</h3>",
                      f'<img src="data:image/png;base64,{data}" alt="{html.escape(fig.title)}">',
                      f"<p>{html.escape(fig.caption)}</p>"]
    if notes:
        parts += ["<h2>Notes</h2>", '<ul class="notes">' + "".join(f"<li>{html.escape(n)}</li>" for n in notes)
                  + "</ul>"]
    parts += ["</body>", "</html>", ""]
    return "\n".join(parts)
