"""Training the segmentation net: class-weighted CE + SE loss + auxiliary loss, SGD with a poly schedule,
per-epoch IoU per class and per state category, best checkpoint kept, bit-identical resume."""

from __future__ import annotations

import json
import math
import time
from collections.abc import Callable, Sequence
from dataclasses import asdict, dataclass, field
from pathlib import Path
from typing import Any

import numpy as np
import torch
import torch.nn.functional as F

from brlcli.errors import BrlInputError
from brlcli.features import CLASS_TO_CATEGORY, N_CATEGORIES
from brlcli.provenance import atomic_write_bytes
from brlcli.segnet.io import load_checkpoint, save_checkpoint
from brlcli.segnet.model import NUM_CLASSES, SegNet, SegNetConfig

Frames = Sequence[tuple[np.ndarray, np.ndarray]]
CATEGORY_NAMES = ("road", "road_line", "off_road", "dynamic", "static")


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
    net: dict[str, Any] = field(default_factory=lambda: SegNetConfig().to_dict())

    def __post_init__(self) -> None:
        if self.epochs < 1 or self.batch_size < 4:
            raise BrlInputError("--epochs must be >= 1 and --batch-size >= 4 (BatchNorm needs batches)")
        if self.threads < 1:
            raise BrlInputError("--workers must be at least 1")

    def to_dict(self) -> dict[str, Any]:
        """JSON-ready form."""
        return asdict(self)


def confusion(pred: np.ndarray, truth: np.ndarray, n: int) -> np.ndarray:
    """n x n confusion matrix (rows truth, columns prediction) of integer label arrays."""
    return np.bincount(truth.ravel().astype(np.int64) * n + pred.ravel(), minlength=n * n).reshape(n, n)


def iou_from_confusion(cm: np.ndarray) -> np.ndarray:
    """IoU per class (nan where a class never occurs in truth or prediction)."""
    tp = np.diag(cm).astype(np.float64)
    denom = cm.sum(0) + cm.sum(1) - tp
    with np.errstate(invalid="ignore", divide="ignore"):
        return np.where(denom > 0, tp / denom, np.nan)


def category_confusion(cm: np.ndarray) -> np.ndarray:
    """Collapse a 13-class confusion matrix to the paper's 5 state categories."""
    m = np.zeros((N_CATEGORIES, NUM_CLASSES))
    m[CLASS_TO_CATEGORY[:NUM_CLASSES], np.arange(NUM_CLASSES)] = 1
    return m @ cm @ m.T


def presence_targets(labels: np.ndarray) -> np.ndarray:
    """Per-image class presence (B, 13) in {0, 1}: the Semantic Encoding loss targets."""
    flat = labels.reshape(len(labels), -1).astype(np.int64) + NUM_CLASSES * np.arange(len(labels))[:, None]
    counts = np.bincount(flat.ravel(), minlength=NUM_CLASSES * len(labels)).reshape(len(labels), NUM_CLASSES)
    return (counts > 0).astype(np.float32)


def class_weights(frames: Frames) -> np.ndarray:
    """ENet-style weights 1 / ln(1.02 + p_c) from the training labels' class frequencies."""
    counts = np.zeros(NUM_CLASSES)
    for _, labels in frames:
        counts += np.bincount(labels.ravel(), minlength=NUM_CLASSES)[:NUM_CLASSES]
    p = counts / counts.sum()
    return 1.0 / np.log(1.02 + p)


def _to_tensor(rgb: np.ndarray, mean: np.ndarray, std: np.ndarray) -> torch.Tensor:
    x = (rgb.astype(np.float32) / 255.0 - mean) / std
    return torch.from_numpy(np.ascontiguousarray(x.transpose(0, 3, 1, 2)))


def evaluate(net: SegNet, frames: Frames, mean: np.ndarray, std: np.ndarray, batch: int = 32) -> dict[str, Any]:
    """IoU per class and per category, and their means, on labelled frames."""
    net.eval()
    cm = np.zeros((NUM_CLASSES, NUM_CLASSES), np.int64)
    with torch.inference_mode():
        for i in range(0, len(frames), batch):
            rgb = np.stack([f[0] for f in frames[i : i + batch]])
            labels = np.stack([f[1] for f in frames[i : i + batch]])
            pred = net(_to_tensor(rgb, mean, std))[0].argmax(1).numpy()
            cm += confusion(pred, labels, NUM_CLASSES)
    per_class = iou_from_confusion(cm)
    per_cat = iou_from_confusion(category_confusion(cm))
    return {"miou_classes": float(np.nanmean(per_class)), "miou_categories": float(np.nanmean(per_cat)),
            "iou_classes": [None if np.isnan(v) else round(float(v), 6) for v in per_class],
            "iou_categories": dict(zip(CATEGORY_NAMES, [None if np.isnan(v) else round(float(v), 6) for v in per_cat],
                                       strict=True))}


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


def train_segnet(train: Frames, val_sets: dict[str, Frames], cfg: SegTrainConfig, out: Path,
                 progress: Callable[[dict], None] | None = None, resume: bool = False) -> dict[str, Any]:
    """Train on `train`, validate on each named set per epoch; best (first val set, category mIoU) -> segnet.pt."""
    out = Path(out)
    out.mkdir(parents=True, exist_ok=True)
    if len(train) < cfg.batch_size:
        raise BrlInputError(f"only {len(train)} training frames; need at least one batch of {cfg.batch_size}")
    torch.set_num_threads(cfg.threads)
    torch.use_deterministic_algorithms(True)
    torch.manual_seed(cfg.seed)
    h, w = train[0][1].shape
    rgb_all = np.stack([f[0] for f in train]).astype(np.float32) / 255.0
    mean = rgb_all.mean(axis=(0, 1, 2)).astype(np.float32)
    std = (rgb_all.std(axis=(0, 1, 2)) + 1e-6).astype(np.float32)
    del rgb_all
    weights = torch.tensor(class_weights(train), dtype=torch.float32)
    net = SegNet(SegNetConfig.from_dict(cfg.net))
    opt = torch.optim.SGD(net.parameters(), lr=cfg.lr, momentum=cfg.momentum, weight_decay=cfg.weight_decay)
    steps_per_epoch = len(train) // cfg.batch_size
    total = steps_per_epoch * cfg.epochs
    rng = np.random.default_rng(cfg.seed)
    start_epoch, best, history = 0, -math.inf, []
    meta = {"mean": mean.tolist(), "std": std.tolist(), "input_size": [h, w], "train_config": cfg.to_dict()}
    if resume and (out / "last.pt").exists():
        state = load_checkpoint(out / "last.pt")
        if state["extra"]["train_config"] != cfg.to_dict():
            raise BrlInputError(f"{out} was trained with other options; resume with the same options")
        net.load_state_dict(state["state_dict"])
        opt.load_state_dict(state["extra"]["optimizer"])
        torch.set_rng_state(state["extra"]["torch_rng"])
        rng.bit_generator.state = json.loads(state["extra"]["numpy_rng"])
        start_epoch, best = state["extra"]["epoch"], state["extra"]["best"]
        history = json.loads(state["extra"]["history"])
    labels_all = np.stack([f[1] for f in train])
    rgb_u8 = np.stack([f[0] for f in train])
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
            rgb, labels = _augment(rgb_u8[idx], labels_all[idx], rng, cfg)
            x = _to_tensor(rgb, mean, std)
            y = torch.from_numpy(labels.astype(np.int64))
            present = torch.from_numpy(presence_targets(labels))
            logits, aux, presence = net(x)
            loss = F.cross_entropy(logits, y, weight=weights)
            loss = loss + cfg.aux_weight * F.cross_entropy(aux, y, weight=weights)
            loss = loss + cfg.se_weight * F.binary_cross_entropy_with_logits(presence, present)
            opt.zero_grad()
            loss.backward()
            opt.step()
            losses.append(float(loss.detach()))
        record: dict[str, Any] = {"epoch": epoch + 1, "loss": float(np.mean(losses)),
                                  "wall_s": round(time.perf_counter() - t0, 1)}
        for name, frames in val_sets.items():
            record[name] = evaluate(net, frames, mean, std)
        history.append(record)
        score = record[next(iter(val_sets))]["miou_categories"] if val_sets else -record["loss"]
        extra = {**meta, "epoch": epoch + 1, "best": max(best, score), "history": json.dumps(history),
                 "optimizer": opt.state_dict(), "torch_rng": torch.get_rng_state(),
                 "numpy_rng": json.dumps(rng.bit_generator.state)}
        if score > best:
            best = score
            save_checkpoint(out / "segnet.pt", net, {**meta, "epoch": epoch + 1, "metrics": json.dumps(record)})
        save_checkpoint(out / "last.pt", net, extra)
        atomic_write_bytes(out / "metrics.jsonl", "".join(json.dumps(r, sort_keys=True) + "\n"
                                                         for r in history).encode())
        if progress:
            progress(record)
    return {"epochs": len(history), "best": best, "history": history}
