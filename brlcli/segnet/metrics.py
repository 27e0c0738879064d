"""How good a segmentation net is for the agent: IoU per class and per state category, and the state error.

The agent never sees labels, only the 30-number state (area shares of 5 categories in 6 regions, road lines
weighted by 20). A net can score well on IoU and still bias every state, so next to IoU this reports what the
state needs: the mean L1 distance between the states of the ground-truth and the estimated labels, the bias of
each category's share (estimated - GT, summed over the six regions) and the estimated / GT pixel-area ratio of
each category (pooled over all frames, and the median over frames in which the category occurs).
"""

from __future__ import annotations

from typing import Any

import numpy as np

from brlcli.features import CLASS_TO_CATEGORY, N_CATEGORIES, N_REGIONS, category_counts, states_from_counts

NUM_CLASSES = 13
CATEGORY_NAMES = ("road", "road_line", "off_road", "dynamic", "static")


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


def _rounded(values: np.ndarray) -> list[float | None]:
    return [None if not np.isfinite(v) else round(float(v), 6) for v in values]


class SegMetrics:
    """Accumulates IoU and state-error figures over batches of (ground-truth, estimated) label images."""

    def __init__(self) -> None:
        self.cm = np.zeros((NUM_CLASSES, NUM_CLASSES), np.int64)
        self._l1: list[np.ndarray] = []
        self._bias: list[np.ndarray] = []
        self._gt_px: list[np.ndarray] = []
        self._est_px: list[np.ndarray] = []

    def add(self, truth: np.ndarray, pred: np.ndarray) -> None:
        """Add a batch of label images (N, H, W) in CARLA ids: truth and the net's prediction."""
        truth, pred = np.asarray(truth), np.asarray(pred)
        if truth.ndim == 2:
            truth, pred = truth[None], pred[None]
        self.cm += confusion(pred, truth, NUM_CLASSES)
        gt_counts, est_counts = category_counts(truth), category_counts(pred)
        gt_state, est_state = states_from_counts(gt_counts), states_from_counts(est_counts)
        self._l1.append(np.abs(est_state - gt_state).sum(1))
        self._bias.append((est_state - gt_state).reshape(-1, N_REGIONS, N_CATEGORIES).sum(1))
        self._gt_px.append(gt_counts.sum(1))
        self._est_px.append(est_counts.sum(1))

    @property
    def frames(self) -> int:
        """Number of frames added."""
        return sum(len(x) for x in self._l1)

    def state_l1(self) -> float:
        """Mean L1 distance between the GT and the estimated states."""
        return float(np.concatenate(self._l1).mean()) if self._l1 else float("nan")

    def result(self) -> dict[str, Any]:
        """IoU per class / category with their means, and the state error (see the module docstring)."""
        per_class = iou_from_confusion(self.cm)
        per_cat = iou_from_confusion(category_confusion(self.cm))
        out: dict[str, Any] = {
            "frames": self.frames,
            "miou_classes": float(np.nanmean(per_class)), "miou_categories": float(np.nanmean(per_cat)),
            "iou_classes": _rounded(per_class),
            "iou_categories": dict(zip(CATEGORY_NAMES, _rounded(per_cat), strict=True)),
        }
        if not self._l1:
            return out
        l1 = np.concatenate(self._l1)
        bias = np.concatenate(self._bias).mean(0)
        gt_px, est_px = np.concatenate(self._gt_px), np.concatenate(self._est_px)
        with np.errstate(invalid="ignore", divide="ignore"):
            pooled = est_px.sum(0) / gt_px.sum(0)
            per_frame = np.where(gt_px > 0, est_px / gt_px, np.nan)
        medians = np.array([np.nanmedian(col) if np.isfinite(col).any() else np.nan for col in per_frame.T])
        out.update({
            "state_l1": round(float(l1.mean()), 6),
            "state_l1_p95": round(float(np.quantile(l1, 0.95)), 6),
            "state_bias": dict(zip(CATEGORY_NAMES, _rounded(bias), strict=True)),
            "area_ratio": dict(zip(CATEGORY_NAMES, _rounded(pooled), strict=True)),
            "area_ratio_median": dict(zip(CATEGORY_NAMES, _rounded(medians), strict=True)),
        })
        return out
