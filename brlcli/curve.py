"""Learning curves: greedy success on an evaluation suite against environment steps (decisions), as a file.

Both learners write the same `learning_curve.csv` beside their run: `brl train --curve-every N` (the Bayesian RL
agent) and `brl train-rl` (the deep RL baseline), so `brl report` can plot their sample efficiency side by side.
An environment step is one decision (the action held for 7 simulator frames), the unit of the paper's t_max.
The rows come from an `Evaluator` (`brlcli.bench.runner.SuiteEvaluator`): greedy, in its own worlds, never touching
the learner's random generators.
"""

from __future__ import annotations

import csv
import io
from pathlib import Path
from typing import Any, Protocol

from brlcli.errors import BrlInputError
from brlcli.provenance import atomic_write_bytes

CURVE_FILE = "learning_curve.csv"
CURVE_COLUMNS = ("env_steps", "episodes", "success", "collision_free", "either", "score", "eval_suite")


class Evaluator(Protocol):
    """What a learner evaluates its greedy policy with (a learning curve's rows)."""

    def evaluate(self, policy: Any) -> dict[str, Any]:
        """Figures of one greedy evaluation (episodes, success, collision_free, either, score, eval_suite)."""

    def close(self) -> None:
        """Release what the evaluator holds."""


def write_curve(path: Path, rows: list[dict[str, Any]]) -> None:
    """Write the curve rows atomically (floats with repr precision)."""
    buf = io.StringIO()
    writer = csv.writer(buf, lineterminator="\n")
    writer.writerow(CURVE_COLUMNS)
    for r in rows:
        writer.writerow([repr(float(r[c])) if isinstance(r[c], float) else str(r[c]) for c in CURVE_COLUMNS])
    atomic_write_bytes(Path(path), buf.getvalue().encode())


def read_curve(path: Path) -> list[dict[str, Any]]:
    """Rows of a learning_curve.csv (env_steps and episodes as int, shares as float)."""
    path = Path(path)
    try:
        with open(path, newline="") as fh:
            rows = list(csv.DictReader(fh))
    except OSError as exc:
        raise BrlInputError(f"cannot read learning curve {path}: {exc.strerror}") from None
    out = []
    try:
        for r in rows:
            out.append({"env_steps": int(r["env_steps"]), "episodes": int(r["episodes"]),
                        **{k: float(r[k]) for k in ("success", "collision_free", "either", "score")},
                        "eval_suite": r["eval_suite"]})
    except (KeyError, ValueError, TypeError):
        raise BrlInputError(f"{path} is not a brl learning curve (columns {', '.join(CURVE_COLUMNS)})") from None
    return out


def steps_to_reach(rows: list[dict[str, Any]], success: float) -> int | None:
    """The first evaluated env-step count whose success is at least `success` (None if never reached)."""
    for r in sorted(rows, key=lambda r: r["env_steps"]):
        if r["success"] >= success - 1e-12:
            return int(r["env_steps"])
    return None
