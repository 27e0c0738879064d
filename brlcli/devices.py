"""Where torch models train and infer: `--device auto|cpu|cuda[:N]` (issue 36).

The CPU is the default and its results are bit-identical to brl's before devices existed. On CUDA, brl keeps the
data on the device when it fits (pinned host memory and asynchronous copies otherwise), augments and normalises
there, and asks torch for deterministic algorithms where it has them (`warn_only`: a few CUDA kernels, e.g. the
weighted 2-D cross-entropy and bilinear upsampling's backward pass, have none), so a CUDA run is repeatable on one
machine as far as torch allows, not bit-identical to a CPU run (docs/performance.md, GPU).
"""

from __future__ import annotations

import os
import warnings
from typing import Any

from brlcli.errors import BrlInputError

DEVICE_CHOICES = ("auto", "cpu", "cuda")
"""What `--device` takes (and `cuda:N` for the N-th GPU)."""
DEVICE_FRACTION = 0.5
"""Share of the GPU's free memory the training data may take to stay resident there."""


def resolve_device(name: str) -> str:
    """`auto` -> `cuda` when torch sees a GPU, else `cpu`; `cpu`, `cuda`, `cuda:N` checked; one-line errors."""
    import torch

    name = str(name).strip().lower()
    if name == "auto":
        return "cuda" if torch.cuda.is_available() else "cpu"
    if name == "cpu":
        return "cpu"
    if name == "cuda" or name.startswith("cuda:"):
        index = name.partition(":")[2]
        if index and not index.isdigit():
            raise BrlInputError(f"--device '{name}' is not a device; use auto, cpu, cuda or cuda:N")
        if not torch.cuda.is_available():
            why = "this torch is built without CUDA" if torch.version.cuda is None else "torch sees no GPU"
            raise BrlInputError(f"--device {name}: {why}; use --device cpu (or auto)")
        if index and int(index) >= torch.cuda.device_count():
            raise BrlInputError(f"--device {name}: torch sees {torch.cuda.device_count()} GPU(s)")
        return name
    raise BrlInputError(f"--device '{name}' is not a device; use auto, cpu, cuda or cuda:N")


def check_device_name(device: str, where: str = "device") -> None:
    """A device name a config may hold (`auto`, `cpu`, `cuda`, `cuda:N`; resolved before a run); BrlInputError
    otherwise."""
    d = str(device)
    if d not in DEVICE_CHOICES and not (d.startswith("cuda:") and d[5:].isdigit()):
        raise BrlInputError(f"{where} must be auto, cpu, cuda or cuda:N, not '{device}'")


def prepare_cuda_determinism() -> None:
    """Before CUDA work: cuBLAS's fixed workspace and torch's deterministic algorithms where CUDA has them."""
    import torch

    os.environ.setdefault("CUBLAS_WORKSPACE_CONFIG", ":4096:8")
    torch.use_deterministic_algorithms(True, warn_only=True)
    torch.backends.cudnn.benchmark = False
    warnings.filterwarnings("ignore", message=".*does not have a deterministic implementation.*")


def device_record(device: str) -> dict[str, Any]:
    """What a run's provenance says about its device: the name torch uses and, on CUDA, the GPU and CUDA version."""
    import torch

    record: dict[str, Any] = {"device": device}
    if device.startswith("cuda"):
        record.update(gpu=torch.cuda.get_device_name(torch.device(device)), cuda=torch.version.cuda)
    return record


def fits_on_device(n_bytes: int, device: str) -> bool:
    """Whether `n_bytes` of training data may stay resident on `device` (DEVICE_FRACTION of its free memory)."""
    import torch

    if not device.startswith("cuda"):
        return True
    free, _ = torch.cuda.mem_get_info(torch.device(device))
    return n_bytes <= DEVICE_FRACTION * free


def to_device_tensor(array: Any, device: str) -> Any:
    """A numpy array as a torch tensor on `device` (resident), or in pinned host memory when it does not fit (the
    batches then copy asynchronously)."""
    import torch

    t = torch.from_numpy(array)
    if device == "cpu":
        return t
    if fits_on_device(t.numel() * t.element_size(), device):
        return t.to(device)
    return t.pin_memory()
