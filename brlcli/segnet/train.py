"""Training the segmentation net: class-weighted CE + SE loss + auxiliary loss, SGD with a poly schedule,
per-epoch IoU per class and per state category, best checkpoint kept, bit-identical resume."""

from __future__ import annotations

import json
import math
import time
from collections.abc import Callable, Sequence
from dataclasses import asdict, dataclass, field, replace
from pathlib import Path
from typing import Any

import numpy as np
import torch
import torch.nn.functional as F

from brlcli.config import check_known_keys
from brlcli.devices import check_device_name, prepare_cuda_determinism, resolve_device, to_device_tensor
from brlcli.errors import BrlInputError
from brlcli.outdir import refuse_existing
from brlcli.provenance import atomic_write_bytes
from brlcli.segnet.calibrate import calibrate
from brlcli.segnet.infer import batch_logits, normalise, normalise_on_device
from brlcli.segnet.io import load_checkpoint, load_segnet, save_checkpoint
from brlcli.segnet.metrics import SegMetrics
from brlcli.segnet.model import NUM_CLASSES, SegNet, SegNetConfig

Frames = Sequence[tuple[np.ndarray, np.ndarray]]
CLASS_WEIGHTINGS = ("enet", "none")
SELECTIONS = ("miou", "state")


@dataclass(frozen=True)
class SegTrainConfig:
    """Training options (defaults: the shipped net's recipe)."""

    epochs: int = 14
    batch_size: int = 16
    lr: float = 0.02
    momentum: float = 0.9
    weight_decay: float = 1e-4
    poly_power: float = 0.9
    se_weight: float = 0.2
    aux_weight: float = 0.2
    seed: int = 0
    threads: int = 2
    flip: bool = True
    colour_jitter: float = 0.25
    class_weighting: str = "enet"  # enet: 1 / ln(1.02 + p_c); none: plain cross-entropy
    select: str = "miou"  # best epoch by the first validation set's category mIoU, or by its state L1 ("state")
    net: dict[str, Any] = field(default_factory=lambda: SegNetConfig().to_dict())
    device: str = "cpu"  # cpu (bit-identical to brl before devices), cuda or cuda:N (brlcli.devices)

    def __post_init__(self) -> None:
        check_device_name(self.device, "--device")
        if self.epochs < 1 or self.batch_size < 4:
            raise BrlInputError("--epochs must be >= 1 and --batch-size >= 4 (BatchNorm needs batches)")
        if self.threads < 1:
            raise BrlInputError("--workers must be at least 1")
        if self.select not in SELECTIONS:
            raise BrlInputError(f"--select must be {' or '.join(SELECTIONS)}, not '{self.select}'")
        if self.seed < 0:
            raise BrlInputError(f"--seed must be >= 0, got {self.seed}")
        try:
            net = SegNetConfig.from_dict(self.net)
        except (TypeError, KeyError, ValueError) as exc:
            raise BrlInputError(f"bad segmentation net configuration (net.*): {exc}") from None
        if net.fine < 0:
            raise BrlInputError("--fine-channels (net.fine) must be >= 0")
        if self.class_weighting not in CLASS_WEIGHTINGS:
            raise BrlInputError(f"--class-weights must be {' or '.join(CLASS_WEIGHTINGS)}, "
                                f"not '{self.class_weighting}'")

    def to_dict(self) -> dict[str, Any]:
        """JSON-ready form."""
        return asdict(self)

    @classmethod
    def from_dict(cls, d: dict[str, Any]) -> SegTrainConfig:
        """Inverse of `to_dict`; unknown keys are an error."""
        check_known_keys(cls, d, "segmentation")
        return cls(**d)


def presence_targets(labels: np.ndarray) -> np.ndarray:
    """Per-image class presence (B, 13) in {0, 1}: the Semantic Encoding loss targets."""
    flat = labels.reshape(len(labels), -1).astype(np.int64) + NUM_CLASSES * np.arange(len(labels))[:, None]
    counts = np.bincount(flat.ravel(), minlength=NUM_CLASSES * len(labels)).reshape(len(labels), NUM_CLASSES)
    return (counts > 0).astype(np.float32)


def class_weights(frames: Frames, weighting: str = "enet") -> np.ndarray:
    """Cross-entropy class weights: ENet-style 1 / ln(1.02 + p_c) from the training labels' frequencies, or ones."""
    if weighting == "none":
        return np.ones(NUM_CLASSES)
    counts = np.zeros(NUM_CLASSES)
    for _, labels in frames:
        counts += np.bincount(labels.ravel(), minlength=NUM_CLASSES)[:NUM_CLASSES]
    p = counts / counts.sum()
    return 1.0 / np.log(1.02 + p)


def evaluate(net: SegNet, frames: Frames, mean: np.ndarray, std: np.ndarray,
             logit_offsets: np.ndarray | None = None, batch: int = 32, device: str = "cpu") -> dict[str, Any]:
    """IoU per class and per category with their means, and the state error, on labelled frames."""
    metrics = SegMetrics()
    bias = 0.0 if logit_offsets is None else np.asarray(logit_offsets, np.float32)[None, :, None, None]
    for i in range(0, len(frames), batch):
        chunk = frames[i : i + batch]
        logits = batch_logits(net, np.stack([f[0] for f in chunk]), mean, std, batch, device)
        metrics.add(np.stack([f[1] for f in chunk]), (logits + bias).argmax(1))
    return metrics.result()


def _augment(rgb: np.ndarray, labels: np.ndarray, rng: np.random.Generator, cfg: SegTrainConfig
             ) -> tuple[np.ndarray, np.ndarray]:
    rgb = rgb.astype(np.float32)
    if cfg.flip:
        flip = rng.uniform(size=len(rgb)) < 0.5
        rgb[flip] = rgb[flip, :, ::-1]
        labels = labels.copy()
        labels[flip] = labels[flip, :, ::-1]
    if cfg.colour_jitter > 0:  # per-image brightness, contrast and per-channel gain
        j = cfg.colour_jitter
        gain = rng.uniform(1 - j, 1 + j, size=(len(rgb), 1, 1, 3)) * rng.uniform(1 - j, 1 + j, size=(len(rgb), 1, 1, 1))
        mean = rgb.mean(axis=(1, 2, 3), keepdims=True)
        contrast = rng.uniform(1 - j, 1 + j, size=(len(rgb), 1, 1, 1))
        rgb = np.clip((rgb - mean) * contrast + mean, 0, 255) * gain
    return np.clip(rgb, 0, 255), labels


def augment_on_device(rgb_u8: torch.Tensor, labels: torch.Tensor, gen: torch.Generator, cfg: SegTrainConfig
                      ) -> tuple[torch.Tensor, torch.Tensor]:
    """`_augment` on the device's tensors (N, H, W, 3) uint8 and (N, H, W): the same flip and colour jitter, drawn
    from the device's generator `gen` (so not the CPU path's numbers)."""
    rgb = rgb_u8.float()
    n, dev = rgb.shape[0], rgb.device
    if cfg.flip:
        flip = torch.rand(n, generator=gen, device=dev) < 0.5
        rgb = torch.where(flip[:, None, None, None], rgb.flip(2), rgb)
        labels = torch.where(flip[:, None, None], labels.flip(2), labels)
    if cfg.colour_jitter > 0:
        j = cfg.colour_jitter

        def uniform(*shape: int) -> torch.Tensor:
            return torch.empty(shape, device=dev).uniform_(1 - j, 1 + j, generator=gen)

        gain = uniform(n, 1, 1, 3) * uniform(n, 1, 1, 1)
        mean = rgb.mean(dim=(1, 2, 3), keepdim=True)
        rgb = ((rgb - mean) * uniform(n, 1, 1, 1) + mean).clamp(0, 255) * gain
    return rgb.clamp(0, 255), labels


def _device_batch(rgb_u8: torch.Tensor, labels_all: torch.Tensor, idx: np.ndarray, gen: torch.Generator,
                  cfg: SegTrainConfig, mean: torch.Tensor, std: torch.Tensor
                  ) -> tuple[torch.Tensor, torch.Tensor, torch.Tensor]:
    """A training batch on the device: the frames `idx` (resident, or copied from pinned memory), augmented and
    normalised there; (input, labels, class presence)."""
    sel = torch.from_numpy(idx).to(rgb_u8.device)
    rgb, labels = rgb_u8[sel], labels_all[sel]
    if rgb.device != mean.device:
        rgb = rgb.pin_memory().to(mean.device, non_blocking=True)
        labels = labels.pin_memory().to(mean.device, non_blocking=True)
    rgb_f, labels = augment_on_device(rgb, labels, gen, cfg)
    return normalise_on_device(rgb_f, mean, std), labels.long(), presence_on_device(labels)


def presence_on_device(labels: torch.Tensor) -> torch.Tensor:
    """`presence_targets` of a device's label tensor (N, H, W): (N, 13) float32 in {0, 1}."""
    n = labels.shape[0]
    present = torch.zeros(n, NUM_CLASSES, device=labels.device)
    return present.scatter_(1, labels.reshape(n, -1).long(), 1.0)


def train_segnet(train: Frames, val_sets: dict[str, Frames], cfg: SegTrainConfig, out: Path,
                 progress: Callable[[dict], None] | None = None, resume: bool = False) -> dict[str, Any]:
    """Train on `train`, validate on each named set per epoch (IoU and state error); the best epoch (first
    validation set) -> best.pt, then calibrated on that set -> segnet.pt (see `calibrate_run`)."""
    out = Path(out)
    cfg = replace(cfg, device=resolve_device(cfg.device))
    out.mkdir(parents=True, exist_ok=True)
    if len(train) < cfg.batch_size:
        raise BrlInputError(f"only {len(train)} training frames; need at least one batch of {cfg.batch_size}")
    device = cfg.device
    torch.set_num_threads(cfg.threads)
    if device == "cpu":
        torch.use_deterministic_algorithms(True)
    else:
        prepare_cuda_determinism()
    torch.manual_seed(cfg.seed)  # CUDA's generators too
    h, w = train[0][1].shape
    rgb_all = np.stack([f[0] for f in train]).astype(np.float32) / 255.0
    mean = rgb_all.mean(axis=(0, 1, 2)).astype(np.float32)
    std = (rgb_all.std(axis=(0, 1, 2)) + 1e-6).astype(np.float32)
    del rgb_all
    weights = torch.tensor(class_weights(train, cfg.class_weighting), dtype=torch.float32).to(device)
    net = SegNet(SegNetConfig.from_dict(cfg.net)).to(device)
    opt = torch.optim.SGD(net.parameters(), lr=cfg.lr, momentum=cfg.momentum, weight_decay=cfg.weight_decay)
    steps_per_epoch = len(train) // cfg.batch_size
    total = steps_per_epoch * cfg.epochs
    rng = np.random.default_rng(cfg.seed)
    gen = None if device == "cpu" else torch.Generator(device).manual_seed(cfg.seed)  # the device's augmentation
    start_epoch, best, history = 0, -math.inf, []
    meta = {"mean": mean.tolist(), "std": std.tolist(), "input_size": [h, w], "train_config": cfg.to_dict()}
    if resume and (out / "last.pt").exists():
        state = load_checkpoint(out / "last.pt")
        refuse_existing(out, "a segmentation run", resume,
                        {"device": "cpu", **state["extra"]["train_config"]} == cfg.to_dict())
        net.load_state_dict(state["state_dict"])
        opt.load_state_dict(state["extra"]["optimizer"])
        torch.set_rng_state(state["extra"]["torch_rng"])
        rng.bit_generator.state = json.loads(state["extra"]["numpy_rng"])
        if gen is not None:
            gen.set_state(state["extra"]["device_rng"])
            torch.cuda.set_rng_state(state["extra"]["cuda_rng"], torch.device(device))
        start_epoch, best = state["extra"]["epoch"], state["extra"]["best"]
        history = json.loads(state["extra"]["history"])
    labels_all = np.stack([f[1] for f in train])
    rgb_u8 = np.stack([f[0] for f in train])
    if gen is not None:  # resident on the GPU when it fits (pinned host memory otherwise)
        labels_all, rgb_u8 = to_device_tensor(labels_all, device), to_device_tensor(rgb_u8, device)
        mean_t, std_t = torch.from_numpy(mean).to(device), torch.from_numpy(std).to(device)
    t0 = time.perf_counter()
    for epoch in range(start_epoch, cfg.epochs):
        net.train()
        order = rng.permutation(len(train))
        losses = []
        for b in range(steps_per_epoch):
            it = epoch * steps_per_epoch + b
            for g in opt.param_groups:
                g["lr"] = cfg.lr * (1 - it / total) ** cfg.poly_power
            idx = np.sort(order[b * cfg.batch_size : (b + 1) * cfg.batch_size])
            if gen is None:
                rgb, labels = _augment(rgb_u8[idx], labels_all[idx], rng, cfg)
                x = normalise(rgb, mean, std)
                y = torch.from_numpy(labels.astype(np.int64))
                present = torch.from_numpy(presence_targets(labels))
            else:
                x, y, present = _device_batch(rgb_u8, labels_all, idx, gen, cfg, mean_t, std_t)
            logits, aux, presence = net(x)
            loss = F.cross_entropy(logits, y, weight=weights)
            loss = loss + cfg.aux_weight * F.cross_entropy(aux, y, weight=weights)
            loss = loss + cfg.se_weight * F.binary_cross_entropy_with_logits(presence, present)
            opt.zero_grad()
            loss.backward()
            opt.step()
            losses.append(float(loss.detach()) if gen is None else loss.detach())  # the GPU: no sync per step
        mean_loss = float(np.mean(losses)) if gen is None else float(torch.stack(losses).double().mean())
        record: dict[str, Any] = {"epoch": epoch + 1, "loss": mean_loss,
                                  "wall_s": round(time.perf_counter() - t0, 1)}
        for name, frames in val_sets.items():
            record[name] = evaluate(net, frames, mean, std, device=device)
        history.append(record)
        score = _selection_score(record, val_sets, cfg.select)
        extra = {**meta, "epoch": epoch + 1, "best": max(best, score), "history": json.dumps(history),
                 "optimizer": opt.state_dict(), "torch_rng": torch.get_rng_state(),
                 "numpy_rng": json.dumps(rng.bit_generator.state)}
        if gen is not None:
            extra.update(device_rng=gen.get_state(), cuda_rng=torch.cuda.get_rng_state(torch.device(device)))
        if score > best:
            best = score
            save_checkpoint(out / "best.pt", net, {**meta, "epoch": epoch + 1, "metrics": json.dumps(record)})
        save_checkpoint(out / "last.pt", net, extra)
        atomic_write_bytes(out / "metrics.jsonl", "".join(json.dumps(r, sort_keys=True) + "\n"
                                                         for r in history).encode())
        if progress:
            progress(record)
    if (out / "segnet.pt").exists():
        calibration = json.loads((out / "calibration.json").read_text())
    else:  # after the last epoch (also when a resumed run had finished its epochs)
        calibration = calibrate_run(out, val_sets, progress, device=cfg.device)
    return {"epochs": len(history), "best": best, "history": history, "calibration": calibration}


def _selection_score(record: dict[str, Any], val_sets: dict[str, Frames], select: str) -> float:
    """Higher is better: the first validation set's category mIoU, or minus its state L1; else minus the loss."""
    if not val_sets:
        return -record["loss"]
    first = record[next(iter(val_sets))]
    return first["miou_categories"] if select == "miou" else -first["state_l1"]


def calibrate_run(out: Path, val_sets: dict[str, Frames], progress: Callable[[dict], None] | None = None,
                  device: str = "cpu") -> dict[str, Any]:
    """Calibrate the run's best epoch on its first validation set -> segnet.pt (+ calibration.json: before/after)."""
    net, meta = load_segnet(out / "best.pt", deployable=False)
    mean, std = np.asarray(meta["mean"], np.float32), np.asarray(meta["std"], np.float32)
    fit_name = next(iter(val_sets), None)
    if fit_name is None:  # nothing held out to fit on: the identity calibration
        offsets, used = np.zeros(NUM_CLASSES), 0
    else:
        def note(message: str) -> None:
            if progress:
                progress({"calibration": message})

        offsets, used = calibrate(net, mean, std, val_sets[fit_name], progress=note, device=device)
    record: dict[str, Any] = {"fitted_on": fit_name, "frames": used, "objective": "mean state L1",
                              "logit_offsets": [round(float(v), 6) for v in offsets], "sets": {}}
    for name, frames in val_sets.items():
        record["sets"][name] = {"uncalibrated": evaluate(net, frames, mean, std, device=device),
                                "calibrated": evaluate(net, frames, mean, std, offsets, device=device)}
    extra = {k: v for k, v in meta.items() if k not in ("format_version", "logit_offsets")}
    save_checkpoint(out / "segnet.pt", net, {**extra, "logit_offsets": [float(v) for v in offsets],
                                             "calibration": json.dumps(record)})
    atomic_write_bytes(out / "calibration.json", (json.dumps(record, indent=2, sort_keys=True) + "\n").encode())
    return record


def train_from_bags(cfg: SegTrainConfig, data: Sequence[str], val: Sequence[str] | None, val_fraction: float,
                    out: Path, resume: bool = False, progress: Callable[[dict], None] | None = None) -> dict[str, Any]:
    """`brl train-seg`: the training bags and validation sets (each --val one set, or whole episodes of --data held
    out), config.json (the configuration and the bags; resume needs the same), then `train_segnet`. `progress` first
    receives {"frames": N, "val": {set: N}} once the bags are read."""
    from brlcli.provenance import atomic_write_json, provenance
    from brlcli.segdata import load_frames, resolve_data

    out = Path(out)
    cfg = replace(cfg, device=resolve_device(cfg.device))  # recorded as the device it runs on
    train_bags, val_bags = resolve_data(data, val, val_fraction, cfg.seed)
    record = provenance({**cfg.to_dict(), "data": [str(b) for b in train_bags],
                         "val": {k: [str(b) for b in v] for k, v in val_bags.items()}}, kind="train-seg")
    cfg_path = out / "config.json"
    if cfg_path.exists():
        same = {"device": "cpu", **json.loads(cfg_path.read_text())["config"]} == record["config"]  # brl < 0.3: cpu
        refuse_existing(out, "a segmentation run", resume, same)
    train_frames = load_frames(train_bags)
    val_frames = {k: load_frames(v) for k, v in val_bags.items()}
    if progress:
        progress({"frames": len(train_frames), "val": {k: len(v) for k, v in val_frames.items()}})
    atomic_write_json(cfg_path, record)
    return train_segnet(train_frames, val_frames, cfg, out, progress=progress, resume=resume)
