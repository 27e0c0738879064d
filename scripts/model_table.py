"""Per-model figures of lane-keeping bench results, where each model fails, and how well one suite predicts another.

    python scripts/model_table.py RESULTS_DIR [RESULTS_DIR ...] [--against OTHER_DIR ...]

For every model (policy) of the results directories (`brl bench` outputs): success, Either, no-collision share and
Score (the paper's), and the success per town and route kind (straight, right curve, left curve); then the mean ±
std (ddof 1), the worst and the best model. With `--against`, the Spearman rank correlation between the models'
Scores in the first set of directories and in the second (models matched by name), e.g. validation routes against
the paper suite. With `--against-runs`, the same against each run's own end-of-run evaluation Score
(`summary.json`'s `eval`, e.g. the validation_starts suite), models matched as `RUNS_DIR_NAME/seed_N`.
"""

from __future__ import annotations

import argparse
import json
import statistics
from collections import defaultdict
from pathlib import Path

from scipy.stats import spearmanr

from brlcli.bench.metrics import model_stats

KINDS = ("straight", "right_curve", "left_curve")


def read(dirs: list[Path]) -> dict[str, list[dict]]:
    """Policy name -> its episodes, over every results directory."""
    out: dict[str, list[dict]] = defaultdict(list)
    for d in dirs:
        for line in (d / "results.jsonl").read_text().splitlines():
            if line.strip():
                row = json.loads(line)
                out[row["policy"]].append(row)
    return dict(out)


def table(models: dict[str, list[dict]]) -> dict[str, dict]:
    """Policy -> figures."""
    rows = {}
    for name, eps in sorted(models.items()):
        s = model_stats(eps[0]["setting"], name, eps)
        row = {"success": s.success, "either": s.either, "no_collision": s.no_collision, "score": s.score,
               "episodes": s.episodes}
        for town in sorted({e["town"] for e in eps}):
            for kind in KINDS:
                sel = [e for e in eps if e["town"] == town and e["task"] == kind]
                if sel:
                    row[f"{town}/{kind}"] = (sum(e["success"] for e in sel), len(sel))
        rows[name] = row
    return rows


def main() -> None:
    """Print the table (and the rank correlation)."""
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("dirs", type=Path, nargs="+")
    ap.add_argument("--against", type=Path, nargs="*", default=None)
    ap.add_argument("--against-runs", type=Path, nargs="*", default=None)
    args = ap.parse_args()
    rows = table(read(args.dirs))
    cells = sorted({k for r in rows.values() for k in r if "/" in k})
    print("model".ljust(28), "success  Either  Score  ", "  ".join(c.replace("_curve", "") for c in cells))
    for name, r in rows.items():
        parts = "  ".join(f"{r[c][0]:>2}/{r[c][1]:<2}".rjust(len(c.replace('_curve', ''))) if c in r else "-"
                          for c in cells)
        print(name.ljust(28), f"{r['success']:6.1%} {r['either']:6.1%} {r['score']:6.3f}  ", parts)
    for key in ("success", "either", "score"):
        vals = [r[key] for r in rows.values()]
        sd = statistics.stdev(vals) if len(vals) > 1 else 0.0
        worst, best = (max(vals), min(vals)) if key == "either" else (min(vals), max(vals))
        print(f"{key}: mean {statistics.mean(vals):.4f} ± {sd:.4f}, worst {worst:.4f}, best {best:.4f} "
              f"over {len(vals)} models")
    curves = [(sum(r[c][0] for c in cells if "curve" in c), sum(r[c][1] for c in cells if "curve" in c))
              for r in rows.values()]
    print(f"curves: {sum(a for a, _ in curves)}/{sum(b for _, b in curves)} "
          f"({sum(a for a, _ in curves) / max(sum(b for _, b in curves), 1):.1%})")
    other = table(read(args.against)) if args.against else {}
    for runs in args.against_runs or []:
        for summary in sorted(runs.glob("seed_*/summary.json")):
            ev = json.loads(summary.read_text())["summary"].get("eval")
            if ev:
                other[f"{runs.name}/{summary.parent.name}"] = {"score": ev["score"]}
    if other:
        common = [n for n in rows if n in other]
        rho = spearmanr([rows[n]["score"] for n in common], [other[n]["score"] for n in common])
        print(f"Spearman rank correlation of Score over {len(common)} models: {rho.statistic:.3f} "
              f"(p = {rho.pvalue:.3g})")


if __name__ == "__main__":
    main()
