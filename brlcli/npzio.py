"""Byte-reproducible `.npz` files: the same arrays always give the same bytes (no zip timestamps)."""

from __future__ import annotations

import io
import zipfile
from pathlib import Path

import numpy as np

from brlcli.provenance import atomic_write_bytes

_EPOCH = (1980, 1, 1, 0, 0, 0)


def npz_bytes(arrays: dict[str, np.ndarray], compress: bool = False) -> bytes:
    """A .npz archive of `arrays` (readable by `np.load(allow_pickle=False)`), fixed timestamps, optionally deflated."""
    buf = io.BytesIO()
    method = zipfile.ZIP_DEFLATED if compress else zipfile.ZIP_STORED
    with zipfile.ZipFile(buf, "w", compression=method) as zf:
        for name, value in arrays.items():
            arr = np.asarray(value)
            if arr.dtype == object:
                raise ValueError(f"array '{name}' has dtype object; npz files here never hold pickles")
            member = io.BytesIO()
            np.lib.format.write_array(member, arr, allow_pickle=False)
            info = zipfile.ZipInfo(f"{name}.npy", date_time=_EPOCH)
            info.external_attr = 0o644 << 16
            info.compress_type = method
            zf.writestr(info, member.getvalue())
    return buf.getvalue()


def save_npz(path: str | Path, arrays: dict[str, np.ndarray], compress: bool = False) -> None:
    """Write a byte-reproducible .npz atomically (temporary file, then rename)."""
    atomic_write_bytes(Path(path), npz_bytes(arrays, compress))
