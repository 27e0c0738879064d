"""Per-task CoRL2017 (or NoCrash) success of a model set: mean, std, best and worst model, pooled success.

    python scripts/corl_model_set.py runs/issue20/corl10_nav9 [more results dirs ...]

Reads the `results.jsonl` of `brl bench` results directories (one row per episode) and prints, per policy group
(the part of the policy name before '/', e.g. nav9) and task, the success of each model (pooled over conditions and
weathers), their mean ± sample std (ddof 1), best and worst, and the success per condition averaged over the
models. Markdown.
"""

from __future__ import annotations

import argparse
import json
import sys
from collections import defaultdict
from pathlib import Path

import numpy as np


def main(argv: list[str] | None = None) -> int:
    """Print the summary table of the given results directories."""
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("results", nargs="+", type=Path)
    args = ap.parse_args(argv)
    rows = []
    for d in args.results:
        path = d / "results.jsonl"
        if not path.is_file():
            print(f"error: {path} does not exist", file=sys.stderr)
            return 2
        rows += [json.loads(line) for line in path.read_text().splitlines() if line.strip()]
    by: dict[tuple[str, str], dict[str, list[bool]]] = defaultdict(lambda: defaultdict(list))
    cond: dict[tuple[str, str, str], list[bool]] = defaultdict(list)
    for r in rows:
        group = r["policy"].split("/")[0]
        by[(group, r["task"])][r["policy"]].append(bool(r["success"]))
        cond[(group, r["task"], r["condition"])].append(bool(r["success"]))
    conditions = sorted({r["condition"] for r in rows})
    print("| models | task | episodes per model | mean ± std [%] | best [%] | worst [%] | "
          + " | ".join(f"{c} [%]" for c in conditions) + " |")
    print("|---|---|---|---|---|---|" + "---|" * len(conditions))
    for (group, task), models in sorted(by.items()):
        rates = np.array([np.mean(v) for v in models.values()]) * 100
        n = sorted({len(v) for v in models.values()})
        per_cond = [f"{100 * np.mean(cond[(group, task, c)]):.1f}" if cond[(group, task, c)] else "–"
                    for c in conditions]
        std = rates.std(ddof=1) if len(rates) > 1 else 0.0
        print(f"| {group} ({len(models)}) | {task} | {'/'.join(map(str, n))} | {rates.mean():.1f} ± {std:.1f} "
              f"| {rates.max():.1f} | {rates.min():.1f} | " + " | ".join(per_cond) + " |")
    return 0


if __name__ == "__main__":
    sys.exit(main())
