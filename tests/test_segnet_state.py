"""What the state needs from the segmentation net: the state-error metric and the logit-offset calibration."""

import json
from pathlib import Path

import numpy as np
import pytest

from brlcli.features import state_vector
from brlcli.segnet.calibrate import fit_logit_offsets
from brlcli.segnet.io import load_segnet
from brlcli.segnet.metrics import SegMetrics
from brlcli.segnet.model import SegNetConfig
from brlcli.segnet.train import SegTrainConfig, train_segnet

ROAD, LINE, SIDEWALK, BUILDING = 7, 6, 8, 1


def _scene(line_width: int) -> np.ndarray:
    labels = np.full((20, 30), ROAD, np.uint8)
    labels[:8] = BUILDING
    labels[8:, :4] = SIDEWALK
    labels[8:, 14 : 14 + line_width] = LINE
    return labels


def test_state_error_figures_match_the_states_by_hand() -> None:
    gt, est = _scene(2), _scene(4)  # the net paints road lines twice as wide
    m = SegMetrics()
    m.add(np.stack([gt, gt]), np.stack([est, gt]))
    r = m.result()
    l1 = np.abs(state_vector(est) - state_vector(gt)).sum()
    assert r["frames"] == 2 and r["state_l1"] == pytest.approx(l1 / 2, abs=1e-6)
    bias = (state_vector(est) - state_vector(gt)).reshape(6, 5).sum(0) / 2
    assert r["state_bias"]["road_line"] == pytest.approx(bias[1], abs=1e-6) and bias[1] > 0
    assert r["state_bias"]["road"] == pytest.approx(bias[0], abs=1e-6) and bias[0] < 0
    assert r["area_ratio"]["road_line"] == pytest.approx(1.5)  # (24 + 12) / (12 + 12) pixels
    assert r["area_ratio_median"]["road_line"] == pytest.approx(1.5)
    assert r["area_ratio"]["dynamic"] is None  # no dynamic objects anywhere
    assert r["iou_categories"]["road_line"] == pytest.approx(24 / 36)


def test_calibration_undoes_a_known_logit_bias() -> None:
    rng = np.random.default_rng(0)
    true_logits = rng.normal(size=(6, 13, 16, 24)).astype(np.float32)
    true_logits[:, [ROAD, LINE]] += 1.0  # make the state's categories common
    labels = true_logits.argmax(1).astype(np.uint8)
    shift = np.zeros(13, np.float32)
    shift[LINE], shift[ROAD] = 1.5, -0.5  # a net that over-predicts road lines
    offsets = fit_logit_offsets(true_logits + shift[None, :, None, None], labels)
    assert offsets.shape == (13,) and abs(offsets.mean()) < 1e-9
    fitted = (true_logits + shift[None, :, None, None] + offsets[None, :, None, None].astype(np.float32)).argmax(1)
    before = SegMetrics()
    before.add(labels, (true_logits + shift[None, :, None, None]).argmax(1))
    after = SegMetrics()
    after.add(labels, fitted)
    assert before.state_l1() > 0.15 and after.state_l1() < 0.2 * before.state_l1()
    assert (offsets[LINE] - offsets[ROAD]) == pytest.approx(-2.0, abs=0.3)


def _stripes(n: int) -> list[tuple[np.ndarray, np.ndarray]]:
    rng = np.random.default_rng(3)
    out = []
    for _ in range(n):
        labels = np.zeros((32, 64), np.uint8)
        labels[10:16] = BUILDING
        labels[16:] = ROAD
        x = int(rng.integers(20, 40))
        labels[16:, x : x + 2] = LINE
        rgb = np.zeros((32, 64, 3), np.uint8)
        rgb[labels == BUILDING] = (150, 120, 100)
        rgb[labels == ROAD] = (80, 80, 85)
        rgb[labels == LINE] = (230, 220, 60)
        rgb[labels == 0] = (120, 170, 230)
        out.append((np.clip(rgb + rng.integers(-20, 20, rgb.shape), 0, 255).astype(np.uint8), labels))
    return out


def test_training_ends_with_a_calibrated_net_and_its_before_after_figures(tmp_path: Path) -> None:
    frames = _stripes(24)
    net = SegNetConfig(stem=8, widths=(8, 16, 16, 16), enc_channels=16, codewords=4, fine=8).to_dict()
    cfg = SegTrainConfig(epochs=2, batch_size=8, threads=1, net=net, select="state")
    result = train_segnet(frames[:16], {"val": frames[16:], "other": frames[:8]}, cfg, tmp_path)
    for name in ("best.pt", "last.pt", "segnet.pt", "calibration.json", "metrics.jsonl"):
        assert (tmp_path / name).is_file(), name
    _, meta = load_segnet(tmp_path / "segnet.pt")
    assert meta["logit_offsets"] is not None and meta["logit_offsets"].shape == (13,)
    record = json.loads((tmp_path / "calibration.json").read_text())
    assert record["fitted_on"] == "val" and record["frames"] == 8 and set(record["sets"]) == {"val", "other"}
    fit = record["sets"]["val"]
    assert fit["calibrated"]["state_l1"] <= fit["uncalibrated"]["state_l1"] + 1e-9
    assert result["calibration"] == record
    epochs = [json.loads(line) for line in (tmp_path / "metrics.jsonl").read_text().splitlines()]
    assert all("state_l1" in e["val"] and "area_ratio" in e["other"] for e in epochs)
    # a resumed, finished run keeps its calibration
    again = train_segnet(frames[:16], {"val": frames[16:], "other": frames[:8]}, cfg, tmp_path, resume=True)
    assert again["calibration"] == record
