"""Ray executor against local worker processes: `brl bench` wall time, back to back, and per-task overhead.

    python benchmarks/bench_executor.py [--workers 2] [--repeats 1] [--tasks 1000] [--suites paper,corl10]

For each suite, the same `brl bench` command runs with `--workers N` (local processes) and then with
`--executor ray --workers N` (a fresh local Ray instance with N CPUs, start-up included), `--repeats` times in
alternation; the script checks that both wrote the same result lines and prints wall times and their ratio.
Per-task overhead: the marginal wall time of a trivial task through `brlcli.executor.run_tasks` on each executor,
(time of 2N tasks - time of N tasks) / N, so that pool and instance start-up cancel out.
"""

from __future__ import annotations

import argparse
import statistics
import subprocess
import sys
import tempfile
import time
from pathlib import Path

SUITES = {
    "paper": ["--suite", "paper"],
    "corl10": ["--suite", "corl2017", "--episodes", "0.1"],
}


def _bench(args: list[str], out: Path) -> float:
    t0 = time.perf_counter()
    # a session of its own, like Ray's processes: with the kernel's autogroup scheduling both then compete for the
    # CPUs as one group each against other jobs on a shared machine
    subprocess.run([sys.executable, "-m", "brlcli", "bench", *args, "--out", str(out)], check=True,
                   capture_output=True, start_new_session=True)
    return time.perf_counter() - t0


def _noop(x: int) -> int:
    return x


def _task_overhead(workers: int, tasks: int) -> dict[str, float]:
    """Marginal wall time per trivial task: (time of 2N tasks - time of N tasks) / N, per executor."""
    from brlcli.executor import Executor, run_tasks

    out = {}
    for kind in ("local", "ray"):
        t0 = time.perf_counter()
        with Executor(kind, workers) as ex:  # ray: starts a local instance
            list(run_tasks(_noop, range(workers * 4), executor=ex))  # pool start / Ray worker warm-up
            out[f"{kind}_first_batch_s"] = time.perf_counter() - t0
            spent = []
            for n in (tasks, 2 * tasks):
                t0 = time.perf_counter()
                list(run_tasks(_noop, range(n), executor=ex))
                spent.append(time.perf_counter() - t0)
            out[kind] = (spent[1] - spent[0]) / tasks
    return out


def main() -> None:
    """Time local and Ray bench runs back to back and the per-task overhead; print a summary."""
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--workers", type=int, default=2)
    ap.add_argument("--repeats", type=int, default=1)
    ap.add_argument("--tasks", type=int, default=1000)
    ap.add_argument("--suites", default="paper,corl10")
    ap.add_argument("--skip-tasks", action="store_true", help="Skip the per-task overhead measurement.")
    ap.add_argument("--model", default="models/brl_gt/seed_3")
    args = ap.parse_args()
    with tempfile.TemporaryDirectory() as tmp:
        for suite in args.suites.split(","):
            base = [*SUITES[suite], "--model", args.model, "--workers", str(args.workers)]
            times: dict[str, list[float]] = {"local": [], "ray": []}
            for r in range(args.repeats):
                for kind in ("local", "ray"):
                    extra = ["--executor", "ray"] if kind == "ray" else []
                    out = Path(tmp) / f"{suite}_{kind}_{r}"
                    times[kind].append(_bench(base + extra, out))
                    print(f"{suite} {kind} run {r}: {times[kind][-1]:.1f} s", flush=True)
                a = sorted((Path(tmp) / f"{suite}_local_{r}" / "results.jsonl").read_text().splitlines())
                b = sorted((Path(tmp) / f"{suite}_ray_{r}" / "results.jsonl").read_text().splitlines())
                assert a == b, f"{suite}: local and Ray results differ"
            loc, ray = statistics.median(times["local"]), statistics.median(times["ray"])
            print(f"{suite}: {len(a)} episodes, local {loc:.1f} s, ray {ray:.1f} s, ratio {ray / loc:.2f}, "
                  "same result lines", flush=True)
    if args.skip_tasks:
        return
    over = _task_overhead(args.workers, args.tasks)
    print(f"marginal wall time per trivial task: local pool {1e3 * over['local']:.2f} ms, "
          f"ray {1e3 * over['ray']:.2f} ms; start-up and first {args.workers * 4} tasks: local "
          f"{over['local_first_batch_s']:.1f} s, ray {over['ray_first_batch_s']:.1f} s")


if __name__ == "__main__":
    main()
