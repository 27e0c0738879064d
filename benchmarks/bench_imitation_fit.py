"""The imitation fit of `brl train --task navigation` on a finished run's records, one process on one core (issue 35).

    python benchmarks/bench_imitation_fit.py RUN_DIR/seed_S [--iteration 8] [--records N] [--baseline-src DIR]

Refits iteration I of a finished imitation run (`brlcli.imitation.fit_mixture` on the records of iterations 0..I, in
the run's own order) and prints the fit's wall and CPU seconds and whether the mixture equals the run's
`iterations/model_I.npz` array for array (with `--records N`, only the first N records: no comparison). With
`--baseline-src DIR` (a checkout of another brl, e.g. `git worktree add /tmp/fit-base 6214e8d`), the same fit runs
with that package in a subprocess after this one, and the speed-up is printed. The fit is one thread by design; the
figure is the time `brl train` spends after each iteration's drives (`fit_s` in `iterations/data_I.npz`).
"""

from __future__ import annotations

import argparse
import json
import os
import subprocess
import sys
import time
from pathlib import Path
from typing import Any

os.environ.setdefault("OMP_NUM_THREADS", "1")


def fit_once(run: Path, iteration: int, records: int | None) -> dict[str, Any]:
    """Refit `iteration` of the imitation run in `run` with the brl on sys.path; its seconds and the check."""
    import numpy as np

    from brlcli.agent.command import CommandAgent
    from brlcli.imitation import fit_mixture
    from brlcli.trainconfig import TrainConfig

    cfg = TrainConfig.from_saved(json.loads((run / "config.json").read_text())["config"], str(run))
    data = []
    for i in range(iteration + 1):
        with np.load(run / f"iterations/data_{i}.npz", allow_pickle=False) as z:
            data.append({k: z[k] for k in ("states", "commands", "labels")})
    columns = [np.concatenate([d[k] for d in data])[:records] for k in ("states", "commands", "labels")]
    order_seed = [cfg.seed, iteration, 44, *([cfg.member] if cfg.member else [])]
    fit_mixture(*(c[:50] for c in columns), cfg=cfg, order_seed=order_seed)  # compile (or load) the kernels first
    wall, cpu = time.perf_counter(), time.process_time()
    agent = fit_mixture(*columns, cfg=cfg, order_seed=order_seed)
    wall, cpu = time.perf_counter() - wall, time.process_time() - cpu
    same = None
    if records is None:
        saved = CommandAgent.load(run / f"iterations/model_{iteration}.npz")
        pairs = [(x.to_arrays(), y.to_arrays()) for x, y in zip(agent.branches, saved.branches, strict=True)]
        same = all(x.keys() == y.keys() and all(x[k].tobytes() == y[k].tobytes() for k in x) for x, y in pairs)
    return {"records": len(columns[2]), "components": agent.total_components, "wall_s": wall, "cpu_s": cpu,
            "equals_saved_model": same}


def main() -> None:
    """Time the fit here (and with --baseline-src's brl) and print one line each."""
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("run", type=Path, help="a finished imitation run's seed directory (config.json, iterations/)")
    ap.add_argument("--iteration", type=int, default=8)
    ap.add_argument("--records", type=int, default=None)
    ap.add_argument("--baseline-src", type=Path, default=None)
    ap.add_argument("--json-line", action="store_true", help=argparse.SUPPRESS)  # the baseline's subprocess
    args = ap.parse_args()
    if not (args.run / "iterations" / f"data_{args.iteration}.npz").is_file():
        print(f"error: {args.run} has no iterations/data_{args.iteration}.npz; give a finished imitation run's seed "
              "directory", file=sys.stderr)
        sys.exit(2)
    here = fit_once(args.run, args.iteration, args.records)
    if args.json_line:
        print(json.dumps(here))
        return
    print(f"this brl: fit {here['wall_s']:.1f} s wall, {here['cpu_s']:.1f} s CPU, {here['records']} records, "
          f"{here['components']} components, equals model_{args.iteration}.npz: {here['equals_saved_model']}")
    if args.baseline_src is not None:
        argv = [sys.executable, __file__, str(args.run), "--iteration", str(args.iteration), "--json-line",
                *(["--records", str(args.records)] if args.records is not None else [])]
        env = {**os.environ, "PYTHONPATH": str(args.baseline_src.resolve())}
        base = json.loads(subprocess.run(argv, env=env, check=True, capture_output=True, text=True).stdout)
        print(f"baseline: fit {base['wall_s']:.1f} s wall, {base['cpu_s']:.1f} s CPU, equals model_"
              f"{args.iteration}.npz: {base['equals_saved_model']}; speed-up {base['cpu_s'] / here['cpu_s']:.2f}x "
              "(CPU)")


if __name__ == "__main__":
    main()
