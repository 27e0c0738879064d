"""What `brl eval-seg` and `brl calibrate-seg` do with a segmentation-net file and recorded bags."""

from __future__ import annotations

import json
from collections.abc import Callable, Sequence
from pathlib import Path
from typing import Any

import numpy as np

from brlcli.segnet.calibrate import calibrate
from brlcli.segnet.io import load_segnet, save_checkpoint
from brlcli.segnet.train import evaluate

Frames = Sequence[tuple[np.ndarray, np.ndarray]]


def evaluate_file(path: Path, sets: dict[str, Frames], calibrated: bool = True, device: str = "cpu"
                  ) -> dict[str, Any]:
    """IoU and state error of a net file on named sets of labelled frames (its calibration applied, or not), the
    net run on `device`."""
    net, meta = load_segnet(path)
    _check_size(path, meta, sets)
    offsets = meta["logit_offsets"] if calibrated else None
    mean, std = np.asarray(meta["mean"], np.float32), np.asarray(meta["std"], np.float32)
    return {"segnet": str(path), "format_version": meta["format_version"],
            "calibration": "applied" if offsets is not None else ("none in file" if calibrated else "ignored"),
            "device": device,
            "sets": {name: evaluate(net, frames, mean, std, offsets, device=device) for name, frames in sets.items()}}


def calibrate_file(path: Path, frames: Frames, out: Path, fitted_on: str,
                   progress: Callable[[str], None] | None = None, device: str = "cpu") -> dict[str, Any]:
    """Fit a net file's logit offsets on labelled frames and write the calibrated net to `out` (format 2)."""
    net, meta = load_segnet(path, deployable=False)
    _check_size(path, meta, {fitted_on: frames})
    mean, std = np.asarray(meta["mean"], np.float32), np.asarray(meta["std"], np.float32)
    offsets, used = calibrate(net, mean, std, frames, progress, device=device)
    record = {"fitted_on": fitted_on, "frames": used, "objective": "mean state L1", "source": str(path),
              "logit_offsets": [round(float(v), 6) for v in offsets], "device": device,
              "sets": {fitted_on: {"uncalibrated": evaluate(net, frames, mean, std, device=device),
                                   "calibrated": evaluate(net, frames, mean, std, offsets, device=device)}}}
    extra = {k: v for k, v in meta.items() if k not in ("format_version", "logit_offsets", "calibration")}
    save_checkpoint(out, net, {**extra, "logit_offsets": [float(v) for v in offsets],
                               "calibration": json.dumps(record)})
    return record


def _check_size(path: Path, meta: dict[str, Any], sets: dict[str, Frames]) -> None:
    from brlcli.errors import BrlInputError

    size = tuple(meta["input_size"])
    for name, frames in sets.items():
        if frames and frames[0][1].shape != size:
            got = frames[0][1].shape
            raise BrlInputError(f"segmentation net {path} takes {size[1]}x{size[0]} images, the frames of {name} are "
                                f"{got[1]}x{got[0]}; record them with brl collect --width {size[1]} --height {size[0]}")


def set_name(data: str) -> str:
    """A data set's name in tables: its directory name."""
    return Path(data).name or str(data)


def check_new_file(out: Path, what: str = "--out") -> None:
    """Refuse, before any work, an output file that is a directory or cannot be written (a missing or read-only
    directory)."""
    import os
    import time

    from brlcli.errors import BrlInputError

    out = Path(out)
    if out.is_dir():
        raise BrlInputError(f"{what} {out} is a directory; give a file name")
    parent = out.parent if str(out.parent) else Path(".")
    if not parent.is_dir() or not os.access(parent, os.W_OK):
        raise BrlInputError(f"cannot write {what} {out}: directory {parent} is missing or not writable")
    probe = parent / f".brl-probe-{os.getpid()}-{time.monotonic_ns()}"  # the atomic write's temporary file goes here
    try:
        probe.write_bytes(b"")
        probe.unlink()
    except OSError as exc:
        raise BrlInputError(f"cannot write {what} {out}: {exc.strerror or type(exc).__name__}; choose a writable "
                            f"directory") from None


def evaluate_on_bags(segnet: str | None, data: Sequence[str], calibrated: bool = True, out: Path | None = None,
                     status: Callable[[str], None] | None = None, device: str = "cpu") -> dict[str, Any]:
    """`brl eval-seg`: a net file (default: the shipped one) on each --data set of bags; the figures also to `out`
    (JSON, with their provenance)."""
    from brlcli.bags import find_bags
    from brlcli.models import default_segnet_path
    from brlcli.provenance import atomic_write_json, provenance
    from brlcli.segdata import load_frames

    path = Path(segnet) if segnet else default_segnet_path()
    load_segnet(path)  # a bad file fails before the bags are read
    sets = {set_name(d): find_bags([d]) for d in data}
    if out is not None:
        check_new_file(out)
    if status:
        status("reading bags")
    frames = {name: load_frames(bags) for name, bags in sets.items()}
    if status:
        status("segmenting")
    result = evaluate_file(path, frames, calibrated=calibrated, device=device)
    if out is not None:
        atomic_write_json(out, provenance({"segnet": str(path), "data": {k: [str(b) for b in v]
                                                                          for k, v in sets.items()},
                                           "uncalibrated": not calibrated, "device": device}) | {"results": result})
    return result


def calibrate_on_bags(segnet: str | None, data: Sequence[str], out: Path,
                      status: Callable[[str], None] | None = None, device: str = "cpu") -> dict[str, Any]:
    """`brl calibrate-seg`: fit a net file's logit offsets (default: the shipped net) on held-out bags; the
    calibrated net goes to `out`, which must not exist."""
    from brlcli.bags import find_bags
    from brlcli.errors import BrlInputError
    from brlcli.models import default_segnet_path
    from brlcli.segdata import load_frames

    path = Path(segnet) if segnet else default_segnet_path()
    load_segnet(path, deployable=False)
    bags = find_bags(list(data))
    if Path(out).exists():
        raise BrlInputError(f"{out} already exists; choose another --out")
    check_new_file(out)
    if status:
        status("reading bags")
    frames = load_frames(bags)
    name = ",".join(set_name(d) for d in data)
    return calibrate_file(path, frames, Path(out), name,
                          progress=(lambda m: status(f"calibrating: {m}")) if status else None, device=device)
