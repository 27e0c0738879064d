"""Conditional imitation learning (CIL, Codevilla et al., ICRA 2018), branched architecture, sized for a CPU.

A small CNN reads the forward RGB camera (downscaled with cv2.INTER_AREA), a small MLP reads the measured speed,
a joint layer mixes both, and one output branch per high-level route command (follow lane, left, right, straight)
predicts (steer, throttle, brake); an auxiliary head predicts the speed from the image features (CILRS-style).
The loss is the weighted MSE of the branch of each frame's command only (steer 0.5, throttle 0.45, brake 0.05),
plus `speed_weight` times the speed MSE.

Training data are `brl collect` bags. The target is the autopilot's clean control (`expert_control`), not the
noisy applied one. `brl collect` computes the control from the previous simulated frame and stores it with the
frame it produced, so a frame's own expert control lags its image by one simulation step (0.1 s). Where the next
recorded frame of the same bag is exactly one step later (`--every 1`), its stored expert control is the one
computed on this frame's measurements, and that is the target paired with the image ("exact"); otherwise
(`--every N`, N > 1) the frame's own expert control is used ("lag-0.1s"). `metrics.jsonl` / the summary count both.

Files in `out/`: `config.json` (resolved options with provenance), `metrics.jsonl` (one line per epoch), `il.pt`
(best by validation loss) and `last.pt` (weights, optimizer, epoch, RNG states: the resume point); all written
atomically and read back with `torch.load(weights_only=True)`.
"""

from __future__ import annotations

import hashlib
import json
import math
import time
from collections.abc import Callable, Sequence
from dataclasses import asdict, dataclass, field, replace
from pathlib import Path
from typing import Any

import cv2
import numpy as np
import torch
from torch import nn

from brlcli.config import check_known_keys
from brlcli.devices import check_device_name, prepare_cuda_determinism, resolve_device, to_device_tensor
from brlcli.errors import BrlInputError
from brlcli.outdir import refuse_existing
from brlcli.provenance import atomic_write_bytes, atomic_write_json, provenance
from brlcli.segnet import check_input_source
from brlcli.sim.roadnet import BRANCH_COMMANDS, BRANCH_NAMES, command_branch
from brlcli.sim.vehicle import Control
from brlcli.torchfiles import load_torch_doc, save_torch_doc

IL_FORMAT = "brl-il"
IL_FORMAT_VERSION = 1
DEFAULT_IL_MODEL = "il/il.pt"
OUTPUT_NAMES = ("steer", "throttle", "brake")
SPEED_SCALE_KMH = 40.0
"""Speeds enter (and the auxiliary head predicts) speed_kmh / SPEED_SCALE_KMH."""
FRAME_DT_NS = 100_000_000


def default_il_path() -> Path:
    """The shipped IL model (`models/il/il.pt` in a checkout; env `BRL_MODELS_DIR` overrides the directory)."""
    from brlcli.models import models_dir

    return models_dir() / DEFAULT_IL_MODEL


# ---------------------------------------------------------------------------------------------------------- model


@dataclass(frozen=True)
class ILNetConfig:
    """Architecture: conv widths (each stage: a stride-2 conv then a stride-1 conv), feature sizes, branches."""

    widths: tuple[int, ...] = (24, 32, 64, 96)
    image_features: int = 256
    speed_features: int = 64
    joint_features: int = 256
    branch_hidden: int = 128
    dropout: float = 0.3
    input_height: int = 44
    input_width: int = 100

    def to_dict(self) -> dict[str, Any]:
        """Plain-data form (stored in checkpoints)."""
        d = asdict(self)
        d["widths"] = list(self.widths)
        return d

    @classmethod
    def from_dict(cls, d: dict[str, Any]) -> ILNetConfig:
        """Inverse of `to_dict`."""
        d = dict(d)
        d["widths"] = tuple(d["widths"])
        return cls(**d)


def _conv(cin: int, cout: int, k: int, stride: int) -> nn.Sequential:
    return nn.Sequential(nn.Conv2d(cin, cout, k, stride, k // 2, bias=False), nn.BatchNorm2d(cout),
                         nn.ReLU(inplace=True))


class ILNet(nn.Module):
    """Branched CIL network: image CNN + speed MLP -> joint layer -> one (steer, throttle, brake) head per command."""

    def __init__(self, cfg: ILNetConfig) -> None:
        super().__init__()
        self.cfg = cfg
        layers: list[nn.Module] = []
        cin = 3
        for i, w in enumerate(cfg.widths):
            layers += [_conv(cin, w, 5 if i == 0 else 3, 2), _conv(w, w, 3, 1)]
            cin = w
        self.conv = nn.Sequential(*layers)
        with torch.no_grad():
            n_flat = self.conv(torch.zeros(1, 3, cfg.input_height, cfg.input_width)).numel()
        self.image_fc = nn.Sequential(nn.Flatten(), nn.Linear(n_flat, cfg.image_features), nn.ReLU(inplace=True),
                                      nn.Dropout(cfg.dropout))
        self.speed_fc = nn.Sequential(nn.Linear(1, cfg.speed_features), nn.ReLU(inplace=True),
                                      nn.Linear(cfg.speed_features, cfg.speed_features), nn.ReLU(inplace=True))
        self.joint = nn.Sequential(nn.Linear(cfg.image_features + cfg.speed_features, cfg.joint_features),
                                   nn.ReLU(inplace=True), nn.Dropout(cfg.dropout))
        self.branches = nn.ModuleList(
            nn.Sequential(nn.Linear(cfg.joint_features, cfg.branch_hidden), nn.ReLU(inplace=True),
                          nn.Linear(cfg.branch_hidden, len(OUTPUT_NAMES)))
            for _ in BRANCH_COMMANDS)
        self.speed_head = nn.Sequential(nn.Linear(cfg.image_features, cfg.branch_hidden), nn.ReLU(inplace=True),
                                        nn.Linear(cfg.branch_hidden, 1))

    def forward(self, image: torch.Tensor, speed: torch.Tensor) -> tuple[torch.Tensor, torch.Tensor]:
        """(B, 3, H, W) normalised image, (B, 1) scaled speed -> all branches (B, 4, 3), predicted speed (B, 1)."""
        f = self.image_fc(self.conv(image))
        j = self.joint(torch.cat([f, self.speed_fc(speed)], dim=1))
        return torch.stack([b(j) for b in self.branches], dim=1), self.speed_head(f)


def select_branch(outputs: torch.Tensor, branch: torch.Tensor) -> torch.Tensor:
    """(B, 4, 3) branch outputs, (B,) branch indices -> (B, 3) outputs of each sample's branch."""
    return outputs[torch.arange(len(branch)), branch]


# ------------------------------------------------------------------------------------------------------ files


def save_il(path: Path, net: ILNet, extra: dict[str, Any]) -> None:
    """Write weights, architecture and `extra` (plain data and tensors only) atomically."""
    save_torch_doc(path, IL_FORMAT, IL_FORMAT_VERSION, {"arch": net.cfg.to_dict(), "branches": list(BRANCH_NAMES),
                                                       "outputs": list(OUTPUT_NAMES),
                                                       "state_dict": {k: v.cpu() for k, v in net.state_dict().items()},
                                                       "extra": extra})


def load_il_checkpoint(path: Path) -> dict[str, Any]:
    """Read an IL model file (never unpickling objects) and check its format and version."""
    doc = load_torch_doc(path, IL_FORMAT, IL_FORMAT_VERSION, "IL model", "brl train-il",
                         ("arch", "state_dict", "extra", "branches", "outputs"))
    if list(doc["branches"]) != list(BRANCH_NAMES) or list(doc["outputs"]) != list(OUTPUT_NAMES):
        raise BrlInputError(f"IL model {path} has other branches or outputs than brl's CIL net")
    return doc


def load_il(path: Path) -> tuple[ILNet, dict[str, Any]]:
    """The net in eval mode and its metadata (normalisation, input size, training summary)."""
    doc = load_il_checkpoint(path)
    try:
        net = ILNet(ILNetConfig.from_dict(doc["arch"]))
        net.load_state_dict(doc["state_dict"])
    except (TypeError, KeyError, RuntimeError, ValueError) as exc:
        raise BrlInputError(f"IL model {path} does not match its architecture: {exc}".splitlines()[0]) from None
    extra = doc["extra"]
    for key in ("mean", "std"):
        if key not in extra:
            raise BrlInputError(f"IL model {path} lacks '{key}'")
    return net.eval(), extra


# ------------------------------------------------------------------------------------------------------- data


@dataclass
class ILData:
    """Frames in memory: downscaled RGB (N, H, W, 3) uint8, speed km/h, command branch, target (N, 3), bag index."""

    rgb: np.ndarray
    speed_kmh: np.ndarray
    branch: np.ndarray
    target: np.ndarray
    bag: np.ndarray
    bags: list[str]
    exact_pairs: int = 0
    lagged_pairs: int = 0

    def __len__(self) -> int:
        return len(self.rgb)

    def take(self, mask: np.ndarray) -> ILData:
        """The frames where `mask` is true."""
        return ILData(self.rgb[mask], self.speed_kmh[mask], self.branch[mask], self.target[mask], self.bag[mask],
                      self.bags, int(self.exact_pairs), int(self.lagged_pairs))


def downscale(rgb: np.ndarray, height: int, width: int) -> np.ndarray:
    """(H, W, 3) uint8 camera image -> (height, width, 3) with cv2.INTER_AREA (no-op at the same size)."""
    if rgb.shape[:2] == (height, width):
        return np.ascontiguousarray(rgb)
    return cv2.resize(rgb, (width, height), interpolation=cv2.INTER_AREA)


def load_frames(bags: Sequence[str | Path], height: int, width: int) -> ILData:
    """Read bags into memory, pairing each image with the expert control computed on its own measurements."""
    from brlcli.bags import find_bags, iter_frames

    paths = [str(p) for p in find_bags(list(bags))]
    rgb, speed, cmd, target, bag_idx, ts = [], [], [], [], [], []
    index = {p: i for i, p in enumerate(paths)}
    for f in iter_frames(paths, need_labels=False):
        if f.rgb is None or f.measurements is None or f.expert_control is None or f.command is None:
            raise BrlInputError(f"bag {f.bag} lacks RGB, measurements or control messages; record it with brl collect")
        rgb.append(downscale(f.rgb, height, width))
        speed.append(f.measurements.forward_speed_kmh)
        cmd.append(f.command)
        e = f.expert_control
        target.append((e.steer, e.throttle, e.brake))
        bag_idx.append(index[f.bag])
        ts.append(f.timestamp_ns)
    if not rgb:
        raise BrlInputError("the given bags hold no frames")
    tgt = np.asarray(target, np.float32)
    b, t = np.asarray(bag_idx), np.asarray(ts, np.int64)
    # exact pairing where the next frame of the same bag is one simulation step later (recorded with --every 1)
    nxt = np.zeros(len(t), bool)
    nxt[:-1] = (b[1:] == b[:-1]) & (np.abs(t[1:] - t[:-1] - FRAME_DT_NS) < FRAME_DT_NS // 10)
    paired = tgt.copy()
    paired[:-1][nxt[:-1]] = tgt[1:][nxt[:-1]]
    return ILData(np.stack(rgb), np.asarray(speed, np.float32), command_branch(np.asarray(cmd)), paired, b, paths,
                  exact_pairs=int(nxt.sum()), lagged_pairs=int(len(t) - nxt.sum()))


def _to_tensor(rgb: np.ndarray, mean: np.ndarray, std: np.ndarray) -> torch.Tensor:
    x = (rgb.astype(np.float32) / 255.0 - mean) / std
    return torch.from_numpy(np.ascontiguousarray(x.transpose(0, 3, 1, 2)))


def _speed_tensor(speed_kmh: np.ndarray) -> torch.Tensor:
    return torch.from_numpy(np.asarray(speed_kmh, np.float32).reshape(-1, 1) / SPEED_SCALE_KMH)


def augment_on_device(rgb_u8: torch.Tensor, gen: torch.Generator, jitter: float) -> torch.Tensor:
    """`_augment` on a device's uint8 images (N, H, W, 3): the same jitter, drawn from the device's generator."""
    x = rgb_u8.float()
    if jitter <= 0:
        return x
    n, dev = x.shape[0], x.device

    def uniform(low: float, high: float, *shape: int) -> torch.Tensor:
        return torch.empty(shape, device=dev).uniform_(low, high, generator=gen)

    mean = x.mean(dim=(1, 2, 3), keepdim=True)
    contrast = uniform(1 - jitter, 1 + jitter, n, 1, 1, 1)
    gain = uniform(1 - jitter, 1 + jitter, n, 1, 1, 1) * uniform(1 - jitter / 2, 1 + jitter / 2, n, 1, 1, 3)
    return (((x - mean) * contrast + mean).clamp(0, 255) * gain).clamp(0, 255)


def _augment(rgb: np.ndarray, rng: np.random.Generator, jitter: float) -> np.ndarray:
    """Per-image brightness, contrast and per-channel gain (seeded, batched)."""
    x = rgb.astype(np.float32)
    if jitter <= 0:
        return x
    n = len(x)
    mean = x.mean(axis=(1, 2, 3), keepdims=True)
    contrast = rng.uniform(1 - jitter, 1 + jitter, size=(n, 1, 1, 1))
    gain = rng.uniform(1 - jitter, 1 + jitter, size=(n, 1, 1, 1)) * rng.uniform(1 - jitter / 2, 1 + jitter / 2,
                                                                             size=(n, 1, 1, 3))
    return np.clip(np.clip((x - mean) * contrast + mean, 0, 255) * gain, 0, 255)


# --------------------------------------------------------------------------------------------------- training


@dataclass(frozen=True)
class ILTrainConfig:
    """Training options (defaults: the shipped model's recipe)."""

    epochs: int = 5
    batch_size: int = 64
    lr: float = 1e-3
    weight_decay: float = 1e-5
    seed: int = 0
    threads: int = 2
    val_fraction: float = 0.1
    loss_weights: tuple[float, float, float] = (0.5, 0.45, 0.05)
    speed_weight: float = 0.05
    colour_jitter: float = 0.2
    net: dict[str, Any] = field(default_factory=lambda: ILNetConfig().to_dict())
    device: str = "cpu"  # cpu (bit-identical to brl before devices), cuda or cuda:N, auto (brlcli.devices)

    def __post_init__(self) -> None:
        check_device_name(self.device, "--device")
        if self.epochs < 1 or self.batch_size < 4:
            raise BrlInputError("--epochs must be >= 1 and --batch-size >= 4 (BatchNorm needs batches)")
        if self.threads < 1:
            raise BrlInputError("--workers must be at least 1")
        if not 0.0 <= self.val_fraction < 1.0:
            raise BrlInputError("--val-fraction must be in [0, 1)")
        if self.lr <= 0:
            raise BrlInputError("--lr must be positive")
        if self.seed < 0:
            raise BrlInputError(f"--seed must be >= 0, got {self.seed}")

    def to_dict(self) -> dict[str, Any]:
        """JSON-ready form."""
        d = asdict(self)
        d["loss_weights"] = list(self.loss_weights)
        return d

    @classmethod
    def from_dict(cls, d: dict[str, Any]) -> ILTrainConfig:
        """Inverse of `to_dict`; unknown keys are an error."""
        check_known_keys(cls, d, "imitation-learning")
        d = dict(d)
        if "loss_weights" in d:
            d["loss_weights"] = tuple(d["loss_weights"])
        return cls(**d)


def _losses(net: ILNet, x: torch.Tensor, speed: torch.Tensor, branch: torch.Tensor, target: torch.Tensor,
            weights: torch.Tensor) -> tuple[torch.Tensor, torch.Tensor]:
    """Per-output MSE (3,) on each frame's branch, speed MSE ()."""
    out, speed_pred = net(x, speed)
    err = (select_branch(out, branch) - target) ** 2
    return err.mean(0), ((speed_pred - speed) ** 2).mean()


def evaluate_il(net: ILNet, data: ILData, mean: np.ndarray, std: np.ndarray, cfg: ILTrainConfig,
                batch: int = 256, device: str = "cpu") -> dict[str, float]:
    """Validation losses: weighted total, MSE per output, speed MSE, steer MAE, and the loss per branch (the net on
    `device`)."""
    net.eval()
    w = torch.tensor(cfg.loss_weights, dtype=torch.float32)
    sq = np.zeros((len(data), 3))
    abs_steer = np.zeros(len(data))
    speed_sq = 0.0
    with torch.inference_mode():
        for i in range(0, len(data), batch):
            sl = slice(i, i + batch)
            out, sp = net(_to_tensor(data.rgb[sl], mean, std).to(device), _speed_tensor(data.speed_kmh[sl]).to(device))
            out, sp = out.cpu(), sp.cpu()
            pred = select_branch(out, torch.from_numpy(data.branch[sl])).numpy()
            sq[sl] = (pred - data.target[sl]) ** 2
            abs_steer[sl] = np.abs(pred[:, 0] - data.target[sl, 0])
            speed_sq += float(((sp[:, 0].numpy() - data.speed_kmh[sl] / SPEED_SCALE_KMH) ** 2).sum())
    mse = sq.mean(0)
    rec: dict[str, float] = {"loss": float(mse @ w.numpy() + cfg.speed_weight * speed_sq / len(data)),
                             **{f"mse_{n}": float(v) for n, v in zip(OUTPUT_NAMES, mse, strict=True)},
                             "mse_speed": speed_sq / len(data), "mae_steer": float(abs_steer.mean())}
    for i, name in enumerate(BRANCH_NAMES):
        sel = data.branch == i
        if sel.any():
            rec[f"loss_{name}"] = float(sq[sel].mean(0) @ w.numpy())
    return rec


def _split(data: ILData, fraction: float, seed: int) -> tuple[ILData, ILData | None]:
    """Hold out whole bags (consecutive frames are correlated): round(fraction * bags), at least one if any."""
    n = len(data.bags)
    if fraction <= 0 or n < 2:
        return data, None
    n_val = min(max(1, round(fraction * n)), n - 1)
    val_bags = np.random.default_rng([seed, 7]).permutation(n)[:n_val]
    mask = np.isin(data.bag, val_bags)
    return data.take(~mask), data.take(mask)


def _data_digest(bags: Sequence[str]) -> str:
    return hashlib.sha256("\n".join(Path(b).resolve().as_posix() for b in bags).encode()).hexdigest()[:16]


def train_il(cfg: ILTrainConfig, data: list[str], out: Path, val: list[str] | None = None, resume: bool = False,
             progress: Callable[[dict], None] | None = None) -> dict[str, Any]:
    """Train the branched CIL net on bags; best (validation loss) -> out/il.pt, resume point -> out/last.pt."""
    out = Path(out)
    cfg = replace(cfg, device=resolve_device(cfg.device))  # recorded as the device it runs on
    net_cfg = ILNetConfig.from_dict(cfg.net)
    h, w = net_cfg.input_height, net_cfg.input_width
    all_train = load_frames(data, h, w)
    if val:
        train, val_data = all_train, load_frames(val, h, w)
    else:
        train, val_data = _split(all_train, cfg.val_fraction, cfg.seed)
    if len(train) < cfg.batch_size:
        raise BrlInputError(f"only {len(train)} training frames; need at least one batch of {cfg.batch_size}")
    config = {**cfg.to_dict(), "data": [str(d) for d in data], "val": [str(v) for v in val or []]}
    if (out / "config.json").exists():
        refuse_existing(out, "an imitation-learning run", resume)
    out.mkdir(parents=True, exist_ok=True)
    if not (resume and (out / "last.pt").exists()):
        atomic_write_json(out / "config.json", provenance(config, kind="train-il"))
    device = cfg.device
    torch.set_num_threads(cfg.threads)
    if device == "cpu":
        torch.use_deterministic_algorithms(True)
    else:
        prepare_cuda_determinism()
    torch.manual_seed(cfg.seed)  # CUDA's generators too
    rgb01 = train.rgb.reshape(-1, 3).astype(np.float32) / 255.0
    mean = rgb01.mean(0).astype(np.float32)
    std = (rgb01.std(0) + 1e-6).astype(np.float32)
    del rgb01
    net = ILNet(net_cfg).to(device)
    opt = torch.optim.Adam(net.parameters(), lr=cfg.lr, weight_decay=cfg.weight_decay)
    weights = torch.tensor(cfg.loss_weights, dtype=torch.float32).to(device)
    gen = None if device == "cpu" else torch.Generator(device).manual_seed(cfg.seed)  # the device's augmentation
    steps_per_epoch = len(train) // cfg.batch_size
    total = steps_per_epoch * cfg.epochs
    rng = np.random.default_rng(cfg.seed)
    digest = _data_digest(train.bags + (val_data.bags if val_data is not None and val else []))
    meta = {"mean": mean.tolist(), "std": std.tolist(), "input_size": [h, w], "speed_scale_kmh": SPEED_SCALE_KMH,
            "train_config": cfg.to_dict(), "data_digest": digest, "train_frames": len(train),
            "val_frames": len(val_data) if val_data is not None else 0,
            "exact_pairs": all_train.exact_pairs, "lagged_pairs": all_train.lagged_pairs}
    start_epoch, best, history = 0, math.inf, []
    if resume and (out / "last.pt").exists():
        state = load_il_checkpoint(out / "last.pt")
        ex = state["extra"]
        if {"device": "cpu", **ex.get("train_config", {})} != cfg.to_dict() or ex.get("data_digest") != digest:
            raise BrlInputError(f"{out} was trained with other options or data; resume with the same ones")
        net.load_state_dict(state["state_dict"])
        opt.load_state_dict(ex["optimizer"])
        torch.set_rng_state(ex["torch_rng"])
        rng.bit_generator.state = json.loads(ex["numpy_rng"])
        if gen is not None:
            gen.set_state(ex["device_rng"])
            torch.cuda.set_rng_state(ex["cuda_rng"], torch.device(device))
        start_epoch, best = ex["epoch"], ex["best"]
        history = json.loads(ex["history"])
    x_speed = train.speed_kmh
    if gen is not None:  # resident on the GPU when it fits (pinned host memory otherwise)
        dev_rgb = to_device_tensor(train.rgb, device)
        dev_speed = to_device_tensor(np.asarray(x_speed, np.float32).reshape(-1, 1) / SPEED_SCALE_KMH, device)
        dev_branch, dev_target = to_device_tensor(train.branch, device), to_device_tensor(train.target, device)
        mean_t, std_t = torch.from_numpy(mean).to(device), torch.from_numpy(std).to(device)
    t0 = time.perf_counter()
    for epoch in range(start_epoch, cfg.epochs):
        net.train()
        order = rng.permutation(len(train))
        sums = np.zeros(4)
        device_sums = None if gen is None else torch.zeros(4, dtype=torch.float64, device=device)
        for b in range(steps_per_epoch):
            it = epoch * steps_per_epoch + b
            for g in opt.param_groups:  # cosine decay to 5 % over all iterations
                g["lr"] = cfg.lr * (0.05 + 0.95 * 0.5 * (1 + math.cos(math.pi * it / total)))
            idx = np.sort(order[b * cfg.batch_size : (b + 1) * cfg.batch_size])
            if gen is None:
                x = _to_tensor(_augment(train.rgb[idx], rng, cfg.colour_jitter), mean, std)
                mse, speed_mse = _losses(net, x, _speed_tensor(x_speed[idx]), torch.from_numpy(train.branch[idx]),
                                         torch.from_numpy(train.target[idx]), weights)
            else:
                rgb, speed, branch, target = (_rows_on(t, idx, device) for t in (dev_rgb, dev_speed, dev_branch,
                                                                                  dev_target))
                x = ((augment_on_device(rgb, gen, cfg.colour_jitter) / 255.0 - mean_t) / std_t).permute(0, 3, 1, 2)
                mse, speed_mse = _losses(net, x.contiguous(), speed, branch, target, weights)
            loss = mse @ weights + cfg.speed_weight * speed_mse
            opt.zero_grad()
            loss.backward()
            opt.step()
            if gen is None:
                sums += np.array([float(loss.detach()), *mse.detach().numpy()])
            else:  # summed on the GPU: no sync per step
                device_sums += torch.cat([loss.detach()[None], mse.detach()]).double()
        if gen is not None:
            sums = device_sums.cpu().numpy()
        mean_train = sums / steps_per_epoch
        record: dict[str, Any] = {"epoch": epoch + 1, "train_loss": float(mean_train[0]),
                                  **{f"train_mse_{n}": float(v) for n, v in zip(OUTPUT_NAMES, mean_train[1:],
                                                                                strict=True)},
                                  "wall_s": round(time.perf_counter() - t0, 1)}
        if val_data is not None and len(val_data):
            record["val"] = evaluate_il(net, val_data, mean, std, cfg, device=device)
        history.append(record)
        score = record["val"]["loss"] if "val" in record else record["train_loss"]
        if score < best:
            best = score
            save_il(out / "il.pt", net, {**meta, "epoch": epoch + 1, "metrics": json.dumps(record)})
        resume_point = {**meta, "epoch": epoch + 1, "best": best, "history": json.dumps(history),
                        "optimizer": opt.state_dict(), "torch_rng": torch.get_rng_state(),
                        "numpy_rng": json.dumps(rng.bit_generator.state)}
        if gen is not None:
            resume_point.update(device_rng=gen.get_state(), cuda_rng=torch.cuda.get_rng_state(torch.device(device)))
        save_il(out / "last.pt", net, resume_point)
        atomic_write_bytes(out / "metrics.jsonl", "".join(json.dumps(r, sort_keys=True) + "\n"
                                                         for r in history).encode())
        if progress:
            progress(record)
    return {"epochs": len(history), "best_val_loss": best, "train_frames": len(train),
            "val_frames": meta["val_frames"], "exact_pairs": all_train.exact_pairs,
            "lagged_pairs": all_train.lagged_pairs, "history": history, "model": str(out / "il.pt")}


def _rows_on(t: torch.Tensor, idx: np.ndarray, device: str) -> torch.Tensor:
    """Rows `idx` of a resident (or pinned host) tensor, on `device`."""
    rows = t[torch.from_numpy(idx).to(t.device)]
    return rows if rows.device.type != "cpu" else rows.pin_memory().to(device, non_blocking=True)


# ----------------------------------------------------------------------------------------------------- policy


class ILPolicy:
    """The CIL baseline on the bench: reads the forward RGB camera, the speed and the route command.

    `deploy` is accepted for symmetry with the BRL agents (gt | estimated) but changes nothing: IL drives from the
    raw RGB image in either setting (it never reads label images, so `segnet` is ignored too).
    """

    frames_per_decision = 1
    needs_camera = True
    setting = "IL"

    def __init__(self, name: str = "il", model: str | None = None, deploy: str = "gt",
                 segnet: str | None = None) -> None:
        check_input_source(deploy)
        self.name = name
        path = Path(model) if model else default_il_path()
        if path.is_dir():
            path = path / "il.pt"
        self.model_path = path
        self.net, extra = load_il(path)
        self.mean = np.asarray(extra["mean"], np.float32)
        self.std = np.asarray(extra["std"], np.float32)
        self.height, self.width = self.net.cfg.input_height, self.net.cfg.input_width

    def reset(self, spec: Any, world: Any) -> None:
        """Feed-forward policy: nothing to reset."""

    def predict(self, rgb: np.ndarray, speed_kmh: float, command: int) -> tuple[float, float, float]:
        """Raw (steer, throttle, brake) of the command's branch for one camera image."""
        x = _to_tensor(downscale(rgb, self.height, self.width)[None], self.mean, self.std)
        with torch.inference_mode():
            out, _ = self.net(x, _speed_tensor(np.array([speed_kmh])))
        steer, throttle, brake = out[0, int(command_branch(command))].tolist()
        return steer, throttle, brake

    def decide(self, obs: Any) -> Control:
        """Control from the camera image, speed and command (CIL's post-processing of brake, then clipped)."""
        if obs.rgb is None:
            raise BrlInputError("the IL policy needs the RGB camera")
        steer, throttle, brake = self.predict(obs.rgb, obs.measurements.forward_speed_kmh, obs.command)
        if brake < 0.1 or throttle > brake:  # as in CIL's agent: no brake unless it dominates
            brake = 0.0
        return Control(steer=steer, throttle=throttle, brake=brake).clipped()
