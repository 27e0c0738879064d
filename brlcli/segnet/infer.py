"""Batch-1 CPU inference of the segmentation net inside the simulation loop.

The deployed function is the whole path from the camera's uint8 RGB image to uint8 CARLA labels: normalisation,
the net, the file's calibration (per-class logit offsets) and the argmax. It runs on ONNX Runtime: the net is
exported from its torch weights in memory when the file is loaded (once per process and file), and ONNX Runtime
fuses BatchNorm into the convolutions, keeps the features in its blocked layout and runs the dilated convolutions
on its fast kernels: about 3x the frames per second of torch's eager mode at batch 1 on one core
(`benchmarks/bench_segnet.py`). `backend="torch"` runs the same function in torch (the reference).
"""

from __future__ import annotations

import io
import warnings
from pathlib import Path
from typing import Any

import numpy as np
import torch
from torch import nn

from brlcli.errors import BrlInputError
from brlcli.models import default_segnet_path
from brlcli.segnet.io import load_segnet
from brlcli.segnet.model import SegNet

BACKENDS = ("onnxruntime", "torch")


def normalise(rgb: np.ndarray, mean: np.ndarray, std: np.ndarray) -> torch.Tensor:
    """uint8 or float RGB images (N, H, W, 3) in 0..255 -> the net's input tensor (N, 3, H, W)."""
    x = (np.asarray(rgb, np.float32) / 255.0 - mean) / std
    return torch.from_numpy(np.ascontiguousarray(x.transpose(0, 3, 1, 2)))


def batch_logits(net: SegNet, rgb: np.ndarray, mean: np.ndarray, std: np.ndarray, batch: int = 32,
                 device: str = "cpu") -> np.ndarray:
    """Class logits (N, 13, H, W) float32 of RGB images (N, H, W, 3), in batches (evaluation, calibration), on
    `device` (the net is moved there; on CUDA the images are normalised there too)."""
    net.eval()
    out = np.empty((len(rgb), net.cfg.num_classes, *rgb.shape[1:3]), np.float32)
    with torch.inference_mode():
        if device == "cpu":
            for i in range(0, len(rgb), batch):
                out[i : i + batch] = net(normalise(rgb[i : i + batch], mean, std))[0].numpy()
            return out
        net.to(device)
        mean_t = torch.as_tensor(mean, dtype=torch.float32, device=device)
        std_t = torch.as_tensor(std, dtype=torch.float32, device=device)
        for i in range(0, len(rgb), batch):
            x = torch.from_numpy(np.ascontiguousarray(rgb[i : i + batch])).to(device, non_blocking=True)
            out[i : i + batch] = net(normalise_on_device(x, mean_t, std_t))[0].float().cpu().numpy()
    return out


def normalise_on_device(rgb: torch.Tensor, mean: torch.Tensor, std: torch.Tensor) -> torch.Tensor:
    """RGB images (N, H, W, 3) in 0..255 on a device -> the net's input (N, 3, H, W) there (as `normalise`)."""
    return ((rgb.float() / 255.0 - mean) / std).permute(0, 3, 1, 2).contiguous()


class LabelNet(nn.Module):
    """uint8 RGB (1, H, W, 3) -> uint8 labels (1, H, W): normalisation, net, logit offsets, argmax in one graph."""

    def __init__(self, net: SegNet, mean: list[float], std: list[float], offsets: np.ndarray | None) -> None:
        super().__init__()
        self.net = net.eval()
        self.register_buffer("mean", torch.tensor(mean, dtype=torch.float32).view(1, 3, 1, 1) * 255.0)
        self.register_buffer("inv_std", 1.0 / (torch.tensor(std, dtype=torch.float32).view(1, 3, 1, 1) * 255.0))
        zeros = np.zeros(net.cfg.num_classes)
        self.register_buffer("offsets", torch.tensor(zeros if offsets is None else offsets,
                                                     dtype=torch.float32).view(1, -1, 1, 1))

    def forward(self, rgb: torch.Tensor) -> torch.Tensor:
        """Labels of one image."""
        x = (rgb.permute(0, 3, 1, 2).float() - self.mean) * self.inv_std
        return (self.net(x)[0] + self.offsets).argmax(1).to(torch.uint8)


def _onnx_session(model: LabelNet, size: tuple[int, int], threads: int) -> Any:
    import onnxruntime as ort

    buf = io.BytesIO()
    example = torch.zeros((1, *size, 3), dtype=torch.uint8)
    with warnings.catch_warnings(), torch.inference_mode(False):
        warnings.simplefilter("ignore")
        torch.onnx.export(model, (example,), buf, dynamo=False, opset_version=17, input_names=["rgb"],
                          output_names=["labels"])
    opts = ort.SessionOptions()
    opts.intra_op_num_threads = threads
    opts.inter_op_num_threads = 1
    opts.execution_mode = ort.ExecutionMode.ORT_SEQUENTIAL
    opts.graph_optimization_level = ort.GraphOptimizationLevel.ORT_ENABLE_ALL
    opts.log_severity_level = 3
    return ort.InferenceSession(buf.getvalue(), opts, providers=["CPUExecutionProvider"])


class Segmenter:
    """RGB uint8 (H, W, 3) -> estimated label image uint8 (H, W) in CARLA ids, calibrated if the file is."""

    def __init__(self, path: str | Path | None = None, threads: int = 1, backend: str = "onnxruntime") -> None:
        if backend not in BACKENDS:
            raise BrlInputError(f"segmentation backend must be {' or '.join(BACKENDS)}, not '{backend}'")
        self.path = Path(path) if path else default_segnet_path()
        net, meta = load_segnet(self.path)
        self.input_size = tuple(meta["input_size"])
        self.offsets = meta["logit_offsets"]
        self.calibrated = self.offsets is not None
        self.backend = backend
        self._model = LabelNet(net, meta["mean"], meta["std"], self.offsets)
        if backend == "onnxruntime":
            self._session = _onnx_session(self._model, self.input_size, threads)
        else:
            self._threads = threads

    def predict(self, rgb: np.ndarray) -> np.ndarray:
        """Estimated labels of one image (must have the net's input size)."""
        if rgb.shape[:2] != self.input_size:
            raise BrlInputError(f"the segmentation net {self.path} expects {self.input_size[1]}x{self.input_size[0]} "
                                f"images, the camera gives {rgb.shape[1]}x{rgb.shape[0]}")
        x = np.ascontiguousarray(rgb, dtype=np.uint8)[None]
        if self.backend == "onnxruntime":
            return self._session.run(None, {"rgb": x})[0][0]
        torch.set_num_threads(self._threads)
        with torch.inference_mode():
            return self._model(torch.from_numpy(x))[0].numpy()


_CACHE: dict[tuple[str, int, int, str], Segmenter] = {}


def load_segmenter(path: str | Path | None = None, backend: str = "onnxruntime") -> Segmenter:
    """The segmenter of a file, built once per process (keyed by path, size and modification time)."""
    p = Path(path) if path else default_segnet_path()
    try:
        st = p.resolve().stat()
        key = (str(p.resolve()), st.st_size, st.st_mtime_ns, backend)
    except OSError:
        return Segmenter(p, backend=backend)  # the loader gives the one-line error
    if key not in _CACHE:
        _CACHE[key] = Segmenter(p, backend=backend)
    return _CACHE[key]


def uncalibrated_notice(path: str | Path | None = None) -> str | None:
    """A one-line notice if the net's file carries no calibration (a brl 0.1 file), else None."""
    seg = load_segmenter(path)
    if seg.calibrated:
        return None
    return (f"segmentation net {seg.path} is uncalibrated (format 1): its states are biased; calibrate it with "
            f"brl calibrate-seg --segnet {seg.path} --data BAGS --out FILE")
