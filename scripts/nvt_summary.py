"""Issue 35: one line per bench directory: successes (crashes) per traffic level and the opposite-lane share.

    python scripts/nvt_summary.py runs/s38/nvt_fine_ghost [more bench directories]

Reads each directory's results.jsonl (nav_validation_traffic or NoCrash): per task (empty, regular, dense) the
episodes reaching the goal, those ended by a crash in brackets, and the share of all frames partly in the opposite
lane. Outside the paper.
"""

from __future__ import annotations

import json
import sys
from pathlib import Path


def summary(bench_dir: Path) -> str:
    """'Empty g/n (c) | Regular ... | opposite lane x %' for one bench directory."""
    rows = [json.loads(line) for line in (bench_dir / "results.jsonl").read_text().splitlines() if line.strip()]
    parts = []
    for task in dict.fromkeys(r["task"] for r in rows):
        sel = [r for r in rows if r["task"] == task]
        goals = sum(r["success"] for r in sel)
        crashes = sum(bool(r.get("crashed", r["collided"])) for r in sel)
        parts.append(f"{task} {goals}/{len(sel)} ({crashes})")
    otherlane = sum(r["otherlane_steps"] for r in rows) / max(sum(r["steps"] for r in rows), 1)
    return f"{bench_dir}: " + " | ".join(parts) + f" | opposite lane {100 * otherlane:.1f} % of frames"


if __name__ == "__main__":
    for arg in sys.argv[1:]:
        print(summary(Path(arg)))
