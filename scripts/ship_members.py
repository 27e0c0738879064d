"""Copy the finished members of a committee training run, or the finished seeds of a one-model run, into a
shipped model directory.

    python scripts/ship_members.py runs/s30/committee7 models/brl_nav_empty
    python scripts/ship_members.py --deployment runs/s46/ship_s0 models/brl_nav

For every `seed_<s>/member_<k>` (or `seed_<s>` without members) of the run that holds a `summary.json` (a finished
run), writes `<dest>/seed_<s>/member_<k>/` (or `<dest>/seed_<s>/`) with its `config.json`, `summary.json`, an
imitation run's `iterations.csv` and `model.npz`, the model re-saved zip-compressed (the same arrays, a third of the
size; `np.load` reads both) and checked array for array. With `--deployment` the copy leaves out every mixture's
scatter matrices (`brlcli.agent.bayes.deployment_arrays`: about half the file again): it drives exactly as the run's
model (the same means, Cholesky factors, action values; loaded back through brl and checked) but cannot learn
further. Runs already shipped are left as they are. For committees, a
later `brl train ... --set committee=K --resume` on a copy of `<dest>` finishes the missing members and writes each
seed's committee (`models/README.md`).
"""

from __future__ import annotations

import argparse
import os
import shutil
import sys
import tempfile
from pathlib import Path

import numpy as np

from brlcli.agent.bayes import deployment_arrays
from brlcli.agent.command import is_command_model, load_navigation_agent
from brlcli.agent.committee import load_lane_keeping_agent
from brlcli.errors import BrlInputError


def ship_member(src: Path, dst: Path, deployment: bool = False) -> None:
    """Copy one finished member run (config, summary, compressed model) into dst, atomically per file."""
    dst.mkdir(parents=True, exist_ok=True)
    with np.load(src / "model.npz", allow_pickle=False) as npz:
        arrays = {k: npz[k] for k in npz.files}
    if deployment:
        arrays = deployment_arrays(arrays)
    fd, tmp = tempfile.mkstemp(dir=dst, suffix=".npz.tmp")
    os.close(fd)
    with open(tmp, "wb") as fh:
        np.savez_compressed(fh, **arrays)
    with np.load(tmp, allow_pickle=False) as back:
        if sorted(back.files) != sorted(arrays) or any(
                back[k].dtype != v.dtype or back[k].tobytes() != v.tobytes() for k, v in arrays.items()):
            os.unlink(tmp)
            raise SystemExit(f"{src}: the compressed copy differs from the model")
    try:  # brl reads it back (a deployment copy included)
        (load_navigation_agent if is_command_model(tmp) else load_lane_keeping_agent)(tmp)
    except BrlInputError as exc:
        os.unlink(tmp)
        raise SystemExit(f"{src}: brl cannot read the shipped copy: {exc}") from None
    os.replace(tmp, dst / "model.npz")
    log = ["iterations.csv"] if (src / "iterations.csv").exists() else []  # an imitation run's DAgger iterations
    for name in (*log, "config.json", "summary.json"):  # summary last: it marks the run as finished
        shutil.copyfile(src / name, dst / f"{name}.tmp")
        os.replace(dst / f"{name}.tmp", dst / name)


def main() -> None:
    """Ship every finished member (or one-model seed) of a run that is not shipped yet."""
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("run", type=Path)
    ap.add_argument("dest", type=Path)
    ap.add_argument("--deployment", action="store_true",
                    help="ship deployment copies (no scatter matrices: about half the size; they cannot learn)")
    args = ap.parse_args()
    shipped = 0
    finished = [s for s in args.run.glob("seed_*/summary.json") if not any(s.parent.glob("member_*"))]
    for summary in sorted(args.run.glob("seed_*/member_*/summary.json")) + sorted(finished):
        src = summary.parent
        dst = args.dest / src.relative_to(args.run)
        if (dst / "summary.json").exists():
            continue
        ship_member(src, dst, deployment=args.deployment)
        shipped += 1
    total = len(list(args.dest.glob("seed_*/member_*/summary.json")) + list(args.dest.glob("seed_*/summary.json")))
    print(f"shipped {shipped} runs; {args.dest} holds {total}", file=sys.stderr)


if __name__ == "__main__":
    main()
