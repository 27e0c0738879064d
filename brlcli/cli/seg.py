"""`brl train-seg`, `brl eval-seg`, `brl calibrate-seg`: the segmentation net behind the estimated input."""

from __future__ import annotations

from pathlib import Path
from typing import Annotated, Any

import typer

from brlcli.cli.common import (
    ConfigFile,
    Device,
    PrintConfig,
    Resume,
    Sets,
    app,
    given,
    out_option,
    print_config,
    run_command,
    stderr_console,
    table_console,
)


@app.command("train-seg")
def train_seg(
    ctx: typer.Context,
    data: Annotated[list[str], typer.Option(help="Training bags: bag directories, directories of bags, globs.")],
    val: Annotated[list[str] | None, typer.Option(help="A validation set (repeatable; the first picks the best "
                                                       "epoch and calibrates it). None: hold out episodes of --data.")]
    = None,
    val_fraction: Annotated[float, typer.Option(help="Share of --data episodes held out when no --val.")] = 0.1,
    epochs: Annotated[int, typer.Option(help="Training epochs.")] = 14,
    batch_size: Annotated[int, typer.Option(help="Batch size (>= 4).")] = 16,
    class_weights: Annotated[str, typer.Option(help="Cross-entropy class weights: enet (1 / ln(1.02 + p_c)) or "
                                                    "none.")] = "enet",
    fine_channels: Annotated[int, typer.Option(help="Channels of the output-stride-2 refinement (0: none, the "
                                                    "brl 0.1 net).")] = 0,
    select: Annotated[str, typer.Option(help="Best epoch by the first validation set's miou (category mean IoU) "
                                             "or state (mean state L1).")] = "miou",
    seed: Annotated[int, typer.Option(min=0, help="Seed of initialisation, order and augmentation.")] = 0,
    workers: Annotated[int, typer.Option(help="CPU threads for torch.")] = 2,
    device: Device = "cpu",
    out: Annotated[str | None, out_option("train-seg", "segnet.pt = best epoch, calibrated; best.pt, last.pt, "
                                                       "metrics.jsonl, calibration.json")] = None,
    resume: Resume = False,
    config: ConfigFile = None,
    set_: Sets = None,
    print_config_: PrintConfig = False,
) -> None:
    """Train the EncNet-style segmentation net on frames recorded by brl collect, then calibrate it for the state."""
    from brlcli.config import command_layers, resolve
    from brlcli.segnet.train import SegTrainConfig, train_from_bags

    options = {"epochs": ("epochs", epochs), "batch_size": ("batch_size", batch_size),
               "class_weights": ("class_weighting", class_weights), "fine_channels": ("net.fine", fine_channels),
               "select": ("select", select), "seed": ("seed", seed), "workers": ("threads", workers),
               "device": ("device", device)}
    cfg = resolve(SegTrainConfig, command_layers(config, given(ctx, options), set_), "segmentation")
    if print_config_:
        print_config(cfg)
        return
    console = stderr_console()
    val_names: list[str] = []

    def report(r: dict) -> None:
        if "frames" in r:
            val_names.extend(r["val"])
            console.print(f"{r['frames']} training frames; validation: "
                          + ", ".join(f"{k} {n}" for k, n in r["val"].items()))
        elif "calibration" in r:
            console.print(f"calibration on {val_names[0]}: {r['calibration']}")
        else:
            vals = "  ".join(f"{k}: mIoU cat {r[k]['miou_categories']:.3f} state L1 {r[k]['state_l1']:.3f}"
                             for k in val_names)
            console.print(f"epoch {r['epoch']:3d}/{cfg.epochs}  loss {r['loss']:.4f}  {vals}  ({r['wall_s']:.0f} s)")

    with run_command("train-seg", out, resume, console=console, kept="finished epochs are saved") as run_dir:
        result = train_from_bags(cfg, data, val, val_fraction, run_dir, resume=resume, progress=report)
    console.print(f"best epoch by {cfg.select} on {val_names[0]}: {result['best']:.3f}; calibrated:")
    calibrated = {name: sets["calibrated"] for name, sets in result["calibration"]["sets"].items()}
    table_console().print(seg_table(calibrated, "segmentation net (calibrated)"))
    typer.echo(str(run_dir / "segnet.pt"))


def seg_table(results: dict, title: str) -> Any:  # -> rich.table.Table
    """IoU and state error per set of frames (what `brl eval-seg` and `brl train-seg` print)."""
    from rich.table import Table

    table = Table(title=title)
    for col in ("set", "frames", "mIoU 5 cat", "road", "line", "off-road", "dynamic", "static", "state L1",
                "line bias", "road bias", "line area", "road area"):
        table.add_column(col, justify="left" if col == "set" else "right")

    def num(value: float | None, fmt: str) -> str:
        return "–" if value is None else format(value, fmt)

    for name, r in results.items():
        iou = r["iou_categories"]
        table.add_row(name, str(r["frames"]), f"{r['miou_categories']:.3f}",
                      *(num(iou[k], ".3f") for k in ("road", "road_line", "off_road", "dynamic", "static")),
                      f"{r['state_l1']:.3f}", num(r["state_bias"]["road_line"], "+.3f"),
                      num(r["state_bias"]["road"], "+.3f"), num(r["area_ratio"]["road_line"], ".2f") + "x",
                      num(r["area_ratio"]["road"], ".2f") + "x")
    return table


@app.command("eval-seg")
def eval_seg(
    data: Annotated[list[str], typer.Option(help="Recorded bags to evaluate on (repeatable: one set each).")],
    segnet: Annotated[str | None, typer.Option(help="Segmentation-net file (default: the shipped one).")] = None,
    uncalibrated: Annotated[bool, typer.Option("--uncalibrated", help="Ignore the file's calibration (logit "
                                                                     "offsets).")] = False,
    out: Annotated[Path | None, typer.Option("--out", help="Also write the figures to this JSON file.")] = None,
    device: Device = "cpu",
) -> None:
    """IoU and the state error (L1 between GT and estimated states, bias, area ratios) of a net on bags."""
    from brlcli.devices import resolve_device
    from brlcli.segnet.filetools import evaluate_on_bags

    device = resolve_device(device)
    console = stderr_console()
    with console.status("reading bags") as status:
        result = evaluate_on_bags(segnet, data, calibrated=not uncalibrated, out=out, status=status.update,
                                  device=device)
    path = result["segnet"]
    if result["calibration"] == "none in file":
        console.print(f"note: {path} carries no calibration (format {result['format_version']})")
    table_console().print(seg_table(result["sets"], f"{path} ({result['calibration']} calibration)"))
    if out is not None:
        typer.echo(str(out))


@app.command("calibrate-seg")
def calibrate_seg(
    data: Annotated[list[str], typer.Option(help="Held-out recorded bags to fit the calibration on (not the "
                                                 "net's training bags, not the ones you report on).")],
    out: Annotated[Path, typer.Option("--out", help="The calibrated net's file (must not exist).")],
    segnet: Annotated[str | None, typer.Option(help="Segmentation-net file (default: the shipped one).")] = None,
    device: Device = "cpu",
) -> None:
    """Fit a net's per-class logit offsets so that its labels give the states of the ground truth."""
    from brlcli.devices import resolve_device
    from brlcli.segnet.filetools import calibrate_on_bags

    device = resolve_device(device)
    console = stderr_console()
    with console.status("reading bags") as status:
        record = calibrate_on_bags(segnet, data, out, status=status.update, device=device)
    name = record["fitted_on"]
    table_console().print(seg_table({f"{name} before": record["sets"][name]["uncalibrated"],
                                     f"{name} after": record["sets"][name]["calibrated"]}, f"{out}"))
    typer.echo(str(out))
