"""Versioned torch model files: one dict of plain data and tensors, written atomically, read with weights_only."""

from __future__ import annotations

import io
from collections.abc import Sequence
from pathlib import Path
from typing import Any

import torch

from brlcli.errors import BrlInputError
from brlcli.provenance import atomic_write_bytes


def save_torch_doc(path: Path, fmt: str, version: int, payload: dict[str, Any]) -> None:
    """Write {'format', 'format_version', **payload} (plain data and tensors only) atomically."""
    buf = io.BytesIO()
    torch.save({"format": fmt, "format_version": version, **payload}, buf)
    atomic_write_bytes(Path(path), buf.getvalue())


def load_torch_doc(path: Path, fmt: str, version: int | tuple[int, ...], what: str, train_hint: str,
                   keys: Sequence[str] = ()) -> dict[str, Any]:
    """Read a model file without unpickling objects; check its format, version (one, or several readable ones)
    and required `keys`.

    `what` names the file in errors ("IL model"), `train_hint` says how to make one ("brl train-il").
    """
    versions = (version,) if isinstance(version, int) else tuple(version)
    path = Path(path)
    if not path.is_file():
        raise BrlInputError(f"{what} {path} does not exist; train one with {train_hint}")
    try:
        doc = torch.load(path, map_location="cpu", weights_only=True)
    except Exception:
        raise BrlInputError(f"{path} is not a brl {what} (not a torch file brl wrote); make one with "
                            f"{train_hint}") from None
    if not isinstance(doc, dict) or doc.get("format") != fmt:
        raise BrlInputError(f"{path} is not a brl {what}")
    if doc.get("format_version") not in versions:
        readable = " or ".join(str(v) for v in versions)
        raise BrlInputError(f"{what} {path} has format version {doc.get('format_version')}, this brl reads "
                            f"{readable}; make a new one with {train_hint}")
    for key in keys:
        if key not in doc:
            raise BrlInputError(f"{what} {path} lacks '{key}'")
    return doc
